"""`launch` under systemd's notify protocol: what it sends to a real AF_UNIX datagram socket given as $NOTIFY_SOCKET,
from a real launch of real rospy nodes (READY=1 only once they registered, STATUS= through a crash and its respawn,
WATCHDOG=1 at half of WATCHDOG_USEC and none while the loop is held, STOPPING=1 at Ctrl-C)."""

from __future__ import annotations

import ctypes
import json
import os
import re
import signal
import socket
import statistics
import subprocess
import sys
import time

import pytest

from helpers import ROOT, ROS_PATH, ROS_PYTHON, free_port, until
from running import Launcher, SlowSpinner, make_package, master_proxy, ros_env, write_launch

# a program that never registers and dies after a while (respawned by the launch)
Crasher = "#!/bin/sh\nsleep 6\nexit 3\n"


class NotifySocket:
    """The service manager's end: a bound datagram socket, each message kept with its arrival (wall clock)."""

    def __init__(self, path: str):
        self.path = path
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(path)
        self.sock.setblocking(False)
        self.messages: list[tuple[float, dict[str, str]]] = []

    def read(self) -> list[tuple[float, dict[str, str]]]:
        while True:
            try:
                data = self.sock.recv(4096)
            except BlockingIOError:
                return self.messages
            fields = dict(line.split("=", 1) for line in data.decode().split("\n") if line)
            self.messages.append((time.time(), fields))

    def first(self, key: str, value: str | None = None, after: float = 0.0):
        for when, fields in self.read():
            if when >= after and key in fields and (value is None or fields[key] == value):
                return when, fields
        return None

    def close(self) -> None:
        self.sock.close()


@pytest.fixture
def setup(tmp_path, ros_env):
    root = str(tmp_path / "pkgs")
    make_package(root, "sd_tests", {"slow_spinner": SlowSpinner, "crasher": Crasher})
    stamps = tmp_path / "stamps"
    stamps.mkdir()
    notify = NotifySocket(str(tmp_path / "notify"))
    env = ros_env_for(str(tmp_path), root)
    env.update(NOTIFY_SOCKET=notify.path, STAMPS=str(stamps))
    yield env, notify, stamps
    notify.close()


def ros_env_for(tmp: str, root: str) -> dict[str, str]:
    env = ros_env(tmp, free_port(), root)
    env["PATH"] = ROS_PATH + ":" + env.get("PATH", "")
    return env


def port_of(env: dict[str, str]) -> int:
    return int(env["ROS_MASTER_URI"].rsplit(":", 1)[1].strip("/"))


def test_ready_after_registration_status_through_respawn_and_stopping(tmp_path, setup):
    env, notify, stamps = setup
    # (the crasher is no ROS node and says so: registers="false"; the rospy nodes count once registered)
    body = "\n".join('<node pkg="sd_tests" type="slow_spinner" name="n%d" args="%s n%d" respawn_min_uptime="20"/>'
                     % (i, delay, i) for i, delay in enumerate((0.2, 1.0, 2.0)))
    body += '\n<node pkg="sd_tests" type="crasher" name="crasher" respawn="true" respawn_delay="1" registers="false"/>'
    launch = Launcher([write_launch(str(tmp_path), body), "-p", str(port_of(env))], env, str(tmp_path))
    try:
        when_ready, fields = launch.until(lambda: notify.first("READY", "1"), 60, what="READY=1")
        # READY=1 came after every rospy node began to register (and each is registered now) ...
        for i in range(3):
            began = float((stamps / ("n%d" % i)).read_text())
            assert when_ready > began, "READY=1 %.3fs before n%d registered" % (began - when_ready, i)
            assert master_proxy(port_of(env)).lookupNode("/test", "/n%d" % i)[0] == 1
        # ... and said so: all four up (the crasher, which never registers, counts once it runs)
        assert fields["STATUS"] == "4/4 nodes running", fields
        # the crash and the respawn are told as they happen
        crashed, _ = launch.until(lambda: notify.first("STATUS", "3/4 nodes running, 1 respawning"), 30,
                           what="STATUS= of the crash")
        launch.until(lambda: notify.first("STATUS", "4/4 nodes running", after=crashed), 30,
                     what="STATUS= of the respawn")
        # Ctrl-C: STOPPING=1 comes first, before the launch has ended
        launch.signal(signal.SIGINT)
        launch.until(lambda: notify.first("STOPPING", "1"), 20, what="STOPPING=1")
        assert launch.wait(30) == 0
        stopping = next(i for i, (_, f) in enumerate(notify.read()) if "STOPPING" in f)
        assert not any("READY" in f for _, f in notify.read()[stopping:])
        # the watchdog was not asked for (no WATCHDOG_USEC): no pings
        assert not any("WATCHDOG" in f for _, f in notify.read())
    finally:
        launch.close()


