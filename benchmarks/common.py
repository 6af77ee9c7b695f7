"""What the benchmark scripts share: Debian's ROS tools first on PATH, a free port, a Debian rosmaster, a process's
CPU and peak memory, the launchers compared and a workspace's environment.

The scripts run as `python3 benchmarks/NAME.py`, so this folder is on their import path.
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import time
import xmlrpc.client
from typing import Iterator

ROS_PATH = "/usr/bin:/bin:/usr/sbin:/sbin"  # Debian's ROS scripts need Debian's python: its bin first


def launcher_commands(given: list[str]) -> list[list[str]]:
    """`--cmd LABEL=COMMAND` options as [label, command] pairs; none given: roslaunch, the reference, and our
    `launch` beside this Python."""
    ours = os.path.join(os.path.dirname(sys.executable), "launch")
    return [c.split("=", 1) for c in given] or [["roslaunch", "roslaunch"], ["launch", ours]]


def tool_command(launch: list[str]) -> list[str]:
    """The `launcher` tool (status, ui, web, ...) of the install a launch command runs: `PYTHON -m launcher` gives
    `PYTHON -m launcher.cli.tool`, a `launch` script its `launcher` beside it; anything else, this Python's."""
    if launch[-1] == "launcher":
        return launch[:-1] + ["launcher.cli.tool"]
    if os.path.basename(launch[-1]) == "launch" and os.access(os.path.join(os.path.dirname(launch[-1]), "launcher"),
                                                                  os.X_OK):
        return launch[:-1] + [os.path.join(os.path.dirname(launch[-1]), "launcher")]
    return [sys.executable, "-m", "launcher.cli.tool"]


def workspace_env(root: str) -> dict:
    """This environment for a workspace of packages under `root`/pkgs, its ROS_HOME and log folder there too, and
    Debian's bin first on PATH (roslaunch is Debian's)."""
    env = dict(os.environ, ROS_PACKAGE_PATH=os.path.join(root, "pkgs"), ROS_HOME=os.path.join(root, "home"),
               ROS_LOG_DIR=os.path.join(root, "log"))
    env["PATH"] = ROS_PATH + ":" + env.get("PATH", "")
    return env


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextlib.contextmanager
def debian_rosmaster(port: int, env: dict, uri: str) -> Iterator[subprocess.Popen]:
    """Debian's rosmaster on `port` (with `env`, Debian's bin first on its PATH) from when it answers getPid at
    `uri` until the block ends; RuntimeError if it does not within 30 s."""
    env = dict(env, PATH=ROS_PATH + ":" + env.get("PATH", ""))
    master = subprocess.Popen(["rosmaster", "--core", "-p", str(port)], env=env, stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        deadline = time.monotonic() + 30
        while True:  # the master is up when it answers getPid
            try:
                xmlrpc.client.ServerProxy(uri).getPid("/bench")
                break
            except OSError:
                if master.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError("rosmaster did not start on %s" % uri) from None
                time.sleep(0.02)
        yield master
    finally:
        stop_process(master, 10)

def stop_process(proc: subprocess.Popen, timeout: float, group: bool = False) -> None:
    """A Ctrl-C to `proc` (to its process group with `group`), SIGKILL if it has not ended within `timeout` s;
    returns once it is reaped."""
    def send(sig: int) -> None:
        try:
            if group:
                os.killpg(proc.pid, sig)
            else:
                proc.send_signal(sig)
        except ProcessLookupError:
            pass  # (ended already: the wait reaps it)
    send(signal.SIGINT)
    try:
        proc.wait(timeout)
    except subprocess.TimeoutExpired:
        send(signal.SIGKILL)
        proc.wait()


def make_package(root: str, package: str) -> str:
    """An empty package `package` under `root` (its package.xml alone); its folder."""
    pkg = os.path.join(root, package)
    os.makedirs(pkg)
    with open(os.path.join(pkg, "package.xml"), "w") as f:
        f.write('<?xml version="1.0"?><package format="2"><name>%s</name><version>0.0.1</version>'
                '<description>b</description><maintainer email="b@example.com">b</maintainer>'
                '<license>BSD</license></package>\n' % package)
    return pkg


def idle_launch(root: str, package: str, n: int) -> str:
    """A package `package` under `root` with an idle node (`exec sleep`: one process per node) and a launch file of
    `n` of them; the launch file's path."""
    pkg = make_package(root, package)
    idle = os.path.join(pkg, "idle")
    with open(idle, "w") as f:
        f.write("#!/bin/sh\nexec sleep 100000\n")
    os.chmod(idle, 0o755)
    launch = os.path.join(root, "idle.launch")
    with open(launch, "w") as f:
        f.write("<launch>\n%s</launch>\n" % "".join('  <node pkg="%s" type="idle" name="n%d"/>\n' % (package, i)
                                                    for i in range(n)))
    return launch


def cpu_seconds(pid: int) -> float:
    """CPU time of all the process's threads, in ns resolution (stat's ticks are 10 ms: 1 % of a second)."""
    total = 0
    for tid in os.listdir("/proc/%d/task" % pid):
        try:
            with open("/proc/%d/task/%s/schedstat" % (pid, tid)) as f:
                total += int(f.read().split()[0])
        except OSError:
            pass  # a thread that just ended (a scrape's)
    return total / 1e9


def vm_hwm_mb(pid: int) -> float:
    """A running process's peak resident memory (VmHWM), in MB: every startup figure is reported beside it."""
    with open("/proc/%d/status" % pid) as f:
        for line in f:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def vmhwm_note(metrics: dict, labels: tuple = ("new", "roslaunch", "floor")) -> str:
    """ "VmHWM new 20.1 MB, roslaunch 47.3 MB" from a bench.py summary's metrics (its launcher_vmhwm_mb), or ''."""
    found = ["%s %.1f MB" % (label, metrics[label]["launcher_vmhwm_mb"]["median"]) for label in labels
             if metrics.get(label, {}).get("launcher_vmhwm_mb", {}).get("median") is not None]
    return "VmHWM " + ", ".join(found) if found else ""
