"""No shutdown to a stale URI (ros/ros_comm#2241, #2018): when a node name registers again, the master tells
the old URI to shut down; if another node has taken that port since, Debian's rosmaster kills the wrong node
and ours, which checks the pid behind the URI first, does not. Both masters run the same scenario with real
rospy nodes."""

from __future__ import annotations

import os
import select
import signal
import subprocess
import sys
import time
import xmlrpc.client

import pytest

from helpers import Procs, free_port, until

pytestmark = pytest.mark.integration

RPC_DOWN = (OSError, xmlrpc.client.Error)

# a rospy node named argv[1] serving its slave API on port argv[2] (rospy's init_node takes xmlrpc_port)
NODE = """
import os, sys, rospy
rospy.init_node(sys.argv[1], xmlrpc_port=int(sys.argv[2]))
print('READY', os.getpid(), flush=True)
rospy.spin()
print('SHUTDOWN', flush=True)
"""


@pytest.fixture(params=["rosmaster", "ours"])
def master(request, ros_env, tmp_path):
    """(kind, procs, master proxy, env): Debian's rosmaster or our `launch --core` on a free port."""
    port = free_port()
    env = dict(os.environ, PATH=ros_env["path"] + ":" + os.environ.get("PATH", ""),
               ROS_MASTER_URI="http://127.0.0.1:%d/" % port, ROS_HOME=str(tmp_path / "home"),
               ROS_LOG_DIR=str(tmp_path / "log"), ROS_IP="127.0.0.1", PYTHONPATH="")
    env.pop("ROS_HOSTNAME", None)
    procs = Procs(env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    if request.param == "rosmaster":
        procs.start(["rosmaster", "--core", "-p", str(port)])
    else:
        launch_env = dict(env, PATH=os.environ.get("PATH", ""), PYTHONPATH=os.environ.get("PYTHONPATH", ""))
        procs.start([sys.executable, "-m", "launcher", "--core", "-p", str(port)], env=launch_env)
    proxy = xmlrpc.client.ServerProxy(env["ROS_MASTER_URI"])
    until(lambda: proxy.getPid("/t")[0] == 1, 30, what="the master", errors=RPC_DOWN)
    try:
        yield request.param, procs, proxy, env
    finally:
        procs.stop_all()


def _node(procs, ros_env, name: str, port: int):
    p = procs.start([ros_env["python"], "-c", NODE, name, str(port)])
    ready, _, _ = select.select([p.stdout], [], [], 30)
    line = p.stdout.readline() if ready else "(nothing within 30 s)"
    assert line.startswith("READY"), line
    return p


def test_a_name_registered_again_does_not_shut_down_the_node_that_took_its_old_port(master, ros_env):
    kind, procs, proxy, env = master
    port = free_port()
    first = _node(procs, ros_env, "a", port)
    old_uri = proxy.lookupNode("/t", "/a")[2]
    assert old_uri == "http://127.0.0.1:%d/" % port
    first.send_signal(signal.SIGKILL)  # gone without unregistering: the master still has /a at old_uri
    first.wait(10)
    assert "/a" in procs.run(["rosnode", "list"]).stdout.split()  # (the stale registration of the scenario)
    other = _node(procs, ros_env, "c", port)  # an unrelated node on the same port
    assert proxy.lookupNode("/t", "/c")[2] == old_uri
    again = _node(procs, ros_env, "a", 0)  # /a again: the master tells old_uri to shut down...
    until(lambda: proxy.lookupNode("/t", "/a")[2] != old_uri, 10, what="/a registered again")
    if kind == "rosmaster":
        # ...and rosmaster's shutdown reaches /c, which exits
        assert other.wait(15) is not None
        assert "SHUTDOWN" in other.stdout.read()
    else:
        # ours asks old_uri for its pid first: /c answers its own, so no shutdown goes (master.log says so)
        log = os.path.join(env["ROS_LOG_DIR"], "latest", "master.log")
        until(lambda: "shutdown of %s not sent" % old_uri in open(log).read(), 10,
              what="the master's decision in master.log", errors=(OSError,))
        end = time.monotonic() + 2.0
        while time.monotonic() < end:  # (rosmaster's shutdown takes effect well within this)
            assert other.poll() is None, "the node on the reused port was shut down"
            time.sleep(0.1)
        assert "/c" in procs.run(["rosnode", "list"]).stdout.split()
    assert again.poll() is None
