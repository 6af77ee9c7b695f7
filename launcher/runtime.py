"""Running a launch on one asyncio loop: master (found or ours), log, rosout, parameters, supervised nodes, shutdown.

There is one path. `launch --core` is a run of an empty launch whose master
must be ours (roscore's words and output); `launch file.launch` uses a
master that already answers at the master URI, else starts ours. The
collaborators, one per phase:

- `masterlink`: finding or starting the master, and `Params`, the one
  parameter interface (in-process for ours, XML-RPC for a running one);
- `runlog.RunLog`: the run's log directory and launch log, the summary;
- `StopSignals`: SIGINT/SIGTERM/SIGHUP for the whole run, installed on the
  loop before anything starts;
- `node_specs` and `process.Supervisor`: what runs for each node, and running it.
"""

from __future__ import annotations

import asyncio
import os
import signal
import sys
import time
import urllib.parse
from typing import Any, Awaitable, Callable

from launcher import masterlink
from launcher.command import master_uri, node_command
from launcher.config import LaunchConfig
from launcher.errors import LaunchError
from launcher.packages import PackageIndex
from launcher.masterlink import LocalParams, RemoteParams, is_local_host
from launcher.master import advertised_host
from launcher.names import ns_join
from launcher.net.allow import AllowList
from launcher.net.rosout import Rosout
from launcher.net.open_files import raise_open_file_limit
from launcher.process import console
from launcher.remote import ssh
from launcher.remote.parent import RemoteParent, check_addresses, machine_nodes, policy_warnings
from launcher.process.coredumps import CoreDumpReporter
from launcher.process.hang import HangDetector
from launcher.process.logdir import DEFAULT_THRESHOLD, parse_size, watch_log_disk
from launcher.process.logrotate import LogRotator
from launcher.process.readiness import Readiness
from launcher.process.reaper import Reaper, become_subreaper
from launcher.process.resources import DEFAULT_PERIOD_S, ResourceMonitor
from launcher.roshome import log_root
from launcher.process.spawn import ProcessSpec
from launcher.process.state import EVENTS_FILE, Fleet
from launcher.operate import systemd
from launcher.process.supervisor import Supervisor
from launcher.process.watchdog import Watchdog
from launcher.runlog import RunLog, summary
from launcher.runopts import RunOptions
from launcher.xml import load, resolve_launch_arguments

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
# Every node's state changes, one JSON object a line, in the run's log directory.
# `--wait`: how often a master that is not up yet is asked again.
WAIT_POLL_S = 0.1
# How long a launch leaves a roscore that has just started its master to set /run_id itself.
ROSCORE_RUN_ID_WAIT_S = 20.0


def _short_repr(value: Any, limit: int = 200) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[:limit] + "... (%d characters)" % len(text)


class Stopped(Exception):
    """A stop signal arrived while the run was starting."""


