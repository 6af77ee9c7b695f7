"""README's demo (examples/launch/demo.launch) runs without ROS and ends by itself."""

from __future__ import annotations

import os
import re
import sys

from helpers import ROOT, free_port
from running import Launcher



def test_demo_runs_and_ends_by_itself(tmp_path):
    env = dict(os.environ, ROS_PACKAGE_PATH=os.path.join(ROOT, "examples"), ROS_HOME=str(tmp_path / "home"),
               ROS_MASTER_URI="http://127.0.0.1:%d/" % free_port())
    env.pop("ROS_LOG_DIR", None)
    # plain Python nodes: make sure they could not borrow anything from a ROS install
    env["PATH"] = os.path.dirname(sys.executable) + ":/bin"
    lp = Launcher([os.path.join(ROOT, "examples", "launch", "demo.launch"), "duration:=5"], env, str(tmp_path))
    try:
        assert lp.wait(60) == 0  # (5 s of demo; a loaded machine takes longer to start and stop it)
        out, err = lp.stdout, lp.stderr
        assert "auto-starting new master" in out and "started core service [/rosout]" in out
        # nodes read their parameters from our master over XML-RPC
        assert "[/demo/greeter] parameters from the master: greeting='hello from the parameter server' " \
               "period=1.5" in out
        # the crasher died (exit code 1) and was restarted after its respawn_delay
        assert re.search(r"\[demo/crasher-3\] process has died \[pid \d+, exit code 1, cmd ", err)
        assert "[demo/crasher-3] restarting process" in out
        # the required mission finished cleanly and ended the launch
        assert "REQUIRED process [mission-5] has died!\nprocess has finished cleanly" in err
        latest = tmp_path / "home" / "log" / "latest"
        assert "hello from the parameter server #1" in (latest / "demo-quiet-4-stdout.log").read_text()
        assert (latest / "rosout.log").exists()
    finally:
        lp.close()
