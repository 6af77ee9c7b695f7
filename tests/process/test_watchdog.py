"""No orphans: when the launcher is SIGKILLed, the guard kills every node and the nodes' children."""

from __future__ import annotations

import fcntl
import os
import re
import signal
import struct
import subprocess
import sys
import termios
import time
import textwrap

from launcher.process.watchdog import Watchdog, guard_argv

from helpers import descendants, pid_alive, until

# A stand-in launcher: the real guard and supervisor, nodes with grandchildren
# (one that ignores SIGTERM, one that moved to its own process group).
LAUNCHER = textwrap.dedent(r"""
    import asyncio, os, sys
    from launcher.process.watchdog import Watchdog
    from launcher.plan.command import NodeCommand
    from launcher.process.supervisor import ProcessSpec, Supervisor
    wd = Watchdog.start()
    tmp = sys.argv[1]
    GRAND = ("import os,signal,sys,time\n"
             "signal.signal(signal.SIGTERM, signal.SIG_IGN)\n"
             "os.setpgid(0, 0)\n"
             "open(os.path.join(sys.argv[1], 'g%d' % os.getpid()), 'w').close()\n"
             "time.sleep(100)")
    NODE = ("import subprocess,sys,time\n"
            "subprocess.Popen([sys.executable, '-c', sys.argv[1], sys.argv[2]])\n"
            "time.sleep(100)")
    async def main():
        sup = Supervisor(watchdog=wd)
        for i in range(3):
            sup.start(ProcessSpec("n%d-%d" % (i, i + 1), NodeCommand([sys.executable, "-c", NODE, GRAND, tmp],
                                                                     dict(os.environ), cwd=tmp)))
        print("up", flush=True)
        await asyncio.sleep(100)
    asyncio.run(main())
""")


def test_sigkill_of_launcher_leaves_no_process(tmp_path):
    p = subprocess.Popen([sys.executable, "-c", LAUNCHER, str(tmp_path)], stdout=subprocess.PIPE, text=True)
    try:
        while p.stdout.readline().strip() != "up":
            assert p.poll() is None
        until(lambda: len([f for f in os.listdir(tmp_path) if f.startswith("g")]) >= 3, 15, 0.01,
              what="grandchildren started")
        grandchildren = {int(f[1:]) for f in os.listdir(tmp_path) if f.startswith("g")}
        procs = descendants(p.pid) | grandchildren
        assert len(procs) >= 3 + 3 + 1  # nodes, grandchildren, guard
        os.kill(p.pid, signal.SIGKILL)
        p.wait()
        t0 = time.monotonic()
        while any(pid_alive(q) for q in procs):
            assert time.monotonic() - t0 < 1.0, "left running: %s" % [q for q in procs if pid_alive(q)]
            time.sleep(0.01)
    finally:
        p.kill()
        p.wait()
        for f in os.listdir(tmp_path):
            if f.startswith("g"):
                try:
                    os.kill(int(f[1:]), signal.SIGKILL)
                except OSError:
                    pass


def test_normal_exit_releases_guard_quickly():
    wd = Watchdog.start()
    assert wd is not None and pid_alive(wd.pid)
    child = subprocess.Popen(["sleep", "100"], start_new_session=True)
    wd.watch(child.pid)
    wd.forget(child.pid)
    t0 = time.monotonic()
    wd.close()  # reaps the guard
    assert time.monotonic() - t0 < 0.5
    assert child.poll() is None  # a forgotten group is left alone
    child.kill()
    child.wait()


def _gone(pid: int, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            if os.waitpid(pid, os.WNOHANG)[0] == pid:
                return True
        except ChildProcessError:
            return True
        time.sleep(0.01)
    return False


def unread(fd: int) -> int:
    """Bytes written to the pipe and not yet read by the guard."""
    return struct.unpack("i", fcntl.ioctl(fd, termios.FIONREAD, b"\0\0\0\0"))[0]


def test_exit_does_not_wait_for_an_idle_guard():
    wd = Watchdog.start()
    assert wd is not None
    child = subprocess.Popen(["sleep", "100"], start_new_session=True)
    wd.watch(child.pid)
    # the guard has read the line (the pipe is empty) and naps
    deadline = time.monotonic() + 10
    while unread(wd._wfd) and time.monotonic() < deadline:
        time.sleep(0.001)
    assert unread(wd._wfd) == 0
    wd.forget(child.pid)
    t0 = time.monotonic()
    wd.close()  # nothing left on the guard's list: it is ended and reaped at once
    assert time.monotonic() - t0 < 0.02
    assert not pid_alive(wd.pid)
    assert child.poll() is None  # and the forgotten group is left alone
    child.kill()
    child.wait()


def test_exit_waits_while_the_guard_has_groups_left():
    wd = Watchdog.start()
    assert wd is not None
    child = subprocess.Popen(["sleep", "100"], start_new_session=True)
    wd.watch(child.pid)
    wd.close()  # a group is still recorded: the guard deals with it before close returns
    assert _gone(child.pid, 0.5)  # (the guard killed it; it is our child, so reap it here)


def test_the_guard_imports_this_module_and_no_more_than_it_needs():
    """The guard starts beside every launch: it imports its module (cached bytecode, not a script compiled at each
    start) and the C half of `signal`, not `signal`'s enums (enum, functools, collections: ~3 ms of its start)."""
    argv = guard_argv()
    out = subprocess.run(argv[:1] + ["-X", "importtime"] + argv[1:], stdin=subprocess.DEVNULL,
                         capture_output=True, text=True, timeout=30)
    assert out.returncode == 0, out.stderr
    imported = set(re.findall(r"^import time:\s+\d+ \|\s+\d+ \|\s*(\S+)\s*$", out.stderr, re.M))
    assert "launcher.process.watchdog" in imported
    assert not imported & {"signal", "enum", "functools", "collections", "launcher.output", "launcher.model"}
