"""`launch` running real nodes: respawn, required, launch-prefix, output and log files, cwd, env, failures."""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import time

import pytest

from helpers import ROS_PATH, ROS_PYTHON, free_port, pid_alive, until
from running import (Launcher, RosMaster, compile_roscpp, get_param, make_package, master_proxy, ros_env,
                     write_launch)

# rospy node: prints, then spins until SIGINT
RospySpinner = """#!%s
import rospy
rospy.init_node("spinner")
print("spinner %%s up" %% rospy.get_name(), flush=True)
rospy.spin()
""" % ROS_PYTHON

# writes its environment, cwd and argv as lines KEY=VALUE into $REPORT_DIR/<__name>.txt, then exits 0
Reporter = """#!/bin/sh
name=$(for a in "$@"; do case $a in __name:=*) echo ${a#__name:=};; esac; done)
{ echo "cwd=$(pwd)"; echo "args=$*"; env; } > "$REPORT_DIR/$name.txt.tmp"
mv "$REPORT_DIR/$name.txt.tmp" "$REPORT_DIR/$name.txt"
echo "reporter $name stdout line"
"""

Exiter = """#!/bin/sh
sleep ${EXIT_AFTER:-0.2}
exit ${EXIT_CODE:-0}
"""


@pytest.fixture
def pkgs(tmp_path, ros_env):
    pkg = make_package(str(tmp_path / "pkgs"), "run_tests",
                       {"spinner": RospySpinner, "reporter": Reporter, "exiter": Exiter})
    compile_roscpp("param_node.cpp", os.path.join(pkg, "param_cpp"))
    return str(tmp_path / "pkgs")


def lookup_node(port: int, name: str) -> str | None:
    try:
        code, _msg, uri = master_proxy(port).lookupNode("/test", name)
    except OSError:  # our master is not up yet
        return None
    return uri if code == 1 else None


def test_respawn_and_respawn_delay_with_real_nodes(tmp_path, pkgs):
    port = free_port()
    launch = write_launch(str(tmp_path), """
      <node pkg="run_tests" type="param_cpp" name="fast" respawn="true">
        <param name="out" value="%s/fast.txt"/></node>
      <node pkg="run_tests" type="spinner" name="slow" respawn="true" respawn_delay="1.5"/>
    """ % tmp_path)
    lp = Launcher([launch], ros_env(str(tmp_path), port, pkgs), str(tmp_path))
    try:
        until(lambda: lookup_node(port, "/fast") and lookup_node(port, "/slow"), 60, what="both registered")
        pids = lp.started_pids()
        fast_pid, slow_pid = pids["fast-2"], pids["slow-3"]  # rosout counts as process 1, as in roslaunch
        old_uri = lookup_node(port, "/fast")
        os.kill(fast_pid, signal.SIGKILL)
        t0 = time.monotonic()
        new_fast = until(lambda: lp.started_pids()["fast-2"] != fast_pid and lp.started_pids()["fast-2"], 10,
                         period=0.005, what="fast respawned")
        assert time.monotonic() - t0 < 1.0  # at once (the delayed node below takes 1.5 s); margin for a loaded box
        until(lambda: lookup_node(port, "/fast") not in (None, old_uri), 30, what="fast re-registered")
        assert pid_alive(new_fast)
        os.kill(slow_pid, signal.SIGKILL)
        t0 = time.monotonic()
        until(lambda: lp.started_pids()["slow-3"] != slow_pid, 10, period=0.01, what="slow respawned")
        assert 1.4 <= time.monotonic() - t0 < 3.0
        out, err = lp.stdout, lp.stderr
        assert "[fast-2] process has died [pid %d, exit code -9, cmd " % fast_pid in err
        assert out.count("[fast-2] restarting process") == 1 and out.count("[slow-3] restarting process") == 1
        lp.signal(signal.SIGINT)
        assert lp.wait(30) == 0
    finally:
        lp.close()


@pytest.mark.parametrize("code,status", [(0, 0), (3, 3)])  # the required node's own code (ros/ros_comm#2082)
def test_required_node_exit_ends_launch(tmp_path, pkgs, code, status):
    port = free_port()
    launch = write_launch(str(tmp_path), """
      <node pkg="run_tests" type="spinner" name="bystander"/>
      <node pkg="run_tests" type="exiter" name="boss" required="true">
        <env name="EXIT_AFTER" value="1.5"/><env name="EXIT_CODE" value="%d"/></node>
    """ % code)
    lp = Launcher([launch], ros_env(str(tmp_path), port, pkgs), str(tmp_path))
    try:
        assert lp.wait(60) == status
        err = lp.stderr
        assert "REQUIRED process [boss-3] has died!" in err and "Initiating shutdown!" in err
        assert ("process has finished cleanly" if code == 0 else "exit code 3") in err
        assert not pid_alive(lp.started_pids()["bystander-2"])
    finally:
        lp.close()