def test_watchdog_at_half_the_period_and_none_while_the_loop_is_held(tmp_path, setup):
    env, notify, _stamps = setup
    env["WATCHDOG_USEC"] = "400000"  # pings every 0.2 s
    body = '<node pkg="sd_tests" type="slow_spinner" name="n0" args="0 n0"/>'
    launch = Launcher([write_launch(str(tmp_path), body), "-p", str(port_of(env))], env, str(tmp_path))
    try:
        launch.until(lambda: notify.first("READY", "1"), 60, what="READY=1")
        pings = lambda: [t for t, f in notify.read() if f.get("WATCHDOG") == "1"]  # noqa: E731
        n = len(pings())
        until(lambda: len(pings()) >= n + 10, 10, what="10 more pings")
        gaps = [b - a for a, b in zip(pings()[n:], pings()[n + 1:])]
        assert 0.15 < statistics.median(gaps) < 0.3, gaps
        # hold the launch's main thread (its loop) for 3 s, as a loop stuck in a call would be; its other
        # threads run on (SIGSTOP would stop them too): no ping may come while it is held
        held_from = time.time()
        hold_one_thread(launch.pid, 3.0)
        held_to = time.time()
        count = len(pings())
        until(lambda: len(pings()) >= count + 3, 10, what="pings again once the loop runs")
        during = [t for t in pings() if held_from + 0.5 < t < held_to - 0.5]
        assert not during, "pings while the loop was held: %r" % during
        assert max(b - a for a, b in zip(pings(), pings()[1:])) >= 3.0
    finally:
        launch.close()


def hold_one_thread(tid: int, seconds: float) -> None:
    """Stop thread `tid` alone for `seconds`: ptrace is per thread, and PTRACE_SEIZE with PTRACE_INTERRUPT stops
    the tracee without the group stop a SIGSTOP would bring (gdb's `call sleep(3)` did the same, but an inferior
    call needs the registers written back, which some virtual machines refuse: "Couldn't write extended state")."""
    libc = ctypes.CDLL(None, use_errno=True)
    libc.ptrace.restype = ctypes.c_long
    libc.ptrace.argtypes = [ctypes.c_long, ctypes.c_long, ctypes.c_void_p, ctypes.c_void_p]
    seize, interrupt, detach = 0x4206, 0x4207, 17
    if libc.ptrace(seize, tid, None, None) != 0:
        raise OSError(ctypes.get_errno(), "PTRACE_SEIZE %d" % tid)
    try:
        if libc.ptrace(interrupt, tid, None, None) != 0:
            raise OSError(ctypes.get_errno(), "PTRACE_INTERRUPT %d" % tid)
        os.waitpid(tid, 0x40000000)  # (__WALL: the tracee's stop)
        time.sleep(seconds)
    finally:
        libc.ptrace(detach, tid, None, None)


def test_without_notify_socket_nothing_is_sent(tmp_path, setup):
    env, notify, _stamps = setup
    del env["NOTIFY_SOCKET"]
    env["WATCHDOG_USEC"] = "200000"
    body = '<node pkg="sd_tests" type="slow_spinner" name="n0" args="0 n0"/>'
    launch = Launcher([write_launch(str(tmp_path), body), "-p", str(port_of(env))], env, str(tmp_path))
    try:
        until(lambda: master_proxy(port_of(env)).lookupNode("/test", "/n0")[0] == 1, 60, what="n0 registered",
              errors=(OSError,))
        launch.signal(signal.SIGINT)
        assert launch.wait(30) == 0
        assert notify.read() == []
    finally:
        launch.close()


def test_ready_timeout_sends_ready_naming_the_nodes_not_up(tmp_path, setup):
    env, notify, _stamps = setup
    body = ('<node pkg="sd_tests" type="slow_spinner" name="n0" args="0 n0"/>\n'
            '<node pkg="sd_tests" type="slow_spinner" name="late" args="1000 late" respawn_min_uptime="2000"/>')
    launch = Launcher([write_launch(str(tmp_path), body), "--ready-timeout", "3"], env, str(tmp_path))
    try:
        started = time.time()
        when, fields = launch.until(lambda: notify.first("READY", "1"), 30, what="READY=1 at the ready timeout")
        assert 2.5 < when - started < 10, when - started
        assert fields["STATUS"] == "2/2 nodes running; not up after 3s: /late", fields
    finally:
        launch.close()


# a rospy node writing INFO (stdout), ERROR (stderr) and a plain stderr line
Chatty = """#!%s
import sys, rospy
rospy.init_node("chatty")
rospy.loginfo("all is well")
rospy.logerr("the arm is stuck")
sys.stderr.write("a plain line on stderr\\n")
sys.stderr.flush()
rospy.spin()
""" % ROS_PYTHON


