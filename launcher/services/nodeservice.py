"""A run's nodes as one service: the fleet, the local supervisor, the health checks, the remote parent and the output-log rotation, started and stopped together.

What the launch's API server steers (`control`: start, stop, restart one
node, here or on another machine) and reads (`spec`, `package_of`) goes
through this service too, so that the server sees the nodes, not the run.
"""

from __future__ import annotations

import asyncio
import os
import sys
from typing import TYPE_CHECKING, Any, Callable, Mapping

from launcher import compat
from launcher.net.hostname import advertised_host
from launcher.model.config import LaunchConfig
from launcher.plan.specs import node_specs, packages_of
from launcher.output import console, screen
from launcher.process.coredumps import CoreDumpReporter
from launcher.health.hang import HangDetector
from launcher.health.stall import StallWatch
from launcher.output.logrotate import LogRotator
from launcher.health.readiness import Readiness
from launcher.health.registration import Registrations
from launcher.model.graph import Graph
from launcher.health.resources import DEFAULT_PERIOD_S, ResourceMonitor
from launcher.plan.specs import ProcessSpec
from launcher.fleet import launchphase
from launcher.fleet.state import EVENTS_FILE, Fleet
from launcher.process.supervisor import Supervisor
from launcher.services import runrecord
from launcher.model.runopts import RunOptions

if TYPE_CHECKING:  # (annotations only; the remote machinery is imported where a node runs on another machine)
    from launcher.plan.diff import Difference  # (a reload's: run/reload.py imports it when one comes)
    from launcher.plan.plan import Plan
    from launcher.process.watchdog import Watchdog
    from launcher.services.service import Signals
    from launcher.output.runlog import RunLog
    from launcher.remote.parent import RemoteParent


def _short_repr(value: Any, limit: int = 200) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[:limit] + "... (%d characters)" % len(text)


