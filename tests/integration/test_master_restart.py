"""An external master that restarts (clearpathrobotics/robot_upstart#35): Debian's roscore is killed and
started again on the same port; the launch sets its parameters again and restarts the nodes that were
registered with it (rospy nodes never register again by themselves), as Debian's rosparam and rosnode see."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import xmlrpc.client

import pytest

from helpers import ROS_PATH, free_port, until
from running import Launcher, master_proxy, master_up, write_launch
from running import ros_env as run_env

pytestmark = pytest.mark.integration

BODY = """
  <param name="/watched/greeting" value="hello"/>
  <rosparam param="/watched/list">[1, 2, 3]</rosparam>
  <node pkg="rostopic" type="rostopic" name="talker" args="pub /chatter std_msgs/String hello -r 5"/>
  <node pkg="rostopic" type="rostopic" name="listener" args="echo /chatter"/>
"""


def ros_tool(env: dict, *argv: str) -> str:
    return subprocess.run(list(argv), env=env, capture_output=True, text=True, timeout=30).stdout


def roscore(env: dict, port: int) -> subprocess.Popen:
    return subprocess.Popen(["roscore", "-p", str(port)], env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)


def pid_of(port: int, node: str) -> int:
    uri = master_proxy(port).lookupNode("/test", node)[2]
    return xmlrpc.client.ServerProxy(uri).getPid("/test")[2]


def kill_roscore(proc: subprocess.Popen, port: int) -> None:
    """SIGKILL for roscore, its rosmaster and its rosout (each a session of its own)."""
    pids = [master_proxy(port).getPid("/test")[2], pid_of(port, "/rosout"), proc.pid]
    for pid in pids:
        os.kill(pid, signal.SIGKILL)
    proc.wait(10)
    until(lambda: not master_up(port), 10, what="the master gone")


def stop_roscore(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)  # (it stops its master and rosout)
        proc.wait(30)


class Beside:
    """Debian's roscore on a free port (`core`, restarted by a test) and a launch of BODY that found it (`lp`)."""

    def __init__(self, tmp_path):
        self.tmp_path = tmp_path
        self.port = free_port()
        self.env = run_env(str(tmp_path), self.port, str(tmp_path))
        self.tool_env = dict(self.env, PATH=ROS_PATH, ROS_LOG_DIR=str(tmp_path / "corelog"))
        self.core = roscore(self.tool_env, self.port)
        self.lp = None

    def start_launch(self) -> None:
        until(lambda: master_up(self.port), 30, what="roscore up")
        until(lambda: "/rosout" in self.nodes(), 30, what="roscore's rosout")
        self.lp = Launcher([write_launch(str(self.tmp_path), BODY)],
                           dict(self.env, PATH=ROS_PATH + ":" + self.env["PATH"]), str(self.tmp_path))
        until(lambda: {"/talker", "/listener"} <= set(self.nodes()), 60, 0.2, what="the nodes registered")

    def nodes(self) -> list[str]:
        return ros_tool(self.tool_env, "rosnode", "list").split()

    def close(self) -> None:
        if self.lp is not None:
            self.lp.close()
        stop_roscore(self.core)


@pytest.fixture
def beside(tmp_path, ros_env):
    b = Beside(tmp_path)
    try:
        b.start_launch()
        yield b
    finally:
        b.close()


def test_a_restarted_roscore_gets_the_parameters_and_the_nodes_again(tmp_path, beside):
    port, tool_env, lp = beside.port, beside.tool_env, beside.lp
    before = lp.started_pids()

    kill_roscore(beside.core, port)
    beside.core = roscore(tool_env, port)
    until(lambda: master_up(port), 30, what="roscore up again")
    until(lambda: ros_tool(tool_env, "rosparam", "get", "/watched/greeting").strip() == "hello", 30, 0.2,
          what="the launch's parameters back")
    assert ros_tool(tool_env, "rosparam", "get", "/watched/list").split() == ["-", "1", "-", "2", "-", "3"]
    until(lambda: {"/talker", "/listener"} <= set(beside.nodes()), 30, 0.2, what="the nodes registered again")
    info = ros_tool(tool_env, "rostopic", "info", "/chatter")
    assert "/talker" in info and "/listener" in info, info
    after = lp.started_pids()
    assert len(before) == 2 and all(after[name] != pid for name, pid in before.items()), (before, after)
    lp.wait_output(r"the master at \S+ restarted .*restarting the 2 node\(s\) that were registered with it: "
                   r"/listener, /talker")
    events_file = next(os.path.join(root, f) for root, _, files in os.walk(tmp_path / "log")
                       for f in files if f == "launcher-events.jsonl")
    with open(events_file) as f:
        events = [json.loads(line) for line in f]
    restarted = [e for e in events if e.get("event") == "master_restarted"]
    assert restarted and restarted[0]["nodes"] == ["/listener", "/talker"], events


def test_a_master_that_stops_answering_and_comes_back_unchanged_restarts_nothing(beside):
    lp = beside.lp
    before = lp.started_pids()
    master_pid = master_proxy(beside.port).getPid("/test")[2]
    os.kill(master_pid, signal.SIGSTOP)  # silent, not gone
    try:
        lp.wait_output(r"WARNING: the master at \S+ does not answer", 20, stream="stderr")
    finally:
        os.kill(master_pid, signal.SIGCONT)
    lp.wait_output(r"the master at \S+ answers again", 20)
    assert lp.started_pids() == before
    assert "restarted" not in lp.stdout
