"""A clean master: what a node's process registered goes when it ends, as Debian's rosnode and rostopic see,
and a new run of the same name keeps its own registrations."""

from __future__ import annotations

import os
import signal
import subprocess
import time

from helpers import ROS_PATH, free_port, until
from running import Launcher, master_proxy, write_launch
from running import ros_env as run_env

BODY = """
  <node pkg="rostopic" type="rostopic" name="talker" args="pub /chatter std_msgs/String hello -r 10"/>
  <node pkg="rostopic" type="rostopic" name="listener" args="echo /chatter"/>
  <node pkg="rostopic" type="rostopic" name="ticker" args="pub /ticks std_msgs/Empty -r 5" respawn="true"/>
"""


def ros_tool(env: dict, *argv: str) -> str:
    return subprocess.run(list(argv), env=env, capture_output=True, text=True, timeout=30).stdout


def publishers(port: int, topic: str) -> list[str]:
    _code, _msg, (pubs, _subs, _srvs) = master_proxy(port).getSystemState("/test")
    return next((nodes for name, nodes in pubs if name == topic), [])


def pid_at(port: int, node: str) -> int | None:
    """The pid that answers at the node's registered URI (None: not registered, or no answer)."""
    import xmlrpc.client
    code, _msg, api = master_proxy(port).lookupNode("/test", node)
    if code != 1:
        return None
    try:
        return xmlrpc.client.ServerProxy(api).getPid("/test")[2]
    except OSError:
        return None


def test_a_killed_nodes_registrations_go_at_once_and_a_respawned_ones_stay(tmp_path, ros_env):
    port = free_port()
    env = run_env(str(tmp_path), port, str(tmp_path))
    env["PATH"] = ROS_PATH
    lp = Launcher([write_launch(str(tmp_path), BODY)], env, str(tmp_path))
    try:
        until(lambda: publishers(port, "/chatter") == ["/talker"] and publishers(port, "/ticks") == ["/ticker"]
              and pid_at(port, "/talker") and pid_at(port, "/ticker"), 60, 0.2, what="the nodes registered",
              errors=(OSError,))
        assert "/talker" in ros_tool(env, "rosnode", "list").split()

        os.kill(pid_at(port, "/talker"), signal.SIGKILL)
        killed_at = time.monotonic()
        until(lambda: "/talker" not in ros_tool(env, "rosnode", "list").split(), 5, 0.05,
              what="/talker gone from rosnode list")
        assert time.monotonic() - killed_at < 1.0 + 0.5  # (within 1 s; a rosnode run itself takes ~0.3 s)
        info = ros_tool(env, "rostopic", "info", "/chatter")
        assert "Publishers: None" in info and "/listener" in info, info

        first = pid_at(port, "/ticker")
        os.kill(first, signal.SIGKILL)
        until(lambda: pid_at(port, "/ticker") not in (None, first), 30, 0.1, what="the ticker respawned")
        # the end of its first run must not take the new run's registrations with it
        end = time.monotonic() + 2.0
        while time.monotonic() < end:
            assert publishers(port, "/ticks") == ["/ticker"], "the respawned ticker's publication went"
            time.sleep(0.1)
        assert "/ticker" in ros_tool(env, "rosnode", "list").split()
    finally:
        lp.close()
