"""A run's master: its URI, a running one found or ours started (`MasterSession`), and one parameter interface for either.

`Params` is what the run uses to touch the parameter server. `LocalParams`
calls our in-process master directly; `RemoteParams` speaks XML-RPC to a
master that was already running. Everything above this module (the
parameter upload, `<rosparam command=...>`, `/run_id`) is written once
against that interface.
"""

from __future__ import annotations

import asyncio
import os
from typing import TYPE_CHECKING, Any, Mapping

from launcher.model.errors import LaunchError
from launcher.net.hostname import advertised_host
from launcher.model.graph import Graph
from launcher.model.names import CALLER_ID, resolve_name
from launcher.net.http import split_uri
from launcher.net.xmlrpc import Fault, call
from launcher.plan.machines import is_local_host
from launcher.output import console
from launcher.model.runopts import RunOptions
from launcher.workspace.packages import package_version

if TYPE_CHECKING:  # (annotations only)
    from launcher.master.server import Master
    from launcher.plan.plan import Plan
    from launcher.services.service import Params, Signals

DEFAULT_MASTER_PORT = 11311
DEFAULT_ROSVERSION = "1.15.15"
DEFAULT_ROSDISTRO = "noetic"
# How long to wait for an answer from a master that accepted the connection.
PROBE_TIMEOUT_S = 3.0
PARAM_TIMEOUT_S = 30.0
# `--wait`: how often a master that is not up yet is asked again.
WAIT_POLL_S = 0.1
# How long a launch leaves a roscore that has just started its master to set /run_id itself.
ROSCORE_RUN_ID_WAIT_S = 20.0


def master_port(port: int | None, environ: Mapping[str, str]) -> int:
    """-p (`port`), else the port of ROS_MASTER_URI, else 11311 (as roscore picks it)."""
    if port:
        return int(port)
    uri = environ.get("ROS_MASTER_URI")
    if uri:
        try:
            port = split_uri(uri).port
        except ValueError:
            raise LaunchError("invalid ROS_MASTER_URI [%s]" % uri) from None
        if port:
            return port
    return DEFAULT_MASTER_PORT


def _roslaunch_package_xml(environ: Mapping[str, str]) -> str | None:
    """roslaunch's package.xml where rospkg would find it (no crawl: it sits at <entry>/roslaunch)."""
    roots = [p for p in environ.get("ROS_PACKAGE_PATH", "").split(os.pathsep) if p]
    roots += [os.path.join(p, "share") for p in environ.get("CMAKE_PREFIX_PATH", "").split(os.pathsep) if p]
    roots.append("/usr/share")  # Debian's rospkg always looks there
    for root in roots:
        candidate = os.path.join(root, "roslaunch", "package.xml")
        if os.path.isfile(candidate):
            return candidate
    return None


def ros_version_params(environ: Mapping[str, str]) -> tuple[str, str]:
    """(/rosversion, /rosdistro) as roscore sets them from `rosversion roslaunch` / `rosversion -d`.

    Both are command outputs, so they end with a newline. Without a ROS
    install there is no rosversion: sensible Noetic values are used instead.
    """
    package_xml = _roslaunch_package_xml(environ)
    version = package_version(package_xml) if package_xml is not None else None  # (unreadable: the default)
    distro = environ.get("ROS_DISTRO") or ("Debian" if package_xml is not None else DEFAULT_ROSDISTRO)
    return (version or DEFAULT_ROSVERSION).strip() + "\n", distro + "\n"


async def probe(uri: str) -> tuple[bool, tuple[Any, Any] | None]:
    """Does a master answer at `uri`? Asked as getParam('/run_id'): (answers, (code, value) of that call)."""
    try:
        reply = await call(uri, "getParam", CALLER_ID, "/run_id", timeout=PROBE_TIMEOUT_S)
    except Fault:
        return True, None  # anything answering XML-RPC with a fault is still a master
    except (OSError, ValueError, asyncio.TimeoutError):  # (XmlRpcError is a ValueError; so is a host idna refuses)
        return False, None
    if isinstance(reply, list) and len(reply) == 3:
        return True, (reply[0], reply[2])
    return True, None


