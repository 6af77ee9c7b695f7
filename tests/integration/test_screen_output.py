"""output="screen" through the launcher: `launcher logs -f` follows screen nodes (roscpp, rospy) and log nodes;
a node sees a tty under a terminal and a pipe otherwise; no output is lost, even while the terminal is blocked,
and it all comes before the node's exit line."""

from __future__ import annotations

import fcntl
import json
import os
import pty
import re
import shlex
import signal
import struct
import subprocess
import sys
import termios
import time

import pytest

from helpers import ROS_PYTHON, free_port, start_reading, until
from running import Launcher, compile_roscpp, make_package, master_up, ros_env, stop_group, write_launch

pytestmark = pytest.mark.integration

# rospy node: a plain print per tick (flushed: stdout is a pipe in this test, as it would be under roslaunch)
RospyPrinter = """#!%s
import rospy
rospy.init_node("printer")
n = 0
while not rospy.is_shutdown():
    n += 1
    print("print %%d" %% n, flush=True)
    rospy.sleep(0.2)
""" % ROS_PYTHON

# what a node sees of its output streams: one JSON line on stdout, then a plain (unflushed) print per tick
Looker = """#!%s
import json, os, stat, sys, time
def kind(fd):
    mode = os.fstat(fd).st_mode
    return "tty" if os.isatty(fd) else "pipe" if stat.S_ISFIFO(mode) else "other"
try:
    os.close(os.open("/dev/tty", os.O_RDWR))
    controlling = True
except OSError:
    controlling = False
try:
    size = list(os.get_terminal_size(1))
except OSError:
    size = None
print("LOOK " + json.dumps({"stdout": kind(1), "stderr": kind(2), "same": os.path.samestat(os.fstat(1), os.fstat(2)),
                            "controlling": controlling, "size": size}))
n = 0
while True:
    n += 1
    print("line %%d" %% n)  # not flushed: only a tty's line buffering shows it at once
    time.sleep(0.2)
""" % sys.executable

# many numbered lines as fast as it can, then exits
Flood = """#!%s
import sys
out = sys.stdout
for i in range(int(sys.argv[1])):
    out.write("flood line %%d\\n" %% i)
""" % sys.executable

# the size of its terminal as it asks for it, each tick
Sizer = """#!%s
import os, time
while True:
    print("SIZE %%dx%%d" %% tuple(os.get_terminal_size(1)), flush=True)
    time.sleep(0.1)
""" % sys.executable

LOOKER_LAUNCH = '<node pkg="screen_tests" type="looker" name="looker" output="screen"/>'


@pytest.fixture
def pkgs(tmp_path, ros_env):
    pkg = make_package(str(tmp_path / "pkgs"), "screen_tests",
                       {"printer": RospyPrinter, "looker": Looker, "flood": Flood, "sizer": Sizer})
    compile_roscpp("info_node.cpp", os.path.join(pkg, "info_cpp"))
    return str(tmp_path / "pkgs")


def tool(env: dict, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "launcher.cli.tool"] + list(args), env=env, capture_output=True,
                          text=True, timeout=60)