def run(opts: RunOptions, *, exit_process: bool = False) -> int:
    """`launch [pkg] file.launch ...` or `launch --core`: run until a stop signal, a `shutdown` call, a
    required node's exit, or (with a master already running) every node's exit; the exit status.

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
        plan = Plan.core(opts) if core else Plan.load(opts)
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


class Plan:
    """What a run runs: the loaded launch, its master URI, the checks that need no master."""

    def __init__(self, config: Any, master_uri: str, environ: dict[str, str], *, core: bool = False,
                 packages: Any = None, log_threshold: int = DEFAULT_THRESHOLD, core_port: int = 0):
        self.config = config
        self.master_uri = master_uri
        self.environ = environ
        self.core = core
        self.packages = packages
        self.log_threshold = log_threshold
        self.log_max_size = 0  # node output logs are rotated past this size (0: never)
        self.core_port = core_port

    @classmethod
    def core(cls, opts: RunOptions) -> Plan:
        """roscore: an empty launch, our master on -p or ROS_MASTER_URI's port."""
        environ = dict(os.environ)
        port = masterlink.master_port(opts, environ)
        uri_port = masterlink.master_port(None, environ)
        if environ.get("ROS_MASTER_URI") and uri_port != port:
            print("WARNING: ROS_MASTER_URI port [%d] does not match this roscore [%d]" % (uri_port, port),
                  file=sys.stderr)
        return cls(LaunchConfig(), "", environ, core=True, core_port=port)

    @classmethod
    def load(cls, opts: RunOptions) -> Plan:
        """Read the launch files; LaunchError (file and line) for bad input."""
        environ = dict(os.environ)
        warn = lambda msg: console.printerrlog("WARNING: %s" % msg)  # noqa: E731
        packages = PackageIndex(environ, warn=warn)
        files, argv = resolve_launch_arguments(list(opts.positional), packages)
        if not files:
            raise LaunchError("you must specify at least one input file")
        config = load(files, argv, environ=environ, packages=packages, warn=warn)
        uri = master_uri(argv, environ)
        if opts.port:
            if not 0 < opts.port < 65536:
                raise LaunchError("invalid port assignment: %s" % opts.port)
            uri = "http://%s:%d/" % (advertised_host(environ), opts.port)
        threshold = DEFAULT_THRESHOLD
        if opts.log_check_threshold:
            try:
                threshold = parse_size(opts.log_check_threshold)
            except ValueError as e:
                raise LaunchError("--log-check-threshold: %s" % e) from None
        plan = cls(config, uri, environ, packages=packages, log_threshold=threshold)
        try:
            plan.log_max_size = parse_size(opts.log_max_size or "0")
        except ValueError as e:
            raise LaunchError("--log-max-size: %s" % e) from None
        plan.check_nodes(opts)
        return plan

    def remote(self, node: Any) -> bool:
        """Is the node assigned to another machine?"""
        if not node.machine_name:
            return False
        machine = self.config.machines.get(node.machine_name)
        return machine is not None and not (machine.is_local or is_local_host(machine.address, self.environ))

    def check_nodes(self, opts: RunOptions) -> None:
        for node in self.config.nodes:
            if opts.required and node.respawn:
                raise LaunchError("respawn and required cannot both be set to true (node [%s], --required)"
                                  % node.full_name, node.filename or None, node.line or None)
            if node.respawn and node.required:
                raise LaunchError("respawn and required cannot both be set to true (node [%s])" % node.full_name,
                                  node.filename or None, node.line or None)
        if not opts.local:
            machines = {self.config.machines[n.machine_name] for n in self.config.nodes if self.remote(n)}
            for machine in sorted(machines, key=lambda m: m.name):
                ssh.check_machine(machine)
            if machines:
                check_addresses(self.master_uri, advertised_host(self.environ), sorted(machines, key=lambda m: m.name))
            for node in self.config.nodes:
                if self.remote(node):
                    for warning in policy_warnings(node, self.config.machines[node.machine_name]):
                        console.printerrlog("WARNING: %s" % warning)

    def remote_nodes(self) -> dict[str, list[Any]]:
        """The nodes to launch on other machines, by machine name."""
        return machine_nodes(list(self.config.nodes), self.config.machines, self.remote)


class StopSignals:
    """SIGINT, SIGTERM and SIGHUP for the whole run: each sets `event`, which ends the run."""

    def __init__(self, loop: asyncio.AbstractEventLoop):
        self.loop = loop
        self.event = asyncio.Event()
        # set while nodes are being stopped: a stop signal then means "now" (the second Ctrl-C)
        self.while_stopping: Callable[[], None] | None = None
        self.received = ""  # the first stop signal's name
        for sig in STOP_SIGNALS:
            loop.add_signal_handler(sig, self._on_signal, sig)

    def _on_signal(self, sig: int = 0) -> None:
        if not self.received and sig:
            self.received = signal.Signals(sig).name
        if self.while_stopping is not None:
            self.while_stopping()
        self.event.set()

    def check(self) -> None:
        if self.event.is_set():
            raise Stopped()

    async def guard(self, step: Awaitable[Any]) -> Any:
        """Await a start-up step, or raise Stopped as soon as a stop signal arrives (the step is cancelled)."""
        self.check()
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
        for sig in STOP_SIGNALS:
            self.loop.remove_signal_handler(sig)