def test_required_node_that_cannot_start_fails_the_launch(tmp_path, pkgs):
    launch = write_launch(str(tmp_path), """
      <node pkg="run_tests" type="spinner" name="bystander"/>
      <node pkg="run_tests" type="no_such_exe" name="needed" required="true"/>
    """)
    lp = Launcher([launch], ros_env(str(tmp_path), free_port(), pkgs), str(tmp_path))
    try:
        assert lp.wait(60) == 1
        assert "cannot launch node of type [run_tests/no_such_exe]" in lp.stderr
        assert "REQUIRED process [needed-3] could not be started!" in lp.stderr
    finally:
        lp.close()


def test_missing_executable_is_reported_and_the_rest_run(tmp_path, pkgs):
    port = free_port()
    launch = write_launch(str(tmp_path), """
      <node pkg="run_tests" type="no_such_exe" name="ghost"/>
      <node pkg="run_tests" type="spinner" name="survivor"/>
    """)
    lp = Launcher([launch], ros_env(str(tmp_path), port, pkgs), str(tmp_path))
    try:
        until(lambda: lookup_node(port, "/survivor"), 60, what="survivor registered")
        err = lp.stderr
        assert re.search(r"ERROR: cannot launch node of type \[run_tests/no_such_exe\]: .*node \[/ghost\].*"
                         r"Cannot locate node of type \[no_such_exe\] in package \[run_tests\]", err)
        # a bad launch-prefix fails at exec time: reported by name, too
        assert lp.proc.poll() is None
        lp.signal(signal.SIGINT)
        assert lp.wait(30) == 0
    finally:
        lp.close()


def test_a_bad_launch_prefix_ends_the_launch_as_roslaunch_does(tmp_path, pkgs):
    """A node's exec that fails while the launch starts its nodes (roslaunch's FatalProcessLaunch) ends the launch
    with status 1, said by name: the node started before it is stopped, the one after it is never started; Debian's
    roslaunch beside it."""
    report = tmp_path / "reports"
    report.mkdir()
    launch = write_launch(str(tmp_path), """
      <node pkg="run_tests" type="spinner" name="before"/>
      <node pkg="run_tests" type="exiter" name="prefixed" launch-prefix="/no/such/wrapper --x"/>
      <node pkg="run_tests" type="reporter" name="after"><env name="REPORT_DIR" value="%s"/></node>
    """ % report)
    rosmaster = RosMaster(str(tmp_path))
    env = ros_env(str(tmp_path), rosmaster.port, pkgs)
    try:
        ref = subprocess.run(["roslaunch", launch], env=dict(env, PATH=ROS_PATH), stdin=subprocess.DEVNULL,
                             capture_output=True, text=True, timeout=60)
        assert ref.returncode == 1 and "This is often caused by a bad launch-prefix" in ref.stderr, ref
        assert "[before-1] killing on exit" in ref.stdout and "after-3" not in ref.stdout + ref.stderr
        lp = Launcher([launch], env, str(tmp_path))
        try:
            assert lp.wait(60) == 1
        finally:
            lp.close()
        assert "[prefixed-2] got a 'No such file or directory' error while attempting to run:" in lp.stderr
        assert "/no/such/wrapper --x " in lp.stderr and "This is often caused by a bad launch-prefix" in lp.stderr
        assert "[before-1] killing on exit" in lp.stdout and "after-3" not in lp.stdout + lp.stderr
        assert not os.listdir(str(report))
    finally:
        rosmaster.stop()


