"""READY=1 under systemd's notify protocol comes when the nodes have registered, told by the master as it
happens: a real AF_UNIX datagram socket as $NOTIFY_SOCKET, Debian's rospy nodes that register 2, 4 and 6 s
after they start (the last one anonymous: found by its process), a shell script that never registers (READY=1
waits for --ready-timeout and STATUS= names it), and the same script with registers="false" (not waited for)."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import threading
import time
import xmlrpc.client

import pytest

from helpers import ROS_PATH, ROS_PYTHON, free_port, until
import running
from running import Launcher, make_package, write_launch

# imports rospy, waits argv[1] s, then registers as argv[2] (argv[3] "anon": init_node(anonymous=True) with the
# launch's remappings stripped, so its name is /NAME_PID_TIME, which the launch cannot know)
Registrar = """#!%s
import os, sys, time
import rospy
time.sleep(float(sys.argv[1]))
anon = sys.argv[3] == "anon"
rospy.init_node(sys.argv[2], anonymous=anon, argv=rospy.myargv() if anon else None)
rospy.spin()
""" % ROS_PYTHON
Helper = "#!/bin/sh\nexec sleep 1000\n"  # a program that is no ROS node


class NotifyReader:
    """The service manager's end: a bound datagram socket read by a thread, each message kept with the wall
    clock time it arrived."""

    def __init__(self, path: str):
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(path)
        self.sock.settimeout(0.1)
        self.messages: list[tuple[float, dict[str, str]]] = []
        self._stop = False
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self) -> None:
        while not self._stop:
            try:
                data = self.sock.recv(4096)
            except socket.timeout:
                continue
            when = time.time()
            self.messages.append((when, dict(line.split("=", 1) for line in data.decode().split("\n") if line)))

    def first(self, key: str, value: str):
        return next(((t, f) for t, f in list(self.messages) if f.get(key) == value), None)

    def close(self) -> None:
        self._stop = True
        self._thread.join(5)
        self.sock.close()


class RegistrationClock:
    """When each caller first appears in the master's graph (getSystemState every 20 ms, from a thread): the test's
    own measure of when a node registered. A registration lies between `not_before` (when the last call that did
    not show it was made: the master answered it later) and `seen` (when the first call that shows it returned).
    Under load that interval stretches, so each bound is checked against the end of it that makes it a fact."""

    def __init__(self, port: int, prefixes: tuple[str, ...]):
        self.master = xmlrpc.client.ServerProxy("http://127.0.0.1:%d/" % port)
        self.prefixes = prefixes
        self.seen: dict[str, float] = {}  # prefix -> wall clock time first seen
        self.not_before: dict[str, float] = {}  # prefix -> when the last call that did not show it was made
        self._stop = False
        self._thread = threading.Thread(target=self._poll, daemon=True)
        self._thread.start()

    def _poll(self) -> None:
        while not self._stop and len(self.seen) < len(self.prefixes):
            asked = time.time()
            try:
                _code, _msg, state = self.master.getSystemState("/test")
            except (OSError, xmlrpc.client.Error):
                time.sleep(0.02)
                continue
            now = time.time()
            callers = {c for kind in state for _name, nodes in kind for c in nodes}
            for prefix in self.prefixes:
                if prefix in self.seen:
                    continue
                if any(c == prefix or c.startswith(prefix + "_") for c in callers):
                    self.seen[prefix] = now
                else:
                    self.not_before[prefix] = asked
            time.sleep(0.02)

    def close(self) -> None:
        self._stop = True
        self._thread.join(5)


@pytest.fixture
def setup(tmp_path, ros_env):
    root = str(tmp_path / "pkgs")
    make_package(root, "ready_tests", {"registrar": Registrar, "helper.sh": Helper})
    port = free_port()
    env = running.ros_env(str(tmp_path), port, root)
    env["PATH"] = ROS_PATH + ":" + env.get("PATH", "")
    notify = NotifyReader(str(tmp_path / "notify"))
    env["NOTIFY_SOCKET"] = str(tmp_path / "notify")
    yield env, port, notify
    notify.close()


def registrar(name: str, delay: float, anon: bool = False) -> str:
    return '<node pkg="ready_tests" type="registrar" name="%s" args="%g %s %s"/>' % (
        name, delay, name, "anon" if anon else "named")


def test_ready_comes_within_half_a_second_of_the_last_registration_and_not_before(tmp_path, setup):
    env, port, notify = setup
    body = "\n".join([registrar("n0", 2), registrar("n1", 4), registrar("n2", 6, anon=True)])
    clock = RegistrationClock(port, ("/n0", "/n1", "/n2"))
    launch = Launcher([write_launch(str(tmp_path), body), "-p", str(port)], env, str(tmp_path))
    try:
        when_ready, fields = until(lambda: notify.first("READY", "1"), 60, what="READY=1")
        until(lambda: len(clock.seen) == 3, 10, what="every registration seen by the test's clock")
        order = sorted(clock.seen, key=clock.seen.get)
        assert order == ["/n0", "/n1", "/n2"], clock.seen
        assert clock.seen["/n2"] - clock.seen["/n0"] > 3.0, clock.seen  # (they registered seconds apart)
        last = clock.seen["/n2"]
        # not before: the last registration came after the clock's last call that did not show it was made
        early = clock.not_before["/n2"] - when_ready
        assert early <= 0, "READY=1 %.3f s before the last registration could have been" % early
        assert when_ready - last <= 0.5, "READY=1 %.3f s after the last registration" % (when_ready - last)
        assert fields["STATUS"] == "3/3 nodes running", fields
        # `launcher status --json` says so apart from running: each run registered, at its own URI (the anonymous
        # one too, found by its process: the master knows it by another name)
        nodes = {n["name"]: n for n in json.loads(launch_status(env, tmp_path))["nodes"]}
        assert all(nodes[n]["state"] == "running" and nodes[n]["registered"] for n in ("/n0", "/n1", "/n2")), nodes
        assert len({nodes[n]["uri"] for n in nodes}) == 3 and all(nodes[n]["uri"].startswith("http://") for n in nodes)
        anonymous = [c for c in callers(port) if c.startswith("/n2_")]
        assert len(anonymous) == 1 and "/n2" not in callers(port), anonymous
        assert master_call(port, "lookupNode", anonymous[0]) == nodes["/n2"]["uri"]
    finally:
        clock.close()
        launch.close()


def callers(port: int) -> set[str]:
    state = master_call(port, "getSystemState")
    return {c for kind in state for _name, nodes in kind for c in nodes}


def master_call(port: int, method: str, *args: str):
    code, msg, value = getattr(xmlrpc.client.ServerProxy("http://127.0.0.1:%d/" % port), method)("/test", *args)
    assert code == 1, msg
    return value


def launch_status(env: dict[str, str], tmp_path) -> str:
    out = subprocess.run([sys.executable, "-m", "launcher.cli.tool", "status", "--json"], env=env,
                         capture_output=True, text=True, timeout=30, cwd=str(tmp_path))
    return out.stdout


@pytest.mark.parametrize("registers", [None, "false"])
def test_a_program_that_is_no_ros_node_delays_ready_unless_it_says_so(tmp_path, setup, registers):
    env, port, notify = setup
    attr = ' registers="%s"' % registers if registers else ""
    body = registrar("n0", 0.5) + '\n<node pkg="ready_tests" type="helper.sh" name="helper"%s/>' % attr
    clock = RegistrationClock(port, ("/n0",))
    ready_timeout = 8.0
    started = time.time()
    launch = Launcher([write_launch(str(tmp_path), body), "-p", str(port), "--ready-timeout", "%g" % ready_timeout],
                      env, str(tmp_path))
    try:
        when_ready, fields = until(lambda: notify.first("READY", "1"), 60, what="READY=1")
        until(lambda: "/n0" in clock.seen, 10, what="n0's registration seen")
        if registers is None:
            # awaited until the ready timeout, then named
            assert when_ready - started >= ready_timeout, when_ready - started
            assert when_ready - clock.seen["/n0"] > ready_timeout - 4, (when_ready, clock.seen)
            assert fields["STATUS"] == "2/2 nodes running; not up after 8s: /helper", fields
        else:
            assert clock.not_before["/n0"] <= when_ready <= clock.seen["/n0"] + 0.5, (
                when_ready, clock.not_before, clock.seen)
            assert when_ready - started < ready_timeout, when_ready - started
            assert fields["STATUS"] == "2/2 nodes running", fields
    finally:
        clock.close()
        launch.close()