def test_logs_follow_roscpp_and_rospy_screen_nodes_and_a_log_node(tmp_path, pkgs):
    env = ros_env(str(tmp_path), free_port(), pkgs)
    launch = write_launch(str(tmp_path), """
      <node pkg="screen_tests" type="info_cpp" name="cpp" output="screen">
        <env name="ROSCONSOLE_STDOUT_LINE_BUFFERED" value="1"/></node>
      <node pkg="screen_tests" type="printer" name="py" output="screen"/>
      <node pkg="screen_tests" type="printer" name="lg" output="log"/>
    """)
    lp = Launcher([launch], env, str(tmp_path))
    followers = {}
    try:
        lp.wait_output(r"process\[lg-4\]: started")
        for node in ("/cpp", "/py", "/lg"):
            path = tmp_path / ("follow%s.txt" % node.replace("/", "_"))
            out = open(path, "w")
            followers[node] = (path, out, subprocess.Popen(
                [sys.executable, "-m", "launcher.cli.tool", "logs", "-f", "-n", "-1", node], env=env, stdout=out,
                stderr=subprocess.STDOUT))

        def numbers(node, word):
            return [int(n) for n in re.findall(word + r" (\d+)", followers[node][0].read_text())]
        for node, word in (("/cpp", r"\[ INFO\] \[[\d.]+\]: tick"), ("/py", "print"), ("/lg", "print")):
            first = until(lambda: numbers(node, word), 60, 0.2, what="%s's output followed" % node)
            assert first == list(range(1, len(first) + 1))  # from its first line, in order
            until(lambda: max(numbers(node, word)) >= max(first) + 3, 30, 0.2, what="%s's new output" % node)
        # the screen nodes' lines are on the launcher's stdout too, as under roslaunch
        assert re.search(r"\[ INFO\] \[[\d.]+\]: tick 1\b", lp.stdout) and "print 1\n" in lp.stdout
        r = tool(env, "logs", "/cpp", "-n", "2")
        assert r.returncode == 0 and len(r.stdout.splitlines()) == 2 and "tick" in r.stdout, r
    finally:
        for _, out, proc in followers.values():
            proc.send_signal(signal.SIGINT)
            proc.wait(10)
            out.close()
        lp.close()


def _script(tmp_path, env: dict, launch: str, port: int) -> tuple[subprocess.Popen, str]:
    """The launcher on a real terminal (util-linux `script` gives it a pty), 100x37; the terminal's text goes to
    a file."""
    typescript = str(tmp_path / "typescript")
    inner = "stty cols 100 rows 37; exec %s -m launcher -p %d %s" % (sys.executable, port, shlex.quote(launch))
    proc = subprocess.Popen(["script", "-qfc", inner, typescript], env=env, stdin=subprocess.PIPE,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    return proc, typescript


def _look(text: str) -> dict:
    m = re.search(r"LOOK (\{.*\})", text)
    return json.loads(m.group(1)) if m else None


def test_a_screen_node_sees_a_tty_under_a_terminal(tmp_path, pkgs):
    port = free_port()
    env = ros_env(str(tmp_path), port, pkgs)
    launch = write_launch(str(tmp_path), LOOKER_LAUNCH)
    proc, typescript = _script(tmp_path, env, launch, port)
    try:
        def terminal():
            try:
                with open(typescript, errors="replace", newline="") as f:
                    return f.read()
            except FileNotFoundError:
                return ""
        look = until(lambda: _look(terminal()), 60, 0.1, what="the node's look at its streams")
        # one pty for both streams, sized like the terminal, and not the node's controlling terminal
        assert look == {"stdout": "tty", "stderr": "tty", "same": True, "controlling": False, "size": [100, 37]}
        # line buffered, as on a terminal: unflushed prints arrive one by one
        until(lambda: "line 3\r\n" in terminal(), 30, 0.1, what="unflushed lines on the terminal")
        # and the copy has the node's bytes ("\n"), not the terminal's ("\r\n")
        log = until(lambda: _file(tmp_path, "looker-2-stdout.log"), 30, 0.1, what="the copy")
        until(lambda: "line 3\n" in _file(tmp_path, "looker-2-stdout.log"), 30, 0.1, what="lines in the copy")
        assert "\r" not in _file(tmp_path, "looker-2-stdout.log") and log.startswith("LOOK ")
    finally:
        stop_group(proc, 30)


def test_a_screen_node_sees_the_terminal_resized(tmp_path, pkgs):
    """The launcher's controlling terminal is a pty of the test's; resizing it (SIGWINCH to the launcher) resizes
    the node's pty, so the node sees the new size when it asks, as a node on the terminal itself does."""
    port = free_port()
    env = ros_env(str(tmp_path), port, pkgs)
    launch = write_launch(str(tmp_path), '<node pkg="screen_tests" type="sizer" name="sizer" output="screen"/>')
    terminal, own = pty.openpty()
    fcntl.ioctl(own, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 80, 0, 0))

    def controlling_terminal() -> None:  # (in the launcher's process, before exec)
        os.setsid()
        fcntl.ioctl(0, termios.TIOCSCTTY, 0)
    proc = subprocess.Popen([sys.executable, "-m", "launcher", "-p", str(port), launch], env=env, stdin=own,
                            stdout=own, stderr=own, preexec_fn=controlling_terminal)
    os.close(own)
    screen = bytearray()

    reader = start_reading(terminal, screen)  # (the terminal must be read, or the launcher blocks writing to it)
    try:
        until(lambda: b"SIZE 80x24" in screen, 60, 0.1, what="the node's first size")
        fcntl.ioctl(terminal, termios.TIOCSWINSZ, struct.pack("HHHH", 40, 120, 0, 0))
        until(lambda: b"SIZE 120x40" in screen, 30, 0.1, what="the new size seen by the node")
    finally:
        stop_group(proc, 30)
        os.close(terminal)
        reader.join(10)


