"""Running a launch on one asyncio loop: master (found or ours), log, rosout, parameters, supervised nodes, shutdown.

There is one path. `launch --core` is a run of an empty launch whose master
must be ours (roscore's words and output); `launch file.launch` uses a
master that already answers at the master URI, else starts ours. Here:

- the plan (`plan.plan.Plan`, made by `run.load`): the loaded launch and its
  checks (no socket, no process), which machines are other hosts;
- `StopSignals`: SIGINT/SIGTERM/SIGHUP for the whole run, installed on the
  loop before anything starts;
- `Run`: the run's services (`masterlink.MasterSession`, `servers`,
  `nodeservice.NodeService`), started as one list of steps in roslaunch's
  order of lines (`Run._steps`), stopped in reverse.
"""

from __future__ import annotations

import asyncio
import gc
import os
import signal
import sys
import time
from typing import TYPE_CHECKING, Any, Awaitable, Callable, Coroutine, Iterator

from launcher import compat
from launcher.model.record import record
from launcher.services import masterlink
from launcher.model.errors import LaunchError
from launcher.services.masterlink import MasterSession
from launcher.services.masterwatch import MasterWatch
from launcher.net.open_files import raise_open_file_limit
from launcher.services.nodeservice import NodeService
from launcher.services.service import Service
from launcher.plan.plan import Plan
from launcher.run.apart import Apart
from launcher.run.load import begin_plan, core_plan
from launcher.output import console
from launcher.fleet import launchphase, lifecycle
from launcher.fleet.state import Change
from launcher.process.reaper import Reaper, become_subreaper
from launcher.process.watchdog import Watchdog
from launcher.output.runlog import RunLog, summary
from launcher.model.runopts import RunOptions
from launcher.services.servers import ApiServer, DiagnosticsService, LogDiskCheck, RosoutService, RunView

if TYPE_CHECKING:  # (annotations only: each is imported where a reload or a scrape first needs it)
    from launcher.run.reload import Reloader
    from launcher.services.metrics import Exporter, MetricsServer
    from launcher.services.systemd import Notifier

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


@record
class Step:
    """One step of a run's start (`Run._steps`)."""

    service: Service | None  # the service it starts (the run's stop stops it), or None: a step of one already up
    run: Callable[[], Awaitable[Any] | None]  # what it does; an awaitable it returns is awaited
    guarded: bool = True  # what it awaits is abandoned at a stop signal (Stopped)


class Stopped(Exception):
    """A stop signal arrived while the run was starting."""


def run(opts: RunOptions, reading: Apart | None = None, *, exit_process: bool = False) -> int:
    """`launch [pkg] file.launch ...` or `launch --core`: run until a stop signal, a `shutdown` call, a
    required node's exit, or (with a master already running) every node's exit; the exit status.

    `reading`: the plan's making, begun already (`load.begin_plan`: `launch` begins it before it imports
    this module); else it begins here.

    With `exit_process` (the `launch` command itself), the process ends here
    once everything is stopped and flushed, skipping the interpreter's
    tear-down (tens of ms that a user waiting for the prompt would notice).
    """
    core = opts.core
    # The guard is started first, so that no node can ever run unwatched (a core runs none).
    watchdog = None if core else Watchdog.start()
    pid_fn = opts.pid_fn
    try:
        if pid_fn:
            try:
                with open(pid_fn, "w") as f:
                    f.write(str(os.getpid()))
            except OSError as e:
                raise LaunchError("cannot write pid file [%s]: %s" % (pid_fn, e.strerror)) from None
        raise_open_file_limit()  # every client of the master and the rosout node is a file
        plan = core_plan(opts) if core else (reading or begin_plan(opts)).result()
        status = asyncio.run(Run(opts, plan, watchdog).main())
    finally:
        if watchdog is not None:
            watchdog.close()
        if pid_fn:
            try:
                os.unlink(pid_fn)
            except OSError:
                pass
    if exit_process:
        console.flush()
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError):
                pass
        os._exit(status)
    return status