def test_a_respawn_whose_start_fails_is_the_nodes_business(tmp_path, pkgs):
    """Once every node has been started, a node's start that fails (here its respawn's) ends nothing but that run:
    it is tried again, the launch runs on."""
    exe = os.path.join(pkgs, "run_tests", "exiter")
    launch = write_launch(str(tmp_path), """
      <node pkg="run_tests" type="exiter" name="flaky" respawn="true" respawn_delay="1"/>
      <node pkg="run_tests" type="spinner" name="steady"/>
    """)
    lp = Launcher([launch], ros_env(str(tmp_path), free_port(), pkgs), str(tmp_path))
    try:
        lp.wait_output(r"process\[flaky-2\]: started with pid")
        os.rename(exe, exe + ".away")  # (its next start: exec fails)
        lp.wait_output(r"\[flaky-2\] got a 'No such file or directory' error", stream="stderr")
        os.rename(exe + ".away", exe)
        until(lambda: len(re.findall(r"process\[flaky-2\]: started with pid", lp.stdout)) >= 2, 30,
              what="flaky started again")
        assert lp.proc.poll() is None
        lp.signal(signal.SIGINT)
        assert lp.wait(30) == 0
    finally:
        lp.close()


def test_prefix_env_cwd_output_and_log_files(tmp_path, pkgs):
    rosmaster = RosMaster(str(tmp_path))
    report = tmp_path / "report"
    report.mkdir()
    launch = write_launch(str(tmp_path), """
      <env name="REPORT_DIR" value="%s"/>
      <group ns="grp">
        <node pkg="run_tests" type="reporter" name="logged" output="log" args="a 'b c'">
          <remap from="in" to="out"/>
          <env name="NODE_ENV" value="node-value"/>
        </node>
      </group>
      <node pkg="run_tests" type="reporter" name="shown" output="screen" cwd="node"
            launch-prefix="env PREFIX_ADDED=yes"/>
    """ % report)
    env = ros_env(str(tmp_path), rosmaster.port, pkgs)
    lp = Launcher([launch], env, str(tmp_path))
    try:
        assert lp.wait(60) == 0
        logged = dict(line.split("=", 1) for line in (report / "logged.txt").read_text().splitlines() if "=" in line)
        shown = dict(line.split("=", 1) for line in (report / "shown.txt").read_text().splitlines() if "=" in line)
        run_id = master_proxy(rosmaster.port).getParam("/test", "/run_id")[2]
        run_dir = os.path.join(env["ROS_LOG_DIR"], run_id)
        # environment: ROS_MASTER_URI, ROS_NAMESPACE, <env> (launch-wide and per node), launch-prefix
        assert logged["ROS_MASTER_URI"] == env["ROS_MASTER_URI"]
        # the launch's log file, as roslaunch's nodes inherit it from roslaunch's logging
        assert logged["ROS_LOG_FILENAME"] == os.path.join(run_dir, "roslaunch-%s-%d.log"
                                                          % (socket.gethostname(), lp.proc.pid))
        assert os.path.exists(logged["ROS_LOG_FILENAME"])
        assert logged["ROS_NAMESPACE"] == "/grp" and "ROS_NAMESPACE" not in shown
        assert logged["NODE_ENV"] == "node-value" and "NODE_ENV" not in shown
        assert shown["PREFIX_ADDED"] == "yes" and "PREFIX_ADDED" not in logged
        # cwd: ROS_HOME by default, the executable's directory with cwd="node"
        assert logged["cwd"] == env["ROS_HOME"]
        assert shown["cwd"] == os.path.join(pkgs, "run_tests")
        # args split like a shell, remaps, __name, __log in roslaunch's file naming
        assert logged["args"] == "a b c in:=out __name:=logged __log:=%s/grp-logged-1.log" % run_dir
        # output="log": stdout in <run_id>/<name>-<n>-stdout.log, not on the terminal; screen: on the terminal,
        # and the launcher keeps a copy in the same file name (for `launcher logs`)
        assert (open(os.path.join(run_dir, "grp-logged-1-stdout.log")).read()
                == "reporter logged stdout line\n")
        assert "reporter logged stdout line" not in lp.stdout
        assert "reporter shown stdout line" in lp.stdout
        assert open(os.path.join(run_dir, "shown-2-stdout.log")).read() == "reporter shown stdout line\n"
        assert os.path.realpath(os.path.join(env["ROS_LOG_DIR"], "latest")) == os.path.realpath(run_dir)
        assert "log file: %s/grp-logged-1*.log" % run_dir in lp.stdout
    finally:
        lp.close()
        rosmaster.stop()


def test_screen_option_overrides_output_log(tmp_path, pkgs):
    report = tmp_path / "report"
    report.mkdir()
    launch = write_launch(str(tmp_path), """
      <env name="REPORT_DIR" value="%s"/>
      <node pkg="run_tests" type="reporter" name="logged" output="log"/>
    """ % report)
    rosmaster = RosMaster(str(tmp_path))
    lp = Launcher(["--screen", launch], ros_env(str(tmp_path), rosmaster.port, pkgs), str(tmp_path))
    try:
        assert lp.wait(60) == 0
        assert "reporter logged stdout line" in lp.stdout
    finally:
        lp.close()
        rosmaster.stop()


