"""A run (runtime.Run, in-process) wires the health watchers: wait_for holds, resource samples each --monitor-period."""

from __future__ import annotations

import asyncio
import json
import os

from launcher.model.config import LaunchConfig, Node, NodePolicy
from launcher.workspace.packages import PackageIndex
from launcher.fleet.state import EVENTS_FILE
from launcher.model.runopts import RunOptions
from launcher.plan.plan import Plan
from launcher.run.runtime import Run

from helpers import free_port
from tests.integration.running import make_package
from tests.process.health import console_err


def test_run_holds_a_waiting_node_samples_the_others_and_a_required_timeout_ends_it(tmp_path, capsys):
    make_package(str(tmp_path / "pkgs"), "healthpkg", {"sleeper": "#!/bin/sh\nexec sleep 100\n"})
    port = free_port()
    environ = dict(os.environ, ROS_PACKAGE_PATH=str(tmp_path / "pkgs"), ROS_HOME=str(tmp_path / "home"),
                   ROS_LOG_DIR=str(tmp_path / "log"), ROS_MASTER_URI="http://127.0.0.1:%d/" % port)
    config = LaunchConfig(nodes=(
        Node("healthpkg", "sleeper", "plain"),
        Node("healthpkg", "sleeper", "held", required=True,
             policy=NodePolicy(wait_for=(("param", "/never"), ("node", "/nobody")), wait_timeout=1.0)),
    ))
    plan = Plan(config, environ["ROS_MASTER_URI"], environ, packages=PackageIndex(environ))
    opts = RunOptions(monitor_period=0.1, no_summary=True, skip_log_check=True)
    run = Run(opts, plan)
    status = asyncio.run(asyncio.wait_for(run.main(), 60))
    assert status == 1
    err = console_err(capsys)
    assert "REQUIRED process [held-3] failed to start: still waiting after 1 s for param:/never, node:/nobody" in err
    plain = run.nodes.fleet.nodes["/plain"]
    assert len(plain.history) >= 5  # sampled every 0.1 s during the second of waiting
    assert all(rss > 0 for _t, _cpu, rss in plain.history)
    with open(os.path.join(run.log.run_dir, EVENTS_FILE)) as f:
        held = [e for e in map(json.loads, f) if e.get("node") == "/held"]
    assert [e["state"] for e in held] == ["waiting", "exited"]
    assert held[1]["reason"] == "still waiting after 1 s for param:/never, node:/nobody"


def test_monitor_period_must_be_positive(tmp_path):
    import subprocess
    import sys
    for value in ("0", "-1", "nan"):
        p = subprocess.run([sys.executable, "-m", "launcher", "--monitor-period", value, str(tmp_path / "a.launch")],
                           capture_output=True, text=True, timeout=60)
        assert p.returncode != 0
        assert "--monitor-period must be greater than zero" in p.stderr
        assert "Traceback" not in p.stderr