class StopSignals:
    """SIGINT, SIGTERM and SIGHUP for the whole run: each sets `event`, which ends the run."""

    def __init__(self) -> None:
        self.loop: asyncio.AbstractEventLoop | None = None
        self.event = compat.Event()  # (bound to the loop that first waits on it)
        # told of each stop signal once the launch's nodes exist: the launch's phase (fleet.launchphase) says
        # what it means (while its nodes are being stopped, "now": the second Ctrl-C)
        self.on_signal: Callable[[], None] | None = None
        self.received = ""  # the first stop signal's name

    def install(self, loop: asyncio.AbstractEventLoop) -> None:
        """On the run's loop, before anything starts."""
        self.loop = loop
        for sig in STOP_SIGNALS:
            loop.add_signal_handler(sig, self._on_signal, sig)

    def _on_signal(self, sig: int = 0) -> None:
        if not self.received and sig:
            self.received = signal.Signals(sig).name
        if self.on_signal is not None:
            self.on_signal()
        self.event.set()

    def check(self) -> None:
        if self.event.is_set():
            raise Stopped()

    async def guard(self, step: Coroutine[Any, Any, Any]) -> Any:
        """Await a start-up step, or raise Stopped as soon as a stop signal arrives (the step is cancelled)."""
        if self.event.is_set():
            step.close()  # (never begun: closed, or Python would warn at exit that it was never awaited)
            raise Stopped()
        task = asyncio.ensure_future(step)
        stop = asyncio.ensure_future(self.event.wait())
        await asyncio.wait((task, stop), return_when=asyncio.FIRST_COMPLETED)
        if task.done():
            stop.cancel()
            return task.result()
        task.cancel()
        try:
            await task
        except BaseException:  # noqa: BLE001 - the step was abandoned; its outcome no longer matters
            pass
        raise Stopped()

    def close(self) -> None:
        if self.loop is not None:
            for sig in STOP_SIGNALS:
                self.loop.remove_signal_handler(sig)