async def started_by_roscore(uri: str) -> bool:
    """Is the master at `uri` a process of this machine whose parent is a roscore (roslaunch --core)?

    Such a roscore sets /run_id itself a moment after its master answers, and dies
    ("run_id on parameter server does not match declared run_id") if someone else set it
    first; a launch that finds that master must leave it the first move.
    """
    try:
        reply = await call(uri, "getPid", CALLER_ID, timeout=PROBE_TIMEOUT_S)
        pid = int(reply[2])
        with open("/proc/%d/stat" % pid, "rb") as f:
            ppid = int(f.read().rsplit(b")", 1)[1].split()[1])
        with open("/proc/%d/cmdline" % ppid, "rb") as f:
            argv = [a.decode(errors="replace") for a in f.read().split(b"\0")]
    except (Fault, OSError, ValueError, IndexError, TypeError, asyncio.TimeoutError):
        return False  # another machine's master, or one that will not say: nothing to wait for
    names = {os.path.basename(a) for a in argv[:2]}
    return "roscore" in names or ("roslaunch" in names and "--core" in argv)


class LocalParams:
    """The parameter server of our own, in-process master. Each key is resolved as the master resolves a client's,
    against our caller id, as RemoteParams' calls are: a launch-level `~x` (a literal name roslaunch passes on)
    is /roslaunch/x on either master, as on roslaunch's."""

    def __init__(self, master: Master):
        self.master = master

    async def has(self, key: str) -> bool:
        return self.master.params.has(resolve_name(key, CALLER_ID))

    async def get(self, key: str) -> Any:
        return self.master.params.get(resolve_name(key, CALLER_ID))

    async def set(self, key: str, value: Any) -> None:
        self.master.set_param(resolve_name(key, CALLER_ID), value)

    async def delete(self, key: str) -> None:
        try:
            self.master.delete_param(resolve_name(key, CALLER_ID))
        except KeyError:
            pass

    async def upload(self, clear: list[str], params: list[tuple[str, Any]]) -> None:
        for ns in clear:
            if await self.has(ns):
                await self.delete(ns)
        for key, value in params:
            try:
                self.master.set_param(resolve_name(key, CALLER_ID), value)
            except ValueError as e:  # a value no client could read back (setParam refuses it too)
                raise LaunchError("Failed to set parameter: %s" % e) from None


class RemoteParams:
    """The parameter server of a master that was already running, over XML-RPC."""

    def __init__(self, uri: str):
        self.uri = uri

    async def _call(self, method: str, *args: Any) -> Any:
        try:
            code, msg, value = await call(self.uri, method, CALLER_ID, *args, timeout=PARAM_TIMEOUT_S)
        except (OSError, ValueError, Fault, asyncio.TimeoutError) as e:
            raise LaunchError("%s failed on the master at [%s]: %s" % (method, self.uri, e or type(e).__name__)) \
                from None
        if code != 1:
            raise LaunchError(msg)
        return value

    async def has(self, key: str) -> bool:
        return bool(await self._call("hasParam", key))

    async def get(self, key: str) -> Any:
        return await self._call("getParam", key)

    async def set(self, key: str, value: Any) -> None:
        await self._call("setParam", key, value)

    async def delete(self, key: str) -> None:
        """Delete `key`; one that is not set is no error (as with our own master)."""
        try:
            await call(self.uri, "deleteParam", CALLER_ID, key, timeout=PARAM_TIMEOUT_S)
        except (OSError, ValueError, Fault, asyncio.TimeoutError) as e:
            raise LaunchError("deleteParam failed on the master at [%s]: %s" % (self.uri, e or type(e).__name__)) \
                from None

    async def upload(self, clear: list[str], params: list[tuple[str, Any]]) -> None:
        if not params and not clear:
            return
        # one round trip: deletes first, then sets (the master runs a multicall in order)
        calls = [{"methodName": "deleteParam", "params": [CALLER_ID, ns]} for ns in clear]
        calls += [{"methodName": "setParam", "params": [CALLER_ID, k, v]} for k, v in params]
        try:
            results = await call(self.uri, "system.multicall", calls, timeout=PARAM_TIMEOUT_S)
        except Exception as e:  # noqa: BLE001
            raise LaunchError("cannot set the launch's parameters on the master at [%s]: %s"
                              % (self.uri, e)) from None
        for (key, _value), result in zip(params, results[len(clear):]):
            if isinstance(result, dict):
                raise LaunchError("Failed to set parameter [%s]: %s" % (key, result.get("faultString")))
            code, msg, _ = result[0]
            if code != 1:
                raise LaunchError("Failed to set parameter: %s" % msg)


