"""Ordered stops: a node bound to another (`bind_to`) is stopped before it. The spawner here, like a
controller spawner, needs its manager to answer while it stops: stopped after it, it would wait out its
sigint_timeout and be killed."""

from __future__ import annotations

import os
import signal
import time

from helpers import ROS_PATH, ROS_PYTHON, free_port, until
from running import Launcher, make_package, write_launch
from running import ros_env as run_env

# a rospy node that answers "ok" on a plain TCP port (MANAGER_PORT) and goes at once on SIGINT
MANAGER = """#!%s
import os, socket, threading, rospy
rospy.init_node("manager")
server = socket.create_server(("127.0.0.1", int(os.environ["MANAGER_PORT"])))
def serve():
    while True:
        conn, _ = server.accept()
        conn.recv(16)
        conn.sendall(b"ok")
        conn.close()
threading.Thread(target=serve, daemon=True).start()
rospy.spin()
""" % ROS_PYTHON

# on SIGINT it says goodbye to the manager (after a moment, as a spawner unloading its controllers) and
# retries until the manager answers: with the manager gone first it never ends by itself
SPAWNER = """#!%s
import os, signal, socket, sys, time
def bye(*_):
    time.sleep(1.0)
    while True:
        try:
            with socket.create_connection(("127.0.0.1", int(os.environ["MANAGER_PORT"])), timeout=1) as s:
                s.sendall(b"bye")
                if s.recv(2) == b"ok":
                    sys.exit(0)
        except OSError:
            time.sleep(0.1)
signal.signal(signal.SIGINT, bye)
open(os.path.join(os.environ["READY_DIR"], "spawner-ready"), "w").close()
while True:
    time.sleep(1)
""" % ROS_PYTHON

BODY = """
  <node pkg="order_tests" type="manager" name="manager"/>
  <node pkg="order_tests" type="spawner" name="spawner" bind_to="manager" sigint_timeout="5"/>
"""


def test_a_bound_node_stops_before_its_manager(tmp_path, ros_env):
    make_package(str(tmp_path / "ws"), "order_tests", {"manager": MANAGER, "spawner": SPAWNER})
    env = run_env(str(tmp_path), free_port(), str(tmp_path / "ws"))
    env.update(PATH=ROS_PATH, READY_DIR=str(tmp_path), MANAGER_PORT=str(free_port()))
    lp = Launcher([write_launch(str(tmp_path), BODY)], env, str(tmp_path))
    try:
        # (bind_to is a start condition too: the spawner starts once the manager has registered)
        until(lambda: os.path.exists(tmp_path / "spawner-ready"), 60, 0.1, what="the spawner started")
        pids = lp.started_pids()
        assert set(pids) == {"manager-2", "spawner-3"}, pids  # (rosout is process 1)
        started = time.monotonic()
        lp.signal(signal.SIGINT)
        assert lp.wait(30) == 0
        took = time.monotonic() - started
    finally:
        lp.close()
    assert "escalating to SIGTERM" not in lp.stderr, lp.stderr
    assert took < 5.0, took  # (no sigint_timeout waited out)
    stop_lines = [line for line in lp.stdout.splitlines() if line.endswith("killing on exit")]
    assert stop_lines.index("[spawner-3] killing on exit") < stop_lines.index("[manager-2] killing on exit")