def test_a_screen_node_sees_a_pipe_when_the_output_is_not_a_terminal(tmp_path, pkgs):
    env = ros_env(str(tmp_path), free_port(), pkgs)
    lp = Launcher([write_launch(str(tmp_path), LOOKER_LAUNCH)], env, str(tmp_path))
    try:
        look = until(lambda: _look(lp.stdout), 60, 0.1, what="the node's look at its streams")
        assert look == {"stdout": "pipe", "stderr": "pipe", "same": False, "controlling": False, "size": None}
    finally:
        lp.close()


def _file(tmp_path, name: str) -> str:
    latest = tmp_path / "log" / "latest" / name
    try:
        with open(latest, newline="") as f:  # (as written: "\r" stays)
            return f.read()
    except FileNotFoundError:
        return ""



F_SETPIPE_SZ = 1031


def test_no_output_lost_while_the_terminal_is_blocked_and_all_before_the_exit_line(tmp_path, pkgs):
    lines = 200000  # ~3.4 MB: far more than the pipe, the pty and the console's queue hold
    port = free_port()
    env = ros_env(str(tmp_path), port, pkgs)
    launch = write_launch(str(tmp_path), '<node pkg="screen_tests" type="flood" name="flood" output="screen" '
                                         'args="%d"/>' % lines)
    read_end, write_end = os.pipe()
    fcntl.fcntl(write_end, F_SETPIPE_SZ, 4096)
    proc = subprocess.Popen([sys.executable, "-m", "launcher", "-p", str(port), launch], env=env, stdout=write_end,
                            stderr=subprocess.DEVNULL, stdin=subprocess.DEVNULL)
    os.close(write_end)
    got = bytearray()
    try:
        until(lambda: master_up(port), 30, what="master up")
        # nobody reads the launcher's stdout: the node is held back (its copy stops growing) rather than
        # its output dropped
        copy = tmp_path / "log" / "latest" / "flood-2-stdout.log"
        until(lambda: copy.exists() and copy.stat().st_size > 0, 30, what="the node writing")
        size = -1
        deadline = time.monotonic() + 60
        while copy.stat().st_size != size:  # (settles once the node blocks)
            assert time.monotonic() < deadline, "the node never blocked"
            size = copy.stat().st_size
            time.sleep(0.5)
        assert size < lines * 12
        # the output flows again: every line, in order, then the exit line
        fcntl.fcntl(read_end, fcntl.F_SETFL, os.O_NONBLOCK)

        def read_all():
            try:
                while True:
                    data = os.read(read_end, 65536)
                    if not data:
                        break
                    got.extend(data)
            except BlockingIOError:
                pass
            return b"[flood-2] process has finished cleanly" in got
        until(read_all, 120, 0.05, what="the node's exit line")
        # (the launcher's own lines come between chunks of the node's output, as they would between the node's
        # writes on a shared terminal)
        text = re.sub(r"Done checking log file disk usage\. Usage is <1GB\.\n", "", got.decode())
        body = text[text.index("flood line 0\n"):text.index("[flood-2] process has finished cleanly")]
        expected = "".join("flood line %d\n" % i for i in range(lines))
        assert body == expected  # all of it, in order, and before the exit line
        assert copy.read_text() == expected
        assert "dropped" not in text
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            # keep reading so that the launcher can say its last lines and exit
            deadline = time.monotonic() + 30
            while proc.poll() is None and time.monotonic() < deadline:
                try:
                    os.read(read_end, 65536)
                except BlockingIOError:
                    time.sleep(0.05)
            proc.wait(5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        os.close(read_end)
