"""Stopping a launch: SIGINT -> SIGTERM -> SIGKILL per node on its own clock, whole groups, and no orphans."""

from __future__ import annotations

import os
import signal
import time

import pytest

from running import (ROS_PYTHON, Launcher, RosMaster, compile_roscpp, descendants, free_port, make_package,
                     master_proxy, pid_alive, poll, ros_env, write_launch)

# `trap ''` makes the signal ignored, which survives exec
IgnoreInt = "#!/bin/sh\ntrap '' INT\nexec sleep 1000\n"
IgnoreIntTerm = "#!/bin/sh\ntrap '' INT TERM\nexec sleep 1000\n"
# a node with children in its process group, one of which moves to its own group
Family = """#!/bin/sh
sleep 1000 &
(trap '' INT TERM; exec sleep 1001) &
%s -c 'import os, time; os.setpgid(0, 0); time.sleep(1002)' &
wait
""" % ROS_PYTHON
RospySpinner = """#!%s
import rospy
rospy.init_node("spinner")
rospy.spin()
""" % ROS_PYTHON


@pytest.fixture
def pkgs(tmp_path, ros_env):
    pkg = make_package(str(tmp_path / "pkgs"), "stop_tests",
                       {"ignore_int": IgnoreInt, "ignore_int_term": IgnoreIntTerm, "family": Family,
                        "spinner": RospySpinner})
    compile_roscpp("param_node.cpp", os.path.join(pkg, "param_cpp"))
    return str(tmp_path / "pkgs")


def test_escalation_is_per_node_and_parallel(tmp_path, pkgs):
    port = free_port()
    body = "\n".join('<node pkg="stop_tests" type="ignore_int" name="int%d"/>' % i for i in range(8))
    body += "\n".join('<node pkg="stop_tests" type="ignore_int_term" name="both%d"/>' % i for i in range(8))
    body += '\n<node pkg="stop_tests" type="spinner" name="polite"/>'
    launch = write_launch(str(tmp_path), body)
    lp = Launcher(["--sigint-timeout", "1", "--sigterm-timeout", "1", launch],
                  ros_env(str(tmp_path), port, pkgs), str(tmp_path))
    try:
        lp.wait_output(r"process\[polite-18\]: started")
        poll(lambda: master_proxy(port).lookupNode("/t", "/polite")[0] == 1, 30, what="rospy node registered")
        procs = descendants(lp.pid)
        t0 = time.monotonic()
        lp.signal(signal.SIGINT)
        assert lp.wait(30) == 0
        took = time.monotonic() - t0
        # all 16 stubborn nodes are stopped at once: 1 s + 1 s (+ margin), not 2 waves of 10 as roslaunch
        assert 2.0 <= took < 3.0, took
        assert not [p for p in procs if pid_alive(p)]
        err = lp.stderr
        for i in range(8):
            assert "[int%d-%d] escalating to SIGTERM" % (i, i + 2) in err
            assert "[int%d-%d] escalating to SIGKILL" % (i, i + 2) not in err
            assert "[both%d-%d] escalating to SIGKILL" % (i, i + 10) in err
        assert "[polite-18] escalating" not in err
        assert "Shutdown errors:\n * process[" in err and err.count("required SIGKILL. May still be running.") == 8
        out = lp.stdout
        # reverse start order, as roslaunch; core (rosout, master) last
        assert out.index("[polite-18] killing on exit") < out.index("[int0-2] killing on exit") < out.index(
            "[rosout-1] killing on exit") < out.index("[master] killing on exit")
        assert out.rstrip().endswith("done")
    finally:
        lp.close()


def test_sigkill_of_launcher_leaves_no_process(tmp_path, pkgs):
    port = free_port()
    launch = write_launch(str(tmp_path), """
      <node pkg="stop_tests" type="family" name="family"/>
      <node pkg="stop_tests" type="spinner" name="py"/>
      <node pkg="stop_tests" type="param_cpp" name="cpp"><param name="out" value="%s/cpp.txt"/></node>
      <node pkg="stop_tests" type="ignore_int_term" name="stubborn"/>
    """ % tmp_path)
    lp = Launcher([launch], ros_env(str(tmp_path), port, pkgs), str(tmp_path))
    try:
        poll(lambda: os.path.exists(tmp_path / "cpp.txt"), 60, what="roscpp node up")
        poll(lambda: master_proxy(port).lookupNode("/t", "/py")[0] == 1, 30, what="rospy node up")
        poll(lambda: len(descendants(lp.pid)) >= 4 + 3 + 1, 10, what="family's children up")
        procs = descendants(lp.pid)
        os.kill(lp.pid, signal.SIGKILL)
        lp.wait(10)
        t0 = time.monotonic()
        poll(lambda: not [p for p in procs if pid_alive(p)], 1.0, period=0.01,
             what="every process started by the launcher gone")
        assert time.monotonic() - t0 < 1.0
    finally:
        lp.close()


def test_many_real_nodes_stop_cleanly_and_unregister(tmp_path, pkgs):
    rosmaster = RosMaster(str(tmp_path))
    body = "\n".join('<node pkg="stop_tests" type="param_cpp" name="c%d"><param name="out" value="%s/c%d"/></node>'
                     % (i, tmp_path, i) for i in range(15))
    body += "\n".join('<node pkg="stop_tests" type="spinner" name="p%d"/>' % i for i in range(5))
    launch = write_launch(str(tmp_path), body)
    lp = Launcher([launch], ros_env(str(tmp_path), rosmaster.port, pkgs), str(tmp_path))
    try:
        def registered():
            _c, _m, state = master_proxy(rosmaster.port).getSystemState("/t")
            nodes = {n for _topic, ns in state[0] + state[1] for n in ns}
            return nodes >= {"/c%d" % i for i in range(15)} | {"/p%d" % i for i in range(5)}
        poll(registered, 60, what="all 20 nodes registered")
        procs = descendants(lp.pid)
        t0 = time.monotonic()
        lp.signal(signal.SIGINT)
        assert lp.wait(30) == 0
        assert time.monotonic() - t0 < 5.0
        assert "escalating" not in lp.stderr
        assert not [p for p in procs if pid_alive(p)]
        _c, _m, state = master_proxy(rosmaster.port).getSystemState("/t")
        left = {n for entries in state for _name, ns in entries for n in ns}
        assert not left & ({"/c%d" % i for i in range(15)} | {"/p%d" % i for i in range(5)})
    finally:
        lp.close()
        rosmaster.stop()