class Run:
    """One run on the running loop: its services, started as one list of steps and stopped in reverse.

    The services: the master session (`masterlink.MasterSession`), roslaunch's
    API server, rosout, the nodes (`nodeservice.NodeService`), /diagnostics and
    the log-disk check (`servers`). The start (`_steps`, one list) keeps
    roslaunch's order of lines, so two services start in several steps: the
    master session is found first (its run id names the log), started after
    the summary and given the parameters once rosout is up; the node service's
    `prepare` starts the other machines' children right after the API server
    (they call it). A front-end that runs differently
    (rostest) gives its own master session (a class), False for a server it does
    not run, and its own `body` (what the run does between its start and stop).
    """

    def __init__(self, opts: RunOptions, plan: Plan, watchdog: Watchdog | None = None, *,
                 master: Callable[..., MasterSession] = MasterSession, rosout: bool = True,
                 diagnostics: bool = True, log_disk: bool = True, body: Callable[[Run], Awaitable[None]] | None = None,
                 first_number: int = 0, reap_orphans: bool = True):
        self.opts = opts
        self.plan = plan
        self.watchdog = watchdog
        self.core = plan.core
        self.signals = StopSignals()
        self.log = RunLog(plan.environ)
        env = plan.environ
        self.master = master(opts, plan, self.signals)
        self.nodes = NodeService(opts, plan, self.log, self.signals, watchdog, self._end_reason)
        self.rosout = RosoutService(self.master, self.log, env) if rosout else None
        self.view = RunView(self.master, self.nodes, self.log, self.rosout, plan.config.files)
        self.api = ApiServer(self.view, self.master, env)
        self._reloader: Reloader | None = None
        if not self.core and plan.files:
            self.view.reload = self._reload
        # the run's metrics: read by a scrape of `--metrics`, or through the API server (the web page's /metrics)
        self.view.metrics_of = self._metrics_exporter
        self.metrics: MetricsServer | None = None
        if opts.metrics:
            from launcher.services.metrics import MetricsServer
            self.metrics = MetricsServer(self.view.metrics, opts.metrics)
        self.diagnostics = (DiagnosticsService(self.master, self.nodes, env)
                            if diagnostics and not self.core and not opts.no_diagnostics else None)
        self.log_disk = (LogDiskCheck(env, plan.log_threshold)
                         if log_disk and not self.core and not opts.skip_log_check else None)
        self.body = body if body is not None else Run.wait_for_the_end
        self.first_number = first_number  # roslaunch numbers processes (rosout-1, then the nodes)
        self._started = time.monotonic()  # (the launch log's timings count from here)
        self._up: list[Service] = []  # the services started (or starting)
        # READY=1, STATUS=, WATCHDOG=1, STOPPING=1 to systemd when run as a service ($NOTIFY_SOCKET)
        self.notifier: Notifier | None = None
        if os.environ.get("NOTIFY_SOCKET"):  # (the notify protocol's module is imported only under systemd)
            from launcher.services.systemd import Notifier
            self.notifier = Notifier.from_environ(warn=console.printerrlog, ready_timeout=opts.ready_timeout)
        # orphans re-parented to the launch are reaped (process/reaper.py); a front-end that waits for a
        # child of its own (rostest's test node: its exit status is the test's result) says False
        self.reap_orphans = reap_orphans
        self.reaper: Reaper | None = None
        self.master_watch: MasterWatch | None = None  # a master found running: its restarts (services/masterwatch)

    @property
    def services(self) -> list[Service]:
        """In start order; each has `start()` and `stop()` (the stop undoes what a start did, if anything)."""
        return [s for s in (self.master, self.api, self.rosout, self.nodes, self.master_watch, self.diagnostics,
                            self.log_disk, self.metrics) if s is not None]  # (rosout outlives the nodes: their last words reach its log)

    @property
    def process_count(self) -> int:
        """The processes numbered so far: rosout's, then the nodes'."""
        return self.first_number + (self.rosout.processes if self.rosout is not None else 0) + self.nodes.processes

    async def main(self) -> int:
        self.signals.install(asyncio.get_running_loop())
        if self.notifier is not None:
            self.notifier.start_watchdog()
        if self.reap_orphans and (os.getpid() == 1 or become_subreaper()):
            self.reaper = Reaper(asyncio.get_running_loop(), self._own_pids)
        try:
            await self._start()
            await self.body(self)
        except Stopped:
            pass
        finally:
            gc.unfreeze()  # (a process that runs again, as `launcher test` does, collects this run's cycles)
            if self.notifier is not None:
                self.notifier.stopping()
            for service in reversed(self.services):
                if service in self._up:
                    await service.stop()
            if self.reaper is not None:
                await self.reaper.stop_orphans()  # a node's daemonized grandchildren, re-parented to us
                self.reaper.close()
            if self.notifier is not None:
                self.notifier.close()
            self._done()
            self.signals.close()
        return self.nodes.exit_status

    async def _start(self) -> None:
        """Each step of `_steps` in turn: its service counted as up first (a stop undoes a start begun), and what
        it awaits abandoned at a stop signal unless the step says otherwise."""
        for service, step, guarded in self._steps():
            if service is not None and service not in self._up:
                self._up.append(service)
            begun = step()
            if begun is not None:
                await (self.signals.guard(begun) if guarded else begun)

    def _steps(self) -> Iterator[Step]:
        """The run's start as one list, in roslaunch's order of lines: (the service a step starts, or None; the
        step; whether a stop signal abandons what it awaits). A generator: a step's condition may depend on what
        the steps before it found (a master found running gets a watch)."""
        master, nodes = self.master, self.nodes
        yield Step(master, master.find)  # (a core starts its master here: a busy port is all it has to say)
        yield Step(None, self._open_log)
        yield Step(self.api, self.api.start)
        if self.core:
            yield Step(None, self._say_version)
        else:  # the other machines' children are started now: they call the API server
            yield Step(nodes, self._prepare_nodes, guarded=False)
        if not self.opts.no_summary:
            yield Step(None, self._say_summary)
        yield Step(None, self._start_master, guarded=False)
        yield Step(None, self.api.register)
        if self.rosout is not None:
            yield Step(self.rosout, self.rosout.start)
        yield Step(None, self._note_master)
        yield Step(None, master.set_parameters)
        yield Step(None, self._note_parameters)
        yield Step(nodes, self._start_nodes)
        if master.external:
            self.master_watch = MasterWatch(master, nodes)
            yield Step(self.master_watch, self.master_watch.start)
        for service in (self.diagnostics, self.log_disk, self.metrics):
            if service is not None:
                yield Step(service, service.start)
        yield Step(None, self._started_all)

    def _open_log(self) -> None:
        self.log.open(self.master.run_id)  # (roscore too logs to roslaunch-<host>-<pid>.log, and says so first)
        if self.core:
            self.master.open_log(self.log.run_dir)  # (clients may call the master already)

    def _prepare_nodes(self) -> Awaitable[None]:
        return self.nodes.prepare(self.master.run_id, self.master.uri, self.api.uri)

    def _start_master(self) -> Awaitable[None]:
        return self.master.start(self.log.run_dir)

    def _note_master(self) -> None:
        master = self.master
        self.log.timing(self._started, "master %s at %s" % ("found" if master.external else "started", master.uri))

    def _note_parameters(self) -> None:
        self.log.timing(self._started, "%d parameters set" % len(self.plan.config.params))

    def _say_version(self) -> None:
        console.printlog("ros_comm version %s" % masterlink.ros_version_params(self.plan.environ)[0].strip())

    def _say_summary(self) -> None:
        console.printlog(summary(self.plan.config, self.master.summary_params(), remote=self.plan.remote,
                                 machines=self.nodes.remote is not None))

    def _start_nodes(self) -> None:
        master, nodes = self.master, self.nodes
        first = self.first_number + (self.rosout.processes if self.rosout is not None else 0)
        nodes.start(master.uri, first, exit_when_all_dead=master.external, graph=master.graph,
                    external=master.external)
        if master.master is not None:  # (ours: what a node that ended registered goes with it)
            nodes.fleet.listeners.append(self._process_ended)
        if self.notifier is not None:
            self.notifier.attach(nodes.fleet)

    def _started_all(self) -> None:
        self.log.timing(self._started, "every node started")
        # What start-up made (the loaded launch, the modules, the master's tables) lives as long as the run:
        # out of the cyclic collector's way, a full collection no longer scans it. With 1,000 callbacks in
        # flight, the master's slowest other call went from 20-38 ms to 6-14 ms (benchmarks/hung_subscribers.py).
        gc.freeze()

    def _own_pids(self) -> list[int]:
        """The children whose exits their runners wait for (the reaper leaves them alone)."""
        fleet, remote = self.nodes.fleet, self.nodes.remote
        pids = [r.pid for r in fleet.records.values() if r.pid] if fleet is not None else []
        if remote is not None:  # each machine's ssh (a session of its own, waited for by asyncio)
            pids += [c.ssh.pid for c in remote.children.values() if c.ssh is not None]
        return pids + ([self.watchdog.pid] if self.watchdog is not None else [])

    def _process_ended(self, change: Change) -> None:
        """A fleet listener: a node's process ended (here, or on another machine as its child told), and what
        it registered on our master goes (master.process_ended checks that no new run took its name)."""
        if change.event.kind in (lifecycle.PROCESS_EXITED, lifecycle.DOWN) and change.old.pid:
            self.master.master.process_ended(change.new.name, change.old.pid)

    async def wait_for_the_end(self) -> None:
        """A launch's body: until a stop signal, the nodes' end (a required node...) or a `shutdown` call."""
        self.signals.check()
        waiters = [asyncio.ensure_future(self.signals.event.wait()),
                   asyncio.ensure_future(self.nodes.done.wait())]
        shutdown = self.master.shutdown_requested
        if shutdown is not None:
            waiters.append(asyncio.ensure_future(shutdown.wait()))
        await asyncio.wait(waiters, return_when=asyncio.FIRST_COMPLETED)
        for w in waiters:
            w.cancel()
        if shutdown is not None and shutdown.is_set():
            console.printlog("shutdown request: %s" % self.master.master.shutdown_reason)

    async def _reload(self, given: list[str], dry_run: bool) -> dict:
        if self._reloader is None:
            # here, at the first reload: it and plan/diff are ~80 kB of a launch's memory a run without one keeps
            from launcher.run.reload import Reloader
            self._reloader = Reloader(self)
        return await self._reloader.reload(given, dry_run)

    def _metrics_exporter(self) -> Exporter:
        from launcher.services.metrics import Exporter  # (at the first scrape: a run nobody scrapes never imports it)
        return Exporter(self.master, self.nodes, lambda: self.master.run_id or "")

    def _end_reason(self) -> str:
        """Why the run ends, in words (the events file's last line, which `launcher status` reads after it)."""
        if self.signals.received:
            return "stopped by %s" % self.signals.received
        shutdown = self.master.shutdown_requested
        if shutdown is not None and shutdown.is_set():
            return "shutdown request: %s" % self.master.master.shutdown_reason
        done = self.nodes.done
        if done is not None and done.is_set():
            return self._launch_reason() or "its nodes ended it (exit status %d)" % self.nodes.exit_status
        return "ended"

    def _launch_reason(self) -> str:
        """roslaunch's words for an end its nodes made by all dying or by having no process, else ""."""
        fleet = self.nodes.fleet
        return fleet.launch.reason if fleet is not None else ""

    def _done(self) -> None:
        """roslaunch's last lines, then the launch log closed."""
        if self.core:
            if self.master.master is not None:
                console.printlog("done")
        else:
            console.printlog("shutting down processing monitor...")
            console.printlog("... shutting down processing monitor complete")
            if self._launch_reason() != launchphase.NO_PROCESSES_TEXT:  # (roslaunch returns before its "done" then)
                console.printlog_bold("done")
        self.log.close()
        sys.stdout.flush()
