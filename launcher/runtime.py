"""Running a launch: config -> master (running or embedded) -> parameters -> rosout -> supervised nodes -> shutdown.

With a master already running, everything up to the nodes' start is plain
blocking code: the nodes are spawned before asyncio is even imported (~25 ms,
a quarter of the way to the first node), and the supervisor adopts them once
its event loop runs. An embedded master needs the loop first.
"""

from __future__ import annotations

import os
import signal
import socket
import sys
import time
import urllib.parse
from typing import Any, Mapping

from launcher.errors import LaunchError
from launcher.process import console

_CALLER_ID = "/roslaunch"
# How long to wait for an answer from a master that accepted the connection.
PROBE_TIMEOUT_S = 3.0
PARAM_TIMEOUT_S = 30.0
# With a running master, the event loop is started when something first happens (a node exits, a
# signal arrives) or after this long: until then nothing needs it, and importing and setting up
# asyncio (~25 ms of CPU) would only compete with the nodes that have just been started.
FIRST_EVENT_WAIT_S = 1.0


class _Stop(Exception):
    """Shutdown was requested while starting up."""


def run(opts: Any, *, exit_process: bool = False) -> int:
    """`launch [pkg] file.launch ...`: run until SIGINT/SIGTERM, a required exit, or (external master) all exits.

    With `exit_process` (the `launch` command itself), the process ends here
    once everything is stopped and flushed, skipping the interpreter's
    tear-down (tens of ms that a user waiting for the prompt would notice).
    """
    from launcher.process.watchdog import Watchdog
    # The guard is started first, so that no node can ever run unwatched.
    watchdog = Watchdog.start()
    pid_fn = getattr(opts, "pid_fn", None)
    try:
        if pid_fn:
            try:
                with open(pid_fn, "w") as f:
                    f.write(str(os.getpid()))
            except OSError as e:
                raise LaunchError("cannot write pid file [%s]: %s" % (pid_fn, e.strerror)) from None
        from launcher.net.open_files import raise_open_file_limit
        raise_open_file_limit()  # every client of the master and the rosout node is a file
        launch = Launch(opts, watchdog)
        launch.load()
        launch.start_before_loop()
        import asyncio
        status = asyncio.run(launch.main())
    finally:
        if watchdog is not None:
            watchdog.close()
        if pid_fn:
            try:
                os.unlink(pid_fn)
            except OSError:
                pass
    if exit_process:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError):
                pass
        os._exit(status)
    return status


def summary(config: Any, params: Mapping[str, Any]) -> str:
    """roslaunch's SUMMARY block (ROSLaunchConfig.summary(local=True))."""
    text = "\nSUMMARY\n========"
    if config.clear_params:
        text += "\n\nCLEAR PARAMETERS\n" + "\n".join(sorted(" * %s" % p for p in config.clear_params))
    if params:
        text += "\n\nPARAMETERS\n" + "\n".join(sorted(" * %s: %s" % (k, _summary_value(v)) for k, v in params.items()))
    text += "\n\nNODES\n"
    namespaces: dict[str, list[Any]] = {}
    for n in config.nodes:
        namespaces.setdefault(n.namespace, []).append(n)
    for ns in sorted(namespaces):
        text += "  %s\n" % ns + "\n".join(sorted("    %s (%s/%s)" % (n.name, n.package, n.type)
                                                for n in namespaces[ns]))
        text += "\n"
    return text


def _summary_value(value: Any) -> str:
    """roslaunch's strip_string: at most 20 characters, `<...>` for unprintable ones."""
    try:
        value = str(value)
    except Exception:  # noqa: BLE001 - as roslaunch
        return "<...>"
    if len(value) > 20:
        value = value[:17] + "..."
    for i, char in enumerate(value):
        if ord(char) < 32 or ord(char) > 126:
            value = value.rstrip()
            if i >= len(value):
                break
            return "<...>"
    return value