def node_specs(plan: Plan, opts: RunOptions, run_dir: str, first_number: int) -> tuple[list[ProcessSpec], list[tuple[str, bool]]]:
    """What to run for each local node (numbered as roslaunch's processes), and the (name, required) of
    nodes that cannot be prepared (each reported by name here)."""
    config = plan.config
    if config.tests:
        # roslaunch skips <test> tags without a word; say so, they are the user's
        console.printlog("ignoring %d <test> node(s) (%s): run them with `launcher test` (or rostest)"
                         % (len(config.tests), ", ".join(t.test_name or t.name for t in config.tests)))
    specs: list[ProcessSpec] = []
    failed: list[tuple[str, bool]] = []
    number = first_number
    for node in config.nodes:
        if plan.remote(node):
            continue  # its machine's child runs it (launcher.remote), or --local leaves it out
        number += 1
        name = ("%s-%d" % (ns_join(node.namespace, node.name), number)).lstrip("/")
        log_name = name.replace("/", "-")
        required = node.required or opts.required
        try:
            command = node_command(node, master_uri=plan.master_uri, environ=plan.environ, packages=plan.packages,
                                   log_file=os.path.join(run_dir, log_name + ".log"))
        except LaunchError as e:
            console.printerrlog("ERROR: cannot launch node of type [%s/%s]: %s" % (node.package, node.type, e))
            failed.append((name, required))
            continue
        output = node.output or "log"
        if opts.screen:
            output = "screen"
        elif opts.log:
            output = "log"
        specs.append(ProcessSpec(
            name, command,
            output=output, stdout_path=os.path.join(run_dir, log_name + "-stdout.log"),
            log_dir=run_dir, respawn=node.respawn, respawn_delay=node.respawn_delay, required=required,
            node_name=ns_join(node.namespace, node.name), policy=node.policy))
    return specs, failed


def packages_of(plan: Plan, specs: list[ProcessSpec]) -> dict[str, str]:
    """process name -> the node's package (roslaunch's process_info reports it)."""
    by_node = {ns_join(n.namespace, n.name): n.package for n in plan.config.nodes}
    return {spec.name: by_node.get(spec.node_name, "") for spec in specs}