def test_nodes_that_exit_zero_with_external_master(tmp_path, pkgs):
    rosmaster = RosMaster(str(tmp_path))
    launch = write_launch(str(tmp_path), """
      <node pkg="run_tests" type="exiter" name="one"/>
      <node pkg="run_tests" type="exiter" name="two"><env name="EXIT_AFTER" value="0.5"/></node>
    """)
    lp = Launcher([launch], ros_env(str(tmp_path), rosmaster.port, pkgs), str(tmp_path))
    try:
        assert lp.wait(60) == 0
        out = lp.stdout
        assert "[one-1] process has finished cleanly" in out and "[two-2] process has finished cleanly" in out
        assert out.index("[two-2] process has finished cleanly") < out.index("all processes on machine have died")
    finally:
        lp.close()
        rosmaster.stop()


@pytest.mark.parametrize("nodes", ["", '<node pkg="no_such_package" type="t" name="lost"/>'])
def test_a_launch_without_a_process_ends_on_a_running_master_as_roslaunch_does(tmp_path, pkgs, nodes):
    """roslaunch's #556: a launch that only sets parameters (or whose nodes all could not be made) on a master found
    running says "No processes to monitor" and exits 0, its parameters set; Debian's roslaunch beside it."""
    rosmaster = RosMaster(str(tmp_path))
    launch = write_launch(str(tmp_path), '<param name="loaded/value" value="7"/>' + nodes)
    env = ros_env(str(tmp_path), rosmaster.port, pkgs)
    try:
        ref = subprocess.run(["roslaunch", launch], env=dict(env, PATH=ROS_PATH), stdin=subprocess.DEVNULL,
                             capture_output=True, text=True, timeout=60)
        assert ref.returncode == 0 and "No processes to monitor" in ref.stdout, ref
        master_proxy(rosmaster.port).deleteParam("/test", "/loaded")
        lp = Launcher([launch], env, str(tmp_path))
        try:
            assert lp.wait(60) == 0
        finally:
            lp.close()
        assert get_param(rosmaster.port, "/loaded/value") == 7
        ours = lp.stdout
        tail = ["No processes to monitor", "shutting down processing monitor...",
                "... shutting down processing monitor complete"]  # (and no "done": roslaunch returns before it)
        assert _plain_lines(ref.stdout)[-3:] == tail and _plain_lines(ours)[-3:] == tail, ours
    finally:
        rosmaster.stop()


def test_a_node_on_an_unknown_machine_refuses_the_launch_as_roslaunch_does(tmp_path, pkgs):
    """roslaunch gives every node its machine before it runs anything: an undeclared machine ends the launch with
    status 1 before its parameters are set or a node starts; Debian's roslaunch beside it."""
    rosmaster = RosMaster(str(tmp_path))
    report = tmp_path / "reports"
    report.mkdir()
    launch = write_launch(str(tmp_path), """
      <param name="early/value" value="1"/>
      <node pkg="run_tests" type="reporter" name="here"><env name="REPORT_DIR" value="%s"/></node>
      <node pkg="run_tests" type="reporter" name="far" machine="nowhere"/>
    """ % report)
    env = ros_env(str(tmp_path), rosmaster.port, pkgs)
    try:
        ref = subprocess.run(["roslaunch", launch], env=dict(env, PATH=ROS_PATH), stdin=subprocess.DEVNULL,
                             capture_output=True, text=True, timeout=60)
        assert ref.returncode == 1 and "unknown machine [nowhere]" in ref.stderr, ref
        lp = Launcher([launch], env, str(tmp_path))
        try:
            assert lp.wait(60) == 1
        finally:
            lp.close()
        assert "%s:6: unknown machine [nowhere]: no <machine> tag declares it (node [/far])" % launch in lp.stderr
        assert get_param(rosmaster.port, "/early/value") is None and not os.listdir(str(report))
    finally:
        rosmaster.stop()


def _plain_lines(text: str) -> list[str]:
    return [line for line in re.sub(r"\x1b(\[[0-9;]*m|\][^\x07]*\x07)", "", text).splitlines() if line.strip()]