def _is_local_host(host: str, environ: Mapping[str, str]) -> bool:
    if host in ("localhost", "::1") or host.startswith("127."):
        return True
    names = {socket.gethostname()}
    for key in ("ROS_HOSTNAME", "ROS_IP"):
        if environ.get(key):
            names.add(environ[key])
    if host in names:
        return True
    try:
        import psutil
        local = {a.address.split("%")[0] for addrs in psutil.net_if_addrs().values() for a in addrs}
        resolved = {ai[4][0] for ai in socket.getaddrinfo(host, None)}
    except (OSError, ImportError, UnicodeError):  # (a malformed host name: idna refuses it)
        return False
    return bool(local & resolved)


class Launch:
    """One `launch` run; the steps are methods so that the order reads like roslaunch's."""

    def __init__(self, opts: Any, watchdog: Any = None):
        self.opts = opts
        self.watchdog = watchdog
        self.environ = dict(os.environ)
        self.config: Any = None
        self.argv: list[str] = []
        self.packages: Any = None
        self.master: Any = None  # the embedded master, when we run it
        self.rosout: Any = None
        self.supervisor: Any = None
        self.run_id = ""
        self.run_log_dir = ""
        self.master_uri = ""
        self.external = False  # a master was already running
        self._stop: Any = None  # asyncio.Event, once the loop runs
        self._stop_requested = False  # SIGINT/SIGTERM/SIGHUP seen
        self._interruptible = False  # a signal may abort the blocking steps (no node runs yet)
        self._counter = 0
        self._log_file: Any = None
        self._tasks: list[Any] = []
        # nodes spawned before the supervisor exists: (spec, Popen or None if it failed, monotonic start)
        self._started: list[tuple[Any, Any, float]] = []
        self._not_started: list[tuple[str, bool]] = []  # (name, required) of nodes that could not be prepared

    # ---- loading (synchronous; LaunchError -> the CLI prints it, exit 1) -------------------------------

    def load(self) -> None:
        from launcher.introspect import master_uri
        from launcher.packages import PackageIndex
        from launcher.xml import load, resolve_launch_arguments
        opts = self.opts
        self.packages = PackageIndex(self.environ, warn=lambda msg: console.printerrlog("WARNING: %s" % msg))
        files, self.argv = resolve_launch_arguments(list(opts.positional or []), self.packages)
        if not files:
            raise LaunchError("you must specify at least one input file")
        self.config = load(files, self.argv, environ=self.environ, packages=self.packages,
                           warn=lambda msg: console.printerrlog("WARNING: %s" % msg))
        self.master_uri = master_uri(self.argv, self.environ)
        if opts.port:
            if not 0 < opts.port < 65536:
                raise LaunchError("invalid port assignment: %s" % opts.port)
            from launcher.master import advertised_host
            self.master_uri = "http://%s:%d/" % (advertised_host(self.environ), opts.port)
        if getattr(opts, "log_check_threshold", None):
            from launcher.process.logdir import parse_size
            try:
                self.log_threshold = parse_size(opts.log_check_threshold)
            except ValueError as e:
                raise LaunchError("--log-check-threshold: %s" % e) from None
        self._check_nodes()

    def _check_nodes(self) -> None:
        for node in self.config.nodes:
            if self.opts.required and node.respawn:
                raise LaunchError("respawn and required cannot both be set to true (node [%s], --required)"
                                  % node.full_name, node.filename or None, node.line or None)
            if node.respawn and node.required:
                raise LaunchError("respawn and required cannot both be set to true (node [%s])" % node.full_name,
                                  node.filename or None, node.line or None)
            if node.machine_name:
                machine = self.config.machines.get(node.machine_name)
                if machine is not None and not (machine.is_local or _is_local_host(machine.address, self.environ)):
                    if not getattr(self.opts, "local", False):
                        raise LaunchError(
                            "node [%s] is assigned to machine [%s] at [%s]: launching nodes on other machines is "
                            "not supported (use --local to skip them)" % (node.full_name, machine.name,
                                                                           machine.address),
                            node.filename or None, node.line or None)

    def _remote(self, node: Any) -> bool:
        if not node.machine_name:
            return False
        machine = self.config.machines.get(node.machine_name)
        return machine is not None and not (machine.is_local or _is_local_host(machine.address, self.environ))

    # ---- the run ---------------------------------------------------------------------------------------

    def start_before_loop(self) -> None:
        """With a running master: run_id, log directory, parameters and every node's start, blocking."""
        from launcher.process.spawn import restore_default_signals_for_children
        # handlers (not SIG_IGN) for the signals nodes must get at their default: exec resets handled
        # signals, so nodes start with SIGINT at SIG_DFL even if we inherited it ignored
        restore_default_signals_for_children()
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
            signal.signal(sig, self._on_signal_before_loop)
        self._interruptible = True
        try:
            self.external = self._find_master()
            if self.external:
                self._begin_log()
                self._announce_master()
                self._set_parameters()
                self._interruptible = False
                self._launch_nodes()
                self._wait_for_first_event(FIRST_EVENT_WAIT_S)
        except _Stop:
            pass
        finally:
            self._interruptible = False

    def _wait_for_first_event(self, timeout: float) -> None:
        """Block until a node started here exits, a signal arrives, or `timeout` (see FIRST_EVENT_WAIT_S)."""
        import select
        popens = [popen for _spec, popen, _t in self._started if popen is not None]
        if not popens or self._stop_requested:
            return
        poller = select.poll()
        fds = []
        try:
            for popen in popens:
                fd = os.pidfd_open(popen.pid)  # readable once the process has exited
                fds.append(fd)
                poller.register(fd, select.POLLIN)
            # a signal's handler only sets a flag; the wakeup fd ends the wait at once
            wake_r, wake_w = os.pipe2(os.O_NONBLOCK | os.O_CLOEXEC)
            fds += (wake_r, wake_w)
            poller.register(wake_r, select.POLLIN)
            previous = signal.set_wakeup_fd(wake_w)
        except (OSError, ValueError):  # no pidfds (old kernel): start the loop now
            for fd in fds:
                os.close(fd)
            return
        try:
            if not self._stop_requested:  # (a signal may have come in before the wakeup fd was set)
                poller.poll(timeout * 1000.0)
        finally:
            signal.set_wakeup_fd(previous)
            for fd in fds:
                os.close(fd)

    def _on_signal_before_loop(self, sig: int, _frame: Any) -> None:
        self._stop_requested = True
        if self._interruptible:
            raise _Stop()  # out of a blocking master call at once: no node runs yet
        # otherwise _launch_nodes stops at the next node, and main() shuts down what runs

    async def main(self) -> int:
        import asyncio
        loop = asyncio.get_running_loop()
        self._stop = asyncio.Event()
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
            loop.add_signal_handler(sig, self._on_signal, sig)
        if self._stop_requested:
            self._stop.set()
        status = 0
        try:
            status = await self._run()
        except _Stop:
            pass
        finally:
            await self._teardown()
            for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
                loop.remove_signal_handler(sig)
        if self.supervisor is not None and self.supervisor.required_failed:
            status = 1
        return status

    def _on_signal(self, sig: int) -> None:
        self._stop_requested = True
        if not self._stop.is_set():
            self._stop.set()

    def _check_stop(self) -> None:
        if self._stop_requested:
            raise _Stop()

    async def _run(self) -> int:
        import asyncio

        from launcher.process.supervisor import Supervisor
        opts = self.opts
        if not self.external:
            self._check_stop()
            self._begin_log()
            await self._start_master()
            self._announce_master()
            self._check_stop()
            await self._start_rosout()
            self._check_stop()
            self._set_parameters()
            self._check_stop()
            self._launch_nodes()
        self.supervisor = Supervisor(sigint_timeout=opts.sigint_timeout, sigterm_timeout=opts.sigterm_timeout,
                                     exit_when_all_dead=self.external, watchdog=self.watchdog)
        for spec, popen, started_at in self._started:
            self.supervisor.adopt(spec, popen, started_at)
        for name, required in self._not_started:
            self.supervisor.not_started(name, required)
        self._started.clear()
        self.supervisor.registrations_complete()
        self._check_stop()
        if self.rosout is not None:
            self.rosout.warm_up()
        if not opts.skip_log_check:
            from launcher.process.logdir import log_root, watch_log_disk
            self._tasks.append(asyncio.ensure_future(watch_log_disk(log_root(self.environ), self.log_threshold)))
        waiters = [asyncio.ensure_future(self._stop.wait()), asyncio.ensure_future(self.supervisor.done.wait())]
        if self.master is not None:
            waiters.append(asyncio.ensure_future(self.master.shutdown_requested.wait()))
        await asyncio.wait(waiters, return_when=asyncio.FIRST_COMPLETED)
        for w in waiters:
            w.cancel()
        if self.master is not None and self.master.shutdown_requested.is_set():
            console.printlog("shutdown request: %s" % self.master.shutdown_reason)
        return 0

    def _begin_log(self) -> None:
        """run_id, log directory, summary (roslaunch's order)."""
        self.run_id = self._decide_run_id()
        self._setup_log_dir()
        if not self.opts.no_summary:
            console.printlog(summary(self.config, self._summary_params()))

    def _announce_master(self) -> None:
        console.printlog_bold("ROS_MASTER_URI=%s" % self.master_uri)
        self._set_run_id()

    def _set_parameters(self) -> None:
        self._rosparam_commands()
        self._check_stop()
        self._load_parameters()
        self._check_stop()

    log_threshold = 1073741824
    _run_id_known: bool | None = None  # is /run_id set on the external master? (None: not asked yet)
    _run_id_reply: tuple[Any, Any] | None = None  # (code, value) of the probe's getParam('/run_id')

    # ---- master ----------------------------------------------------------------------------------------

    def _probe(self) -> bool:
        """Does a master answer? Asked as getParam('/run_id'), whose answer _decide_run_id needs next."""
        from launcher.net.xmlrpc import Fault, call_blocking
        try:
            reply = call_blocking(self.master_uri, "getParam", _CALLER_ID, "/run_id", timeout=PROBE_TIMEOUT_S)
        except Fault:
            return True  # anything answering XML-RPC with a fault is still a master
        except (OSError, ValueError):  # (XmlRpcError is a ValueError; so is a host name idna refuses)
            return False
        if isinstance(reply, list) and len(reply) == 3:
            self._run_id_reply = (reply[0], reply[2])
        return True

    def _find_master(self) -> bool:
        """True if a master already answers at the master URI (it is then used, as roslaunch does)."""
        if self._probe():
            return True
        if self.opts.wait:
            console.printlog("master has not been started, waiting for it at %s ..." % self.master_uri)
            while not self._probe():
                self._check_stop()
                time.sleep(0.1)  # a signal ends the wait at once (_on_signal_before_loop)
            return True
        host = urllib.parse.urlsplit(self.master_uri).hostname or ""
        if not _is_local_host(host, self.environ):
            raise LaunchError("unable to contact ROS master at [%s]; it is not on this machine, so it cannot be "
                              "started here" % self.master_uri)
        return False

    async def _start_master(self) -> None:
        from launcher.master import Master
        port = urllib.parse.urlsplit(self.master_uri).port or 11311
        console.printlog("auto-starting new master")
        master = Master(port=port, environ=self.environ)
        try:
            await master.start()
        except OSError as e:
            raise LaunchError("unable to start the master on port %d: %s" % (port, e.strerror or e)) from None
        self.master = master
        from launcher.core import ros_version_params
        rosversion, rosdistro = ros_version_params(self.environ)
        master.set_param("/rosversion", rosversion)
        master.set_param("/rosdistro", rosdistro)

    def _summary_params(self) -> dict[str, Any]:
        params = {k: p.value for k, p in self.config.params.items()}
        from launcher.core import ros_version_params
        rosversion, rosdistro = ros_version_params(self.environ)
        params.setdefault("/rosversion", rosversion)
        params.setdefault("/rosdistro", rosdistro)
        return params

    def _decide_run_id(self) -> str:
        if self.external:
            code, value = self._run_id_reply or (0, None)
            # getParam answered whether /run_id is set: _set_run_id needs no hasParam round trip then
            self._run_id_known = True if code == 1 else False if code == -1 else None
            if code == 1 and value:
                if self.opts.run_id and self.opts.run_id != value:
                    raise LaunchError("run_id on parameter server does not match declared run_id: %s vs %s"
                                      % (value, self.opts.run_id))
                return str(value)
        if self.opts.run_id:
            return self.opts.run_id
        import uuid  # imports platform & co.: only when a run id must be made up
        return str(uuid.uuid1())

    def _set_run_id(self) -> None:
        if self.master is not None:
            self.master.set_param("/run_id", self.run_id)
            console.printlog_bold("setting /run_id to %s" % self.run_id)
            return
        from launcher.net.xmlrpc import call_blocking
        if self._run_id_known is not None:
            code, has = 1, self._run_id_known
        else:
            code, _msg, has = call_blocking(self.master_uri, "hasParam", _CALLER_ID, "/run_id",
                                            timeout=PARAM_TIMEOUT_S)
        if code == 1 and not has:
            console.printlog_bold("setting /run_id to %s" % self.run_id)
            call_blocking(self.master_uri, "setParam", _CALLER_ID, "/run_id", self.run_id, timeout=PARAM_TIMEOUT_S)

    async def _start_rosout(self) -> None:
        try:
            from launcher.net.rosout import Rosout
        except ImportError as e:
            console.printerrlog("no built-in rosout available (%s): /rosout is not served" % e)
            return
        rosout = Rosout(self.master_uri, self.run_log_dir, environ=self.environ)
        try:
            await rosout.start(warm_up=False)  # warmed up once the nodes are spawned (Rosout.warm_up)
        except Exception as e:  # noqa: BLE001 - the launch goes on without a log collector
            console.printerrlog("could not start the built-in rosout: %s" % e)
            return
        self.rosout = rosout
        # roslaunch runs rosout as process "rosout-1"; keep node numbering (and log file names) the same
        self._counter += 1
        console.printlog("started core service [/rosout]")

    # ---- logs ------------------------------------------------------------------------------------------

    def _setup_log_dir(self) -> None:
        from launcher.process.logdir import make_run_log_dir
        self.run_log_dir = make_run_log_dir(self.environ, self.run_id)
        path = os.path.join(self.run_log_dir, "roslaunch-%s-%d.log" % (socket.gethostname(), os.getpid()))
        try:
            self._log_file = open(path, "a", buffering=1)
        except OSError:
            self._log_file = None
            return
        console.add_handler(self._log_line)
        console.printlog("... logging to %s" % path)

    def _log_line(self, msg: str) -> None:
        if self._log_file is not None:
            now = time.time()
            self._log_file.write("[%s.%03d] %s\n" % (time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(now)),
                                                     int(now * 1000) % 1000, msg))

    # ---- parameters ------------------------------------------------------------------------------------

    def _rosparam_commands(self) -> None:
        """`<rosparam command="delete|dump">`, in document order, before the parameters are set."""
        for command, key, filename in getattr(self.config, "rosparam_commands", ()):
            try:
                if command == "delete":
                    self._delete_param(key)
                elif command == "dump" and filename:
                    from launcher.params.rosyaml import dump_yaml
                    value = self._get_param(key)
                    with open(filename, "w") as f:
                        f.write(dump_yaml(value))
            except (KeyError, OSError, LaunchError) as e:
                console.printerrlog("rosparam %s %s failed: %s" % (command, key, e))

    def _delete_param(self, key: str) -> None:
        if self.master is not None:
            try:
                self.master.delete_param(key)
            except KeyError:
                pass
            return
        from launcher.net.xmlrpc import call_blocking
        call_blocking(self.master_uri, "deleteParam", _CALLER_ID, key, timeout=PARAM_TIMEOUT_S)

    def _get_param(self, key: str) -> Any:
        if self.master is not None:
            return self.master.params.get(key)
        from launcher.net.xmlrpc import call_blocking
        code, msg, value = call_blocking(self.master_uri, "getParam", _CALLER_ID, key, timeout=PARAM_TIMEOUT_S)
        if code != 1:
            raise LaunchError(msg)
        return value

    def _load_parameters(self) -> None:
        """Clear the `clear_params` namespaces, then set every parameter, before any node starts."""
        params = [(p.key, p.value) for p in self.config.params.values()]
        clear = list(self.config.clear_params)
        if self.master is not None:
            tree = self.master.params
            for ns in clear:
                try:
                    if tree.has(ns):
                        self.master.delete_param(ns)
                except KeyError:
                    pass
            for key, value in params:
                try:
                    self.master.set_param(key, value)
                except ValueError as e:  # a value no client could read back (as setParam refuses it)
                    raise LaunchError("Failed to set parameter: %s" % e) from None
            return
        if not params and not clear:
            return
        from launcher.net.xmlrpc import call_blocking
        # one round trip: deletes first, then sets (the master runs a multicall in order)
        calls = [{"methodName": "deleteParam", "params": [_CALLER_ID, ns]} for ns in clear]
        calls += [{"methodName": "setParam", "params": [_CALLER_ID, k, v]} for k, v in params]
        try:
            results = call_blocking(self.master_uri, "system.multicall", calls, timeout=PARAM_TIMEOUT_S)
        except Exception as e:  # noqa: BLE001
            raise LaunchError("cannot set the launch's parameters on the master at [%s]: %s"
                              % (self.master_uri, e)) from None
        for (key, _value), result in zip(params, results[len(clear):]):
            if isinstance(result, dict):
                raise LaunchError("Failed to set parameter [%s]: %s" % (key, result.get("faultString")))
            code, msg, _ = result[0]
            if code != 1:
                raise LaunchError("Failed to set parameter: %s" % msg)

    # ---- nodes -----------------------------------------------------------------------------------------

    def _launch_nodes(self) -> None:
        """Spawn every node, in order (the supervisor adopts them: see `_run`).

        Every command line is worked out first: once nodes run, each competes with the
        launcher for the CPU (on 2 cores, 100 starting roscpp nodes leave it a few percent),
        so the loop that spawns them does as little as possible.
        """
        specs = self._node_specs()
        from launcher.process.spawn import start_process
        started = self._started
        watchdog = self.watchdog
        clock = time.monotonic
        for spec in specs:
            if self._stop_requested:
                break
            started.append((spec, start_process(spec, watchdog), clock()))

    def _node_specs(self) -> list[Any]:
        """What to run for each local node; nodes that cannot be prepared are reported and noted."""
        from launcher.command import node_command
        from launcher.names import ns_join
        from launcher.process.spawn import ProcessSpec
        opts = self.opts
        if self.config.tests:
            # roslaunch skips <test> tags without a word; say so, they are the user's
            console.printlog("ignoring %d <test> node(s) (%s): run them with rostest"
                             % (len(self.config.tests), ", ".join(t.test_name or t.name for t in self.config.tests)))
        specs = []
        for node in self.config.nodes:
            if self._remote(node):
                console.printerrlog("skipping node [%s]: it is assigned to another machine (--local)"
                                    % node.full_name)
                continue
            self._counter += 1
            name = "%s-%d" % (ns_join(node.namespace, node.name), self._counter)
            name = name.lstrip("/")
            log_name = name.replace("/", "-")
            required = node.required or opts.required
            try:
                cmd = node_command(node, master_uri=self.master_uri, environ=self.environ,
                                   packages=self.packages, log_file=os.path.join(self.run_log_dir, log_name + ".log"))
            except LaunchError as e:
                console.printerrlog("ERROR: cannot launch node of type [%s/%s]: %s" % (node.package, node.type, e))
                self._not_started.append((name, required))
                continue
            output = node.output or "log"
            if opts.screen:
                output = "screen"
            elif getattr(opts, "log", False):
                output = "log"
            specs.append(ProcessSpec(
                name=name, argv=cmd.argv, env=cmd.env, cwd=cmd.cwd,
                stdout_path=os.path.join(self.run_log_dir, log_name + "-stdout.log") if output == "log" else None,
                log_dir=self.run_log_dir, respawn=node.respawn, respawn_delay=node.respawn_delay,
                required=required))
        return specs

    # ---- shutdown --------------------------------------------------------------------------------------

    async def _teardown(self) -> None:
        for t in self._tasks:
            t.cancel()
        if self.supervisor is not None:
            await self.supervisor.shutdown()
            self.supervisor.close()
        if self.rosout is not None:
            console.printlog("[rosout-1] killing on exit")
            try:
                await self.rosout.stop()
            except Exception as e:  # noqa: BLE001 - the master must still stop
                console.printerrlog("error stopping rosout: %s" % e)
        if self.master is not None:
            console.printlog("[master] killing on exit")
            await self.master.stop()
        console.printlog("shutting down processing monitor...")
        console.printlog("... shutting down processing monitor complete")
        console.printlog_bold("done")
        if self._log_file is not None:
            console.remove_handler(self._log_line)
            self._log_file.close()
            self._log_file = None
        sys.stdout.flush()
