"""`launch` run options against real masters: --wait, --required, --run_id, --pid, remote machines, bad input."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import time

import pytest

from helpers import ROS_PATH, ROS_PYTHON, free_port, until
from running import Launcher, RosMaster, get_param, make_package, master_proxy, ros_env, write_launch

Spinner = """#!%s
import rospy
rospy.init_node("spinner")
rospy.spin()
""" % ROS_PYTHON


@pytest.fixture
def pkgs(tmp_path, ros_env):
    make_package(str(tmp_path / "pkgs"), "opt_tests", {"spinner": Spinner, "quick": "#!/bin/sh\nexit 0\n"})
    return str(tmp_path / "pkgs")


def test_wait_for_master_then_run(tmp_path, pkgs):
    port = free_port()
    launch = write_launch(str(tmp_path), '<param name="p" value="7"/><node pkg="opt_tests" type="spinner" name="w"/>')
    lp = Launcher(["--wait", launch], ros_env(str(tmp_path), port, pkgs), str(tmp_path))
    master = None
    try:
        lp.wait_output(r"waiting for it")
        master = RosMaster(str(tmp_path), port=port)  # the master the launcher waits for (the port was free)
        lp.wait_output(r"process\[w-1\]: started with pid")
        assert get_param(port, "/p") == 7
        assert "auto-starting new master" not in lp.stdout
        lp.signal(signal.SIGINT)
        assert lp.wait(30) == 0
    finally:
        lp.close()
        if master is not None:
            master.stop()


def test_sigint_while_waiting_for_a_master_ends_at_once(tmp_path, pkgs):
    launch = write_launch(str(tmp_path), '<node pkg="opt_tests" type="spinner" name="w"/>')
    lp = Launcher(["--wait", launch], ros_env(str(tmp_path), free_port(), pkgs), str(tmp_path))
    try:
        lp.wait_output(r"waiting for it")
        t0 = time.monotonic()
        lp.signal(signal.SIGINT)
        assert lp.wait(10) == 0
        assert time.monotonic() - t0 < 2.0
        assert "started with pid" not in lp.stdout and "Traceback" not in lp.stderr
    finally:
        lp.close()


def test_required_option_rejects_respawn(tmp_path, pkgs):
    launch = write_launch(str(tmp_path), '<node pkg="opt_tests" type="quick" name="r" respawn="true"/>')
    lp = Launcher(["--required", launch], ros_env(str(tmp_path), free_port(), pkgs), str(tmp_path))
    try:
        assert lp.wait(30) == 1
        assert "respawn and required cannot both be set to true" in lp.stderr
        assert "%s:1:" % launch in lp.stderr or "%s:" % launch in lp.stderr
        assert "Traceback" not in lp.stderr
    finally:
        lp.close()


def test_required_option_makes_every_node_required(tmp_path, pkgs):
    launch = write_launch(str(tmp_path), """
      <node pkg="opt_tests" type="spinner" name="stay"/>
      <node pkg="opt_tests" type="quick" name="leave"/>""")
    lp = Launcher(["--required", launch], ros_env(str(tmp_path), free_port(), pkgs), str(tmp_path))
    try:
        assert lp.wait(60) == 0  # exit code 0 of the required node: a clean end
        assert "REQUIRED process [leave-3] has died!" in lp.stderr
    finally:
        lp.close()


def test_run_id_mismatch_with_running_master(tmp_path, pkgs):
    master = RosMaster(str(tmp_path))
    try:
        master_proxy(master.port).setParam("/t", "/run_id", "existing-run")
        launch = write_launch(str(tmp_path), '<node pkg="opt_tests" type="quick" name="q"/>')
        lp = Launcher(["--run_id", "other-run", launch], ros_env(str(tmp_path), master.port, pkgs), str(tmp_path))
        assert lp.wait(30) == 1
        assert "run_id on parameter server does not match declared run_id: existing-run vs other-run" in lp.stderr
        lp.close()
        # without --run_id the master's run_id is used: logs go to <log>/existing-run/
        lp = Launcher([launch], ros_env(str(tmp_path), master.port, pkgs), str(tmp_path))
        assert lp.wait(30) == 0
        assert os.path.isdir(tmp_path / "log" / "existing-run")
        assert "setting /run_id" not in lp.stdout
        lp.close()
    finally:
        master.stop()


def test_pid_file_written_and_removed(tmp_path, pkgs):
    pid_fn = tmp_path / "launch.pid"
    launch = write_launch(str(tmp_path), '<node pkg="opt_tests" type="spinner" name="s"/>')
    lp = Launcher(["--pid", str(pid_fn), launch], ros_env(str(tmp_path), free_port(), pkgs), str(tmp_path))
    try:
        lp.wait_output(r"started with pid")
        assert pid_fn.read_text() == str(lp.pid)
        lp.signal(signal.SIGTERM)
        assert lp.wait(30) == 0
        assert not pid_fn.exists()
    finally:
        lp.close()


def test_node_on_remote_machine_with_a_loopback_master_is_a_clear_error(tmp_path, pkgs):
    # (the other machine could not reach the master: see tests/integration/test_remote.py for remote runs)
    launch = write_launch(str(tmp_path), """
      <machine name="far" address="192.0.2.10"/>
      <node pkg="opt_tests" type="spinner" name="remote" machine="far"/>""")
    lp = Launcher([launch], ros_env(str(tmp_path), free_port(), pkgs), str(tmp_path))
    try:
        assert lp.wait(30) == 1
        assert ("%s:4: ROS_MASTER_URI [http://127.0.0.1:" % launch in lp.stderr
                and "is a loopback address, which machine [far] at [192.0.2.10] cannot reach" in lp.stderr), lp.stderr
        assert "Traceback" not in lp.stderr and "started with pid" not in lp.stdout
    finally:
        lp.close()


def _summary_nodes(text: str) -> str:
    """The NODES block of a summary (terminal escapes left out)."""
    text = re.sub(r"\x1b\[[0-9;]*m|\x1b\]2;[^\x07]*\x07", "", text)
    return text.split("\nNODES\n", 1)[1].split("\n\n", 1)[0]


def test_local_prints_roslaunchs_banner_and_leaves_remote_nodes_out_as_it_does(tmp_path, pkgs):
    launch = write_launch(str(tmp_path), """
      <machine name="far" address="192.0.2.10" env-loader="/opt/env.sh"/>
      <node pkg="opt_tests" type="spinner" name="remote" machine="far"/>
      <node pkg="opt_tests" type="spinner" name="here"/>""")
    outputs = {}
    for label in ("roslaunch", "ours"):
        env = dict(ros_env(str(tmp_path), free_port(), pkgs), PATH=ROS_PATH)
        if label == "roslaunch":
            out = tmp_path / "roslaunch.out"
            with open(out, "wb") as f:
                proc = subprocess.Popen(["roslaunch", "--local", launch], env=env, stdout=f,
                                        stderr=subprocess.STDOUT, start_new_session=True)
            try:
                until(lambda: b"process[here-2]: started" in out.read_bytes(), 60, what="roslaunch's node")
            finally:
                os.killpg(proc.pid, signal.SIGINT)
                proc.wait(30)
            outputs[label] = out.read_text(errors="replace")
        else:
            lp = Launcher(["--local", launch], env, str(tmp_path))
            try:
                lp.wait_output(r"process\[here-2\]: started with pid", 60)
                lp.signal(signal.SIGINT)
                assert lp.wait(30) == 0
                outputs[label] = lp.stdout + lp.stderr
            finally:
                lp.close()
    banner = "LOCAL\nlocal only launch specified, will not launch remote nodes\nLOCAL\n"
    assert banner in outputs["roslaunch"]  # (the reference says what we must print)
    assert banner in outputs["ours"], outputs["ours"]
    assert "skipping" not in outputs["ours"] and "remote-" not in outputs["ours"]
    assert _summary_nodes(outputs["ours"]) == _summary_nodes(outputs["roslaunch"]) == "  /\n    here (opt_tests/spinner)"


def test_bad_log_check_threshold(tmp_path, pkgs):
    launch = write_launch(str(tmp_path), '<node pkg="opt_tests" type="quick" name="q"/>')
    lp = Launcher(["--log-check-threshold", "lots", launch], ros_env(str(tmp_path), free_port(), pkgs),
                  str(tmp_path))
    try:
        assert lp.wait(30) == 1
        assert "--log-check-threshold: invalid size [lots]" in lp.stderr
    finally:
        lp.close()


def test_log_check_warns_in_background_with_threshold(tmp_path, pkgs):
    launch = write_launch(str(tmp_path), '<node pkg="opt_tests" type="spinner" name="s"/>')
    env = ros_env(str(tmp_path), free_port(), pkgs)
    os.makedirs(env["ROS_LOG_DIR"], exist_ok=True)
    with open(os.path.join(env["ROS_LOG_DIR"], "old.log"), "wb") as f:
        f.write(b"x" * 20000)
    lp = Launcher(["--log-check-threshold", "10KB", launch], env, str(tmp_path))
    try:
        started = lp.wait_output(r"started with pid")
        assert started
        lp.wait_output(r"WARNING: disk usage in log directory \[%s\] is over 10kB\." % env["ROS_LOG_DIR"],
                       timeout=20, stream="stderr")
        # after start-up, never before it
        assert "disk usage" not in lp.stdout.split("started with pid")[0]
    finally:
        lp.close()
