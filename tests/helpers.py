"""What tests share: waiting for a condition with a deadline, a free port, the processes a test started, /proc walks,
where things are, a launch server still setting up, a pipe's slow reader."""

from __future__ import annotations

import asyncio
import os
import random
import signal
import socket
import subprocess
import threading
import time
from types import SimpleNamespace
from typing import Any, Callable

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))  # the checkout
# The project's shared checks (compat corpus, master conformance suite) stand beside the checkout.
SHARED = os.path.normpath(os.path.join(ROOT, "..", "shared"))
COMPAT = os.path.join(SHARED, "compat")

# Debian's ROS scripts (rosnode, rostopic, ...) need Debian's own python.
ROS_PATH = "/usr/bin:/bin:/usr/sbin:/sbin"
ROS_PYTHON = os.environ.get("ROS_PYTHON", "/usr/bin/python3")


def _met(cond: Callable[[], Any], deadline: float, timeout: float, what: str, errors: tuple) -> Any:
    """cond()'s value if truthy, else None (try again); AssertionError once `deadline` has passed."""
    try:
        value = cond()
    except errors:
        value = None
    if value:
        return value
    if time.monotonic() > deadline:
        raise AssertionError("%s not met within %.1f s" % (what, timeout))
    return None


def until(cond: Callable[[], Any], timeout: float, period: float = 0.02, what: str = "condition",
          errors: tuple = ()) -> Any:
    """Poll `cond()` until truthy (returned), or fail after `timeout` s; an exception of `errors` means "not yet"."""
    deadline = time.monotonic() + timeout
    while (value := _met(cond, deadline, timeout, what, errors)) is None:
        time.sleep(period)
    return value


async def until_async(cond: Callable[[], Any], timeout: float, period: float = 0.005, what: str = "condition",
                      errors: tuple = ()) -> Any:
    """`until` on the running loop, which goes on meanwhile (a short period: loop tests time their events)."""
    deadline = time.monotonic() + timeout
    while (value := _met(cond, deadline, timeout, what, errors)) is None:
        await asyncio.sleep(period)
    return value


def _ephemeral_low() -> int:
    try:
        with open("/proc/sys/net/ipv4/ip_local_port_range") as f:
            return int(f.read().split()[0])
    except (OSError, ValueError, IndexError):
        return 32768