async def start_master(port: int, environ: Mapping[str, str], allow: Any = None) -> Master:
    """Our master on `port`, serving, with roscore's /rosversion and /rosdistro set. OSError if the port is taken.

    `allow` (a launcher.net.allow.AllowList) closes it to clients from other networks."""
    from launcher.master.server import Master  # (here: a launch that uses a master found running loads none of it)
    master = Master(port=port, environ=environ, allow=allow)
    await master.start()
    rosversion, rosdistro = ros_version_params(environ)
    master.set_param("/rosversion", rosversion)
    master.set_param("/rosdistro", rosdistro)
    return master


def new_run_id() -> str:
    """A new run id: a UUID, as roslaunch's are, of version 4 (random) where roslaunch's `uuid.uuid1()` is
    time-based: the uuid module imports platform & co., ~0.2 MB a launch would keep for one call."""
    h = os.urandom(16).hex()
    return "%s-%s-4%s-%x%s-%s" % (h[:8], h[8:12], h[13:16], 8 | int(h[16], 16) & 3, h[17:20], h[20:])


class MasterSession:
    """A run's master as one service: found (or, for a core, started) first, then ours started when none
    answers, the run id, the parameters; stopped last.

    `find` runs before the run's log is open (its run id names the log), `start`
    once the summary is printed, `set_parameters` once the master's clients
    (rosout) are up. `is_a_process`: roslaunch starts the master as a process
    of the launch, and says so ("auto-starting new master", "[master] killing
    on exit"); rostest's runs inside it, started and stopped without a word.
    """

    is_a_process = True

    def __init__(self, opts: RunOptions, plan: Plan, signals: Signals):
        self.opts = opts
        self.plan = plan
        self.signals = signals
        self.core = plan.core
        self.uri = plan.master_uri
        self.master: Master | None = None  # ours, when we run it
        self.params: Params | None = None  # LocalParams or RemoteParams
        self.external = False  # a master was already running
        self.run_id = ""
        self._graph = Graph()  # what is registered with a master found running (its watcher asks)
        self._run_id_known: bool | None = None  # is /run_id set on a running master? (None: not known)

    @property
    def graph(self) -> Graph:
        """What is registered with the run's master: ours tells it as it happens; a master found running is
        asked by the run's watcher (services/masterwatch.py)."""
        return self.master.graph if self.master is not None else self._graph

    # ---- find ------------------------------------------------------------------------------------------

    async def find(self) -> None:
        """The master at the master URI, the run id; a core starts its own here (a busy port is all it has to say)."""
        if self.core:
            await self._start_master(self.plan.core_port)
            self.run_id = self._decide_run_id(None)
            return
        self.external, reply = await self._find_master()
        self.run_id = self._decide_run_id(reply)
        if reply is not None:
            self._run_id_known = True if reply[0] == 1 else False if reply[0] == -1 else None

    async def _find_master(self) -> tuple[bool, tuple[Any, Any] | None]:
        """(a master already answers at the master URI, its getParam('/run_id') reply); roslaunch uses it."""
        answers, reply = await probe(self.uri)
        if answers and self.opts.master_allow:
            console.printerrlog("WARNING: --master-allow has no effect: the master at %s is not started "
                                "by this launch" % self.uri)
        if not answers and self.opts.wait:
            console.printlog("master has not been started, waiting for it at %s ..." % self.uri)
            while not answers:
                await asyncio.sleep(WAIT_POLL_S)
                answers, reply = await probe(self.uri)
        if answers:
            if (reply is not None and reply[0] != 1 and not self.opts.run_id
                    and await started_by_roscore(self.uri)):
                reply = await self._wait_for_roscore_run_id(reply)
            return True, reply
        host = split_uri(self.uri).hostname or ""
        if not is_local_host(host, self.plan.environ):
            raise LaunchError("unable to contact ROS master at [%s]; it is not on this machine, so it cannot be "
                              "started here" % self.uri)
        return False, None

    async def _wait_for_roscore_run_id(self, reply: tuple[Any, Any]) -> tuple[Any, Any]:
        """A roscore's master answers before the roscore has set /run_id: let it (roscore dies if we set it
        first); after ROSCORE_RUN_ID_WAIT_S without one, go on and set our own."""
        deadline = asyncio.get_running_loop().time() + ROSCORE_RUN_ID_WAIT_S
        while reply[0] != 1 and asyncio.get_running_loop().time() < deadline:
            await asyncio.sleep(WAIT_POLL_S)
            answers, new = await probe(self.uri)
            reply = new if answers and new is not None else reply
        return reply

    def _decide_run_id(self, reply: tuple[Any, Any] | None) -> str:
        code, value = reply or (0, None)
        if code == 1 and value:
            if self.opts.run_id and self.opts.run_id != value:
                raise LaunchError("run_id on parameter server does not match declared run_id: %s vs %s"
                                  % (value, self.opts.run_id))
            return str(value)
        if self.opts.run_id:
            return self.opts.run_id
        return new_run_id()

    # ---- start -----------------------------------------------------------------------------------------

    def _master_allow(self) -> Any:
        """`--master-allow` / `--core --allow`: the AllowList of our master, or None (open, as rosmaster)."""
        cidrs = [c for arg in self.opts.master_allow for c in arg.split(",") if c.strip()]
        if not cidrs:
            return None
        from launcher.net.allow import AllowList  # (with ipaddress, ~0.25 MB: only for an allow-list)
        try:
            return AllowList(cidrs)
        except ValueError as e:
            raise LaunchError("--master-allow: %s" % e) from None

    async def _start_master(self, port: int) -> None:
        allow = self._master_allow()
        try:
            self.master = await start_master(port, self.plan.environ, allow=allow)
        except OSError as e:
            if self.core:
                raise LaunchError(
                    "RLException: roscore cannot run as another roscore/master is already running. \n"
                    "Please kill other roscore/master processes before relaunching.\n"
                    "The ROS_MASTER_URI is http://%s:%d/ (%s)" % (advertised_host(self.plan.environ), port,
                                                                 e.strerror or e)) from None
            raise LaunchError("unable to start the master on port %d: %s" % (port, e.strerror or e)) from None
        if self.core:
            self.uri = self.master.uri
        if allow is not None:
            console.printlog("master answers only clients from loopback, this machine and: %s" % allow)

    def open_log(self, run_dir: str) -> None:
        """master.log in the run's log directory (ours only)."""
        if self.master is not None and run_dir:
            self.master.open_log(os.path.join(run_dir, "master.log"))

    async def start(self, run_dir: str) -> None:
        """Ours started unless one answered, the parameter interface, /run_id."""
        if not self.external:
            if self.is_a_process:
                console.printlog("auto-starting new master")
            if self.master is None:
                await self._start_master(split_uri(self.uri).port or DEFAULT_MASTER_PORT)
        if not self.core:
            self.open_log(run_dir)
        self.params = LocalParams(self.master) if self.master is not None else RemoteParams(self.uri)
        console.printlog_bold("ROS_MASTER_URI=%s" % self.uri)
        await self.signals.guard(self._set_run_id(self._run_id_known))

    async def _set_run_id(self, known: bool | None) -> None:
        """Set /run_id unless a running master has one (ours never has)."""
        if self.master is None:
            if known is None:
                known = await self.params.has("/run_id")
            if known:
                return
        console.printlog_bold("setting /run_id to %s" % self.run_id)
        await self.params.set("/run_id", self.run_id)

    async def run_id_after_restart(self, seen: str | None) -> str:
        """The /run_id of a master found running that has restarted (`seen`: what it had when asked): a
        roscore's sets its own a moment after its master answers (roscore dies if another sets it first);
        a bare rosmaster gets this run's, as at the launch's start."""
        if seen:
            return seen
        if await started_by_roscore(self.uri):
            code, value = await self._wait_for_roscore_run_id((-1, None))
            if code == 1 and value:
                return str(value)
        await self._set_run_id(False)
        return self.run_id

    async def restore_parameters(self) -> None:
        """The launch's parameters set again (clear_params first), on a master that restarted and lost them."""
        await self.params.upload(list(self.plan.config.clear_params), self._parameters())

    def _parameters(self) -> list[tuple[str, Any]]:
        """What the launch sets, in roslaunch's order: roscore.xml's /rosversion and /rosdistro first (roslaunch
        reads that file into every launch and sets its parameters on whatever master it finds, ours or not), then
        the launch's own, which may replace them."""
        rosversion, rosdistro = ros_version_params(self.plan.environ)
        return [("/rosversion", rosversion), ("/rosdistro", rosdistro)] + \
            [(p.key, p.value) for p in self.plan.config.params.values()]

    def summary_params(self) -> dict[str, Any]:
        """The launch's parameters as the summary lists them."""
        return dict(self._parameters())

    async def set_parameters(self) -> None:
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
        await self.restore_parameters()

    # ---- running and stopping --------------------------------------------------------------------------

    @property
    def shutdown_requested(self) -> asyncio.Event | None:
        """Set when a client calls our master's `shutdown`."""
        return self.master.shutdown_requested if self.master is not None else None

    async def stop(self) -> None:
        if self.master is not None:
            if not self.core and self.is_a_process:
                console.printlog("[master] killing on exit")
            await self.master.stop()
