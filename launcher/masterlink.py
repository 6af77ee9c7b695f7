"""A run's master: its URI, a running one found or ours started, and one parameter interface for either.

`Params` is what the run uses to touch the parameter server. `LocalParams`
calls our in-process master directly; `RemoteParams` speaks XML-RPC to a
master that was already running. Everything above this module (the
parameter upload, `<rosparam command=...>`, `/run_id`) is written once
against that interface.
"""

from __future__ import annotations

import asyncio
import os
import urllib.parse
from typing import Any, Mapping

from launcher.errors import LaunchError
from launcher.master import Master
from launcher.net.xmlrpc import Fault, call
from launcher.plan.machines import is_local_host  # noqa: F401 (where a run asks whether its master is here)
from launcher.runopts import RunOptions

CALLER_ID = "/roslaunch"
DEFAULT_MASTER_PORT = 11311
DEFAULT_ROSVERSION = "1.15.15"
DEFAULT_ROSDISTRO = "noetic"
# How long to wait for an answer from a master that accepted the connection.
PROBE_TIMEOUT_S = 3.0
PARAM_TIMEOUT_S = 30.0


def master_port(opts: RunOptions, environ: Mapping[str, str]) -> int:
    """-p, else the port of ROS_MASTER_URI, else 11311 (as roscore picks it)."""
    if opts.port:
        return int(opts.port)
    uri = environ.get("ROS_MASTER_URI")
    if uri:
        try:
            port = urllib.parse.urlsplit(uri).port
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
    version = None
    if package_xml is not None:
        from launcher.xml.document import XmlSyntaxError, element_text, parse_xml
        try:
            with open(package_xml, "rb") as f:
                root, _ = parse_xml(f.read())
            version = next((element_text(c) for c in root if c.tag == "version"), None)
        except (OSError, XmlSyntaxError):  # unreadable manifest: fall back
            version = None
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
    """The parameter server of our own, in-process master."""

    def __init__(self, master: Any):
        self.master = master

    async def has(self, key: str) -> bool:
        return self.master.params.has(key)

    async def get(self, key: str) -> Any:
        return self.master.params.get(key)

    async def set(self, key: str, value: Any) -> None:
        self.master.set_param(key, value)

    async def delete(self, key: str) -> None:
        try:
            self.master.delete_param(key)
        except KeyError:
            pass

    async def upload(self, clear: list[str], params: list[tuple[str, Any]]) -> None:
        for ns in clear:
            if await self.has(ns):
                await self.delete(ns)
        for key, value in params:
            try:
                self.master.set_param(key, value)
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


async def start_master(port: int, environ: Mapping[str, str], allow: Any = None) -> Any:
    """Our master on `port`, serving, with roscore's /rosversion and /rosdistro set. OSError if the port is taken.

    `allow` (a launcher.net.allow.AllowList) closes it to clients from other networks."""
    master = Master(port=port, environ=environ, allow=allow)
    await master.start()
    rosversion, rosdistro = ros_version_params(environ)
    master.set_param("/rosversion", rosversion)
    master.set_param("/rosdistro", rosdistro)
    return master