def free_port() -> int:
    """A loopback port no socket has (as of now), below the kernel's ephemeral range: a port the kernel
    hands out itself could become some client connection's own port (a node's, a test's) before the server
    the test starts binds it, and that server would then fail to start."""
    top = min(_ephemeral_low(), 65536)
    for _ in range(1000):
        port = random.randrange(max(1024, top // 2), top)
        with socket.socket() as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue
            return port
    raise AssertionError("no free port below %d" % top)


def post_once(port: int, body: bytes, timeout: float = 10.0, headers: bytes = b"") -> bytes:
    """The whole response to one HTTP POST of `body` to 127.0.0.1:`port`, on a connection of its own
    (`headers`: more header lines, each ending in CRLF)."""
    with socket.create_connection(("127.0.0.1", port), timeout=timeout) as s:
        s.sendall(b"POST / HTTP/1.1\r\nHost: x\r\nContent-Length: %d\r\nConnection: close\r\n%s\r\n"
                  % (len(body), headers) + body)
        chunks = []
        while chunk := s.recv(65536):
            chunks.append(chunk)
    return b"".join(chunks)


def still_running(proc: subprocess.Popen) -> bool:
    """True while `proc` runs; once it has exited, an AssertionError (which ends an `until` at once)."""
    assert proc.poll() is None, "%s exited (%s)" % (proc.args, proc.returncode)
    return True


class Procs:
    """Processes of one test, each in its own process group, all stopped at the end (SIGINT, then SIGKILL).

    `popen` are this test's defaults for `start` (e.g. where the output goes)."""

    def __init__(self, env: dict[str, str], **popen: Any):
        self.env = env
        self.popen = popen
        self.procs: list[subprocess.Popen] = []

    def start(self, argv: list[str], **kw: Any) -> subprocess.Popen:
        kw = {"env": self.env, **self.popen, **kw}
        proc = subprocess.Popen(argv, start_new_session=True, **kw)
        self.procs.append(proc)
        return proc

    def run(self, argv: list[str], timeout: float = 30) -> subprocess.CompletedProcess:
        return subprocess.run(argv, env=self.env, capture_output=True, text=True, timeout=timeout)

    def output(self, argv: list[str], timeout: float = 30) -> str:
        """stdout of a command that must succeed."""
        return subprocess.run(argv, env=self.env, capture_output=True, text=True, timeout=timeout,
                              check=True).stdout

    def stop_all(self) -> None:
        for proc in self.procs:
            if proc.poll() is None:
                try:
                    os.killpg(proc.pid, signal.SIGINT)
                except ProcessLookupError:
                    pass
        for proc in self.procs:
            try:
                proc.wait(5)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(5)


def _stat_fields(pid: int | str) -> list[str]:
    """/proc/PID/stat after the command name (which may hold spaces and parentheses): state, ppid, ..."""
    with open("/proc/%s/stat" % pid) as f:
        return f.read().rsplit(")", 1)[1].split()


def pid_alive(pid: int) -> bool:
    """Running, or at least not yet a zombie."""
    try:
        return _stat_fields(pid)[0] != "Z"
    except OSError:
        return False


def ignoring(pid: int, *signals: int) -> bool:
    """The process ignores each of these signals (a script's `trap ''` has run): its SigIgn mask in /proc."""
    try:
        with open("/proc/%d/status" % pid) as f:
            mask = int(next(line for line in f if line.startswith("SigIgn:")).split()[1], 16)
    except (OSError, StopIteration):
        return False
    return all(mask >> (sig - 1) & 1 for sig in signals)


def descendants(root: int) -> set[int]:
    """Every process below `root` (children, their children, ...), from one read of /proc."""
    kids: dict[int, list[int]] = {}
    for e in os.listdir("/proc"):
        if e.isdigit():
            try:
                ppid = int(_stat_fields(e)[1])
            except (OSError, IndexError, ValueError):
                continue
            kids.setdefault(ppid, []).append(int(e))
    out: set[int] = set()
    todo = [root]
    while todo:
        for c in kids.get(todo.pop(), []):
            out.add(c)
            todo.append(c)
    return out


def launch_server_setting_up(names: tuple = ("/a",), core: bool = False) -> tuple[Any, Callable[[], Any]]:
    """A server whose run has no fleet yet (its master and rosout are being started), and what then makes the
    fleet and starts its nodes as `NodeService.start` does: in one step of the loop, then `made` (a core: never)."""
    from launcher import compat
    from launcher.fleet import lifecycle as m
    from launcher.fleet.state import Fleet
    from launcher.services.server import LaunchServer
    nodes = SimpleNamespace(spec=lambda n: None, remote_names=lambda: [], made=compat.Event())
    run = SimpleNamespace(fleet=None, nodes=nodes, warnings=None, log_dir="", run_id="r", master_uri="",
                          launch_files=[], unresponsive=lambda: [], starting=not core)

    def make_nodes() -> Any:  # (the Fleet made)
        run.starting = False
        fleet = run.fleet = Fleet()
        for name in names:
            fleet.add(name)
            fleet.apply(name, m.Event(m.START))
        nodes.made.set()
        return fleet
    return LaunchServer(run, {"ROS_IP": "127.0.0.1"}), make_nodes


def start_reading(read_end: int, got: bytearray, size: int = 65536, rest: float = 0.0) -> threading.Thread:
    """A thread reading the pipe (or a pty's master) into `got` until its end, `size` at most a read, resting `rest`
    s after each. A pty's end is EIO, once every descriptor of its other side is closed."""
    def read() -> None:
        while True:
            try:
                data = os.read(read_end, size)
            except OSError:  # (EIO: a pty whose other side is closed)
                return
            if not data:
                return
            got.extend(data)
            time.sleep(rest)

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    return reader