class Run:
    """One run on the running loop; the steps are methods so that the order reads like roslaunch's."""

    # roslaunch starts the master as a process of the launch, and says so ("auto-starting new master",
    # "[master] killing on exit"); rostest's runs inside it, started and stopped without a word
    MASTER_IS_A_PROCESS = True
    # orphans re-parented to the launch are reaped (process/reaper.py); a run whose process starts children
    # of its own outside the fleet (rostest's test node, waited for by popen.wait) must not
    REAP_ORPHANS = True

    def __init__(self, opts: RunOptions, plan: Plan, watchdog: Any = None):
        self.opts = opts
        self.plan = plan
        self.watchdog = watchdog
        self.core = plan.core
        self.master_uri = plan.master_uri
        self.signals: StopSignals | None = None
        self.log = RunLog(plan.environ)
        self.master: Any = None  # ours, when we run it
        self.params: Any = None  # LocalParams or RemoteParams
        self.external = False  # a master was already running
        self.rosout: Any = None
        self.remote: Any = None  # launcher.remote.parent.RemoteParent, when nodes run on other machines
        self.supervisor: Supervisor | None = None
        self.fleet: Fleet | None = None  # every node's state (process/state.py)
        self.rotator: LogRotator | None = None  # node output logs under --log-max-size
        self.run_id = ""
        self.server: Any = None  # roslaunch's XML-RPC API of this run (launcher.operate.server)
        self.diagnostics: Any = None  # the /diagnostics publisher (launcher.operate.diagnostics)
        self._process_count = 0  # roslaunch numbers processes (rosout-1, then the nodes)
        self._started = time.monotonic()  # (the launch log's timings count from here)
        self._tasks: list[asyncio.Future] = []
        self._health: list[Any] = []  # readiness and hang detection, closed before the nodes are stopped
        # READY=1, STATUS=, WATCHDOG=1, STOPPING=1 to systemd when run as a service ($NOTIFY_SOCKET)
        self.notifier = systemd.Notifier.from_environ(warn=console.printerrlog, ready_timeout=opts.ready_timeout)
        self.reaper: Reaper | None = None  # orphans re-parented to us (PID 1 of a container, or a subreaper)

    async def main(self) -> int:
        self.signals = StopSignals(asyncio.get_running_loop())
        if self.notifier is not None:
            self.notifier.start_watchdog()
        if self.REAP_ORPHANS and (os.getpid() == 1 or become_subreaper()):
            self.reaper = Reaper(asyncio.get_running_loop(), self._own_pids)
        status = 0
        try:
            await self._start()
            await self._wait_for_the_end()
        except Stopped:
            pass
        finally:
            await self._teardown()
            self.signals.close()
        if self.supervisor is not None:
            status = self.supervisor.exit_status
        return status

    # ---- start -----------------------------------------------------------------------------------------

    async def _start(self) -> None:
        env = self.plan.environ
        run_id_known = None  # is /run_id set on a running master? (None: not known)
        if self.core:
            await self._start_master(self.plan.core_port)  # first: a busy port is all a core has to say
            self.run_id = self._decide_run_id(None)
            self.log.open(self.run_id)  # (roscore too logs to roslaunch-<host>-<pid>.log, and says so first)
            self._open_master_log()  # (clients may call the master already)
            await self.signals.guard(self._start_server())
            console.printlog("ros_comm version %s" % masterlink.ros_version_params(env)[0].strip())
        else:
            self.external, reply = await self.signals.guard(self._find_master())
            self.run_id = self._decide_run_id(reply)
            if reply is not None:
                run_id_known = True if reply[0] == 1 else False if reply[0] == -1 else None
            self.log.open(self.run_id)
            await self.signals.guard(self._start_server())
            await self._start_remote()  # the other machines' children start while this one sets up
        if not self.opts.no_summary:
            console.printlog(summary(self.plan.config, self._summary_params(), remote=self.plan.remote,
                                     machines=self.remote is not None))
        if not self.external:
            if self.MASTER_IS_A_PROCESS:
                console.printlog("auto-starting new master")
            if self.master is None:
                await self._start_master(urllib.parse.urlsplit(self.master_uri).port or masterlink.DEFAULT_MASTER_PORT)
        if not self.core:
            self._open_master_log()
        self.params = LocalParams(self.master) if self.master is not None else RemoteParams(self.master_uri)
        console.printlog_bold("ROS_MASTER_URI=%s" % self.master_uri)
        await self.signals.guard(self._set_run_id(run_id_known))
        await self.signals.guard(self._register_server())
        if self.master is not None:
            await self.signals.guard(self._start_rosout())
        self.log.timing(self._started, "master %s at %s" % ("found" if self.external else "started", self.master_uri))
        await self.signals.guard(self._set_parameters())
        self.log.timing(self._started, "%d parameters set" % len(self.plan.config.params))
        self._launch_nodes()
        if self.notifier is not None:
            self.notifier.attach(self.fleet, self.master_uri)
        if not self.core and not self.opts.no_diagnostics:
            await self.signals.guard(self._start_diagnostics())
        self.log.timing(self._started, "every node started")

    async def _find_master(self) -> tuple[bool, tuple[Any, Any] | None]:
        """(a master already answers at the master URI, its getParam('/run_id') reply); roslaunch uses it."""
        answers, reply = await masterlink.probe(self.master_uri)
        if answers and self.opts.master_allow:
            console.printerrlog("WARNING: --master-allow has no effect: the master at %s is not started "
                                "by this launch" % self.master_uri)
        if not answers and self.opts.wait:
            console.printlog("master has not been started, waiting for it at %s ..." % self.master_uri)
            while not answers:
                await asyncio.sleep(WAIT_POLL_S)
                answers, reply = await masterlink.probe(self.master_uri)
        if answers:
            if (reply is not None and reply[0] != 1 and not self.opts.run_id
                    and await masterlink.started_by_roscore(self.master_uri)):
                reply = await self._wait_for_roscore_run_id(reply)
            return True, reply
        host = urllib.parse.urlsplit(self.master_uri).hostname or ""
        if not is_local_host(host, self.plan.environ):
            raise LaunchError("unable to contact ROS master at [%s]; it is not on this machine, so it cannot be "
                              "started here" % self.master_uri)
        return False, None

    async def _wait_for_roscore_run_id(self, reply: tuple[Any, Any]) -> tuple[Any, Any]:
        """A roscore's master answers before the roscore has set /run_id: let it (roscore dies if we set it
        first); after ROSCORE_RUN_ID_WAIT_S without one, go on and set our own."""
        deadline = asyncio.get_running_loop().time() + ROSCORE_RUN_ID_WAIT_S
        while reply[0] != 1 and asyncio.get_running_loop().time() < deadline:
            await asyncio.sleep(WAIT_POLL_S)
            answers, new = await masterlink.probe(self.master_uri)
            reply = new if answers and new is not None else reply
        return reply

    def _master_allow(self) -> Any:
        """`--master-allow` / `--core --allow`: the AllowList of our master, or None (open, as rosmaster)."""
        cidrs = [c for arg in self.opts.master_allow for c in arg.split(",") if c.strip()]
        if not cidrs:
            return None
        try:
            return AllowList(cidrs)
        except ValueError as e:
            raise LaunchError("--master-allow: %s" % e) from None

    async def _start_master(self, port: int) -> None:
        allow = self._master_allow()
        try:
            self.master = await masterlink.start_master(port, self.plan.environ, allow=allow)
        except OSError as e:
            if self.core:
                raise LaunchError(
                    "RLException: roscore cannot run as another roscore/master is already running. \n"
                    "Please kill other roscore/master processes before relaunching.\n"
                    "The ROS_MASTER_URI is http://%s:%d/ (%s)" % (advertised_host(self.plan.environ), port,
                                                                 e.strerror or e)) from None
            raise LaunchError("unable to start the master on port %d: %s" % (port, e.strerror or e)) from None
        if self.core:
            self.master_uri = self.master.uri
        if allow is not None:
            console.printlog("master answers only clients from loopback, this machine and: %s" % allow)

    def _open_master_log(self) -> None:
        if self.master is not None and self.log.run_dir:
            self.master.open_log(os.path.join(self.log.run_dir, "master.log"))

    def _summary_params(self) -> dict[str, Any]:
        params = {k: p.value for k, p in self.plan.config.params.items()}
        rosversion, rosdistro = masterlink.ros_version_params(self.plan.environ)
        params.setdefault("/rosversion", rosversion)
        params.setdefault("/rosdistro", rosdistro)
        return params

    def _decide_run_id(self, reply: tuple[Any, Any] | None) -> str:
        code, value = reply or (0, None)
        if code == 1 and value:
            if self.opts.run_id and self.opts.run_id != value:
                raise LaunchError("run_id on parameter server does not match declared run_id: %s vs %s"
                                  % (value, self.opts.run_id))
            return str(value)
        if self.opts.run_id:
            return self.opts.run_id
        import uuid  # imports platform & co.: only when a run id must be made up
        return str(uuid.uuid1())

    async def _set_run_id(self, known: bool | None) -> None:
        """Set /run_id unless a running master has one (ours never has)."""
        if self.master is None:
            if known is None:
                known = await self.params.has("/run_id")
            if known:
                return
        console.printlog_bold("setting /run_id to %s" % self.run_id)
        await self.params.set("/run_id", self.run_id)

    async def _start_server(self) -> None:
        """roslaunch's XML-RPC API (roscore's too), started first as roslaunch's, registered later."""
        from launcher.operate.server import LaunchServer
        server = LaunchServer(self, self.plan.environ)
        try:
            await server.start()
        except OSError as e:  # the launch runs on, without its operator's side
            console.printerrlog("could not start the roslaunch server: %s" % e)
            await server.stop()
            return
        server.set_packages({})
        self.server = server
        console.printlog_bold("started roslaunch server %s" % server.uri)

    async def _register_server(self) -> None:
        """`/roslaunch/uris/host_<host>__<port>` on the master, as roslaunch sets it once /run_id is."""
        if self.server is None:
            return
        try:
            await self.params.set(self.server.param_key, self.server.uri)
        except LaunchError as e:  # not findable through the master; --uri still reaches it
            console.printerrlog("could not register the roslaunch server on the master: %s" % e)

    async def _start_diagnostics(self) -> None:
        try:
            from launcher.operate.diagnostics import Diagnostics
            diagnostics = Diagnostics(self.master_uri, self.fleet, environ=self.plan.environ, master=self.master)
            await diagnostics.start()
        except Exception as e:  # noqa: BLE001 - the launch goes on without /diagnostics
            console.printerrlog("could not publish /diagnostics: %s" % e)
            return
        self.diagnostics = diagnostics

    async def _start_rosout(self) -> None:
        rosout = Rosout(self.master_uri, self.log.run_dir, environ=self.plan.environ)
        try:
            await rosout.start(warm_up=False)  # warmed up once the nodes are spawned (Rosout.warm_up)
        except Exception as e:  # noqa: BLE001 - the launch goes on without a log collector
            console.printerrlog("could not start the built-in rosout: %s" % e)
            try:
                await rosout.stop()
            except Exception:  # noqa: BLE001
                pass
            return
        self.rosout = rosout
        # roslaunch runs rosout as process "rosout-1"; keep node numbering (and log file names) the same
        self._process_count += 1
        console.printlog("started core service [/rosout]")

    async def _set_parameters(self) -> None:
        """`<rosparam command="delete|dump">` in document order, then clear_params, then every parameter."""
        for command, key, filename in self.plan.config.rosparam_commands:
            try:
                if command == "delete":
                    await self.params.delete(key)
                elif command == "dump" and filename:
                    from launcher.params.rosyaml import dump_yaml  # (PyYAML: 12-27 ms a run would pay for a rare tag)
                    value = await self.params.get(key)
                    with open(filename, "w") as f:
                        f.write(dump_yaml(value))
            except (KeyError, OSError, LaunchError) as e:
                console.printerrlog("rosparam %s %s failed: %s" % (command, key, e))
        config = self.plan.config
        await self.params.upload(list(config.clear_params), [(p.key, p.value) for p in config.params.values()])

    def _launch_nodes(self) -> None:
        """Spawn every node in order, each supervised from its start.

        Every command line is worked out first: once nodes run, each competes with the
        launcher for the CPU (on 2 cores, 100 starting roscpp nodes leave it a few percent),
        so the loop that spawns them does as little as possible.
        """
        self.signals.check()
        specs, failed = node_specs(self.plan, self.opts, self.log.run_dir, self._process_count)
        self._note_launch(specs)
        self.fleet = Fleet(os.path.join(self.log.run_dir, EVENTS_FILE) if self.log.run_dir else None,
                           warn=console.printerrlog)
        self.fleet.listeners.append(self.log.state_change)
        self.supervisor = Supervisor(sigint_timeout=self.opts.sigint_timeout,
                                     sigterm_timeout=self.opts.sigterm_timeout,
                                     exit_when_all_dead=self.external, watchdog=self.watchdog, fleet=self.fleet)
        self._watch_health()
        if self.server is not None:
            self.server.set_packages(packages_of(self.plan, specs))
        if self.remote is not None:
            self.remote.attach(self.fleet)
        stop = self.signals.event
        no_start = self.opts.no_start
        for spec in specs:
            if stop.is_set():
                break
            if no_start:
                self.supervisor.add(spec)  # started later by `launcher start`
            else:
                self.supervisor.start(spec)
        for name, required in failed:
            self.supervisor.not_started(name, required)
        self.supervisor.registrations_complete()
        self.rotator = LogRotator(self.plan.log_max_size, self.opts.log_backups, self.log.note)
        for spec in specs:
            if spec.stdout_path:
                self.rotator.watch(spec.stdout_path, spec.policy.log_max_size, spec.policy.log_backups)
        self.rotator.start()
        if self.rosout is not None:
            self.rosout.warm_up()

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

    def _watch_health(self) -> None:
        """wait_for holds, hang probes, core dump reports, and the resource sampling of every node."""
        sup = self.supervisor
        sup.readiness = Readiness(self.master_uri, sup)
        hang = HangDetector(self.master_uri, sup)
        sup.watchers += [hang, CoreDumpReporter()]
        self._health += [sup.readiness, hang]
        monitor = ResourceMonitor(sup, self.opts.monitor_period or DEFAULT_PERIOD_S)
        self._tasks.append(asyncio.ensure_future(monitor.run()))

    async def _start_remote(self) -> None:
        """The other machines' children, started on their own tasks; they get their nodes at `_launch_nodes`."""
        if self.opts.local:
            # roslaunch's words (ROSLaunchParent._init_remote), whether or not a node is remote
            console.printlog_bold("LOCAL\nlocal only launch specified, will not launch remote nodes\nLOCAL\n")
            return
        by_machine = self.plan.remote_nodes()
        if not by_machine:
            return
        self.remote = RemoteParent(by_machine, self.plan.config.machines, run_id=self.run_id,
                                   master_uri=self.master_uri, host=advertised_host(self.plan.environ),
                                   environ=self.plan.environ, watchdog=self.watchdog, sigint_timeout=self.opts.sigint_timeout,
                                   sigterm_timeout=self.opts.sigterm_timeout)
        await self.remote.start(self.server.uri if self.server is not None else "")

    def _own_pids(self) -> list[int]:
        """The children whose exits their runners wait for (the reaper leaves them alone)."""
        pids = [r.pid for r in self.fleet.records.values() if r.pid] if self.fleet is not None else []
        if self.remote is not None:  # each machine's ssh (a session of its own, waited for by asyncio)
            pids += [c.ssh.pid for c in self.remote.children.values() if c.ssh is not None]
        return pids + ([self.watchdog.pid] if self.watchdog is not None else [])

    # ---- running ---------------------------------------------------------------------------------------

    async def _wait_for_the_end(self) -> None:
        self.signals.check()
        if not self.core and not self.opts.skip_log_check:
            self._tasks.append(asyncio.ensure_future(watch_log_disk(log_root(self.plan.environ),
                                                                    self.plan.log_threshold)))
        waiters = [asyncio.ensure_future(self.signals.event.wait()),
                   asyncio.ensure_future(self.supervisor.done.wait())]
        if self.master is not None:
            waiters.append(asyncio.ensure_future(self.master.shutdown_requested.wait()))
        await asyncio.wait(waiters, return_when=asyncio.FIRST_COMPLETED)
        for w in waiters:
            w.cancel()
        if self.master is not None and self.master.shutdown_requested.is_set():
            console.printlog("shutdown request: %s" % self.master.shutdown_reason)

    # ---- shutdown --------------------------------------------------------------------------------------

    def _kill_now(self) -> None:
        """A stop signal while nodes are being stopped: kill what is left, and say so."""
        killed = self.supervisor.kill_now() if self.supervisor is not None else []
        if killed:
            console.printerrlog("second stop signal: killing %d node(s) still stopping with SIGKILL: %s"
                                % (len(killed), ", ".join(killed)))

    async def _stop_server(self) -> None:
        if self.external:  # a master that outlives us must not list a launch that is gone
            try:
                await asyncio.wait_for(self.params.delete(self.server.param_key), 3.0)
            except (Exception, asyncio.TimeoutError):  # noqa: BLE001 - the master may be gone already
                pass
        await self.server.stop()

    def _end_reason(self) -> str:
        """Why the run ends, in words (the events file's last line, which `launcher status` reads after it)."""
        if self.signals.received:
            return "stopped by %s" % self.signals.received
        if self.master is not None and self.master.shutdown_requested.is_set():
            return "shutdown request: %s" % self.master.shutdown_reason
        if self.supervisor is not None and self.supervisor.done.is_set():
            status = self.supervisor.exit_status
            return "its nodes ended it (exit status %d)" % status
        return "ended"

    async def _teardown(self) -> None:
        if self.notifier is not None:
            self.notifier.stopping()
        for t in self._tasks:
            t.cancel()
        if self.rotator is not None:
            self.rotator.close()
        for h in self._health:
            h.close()
        if self.diagnostics is not None:
            await self.diagnostics.stop()
        stops = [self.remote.shutdown()] if self.remote is not None else []
        if self.supervisor is not None:
            self.signals.while_stopping = self._kill_now
            stops.append(self.supervisor.shutdown())
        await asyncio.gather(*stops)  # the machines stop their nodes while this one stops its own
        if self.reaper is not None:
            await self.reaper.stop_orphans()  # a node's daemonized grandchildren, re-parented to us
        if self.supervisor is not None:
            self.signals.while_stopping = None
            self.supervisor.close()
        if self.fleet is not None:
            self.fleet.launch_ended(self._end_reason(), self.supervisor.exit_status if self.supervisor else 0)
            self.fleet.close()
        if self.server is not None:
            await self._stop_server()
        if self.rosout is not None:
            if not self.core:
                console.printlog("[rosout-1] killing on exit")
            try:
                await self.rosout.stop()
            except Exception as e:  # noqa: BLE001 - the master must still stop
                console.printerrlog("error stopping rosout: %s" % e)
        if self.master is not None:
            if not self.core and self.MASTER_IS_A_PROCESS:
                console.printlog("[master] killing on exit")
            await self.master.stop()
        if self.core:
            if self.master is not None:
                console.printlog("done")
        else:
            console.printlog("shutting down processing monitor...")
            console.printlog("... shutting down processing monitor complete")
            console.printlog_bold("done")
        self.log.close()
        if self.notifier is not None:
            self.notifier.close()
        if self.reaper is not None:
            self.reaper.close()
        sys.stdout.flush()

