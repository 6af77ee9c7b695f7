"""Ready by output: a node waits for a line of another node's output (`wait_for="output:NODE:PATTERN"`), for a
screen node (its output relayed by the launcher) and for an output="log" node (which writes its file itself).
Each driver prints a near miss first, then its line after a delay; the waiting nodes start only after it."""

from __future__ import annotations

import json
import os
import signal

from helpers import ROS_PATH, ROS_PYTHON, free_port, until
from running import Launcher, make_package, write_launch
from running import ros_env as run_env

# a rospy node that prints argv[1] at once and argv[2] after DELAY s, noting the time just before it prints
DRIVER = """#!%s
import os, sys, time, rospy
rospy.init_node("driver")
early, line = rospy.myargv(argv=sys.argv)[1:3]
print(early, flush=True)
time.sleep(float(os.environ["DELAY"]))
with open(os.path.join(os.environ["READY_DIR"], rospy.get_name().strip("/") + ".printed"), "w") as f:
    f.write(repr(time.time()))
print(line, flush=True)
rospy.spin()
""" % ROS_PYTHON

# notes the time it started, then stays
WAITER = """#!%s
import os, sys, time
with open(os.path.join(os.environ["READY_DIR"], sys.argv[1] + ".started"), "w") as f:
    f.write(repr(time.time()))
while True:
    time.sleep(1)
""" % ROS_PYTHON

BODY = """
  <node pkg="output_tests" type="driver" name="screen_driver" output="screen"
        args="'not ready yet' 'driver ready to go'"/>
  <node pkg="output_tests" type="driver" name="log_driver" output="log" args="'logger ready soon' 'logger ready'"/>
  <node pkg="output_tests" type="waiter" name="after_screen" args="after_screen"
        wait_for="output:screen_driver:'ready to go'"/>
  <node pkg="output_tests" type="waiter" name="after_log" args="after_log" wait_for="output:/log_driver:'^logger\\sready$'"
        wait_timeout="60"/>
"""


def test_nodes_start_after_a_line_of_a_screen_node_and_of_a_log_node(tmp_path, ros_env):
    make_package(str(tmp_path / "ws"), "output_tests", {"driver": DRIVER, "waiter": WAITER})
    env = run_env(str(tmp_path), free_port(), str(tmp_path / "ws"))
    env.update(PATH=ROS_PATH, READY_DIR=str(tmp_path), DELAY="2")
    lp = Launcher([write_launch(str(tmp_path), BODY)], env, str(tmp_path))
    try:
        for waiter in ("after_screen", "after_log"):
            until(lambda: os.path.exists(tmp_path / (waiter + ".started")), 60, 0.1, what=waiter + " started")
        lp.signal(signal.SIGINT)
        assert lp.wait(30) == 0
    finally:
        lp.close()
    stamp = lambda name: float((tmp_path / name).read_text())  # noqa: E731
    assert stamp("after_screen.started") > stamp("screen_driver.printed")
    assert stamp("after_log.started") > stamp("log_driver.printed")
    # the screen node's line went to the console as well; the log node's only to its file
    assert "driver ready to go" in lp.stdout and "logger ready" not in lp.stdout
    with open(tmp_path / "log" / "latest" / "launcher-events.jsonl") as f:
        events = [json.loads(line) for line in f if line.strip()]
    held = [e["reason"] for e in events if e.get("node") == "/after_log" and e["phase"] == "held"]
    assert held == ["waiting for output:/log_driver:^logger\\sready$"], held
