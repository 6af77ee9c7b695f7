"""Helpers for the health tests (readiness, hang, resources, core dumps): a supervisor on our real master, rospy nodes."""

from __future__ import annotations

import os
import sys
import time

from launcher.plan.command import NodeCommand
from launcher.model.config import NodePolicy
from launcher.services.masterlink import start_master
from launcher.output import console
from launcher.plan.specs import ProcessSpec
from launcher.fleet import lifecycle
from launcher.fleet.state import Change, Fleet, visible
from launcher.process.supervisor import Supervisor
from launcher.health.registration import Registrations

from helpers import ROS_PYTHON

TALKER = """
import sys, rospy, std_msgs.msg
rospy.init_node(sys.argv[1])
pub = rospy.Publisher(sys.argv[2], std_msgs.msg.String, queue_size=1)
rospy.spin()
"""


def node_spec(tmp_path, name: str, argv: list[str], master_uri: str = "", policy: NodePolicy | None = None,
              **kw) -> ProcessSpec:
    env = dict(os.environ)
    env.update(ROS_MASTER_URI=master_uri or "http://127.0.0.1:1/", ROS_HOME=str(tmp_path / "home"),
               ROS_LOG_DIR=str(tmp_path / "log"), PATH="/usr/bin:" + env.get("PATH", ""))
    env.pop("PYTHONPATH", None)  # Debian's python3 finds rospy in its own dist-packages
    return ProcessSpec(name + "-1", NodeCommand(argv, env, cwd=str(tmp_path)), node_name="/" + name,
                       policy=policy, **kw)


def talker(tmp_path, name: str, topic: str, master_uri: str, **kw) -> ProcessSpec:
    script = tmp_path / "talker.py"
    script.write_text(TALKER)
    return node_spec(tmp_path, name, [ROS_PYTHON, str(script), name, topic], master_uri, **kw)


def python_node(tmp_path, name: str, code: str, **kw) -> ProcessSpec:
    return node_spec(tmp_path, name, [sys.executable, "-I", "-S", "-c", code], **kw)


class Events:
    """Every fleet change as (monotonic time, node, state, reason); `registrations`: (monotonic time, node, uri
    or "" when it went) of each registration's coming and going."""

    def __init__(self, fleet: Fleet):
        self.items: list[tuple[float, str, str, str]] = []
        self.registrations: list[tuple[float, str, str]] = []
        fleet.listeners.append(self._changed)

    def _changed(self, change: Change) -> None:
        if change.event.kind in (lifecycle.REGISTERED, lifecycle.UNREGISTERED):
            self.registrations.append((time.monotonic(), change.new.name, change.new.uri))
        elif visible(change):
            s = change.status
            self.items.append((time.monotonic(), s.name, s.state, s.reason))

    def of(self, node: str, state: str) -> list[tuple[float, str, str, str]]:
        return [e for e in self.items if e[1] == node and e[2] == state]


async def supervisor_with_master(environ=None):
    """(our master on a free port, a supervisor) on the running loop."""
    master = await start_master(0, dict(environ or os.environ))
    sup = Supervisor(exit_when_all_dead=False, sigint_timeout=5.0, sigterm_timeout=1.0)
    Registrations(master.graph, sup.fleet)  # (its records told of their registrations, as a run's are)
    return master, sup


def console_err(capsys) -> str:
    """What the console wrote to stderr so far (its writer thread flushed first)."""
    console.flush()
    return capsys.readouterr().err
