"""`launch --wait` started before Debian's roscore never makes that roscore fail (it must set /run_id first)."""

from __future__ import annotations

import os
import subprocess

import pytest

from helpers import ROS_PATH, free_port, until
from running import Launcher, get_param, make_package, master_up, stop_group, write_launch
from running import ros_env as run_env

RUNS = 20
AT_ONCE = 4  # runs side by side, each on its own port


def _roscore(tmp: str, port: int, env: dict[str, str]) -> subprocess.Popen:
    env = dict(env, PATH=ROS_PATH + ":" + env.get("PATH", ""), ROS_HOME=os.path.join(tmp, "corehome"))
    out = open(os.path.join(tmp, "roscore.out"), "wb")
    return subprocess.Popen(["roscore", "-p", str(port)], env=env, stdout=out, stderr=subprocess.STDOUT,
                            stdin=subprocess.DEVNULL, start_new_session=True)



@pytest.mark.parametrize("batch", range(RUNS // AT_ONCE))
def test_launch_waiting_for_roscore_leaves_it_the_run_id(tmp_path, ros_env, batch):
    runs = []
    try:
        for i in range(AT_ONCE):
            tmp = str(tmp_path / ("run%d" % i))
            pkgs = os.path.join(tmp, "pkgs")
            make_package(pkgs, "race", {"quiet": "#!/bin/sh\nexec sleep 1000\n"})
            port = free_port()
            env = run_env(tmp, port, pkgs)
            launcher = Launcher(["--wait", write_launch(tmp, '<node pkg="race" type="quiet" name="q"/>')], env, tmp)
            runs.append((tmp, port, env, launcher))
        cores = []
        for tmp, port, env, launcher in runs:
            launcher.wait_output(r"waiting for it")
            cores.append(_roscore(tmp, port, env))  # the roscore comes up while the launch polls for it
        for (tmp, port, env, launcher), core in zip(runs, cores):
            until(lambda: master_up(port), 60, what="roscore's master up")
            launcher.wait_output(r"process\[q-\d+\]: started with pid", timeout=60)
            # roscore's own run id is the one on the master, and roscore is alive and well
            until(lambda: get_param(port, "/rosdistro") is not None, 60, what="roscore's parameters")
            assert core.poll() is None, open(os.path.join(tmp, "roscore.out")).read()
            assert "setting /run_id" not in launcher.stdout
            with open(os.path.join(tmp, "roscore.out")) as f:
                core_out = f.read()
            assert "run_id on parameter server does not match" not in core_out
            assert get_param(port, "/run_id") in launcher.stdout  # the launch logs under roscore's run id
    finally:
        for tmp, port, env, launcher in runs:
            launcher.close()
        for core in locals().get("cores", []):
            stop_group(core, 20)
