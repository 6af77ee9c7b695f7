"""`launch --core`: the roscore equivalent (master, roscore's parameters, built-in rosout)."""

from __future__ import annotations

import os
import signal
import sys
import urllib.parse
from typing import Any, Mapping

from launcher.errors import LaunchError
from launcher.net.open_files import raise_open_file_limit

DEFAULT_ROSVERSION = "1.15.15"
DEFAULT_ROSDISTRO = "noetic"


def master_port(opts: Any, environ: Mapping[str, str]) -> int:
    """-p, else the port of ROS_MASTER_URI, else 11311 (as roscore picks it)."""
    if getattr(opts, "port", None):
        return int(opts.port)
    uri = environ.get("ROS_MASTER_URI")
    if uri:
        try:
            port = urllib.parse.urlsplit(uri).port
        except ValueError:
            raise LaunchError("invalid ROS_MASTER_URI [%s]" % uri) from None
        if port:
            return port
    return 11311


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


def log_dir(environ: Mapping[str, str], run_id: str) -> str:
    """$ROS_LOG_DIR or $ROS_HOME/log (default ~/.ros/log), plus the run id."""
    root = environ.get("ROS_LOG_DIR")
    if not root:
        home = environ.get("ROS_HOME") or os.path.join(os.path.expanduser("~"), ".ros")
        root = os.path.join(home, "log")
    return os.path.join(root, run_id)


def run_core(opts: Any) -> int:
    """Run master + rosout until SIGINT/SIGTERM or a `shutdown` call; exit status."""
    environ = dict(os.environ)
    port = master_port(opts, environ)
    uri_port = master_port(None, environ)
    if environ.get("ROS_MASTER_URI") and uri_port != port:
        print("WARNING: ROS_MASTER_URI port [%d] does not match this roscore [%d]" % (uri_port, port),
              file=sys.stderr)
    import asyncio  # (here: `launch` imports this module for ros_version_params before it needs asyncio)
    import uuid
    run_id = getattr(opts, "run_id", None) or str(uuid.uuid1())
    pid_fn = getattr(opts, "pid_fn", None)
    if pid_fn:
        try:
            with open(pid_fn, "w") as f:
                f.write("%d" % os.getpid())
        except OSError as e:
            raise LaunchError("cannot write the pid file %s: %s" % (pid_fn, e.strerror or e)) from None
    raise_open_file_limit()  # every client connection is a file: the master's cap derives from the limit
    try:
        return asyncio.run(_core(port, run_id, environ))
    except KeyboardInterrupt:
        return 0
    finally:
        if pid_fn:
            try:
                os.unlink(pid_fn)
            except OSError:
                pass


async def _core(port: int, run_id: str, environ: dict[str, str]) -> int:
    import asyncio

    from launcher.master import Master

    master = Master(port=port, environ=environ)
    try:
        await master.start()
    except OSError as e:
        print("RLException: roscore cannot run as another roscore/master is already running. \n"
              "Please kill other roscore/master processes before relaunching.\n"
              "The ROS_MASTER_URI is http://%s:%d/ (%s)" % (_display_host(environ), port, e.strerror or e),
              file=sys.stderr)
        return 1
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    rosout = None
    try:
        rosversion, rosdistro = ros_version_params(environ)
        print("ros_comm version %s" % rosversion.strip())
        print("\nSUMMARY\n========\n\nPARAMETERS\n * /rosdistro: %s\n * /rosversion: %s\n\nNODES\n"
              % (rosdistro.strip(), rosversion.strip()))
        print("auto-starting new master")
        master.set_param("/rosversion", rosversion)
        master.set_param("/rosdistro", rosdistro)
        print("ROS_MASTER_URI=%s" % master.uri)
        master.set_param("/run_id", run_id)
        print("setting /run_id to %s" % run_id)
        rosout = await _start_rosout(master.uri, log_dir(environ, run_id))
        sys.stdout.flush()
        waiters = [asyncio.ensure_future(stop.wait()), asyncio.ensure_future(master.shutdown_requested.wait())]
        await asyncio.wait(waiters, return_when=asyncio.FIRST_COMPLETED)
        for w in waiters:
            w.cancel()
        if master.shutdown_requested.is_set():
            print("shutdown request: %s" % master.shutdown_reason)
    finally:
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.remove_signal_handler(sig)
        if rosout is not None:
            try:
                await rosout.stop()
            except Exception as e:  # noqa: BLE001 - the master must still stop
                print("error stopping rosout: %s" % e, file=sys.stderr)
        await master.stop()
    print("done")
    return 0


async def _start_rosout(master_uri: str, directory: str) -> Any:
    """The built-in rosout, if this install has it."""
    try:
        from launcher.net.rosout import Rosout
    except ModuleNotFoundError as e:
        if e.name in ("launcher.net.rosout",):
            print("no built-in rosout available: /rosout is not served", file=sys.stderr)
            return None
        raise
    rosout = Rosout(master_uri, directory)
    try:
        await rosout.start()
    except Exception as e:  # noqa: BLE001 - the master keeps serving without rosout
        print("failed to start the built-in rosout: %s" % e, file=sys.stderr)
        try:
            await rosout.stop()
        except Exception:  # noqa: BLE001
            pass
        return None
    print("started core service [/rosout]")
    return rosout


def _display_host(environ: Mapping[str, str]) -> str:
    from launcher.master import advertised_host
    return advertised_host(environ)
