"""A launcher whose stdout nobody reads keeps its master answering and its nodes respawning."""

from __future__ import annotations

import fcntl
import os
import subprocess
import sys
import termios
import time
import xmlrpc.client

from helpers import free_port, until
from running import make_package, master_up, ros_env, write_launch

# Appends a line per start to $STARTS, then dies: a respawning node that is never up for long.
Crasher = """#!/bin/sh
echo start >> "$STARTS"
exit 1
"""

F_SETPIPE_SZ = 1031  # (fcntl has the name from Python 3.10 on Linux only)


class _TimeoutTransport(xmlrpc.client.Transport):
    """A master call that gets no answer within 5 s fails instead of hanging the test."""

    def make_connection(self, host):
        conn = super().make_connection(host)
        conn.timeout = 5.0
        return conn


def _unread(fd: int) -> int:
    return int.from_bytes(fcntl.ioctl(fd, termios.FIONREAD, b"\0\0\0\0"), sys.byteorder)


def _starts(path: str) -> int:
    try:
        with open(path) as f:
            return len(f.readlines())
    except FileNotFoundError:
        return 0


def test_master_answers_and_nodes_respawn_while_stdout_is_blocked(tmp_path):
    pkgs = str(tmp_path / "pkgs")
    make_package(pkgs, "blocked", {"crasher": Crasher})
    starts = str(tmp_path / "starts.txt")
    # ten of them, with long names: the console's queue (128 KiB) overflows within seconds
    launch_file = write_launch(str(tmp_path), "\n".join(
        '<node pkg="blocked" type="crasher" name="crasher_%d_%s" respawn="true" respawn_delay="0.05"/>'
        % (i, "x" * 200) for i in range(10)))  # (log file names stay under 255)
    port = free_port()
    env = ros_env(str(tmp_path), port, pkgs)
    env["STARTS"] = starts
    read_end, write_end = os.pipe()
    fcntl.fcntl(write_end, F_SETPIPE_SZ, 4096)  # one page: a few dozen lines fill it
    proc = subprocess.Popen([sys.executable, "-m", "launcher", "-p", str(port), launch_file], env=env,
                            stdout=write_end, stderr=subprocess.DEVNULL, stdin=subprocess.DEVNULL)
    os.close(write_end)
    try:
        until(lambda: master_up(port), 30, what="master up")
        # nobody reads: the pipe fills with "started"/"restarting" lines
        until(lambda: _unread(read_end) >= 3000, 60, what="stdout pipe full")  # (a line that does not fit waits whole)
        full_at = _starts(starts)
        master = xmlrpc.client.ServerProxy("http://127.0.0.1:%d/" % port, transport=_TimeoutTransport())
        slow = []
        deadline = time.monotonic() + 3.0
        while time.monotonic() < deadline:  # the master keeps answering, each call well within 1 s
            t0 = time.monotonic()
            assert master.getPid("/test")[0] == 1
            slow += [time.monotonic() - t0] if time.monotonic() - t0 > 1.0 else []
        assert not slow, slow
        # and the nodes keep being respawned, long enough for the console to drop lines
        until(lambda: _starts(starts) >= full_at + 500, 60, what="respawns while stdout is blocked")
        # once the output flows again, the launcher says how much it dropped
        got = b""
        fcntl.fcntl(read_end, fcntl.F_SETFL, os.O_NONBLOCK)

        def drained():
            nonlocal got
            try:
                got += os.read(read_end, 65536)
            except BlockingIOError:
                pass
            return b"dropped while the output was blocked" in got
        until(drained, 30, what="the dropped-lines notice")
    finally:
        proc.terminate()
        try:
            proc.wait(5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        os.close(read_end)