class NodeService:
    """Every node of one run. `prepare` starts the other machines' children (they connect while the run
    sets up its master), `start` spawns this machine's nodes and hands the others to their children,
    `stop` stops them all (the machines while this one stops its own) and writes the launch's end."""

    def __init__(self, opts: RunOptions, plan: Plan, log: RunLog, signals: Signals, watchdog: Watchdog | None,
                 end_reason: Callable[[], str]):
        self.opts = opts
        self.plan = plan
        self.log = log  # where the launch log is, what it notes
        self.signals = signals
        self.watchdog = watchdog
        self.end_reason = end_reason  # why the run ends, in words (the events file's last line)
        self.remote: RemoteParent | None = None  # when nodes run on other machines
        self.supervisor: Supervisor | None = None
        self.fleet: Fleet | None = None  # every node's state (fleet/state.py)
        self.made = compat.Event()  # set once `start` has made the fleet and its nodes (what a view waits for)
        self.rotator: LogRotator | None = None  # node output logs under --log-max-size
        self.registrations: Registrations | None = None  # the master's registrations told as the nodes'
        self.processes = 0  # the local nodes numbered by `start` (roslaunch numbers each process)
        self.first_number = 0  # the processes numbered before the nodes (rosout-1)
        self._packages: dict[str, str] = {}  # process name -> package, for process_info
        self._tasks: list[asyncio.Future] = []
        self._health: list[Any] = []  # readiness and hang detection, closed before the nodes are stopped
        self.stall: StallWatch | None = None  # the watched topics (launch --metrics reads their rates)

    # ---- start -----------------------------------------------------------------------------------------

    async def prepare(self, run_id: str, master_uri: str, parent_uri: str) -> None:
        """The other machines' children, started on their own tasks; they get their nodes at `start`."""
        if self.opts.local:
            # roslaunch's words (ROSLaunchParent._init_remote), whether or not a node is remote
            console.printlog_bold("LOCAL\nlocal only launch specified, will not launch remote nodes\nLOCAL\n")
            return
        by_machine = self.plan.remote_nodes()
        if not by_machine:
            return
        # (the remote machinery is imported only by a launch with other machines' nodes)
        from launcher.remote.parent import RemoteParent
        self.remote = RemoteParent(by_machine, self.plan.config.machines, run_id=run_id,
                                   master_uri=master_uri, host=advertised_host(self.plan.environ),
                                   environ=self.plan.environ, watchdog=self.watchdog, sigint_timeout=self.opts.sigint_timeout,
                                   sigterm_timeout=self.opts.sigterm_timeout)
        await self.remote.start(parent_uri)

    def start(self, master_uri: str, first_number: int, *, exit_when_all_dead: bool, graph: Graph,
              external: bool = False) -> None:
        """Spawn every node in order, each supervised from its start. `graph`: what is registered with the
        master (ours tells it; a master found running, `external`, is asked by its watcher).

        Every command line is worked out first: once nodes run, each competes with the
        launcher for the CPU (on 2 cores, 100 starting roscpp nodes leave it a few percent),
        so the loop that spawns them does as little as possible.
        """
        self.signals.check()
        self.first_number = first_number
        plan = self.plan
        specs, failed = node_specs(plan.config, plan.master_uri, self.node_environ(), plan.packages, plan.remote,
                                   opts=self.opts, run_dir=self.log.run_dir, first_number=first_number,
                                   log=console.printlog, log_error=console.printerrlog)
        self.processes = len(specs) + len(failed)
        self._note_launch(specs)
        self.fleet = Fleet(os.path.join(self.log.run_dir, EVENTS_FILE) if self.log.run_dir else None,
                           warn=console.printerrlog)
        self.fleet.listeners.append(self.log.state_change)
        self.fleet.relate(plan.relations)
        self.fleet.start_failure_ends_the_launch()
        self.supervisor = Supervisor(sigint_timeout=self.opts.sigint_timeout,
                                     sigterm_timeout=self.opts.sigterm_timeout,
                                     exit_when_all_dead=exit_when_all_dead, watchdog=self.watchdog, fleet=self.fleet)
        self.signals.on_signal = self._stop_signal  # (the launch's phase says what a stop signal means from now on)
        self._watch_health(master_uri, graph, external)
        self._packages = packages_of(self.plan.config, specs)
        if self.remote is not None:
            self.remote.attach(self.fleet, graph)
        stop = self.signals.event
        no_start = self.opts.no_start
        for spec in specs:
            if stop.is_set() or not self.fleet.starts_allowed:  # (a stop signal; a node that ended the launch)
                break
            if no_start:
                self.supervisor.add(spec)  # started later by `launcher start`
            else:
                self.supervisor.start(spec)
        for name, required in failed:
            self.supervisor.not_started(name, required)
        self.supervisor.registrations_complete()
        self.made.set()
        self.rotator = LogRotator(self.plan.log_max_size, self.opts.log_backups, self.log.note)
        for spec in specs:
            if spec.stdout_path:
                self.rotator.watch(spec.stdout_path, spec.policy.log_max_size, spec.policy.log_backups)
        self.rotator.start()
        self._write_record()

    def _write_record(self) -> None:
        """The run's record and parameters into its log directory (services/runrecord.py): at once when the
        parameters' text came made with the plan (run/apart.py: two small files), else in a worker thread (the
        YAML of thousands of parameters must not hold the loop). A thread costs a launch ~0.1 MB for good."""
        run_dir = self.log.run_dir
        if not run_dir:
            return
        run = runrecord.record(self.plan.config, os.path.basename(run_dir), self.plan.environ, self._packages, sys.argv)

        def written(problem: str) -> None:
            if problem:
                console.printerrlog("WARNING: %s (launcher report will miss it)" % problem)
        if self.plan.params_text is not None:
            written(runrecord.write(run_dir, run, self.plan.config, self.plan.params_text))
            return
        task = asyncio.get_running_loop().run_in_executor(None, runrecord.write, run_dir, run, self.plan.config)
        task.add_done_callback(lambda done: written(done.result() if not done.cancelled() and done.exception() is None
                                                    else str(done.exception())))

    def node_environ(self) -> Mapping[str, str]:
        """The nodes' environment: the launch's, and the path of its log file in ROS_LOG_FILENAME, as roslaunch's
        nodes inherit it (rosgraph's logging sets it in roslaunch's own environment; a rospy node sets its own)."""
        if not self.log.path:
            return self.plan.environ
        return dict(self.plan.environ, ROS_LOG_FILENAME=self.log.path)

    def _note_launch(self, specs: list[ProcessSpec]) -> None:
        """What this run is, for the launch log: files, args, environment, parameters, command lines."""
        note = self.log.note
        note("launch files: %s" % " ".join(self.plan.config.files or ("(none)",)))
        note("command line: %s" % " ".join(sys.argv))
        note("ROS environment: %s" % ", ".join("%s=%s" % (k, v) for k, v in sorted(self.plan.environ.items())
                                              if k.startswith("ROS_") or k == "CMAKE_PREFIX_PATH"))
        for key, param in sorted(self.plan.config.params.items()):
            note("param %s = %s" % (key, _short_repr(param.value)))
        for spec in specs:
            cmd = spec.command
            note("node [%s] (process %s): %s%s" % (spec.node_name, spec.name, cmd.format_args(),
                                                   " (cwd %s)" % cmd.cwd if cmd.cwd else ""))

    def _watch_health(self, master_uri: str, graph: Graph, external: bool) -> None:
        """The nodes' registrations, wait_for holds, hang probes, stalled-topic watches, core dump reports, and
        the resource sampling of every node."""
        sup = self.supervisor
        self.registrations = Registrations(graph, self.fleet, verify=external)
        sup.readiness = Readiness(master_uri, sup, graph, self.fleet)
        hang = HangDetector(sup)
        stall = self.stall = StallWatch(sup)
        sup.watchers += [hang, stall, CoreDumpReporter()]
        self._health += [self.registrations, sup.readiness, hang, stall]
        monitor = ResourceMonitor(sup, self.opts.monitor_period or DEFAULT_PERIOD_S)
        self._tasks.append(asyncio.ensure_future(monitor.run()))

    # ---- the run's end ---------------------------------------------------------------------------------

    @property
    def done(self) -> asyncio.Event | None:
        """Set when the nodes end the launch (a required node, all dead with a master not ours)."""
        return self.supervisor.done if self.supervisor is not None else None

    @property
    def exit_status(self) -> int:
        return self.supervisor.exit_status if self.supervisor is not None else 0

    def _stop_signal(self) -> None:
        """A stop signal, as the launch's phase takes it: the launch is to end (the run's body waits for the
        signal itself); while its nodes are being stopped, KILL_ALL."""
        for action in self.fleet.launch_step(launchphase.STOP_SIGNAL):
            if action.kind == launchphase.KILL_ALL:
                self._kill_now()

    def _kill_now(self) -> None:
        """A stop signal while nodes are being stopped: kill what is left, and say so."""
        killed = self.supervisor.kill_now() if self.supervisor is not None else []
        if killed:
            console.printerrlog("second stop signal: killing %d node(s) still stopping with SIGKILL: %s"
                                % (len(killed), ", ".join(killed)))

    async def stop(self) -> None:
        for t in self._tasks:
            t.cancel()
        if self.rotator is not None:
            self.rotator.close()
        for h in self._health:
            h.close()
        # (the diagnostics publisher, which reads the fleet, is stopped before this)
        # the launch's phase: its nodes are stopped now (STOP_ALL); with no fleet yet (a stop signal during the
        # start-up) only the other machines' children, started at `prepare`, are there to stop
        fleet = self.fleet
        if fleet is None or any(a.kind == launchphase.STOP_ALL for a in fleet.launch_step(launchphase.STOP)):
            stops = [self.remote.shutdown()] if self.remote is not None else []
            if self.supervisor is not None:
                stops.append(self.supervisor.shutdown())
            await asyncio.gather(*stops)  # the machines stop their nodes while this one stops its own
            if fleet is not None:
                fleet.launch_step(launchphase.ALL_STOPPED)
        if self.supervisor is not None:
            self.supervisor.close()
        relayed = screen.relay_note()
        if relayed is not None:  # (which way the terminal-bound output went: benchmarks/screen_flood.py reads it)
            self.log.note(relayed)
        if self.fleet is not None:
            self.fleet.launch_ended(self.end_reason(), self.exit_status)
            self.fleet.close()

    # ---- a reload ------------------------------------------------------------------------------------

    async def reload(self, diff: Difference, plan: Plan) -> None:
        """Apply a reload's difference (plan/diff) to this machine's nodes, `plan` being the new one: the
        changed and removed nodes are stopped together, then the changed ones start anew and the new ones
        start, in the launch's order; supervision-only changes apply where each node stands. (The other
        machines' nodes: refused before this, run/reload.py.)"""
        if self.supervisor is None:
            return
        await asyncio.gather(self._reload_here(diff, plan), self._reload_remote(diff, plan))
        self.plan = plan
        self._write_record()  # (the parameters the launch set are now the reloaded files')

    async def _reload_remote(self, diff: Difference, plan: Plan) -> None:
        """The other machines' part (remote.parent: the operator's stop and start calls)."""
        remote = self.remote
        if remote is None:
            return
        was = set(remote.node_names())
        now = {n.full_name: n for n in plan.config.nodes if plan.remote(n)}
        refusals = await remote.reload(
            stop={c.name: c.why for c in diff.stop if c.name in was},
            renew={c.name: (now[c.name], c.why) for c in diff.restart if c.name in was and c.name in now},
            start=[now[c.name] for c in diff.start if c.name in now],
            rules={c.name: (now[c.name], c.why) for c in diff.supervise if c.name in now},
            machines=plan.config.machines)
        for refusal in refusals:  # (checked before the reload began: a child that changed its mind since)
            console.printerrlog("reload: %s" % refusal)

    async def _reload_here(self, diff: Difference, plan: Plan) -> None:
        supervisor = self.supervisor
        restart = {c.name: c.why for c in diff.restart}
        start = {c.name: c.why for c in diff.start}
        supervise = {c.name: c.why for c in diff.supervise}
        stopping = [supervisor.reload_stop(c.name, "reload: " + c.why) for c in diff.stop + diff.restart]
        await asyncio.gather(*(s for s in stopping if s is not None))
        for c in diff.stop:
            supervisor.remove(c.name)
        supervisor.fleet.relate(plan.relations)  # (the new plan's, before its nodes start or change rules)
        kept = {name: proc.spec.name for name in list(restart) + list(supervise)
                if (proc := supervisor.node(name)) is not None}
        nodes = tuple(n for n in plan.config.nodes if n.full_name in restart or n.full_name in start
                      or n.full_name in supervise)
        specs, failed = node_specs(LaunchConfig(nodes=nodes), plan.master_uri, self.node_environ(), plan.packages,
                                   plan.remote, opts=self.opts, run_dir=self.log.run_dir,
                                   first_number=self.first_number + self.processes,
                                   process_names=kept, log=console.printlog, log_error=console.printerrlog)
        self.processes += len([s for s in specs if s.node_name in start]) + len(failed)
        self._packages.update(packages_of(plan.config, specs))
        for spec in specs:  # (in the launch's order)
            name = spec.node_name
            if name in supervise:
                supervisor.new_rules(spec, "reload: " + supervise[name])
            elif name in restart:
                supervisor.renew(spec, "reload: " + restart[name])
            else:
                supervisor.start(spec)
                if spec.stdout_path and self.rotator is not None:
                    self.rotator.watch(spec.stdout_path, spec.policy.log_max_size, spec.policy.log_backups)
        for name, required in failed:  # (checked before: a command that cannot be made refuses the reload)
            supervisor.not_started(name, required)
        if self.rotator is not None:
            self.rotator.start()

    # ---- what the launch's API server steers and reads -------------------------------------------------

    def spec(self, node_name: str) -> ProcessSpec | None:
        """The process spec of a local node (its command line, log files), None for a remote one."""
        proc = self.supervisor.node(node_name) if self.supervisor is not None else None
        return proc.spec if proc is not None else None

    def package_of(self, process_name: str) -> str:
        return self._packages.get(process_name, "")

    def remote_names(self) -> list[str]:
        """The nodes of other machines (launcher.remote.parent steers them), once the nodes are started."""
        return self.remote.node_names() if self.remote is not None and self.supervisor is not None else []

    def parent_calls(self) -> tuple[str, ...]:
        """The calls only a child on another machine makes (to its parent: this launch's server)."""
        return self.remote.PARENT_CALLS if self.remote is not None else ()

    def parent_call(self, method: str, params: list) -> Any:
        return self.remote.parent_call(method, params)

    async def control(self, verb: str, name: str, remote: bool) -> str:
        """Start, stop or restart one node (`remote`: a node of another machine); '' or why not."""
        if remote:
            if verb == "start":
                return self.remote.start_node(name)
            return await (self.remote.stop_node(name) if verb == "stop" else self.remote.restart_node(name))
        supervisor = self.supervisor
        if verb == "start":
            supervisor.start_node(name)
        elif verb == "stop":
            stopping = supervisor.stop_node(name)
            if stopping is not None:
                await stopping
        else:
            await supervisor.restart_node(name)
        return ""