def test_embedded_master_keeps_running_after_nodes_finish(tmp_path, pkgs):
    port = free_port()
    launch = write_launch(str(tmp_path), '<node pkg="run_tests" type="exiter" name="one"/>')
    lp = Launcher([launch], ros_env(str(tmp_path), port, pkgs), str(tmp_path))
    try:
        lp.wait_output(r"\[one-2\] process has finished cleanly")
        # roslaunch keeps its own master (and rosout) up: rosnode list still answers
        r = subprocess.run(["rosnode", "list"], env=dict(ros_env(str(tmp_path), port, pkgs), PATH=ROS_PATH),
                           capture_output=True, text=True, timeout=30)
        assert "/rosout" in r.stdout.split()
        assert lp.proc.poll() is None
        lp.signal(signal.SIGTERM)
        assert lp.wait(30) == 0
    finally:
        lp.close()


def test_sigint_reaches_nodes_when_launcher_inherited_it_ignored(tmp_path, pkgs):
    """A background job starts with SIGINT ignored; nodes must still get SIGINT at its default (real rospy)."""
    port = free_port()
    launch = write_launch(str(tmp_path), '<node pkg="run_tests" type="spinner" name="sp" output="screen"/>')
    lp = Launcher(["--sigint-timeout", "10", launch], ros_env(str(tmp_path), port, pkgs), str(tmp_path),
                  ignore_sigint=True)
    try:
        lp.wait_output(r"spinner /sp up")
        pid = lp.started_pids()["sp-2"]
        with open("/proc/%d/status" % pid) as f:
            ignored = int(re.search(r"SigIgn:\s*([0-9a-f]+)", f.read()).group(1), 16)
        assert not ignored & (1 << (signal.SIGINT - 1))
        t0 = time.monotonic()
        lp.signal(signal.SIGINT)  # the launcher itself handles it despite the inherited SIG_IGN
        assert lp.wait(30) == 0
        assert time.monotonic() - t0 < 5  # rospy stopped on SIGINT, no escalation needed
        assert "escalating" not in lp.stderr
    finally:
        lp.close()


def test_launch_log_holds_what_a_debugging_user_needs(tmp_path, pkgs):
    """Beyond the console: the environment, every parameter, each node's command line, exits and timings."""
    port = free_port()
    launch = write_launch(str(tmp_path), """
      <param name="answer" value="42"/>
      <node pkg="run_tests" type="exiter" name="flaky" respawn="true" respawn_delay="0.2">
        <env name="EXIT_AFTER" value="0.1"/><env name="EXIT_CODE" value="3"/></node>
    """)
    env = ros_env(str(tmp_path), port, pkgs)
    lp = Launcher([launch], env, str(tmp_path))
    try:
        path = lp.wait_output(r"\.\.\. logging to (\S+)").group(1)

        def exits_logged():
            with open(path) as f:
                text = f.read()
            return text if text.count("is respawning") >= 2 else None
        text = until(exits_logged, 30, what="two exits in the launch log")
        assert "[launch] launch files: %s" % launch in text
        assert "ROS_MASTER_URI=%s" % env["ROS_MASTER_URI"] in text
        assert "[launch] param /answer = 42" in text
        assert re.search(r'\[launch\] node \[/flaky\] \(process flaky-2\): EXIT_AFTER="0.1" EXIT_CODE="3" '
                         r'\S+/exiter __name:=flaky __log:=\S+ \(cwd \S+\)', text), text
        assert re.search(r"\[launch\] node \[/flaky\] \(process flaky-2\) is running, pid \d+", text)
        assert re.search(r"is respawning, pid \d+, exit code 3, 1 restart, next start in 0\.\d\d s", text), text
        assert re.search(r"\[launch\] \+\d+\.\d{3} s: every node started", text)
        assert "process[flaky-2]: started with pid" in text  # and the console lines, as before
    finally:
        lp.close()


def test_required_node_killed_by_a_signal_ends_launch_with_128_plus_it(tmp_path, pkgs):
    port = free_port()
    launch = write_launch(str(tmp_path), '<node pkg="run_tests" type="spinner" name="boss" required="true"/>')
    lp = Launcher([launch], ros_env(str(tmp_path), port, pkgs), str(tmp_path))
    try:
        pid = int(lp.wait_output(r"process\[boss-\d+\]: started with pid \[(\d+)\]").group(1))
        os.kill(pid, signal.SIGKILL)
        assert lp.wait(60) == 128 + signal.SIGKILL
    finally:
        lp.close()