def test_journal_stream_gets_priority_and_node_per_line(tmp_path, setup):
    env, _notify, _stamps = setup
    del env["NOTIFY_SOCKET"]
    make_package(str(tmp_path / "pkgs"), "sd_tests", {"chatty": Chatty})
    out_path = tmp_path / "journal.out"
    with open(out_path, "wb") as out:
        st = os.fstat(out.fileno())
        env["JOURNAL_STREAM"] = "%d:%d" % (st.st_dev, st.st_ino)
        proc = subprocess.Popen([sys.executable, "-m", "launcher", "--screen",
                                 write_launch(str(tmp_path), '<node pkg="sd_tests" type="chatty" name="chatty"/>')],
                                env=env, stdout=out, stderr=subprocess.STDOUT)
        try:
            until(lambda: b"a plain line" in out_path.read_bytes(), 60, what="the node's lines")
            lines = out_path.read_bytes().splitlines()
            assert any(re.fullmatch(rb"<6>chatty-\d+: \[INFO\] \[[\d.]+\]: all is well", x) for x in lines), lines
            assert any(re.fullmatch(rb"<3>chatty-\d+: \[ERROR\] \[[\d.]+\]: the arm is stuck", x) for x in lines), lines
            assert any(re.fullmatch(rb"<3>chatty-\d+: a plain line on stderr", x) for x in lines), lines
        finally:
            proc.send_signal(signal.SIGINT)
            proc.wait(30)


# Run inside a mount namespace whose /run is a tmpfs: the test's socket stands where journald's native socket is.
JOURNAL_READER = r'''
import json, os, signal, socket, subprocess, sys, time
out_path, launch_file = sys.argv[1:3]
sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
sock.bind("/run/systemd/journal/socket")
sock.settimeout(0.5)
with open(out_path, "wb") as out:
    st = os.fstat(out.fileno())
    env = dict(os.environ, JOURNAL_STREAM="%d:%d" % (st.st_dev, st.st_ino))
    proc = subprocess.Popen([sys.executable, "-m", "launcher", "--screen", launch_file], env=env, stdout=out,
                            stderr=subprocess.STDOUT)
entries, deadline = [], time.time() + 60
while time.time() < deadline and not any("a plain line" in e.get("MESSAGE", "") for e in entries):
    try:
        data = sock.recv(65536)
    except socket.timeout:
        continue
    entries.append(dict(line.split("=", 1) for line in data.decode().split("\n") if line))
proc.send_signal(signal.SIGINT)
proc.wait(30)
print(json.dumps(entries))
'''


def test_journal_socket_gets_an_entry_per_line_with_the_nodes_fields(tmp_path, setup):
    """Under systemd (journald's socket there), `journalctl -u NAME ROS_NODE=/chatty` or `-t chatty-1` finds one
    node's lines and `-p err` its errors: each line is an entry with PRIORITY, SYSLOG_IDENTIFIER and ROS_NODE."""
    env, _notify, _stamps = setup
    del env["NOTIFY_SOCKET"]
    make_package(str(tmp_path / "pkgs"), "sd_tests", {"chatty": Chatty})
    reader = tmp_path / "reader.py"
    reader.write_text(JOURNAL_READER)
    out_path = tmp_path / "journal.out"
    launch = write_launch(str(tmp_path), '<node pkg="sd_tests" type="chatty" name="chatty"/>')
    done = subprocess.run(["unshare", "--mount", "--propagation", "private", "sh", "-c",
                           'mount -t tmpfs tmpfs /run && mkdir -p /run/systemd/journal && exec "$@"', "sh",
                           sys.executable, str(reader), str(out_path), launch],
                          env=dict(env, PYTHONPATH=ROOT), capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    entries = json.loads(done.stdout)
    by_message = {e["MESSAGE"]: e for e in entries}
    info = next(e for m, e in by_message.items() if m.endswith("all is well"))
    error = next(e for m, e in by_message.items() if m.endswith("the arm is stuck"))
    plain = by_message["a plain line on stderr"]
    assert re.fullmatch(r"\[INFO\] \[[\d.]+\]: all is well", info["MESSAGE"])
    assert (info["PRIORITY"], error["PRIORITY"], plain["PRIORITY"]) == ("6", "3", "3")
    for e in (info, error, plain):
        assert re.fullmatch(r"chatty-\d+", e["SYSLOG_IDENTIFIER"]) and e["ROS_NODE"] == "/chatty", e
    # the node's lines went to the journal as entries, not also to the stream; the launcher's own lines still do
    stream = out_path.read_bytes()
    assert b"all is well" not in stream and b"a plain line" not in stream, stream
    assert b"process[chatty-" in stream, stream
