"""master.log: our master writes rosmaster's lines, in its format, for the same sequence of calls."""

from __future__ import annotations

import glob
import os
import re
import signal
import subprocess
import sys
import xmlrpc.client

from helpers import ROS_PATH, free_port, until
from running import master_up

LINE = re.compile(r"^\[(rosmaster\.\w+)\]\[INFO\] \d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d{3}: (.*)$")


def calls(port: int) -> None:
    """The same sequence for both masters (callback URIs nobody serves: the updates fail, and say so)."""
    m = xmlrpc.client.ServerProxy("http://127.0.0.1:%d/" % port)
    api = "http://127.0.0.1:9/"
    m.registerSubscriber("/listener", "/chatter", "std_msgs/String", api)
    m.registerPublisher("/talker", "/chatter", "std_msgs/String", api)
    m.setParam("/talker", "/talker/gain", 2)
    m.subscribeParam("/listener", api, "/talker/gain")
    m.setParam("/talker", "/talker/gain", 3)
    m.deleteParam("/talker", "/talker/gain")
    m.registerService("/talker", "/reset", "rosrpc://127.0.0.1:9", api)
    m.unregisterService("/talker", "/reset", "rosrpc://127.0.0.1:9")
    m.unsubscribeParam("/listener", api, "/talker/gain")
    m.unregisterPublisher("/talker", "/chatter", api)
    m.unregisterSubscriber("/listener", "/chatter", api)


def registrations(path: str) -> list[str]:
    """The +/- lines (registrations and parameters), in order, as (logger) message."""
    out = []
    with open(path) as f:
        for line in f:
            m = LINE.match(line.rstrip("\n"))
            if m and m.group(2)[:1] in "+-":
                out.append("%s %s" % m.groups())
    return out


def log_file(pattern: str) -> str | None:
    found = {os.path.realpath(p) for p in glob.glob(pattern)}  # (our run dir, and latest/ beside it)
    return found.pop() if len(found) == 1 else None


def run_master(cmd: list[str], env: dict[str, str], port: int, log_pattern: str) -> str:
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    try:
        until(lambda: master_up(port), 30, what="master up")
        calls(port)

        def callbacks_logged():  # (both masters call the nodes back in the background)
            path = log_file(log_pattern)
            return path if path and open(path).read().count("paramUpdate[/talker/gain") == 2 else None
        return until(callbacks_logged, 30, what="the callbacks in master.log")
    finally:
        os.killpg(proc.pid, signal.SIGINT)
        proc.wait(30)


def test_master_log_matches_rosmasters(tmp_path, ros_env):
    port = free_port()
    ref_env = dict(os.environ, PATH=ROS_PATH, ROS_LOG_DIR=str(tmp_path / "ref"), ROS_HOME=str(tmp_path / "h1"))
    ref_path = run_master(["rosmaster", "--core", "-p", str(port)], ref_env, port, str(tmp_path / "ref/master.log"))
    port = free_port()
    our_env = dict(os.environ, ROS_LOG_DIR=str(tmp_path / "ours"), ROS_HOME=str(tmp_path / "h2"))
    ours_path = run_master([sys.executable, "-m", "launcher", "--core", "-p", str(port)], our_env, port,
                           str(tmp_path / "ours/*/master.log"))
    theirs = registrations(ref_path)
    ours = [line for line in registrations(ours_path) if not re.search(r" /rosout( |$)", line)]  # (our core runs rosout)
    assert len(theirs) == 11
    assert ours == theirs
    with open(ours_path) as f:
        text = f.read()
    assert "[rosmaster.master][INFO]" in text and "Master initialized: port[%d]" % port in text
    assert re.search(r"publisherUpdate\[/chatter\] -> http://127.0.0.1:9/ \['http://127.0.0.1:9/'\]", text)
    assert "stopping master..." in text
    with open(ref_path) as f:
        assert re.findall(r"paramUpdate\[.*?\]", f.read()) == re.findall(r"paramUpdate\[.*?\]", text)
