"""Stalled topics with real rospy publishers: a node that stops publishing while alive is found stalled and
restarted though another publisher on the same topic goes on; a healthy watched node is never flagged; a slow
one with on_stall="warn" is only reported."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

from helpers import ROS_PATH, ROS_PYTHON, free_port, until
from running import Launcher, make_package, write_launch
from running import ros_env as run_env

# publishes on `data` at 20 Hz; with QUIT_AFTER=N it stops after N messages (and says so in READY_DIR), alive
PUBLISHER = """#!%s
import os, sys, time, rospy
from std_msgs.msg import String
rospy.init_node("pub")
argv = rospy.myargv(argv=sys.argv)
topic, rate = argv[1], float(argv[2])
quit_after = int(argv[3]) if len(argv) > 3 else 0
pub = rospy.Publisher(topic, String, queue_size=10)
n = 0
r = rospy.Rate(rate)
while not rospy.is_shutdown():
    n += 1
    if quit_after and n == quit_after:
        open(os.path.join(os.environ["READY_DIR"], "quiet-%%d" %% os.getpid()), "w").close()
    if not quit_after or n < quit_after:
        pub.publish(String("m%%d" %% n))
    r.sleep()
""" % ROS_PYTHON

BODY = """
  <node pkg="stall_tests" type="pub" name="quitter" args="data 20 30" respawn="true" watch_topic="data"
        watch_timeout="1"/>
  <node pkg="stall_tests" type="pub" name="other" args="data 20"/>
  <node pkg="stall_tests" type="pub" name="steady" args="steady 20" watch_topic="steady" watch_timeout="1"
        watch_min_rate="5" watch_window="2"/>
  <node pkg="stall_tests" type="pub" name="slow" args="slow 2" watch_topic="slow" watch_min_rate="10"
        watch_window="2" on_stall="warn"/>
"""


def status(env: dict) -> dict:
    r = subprocess.run([sys.executable, "-m", "launcher.cli.tool", "status", "--json"], env=env, capture_output=True,
                       text=True, timeout=30)
    return {n["name"]: n for n in json.loads(r.stdout)["nodes"]} if r.returncode == 0 else {}


def test_stalled_topics(tmp_path, ros_env):
    port = free_port()
    make_package(str(tmp_path / "ws"), "stall_tests", {"pub": PUBLISHER})
    env = run_env(str(tmp_path), port, str(tmp_path / "ws"))
    env["PATH"] = ROS_PATH
    env["READY_DIR"] = str(tmp_path)
    lp = Launcher([write_launch(str(tmp_path), BODY)], env, str(tmp_path))
    try:
        first = until(lambda: (status(env).get("/quitter") or {}).get("pid"), 60, 0.2, what="quitter running")
        steady_pid = until(lambda: (status(env).get("/steady") or {}).get("pid"), 60, 0.2, what="steady running")
        quiet = tmp_path / ("quiet-%d" % first)
        until(lambda: quiet.exists(), 60, 0.05, what="the quitter's last message")
        went_quiet = time.monotonic()
        # found stalled within watch_timeout + 1 s of its silence, and restarted (it respawns)
        until(lambda: "[quitter-2] is stalled (no message on /data" in lp.stderr, 1.0 + 1.0 + 0.5, 0.05,
              what="the quitter found stalled")
        assert time.monotonic() - went_quiet <= 1.0 + 1.0 + 0.5
        st = until(lambda: (lambda s: s if s.get("/quitter", {}).get("pid") not in (None, first)
                            and s["/quitter"]["state"] == "running" else None)(status(env)), 30, 0.2,
                   what="the quitter restarted")
        assert st["/quitter"]["restarts"] >= 1
        # the slow one: only reported, same process
        st = until(lambda: (lambda s: s if s.get("/slow", {}).get("state") == "stalled" else None)(status(env)),
                   30, 0.2, what="slow reported stalled")
        assert st["/slow"]["restarts"] == 0 and "under watch_min_rate 10" in st["/slow"]["reason"]
        # the healthy watched one was never flagged, over the whole test
        st = status(env)
        assert st["/steady"]["pid"] == steady_pid and st["/steady"]["state"] == "running"
        assert st["/steady"]["restarts"] == 0 and "[steady-4] is stalled" not in lp.stderr
        events = [json.loads(line) for line in open(os.path.join(tmp_path, "log", "latest",
                                                                  "launcher-events.jsonl"))]
        assert not [e for e in events if e.get("node") == "/steady" and e["state"] != "running"]
        assert [e for e in events if e.get("node") == "/quitter" and e["state"] == "stalled"]
    finally:
        lp.close()
