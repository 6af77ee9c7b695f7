"""Stopping a launch: SIGINT -> SIGTERM -> SIGKILL per node on its own clock, whole groups, and no orphans."""

from __future__ import annotations

import os
import signal
import time

import pytest

from helpers import ROS_PYTHON, descendants, free_port, pid_alive, until
from running import Launcher, RosMaster, compile_roscpp, make_package, master_proxy, ros_env, write_launch

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
# READY_FILE is written once init_node has returned: rospy deadlocks if SIGINT arrives while its main
# thread is inside a master call (init_node makes several), see Wedged; a test that means to stop
# running nodes waits for this file, not just for the registration the master sees mid-init_node.
RospySpinner = """#!%s
import os, rospy
rospy.init_node("spinner")
if os.environ.get("READY_FILE"):
    open(os.environ["READY_FILE"], "w").close()
rospy.spin()
""" % ROS_PYTHON
# rospy's own deadlock, made certain: the main thread holds the lock of rospy's master proxy, as it
# does during any master call (rospy.get_param, the registrations in init_node). rospy's SIGINT and
# SIGTERM handler runs in that thread and unregisters through the same proxy, so it never returns and
# only SIGKILL ends the node, after sigint_timeout + sigterm_timeout, as with roslaunch.
Wedged = """#!%s
import os, time, rospy, rospy.core
rospy.init_node("wedged")
for proxy in list(rospy.core._xmlrpc_cache.values()):
    proxy._lock.acquire()
open(os.environ["READY_FILE"], "w").close()
time.sleep(1000)
""" % ROS_PYTHON


@pytest.fixture
def pkgs(tmp_path, ros_env):
    pkg = make_package(str(tmp_path / "pkgs"), "stop_tests",
                       {"ignore_int": IgnoreInt, "ignore_int_term": IgnoreIntTerm, "family": Family,
                        "spinner": RospySpinner, "wedged": Wedged})
    compile_roscpp("param_node.cpp", os.path.join(pkg, "param_cpp"))
    return str(tmp_path / "pkgs")


def test_escalation_is_per_node_and_parallel(tmp_path, pkgs):
    port = free_port()
    body = "\n".join('<node pkg="stop_tests" type="ignore_int" name="int%d"/>' % i for i in range(8))
    body += "\n".join('<node pkg="stop_tests" type="ignore_int_term" name="both%d"/>' % i for i in range(8))
    body += '\n<node pkg="stop_tests" type="spinner" name="polite"><env name="READY_FILE" value="%s/polite"/></node>' \
        % tmp_path
    launch = write_launch(str(tmp_path), body)
    lp = Launcher(["--sigint-timeout", "1", "--sigterm-timeout", "1", launch],
                  ros_env(str(tmp_path), port, pkgs), str(tmp_path))
    try:
        lp.wait_output(r"process\[polite-18\]: started")
        until(lambda: os.path.exists(tmp_path / "polite"), 60, what="rospy node initialized")
        procs = descendants(lp.pid)
        t0 = time.monotonic()
        lp.signal(signal.SIGINT)
        assert lp.wait(30) == 0
        took = time.monotonic() - t0
        # all 16 stubborn nodes are stopped at once: 1 s + 1 s (+ margin for a loaded CI box), not 2 waves
        # of 10 as roslaunch (>= 4 s)
        assert 2.0 <= took < 3.8, took
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
        until(lambda: os.path.exists(tmp_path / "cpp.txt"), 60, what="roscpp node up")
        until(lambda: master_proxy(port).lookupNode("/t", "/py")[0] == 1, 30, what="rospy node up")
        until(lambda: len(descendants(lp.pid)) >= 4 + 3 + 1, 10, what="family's children up")
        procs = descendants(lp.pid)
        os.kill(lp.pid, signal.SIGKILL)
        lp.wait(10)
        t0 = time.monotonic()
        # the guard's SIGTERM grace is 0.4 s, then SIGKILL; the rest is margin for a loaded CI box
        until(lambda: not [p for p in procs if pid_alive(p)], 2.0, period=0.01,
              what="every process started by the launcher gone")
        assert time.monotonic() - t0 < 2.0
    finally:
        lp.close()


def test_many_real_nodes_stop_cleanly_and_unregister(tmp_path, pkgs):
    rosmaster = RosMaster(str(tmp_path))
    body = "\n".join('<node pkg="stop_tests" type="param_cpp" name="c%d"><param name="out" value="%s/c%d"/></node>'
                     % (i, tmp_path, i) for i in range(15))
    body += "\n".join('<node pkg="stop_tests" type="spinner" name="p%d"><env name="READY_FILE" value="%s/p%d"/></node>'
                      % (i, tmp_path, i) for i in range(5))
    launch = write_launch(str(tmp_path), body)
    lp = Launcher([launch], ros_env(str(tmp_path), rosmaster.port, pkgs), str(tmp_path))
    try:
        def registered():
            _c, _m, state = master_proxy(rosmaster.port).getSystemState("/t")
            nodes = {n for _topic, ns in state[0] + state[1] for n in ns}
            return nodes >= {"/c%d" % i for i in range(15)} | {"/p%d" % i for i in range(5)}
        until(registered, 60, what="all 20 nodes registered")
        # roscpp wrote its file after its last master call; rospy's init_node is over (see RospySpinner)
        until(lambda: all(os.path.exists(tmp_path / ("c%d" % i)) for i in range(15))
              and all(os.path.exists(tmp_path / ("p%d" % i)) for i in range(5)), 60, what="all 20 nodes initialized")
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


def test_rospy_node_deadlocked_in_its_sigint_handler_is_killed_after_the_timeouts(tmp_path, pkgs):
    """A SIGINT that reaches rospy during a master call deadlocks the node (its handler waits for the
    proxy lock the interrupted call holds, SIGTERM runs the same handler): roslaunch's escalation ends
    it with SIGKILL after sigint_timeout + sigterm_timeout, and the other nodes stop at once meanwhile."""
    port = free_port()
    launch = write_launch(str(tmp_path), """
      <node pkg="stop_tests" type="wedged" name="wedged"><env name="READY_FILE" value="%s/wedged"/></node>
      <node pkg="stop_tests" type="spinner" name="polite"><env name="READY_FILE" value="%s/polite"/></node>
    """ % (tmp_path, tmp_path))
    lp = Launcher(["--sigint-timeout", "1", "--sigterm-timeout", "1", launch],
                  ros_env(str(tmp_path), port, pkgs), str(tmp_path))
    try:
        until(lambda: os.path.exists(tmp_path / "wedged") and os.path.exists(tmp_path / "polite"), 60,
              what="both rospy nodes initialized")
        procs = descendants(lp.pid)
        t0 = time.monotonic()
        lp.signal(signal.SIGINT)
        assert lp.wait(30) == 0
        assert 2.0 <= time.monotonic() - t0 < 3.8
        assert not [p for p in procs if pid_alive(p)]
        err = lp.stderr
        assert "[wedged-2] escalating to SIGTERM" in err and "[wedged-2] escalating to SIGKILL" in err
        assert "process[wedged-2, pid %d]: required SIGKILL" % lp.started_pids()["wedged-2"] in err
        assert "[polite-3] escalating" not in err
    finally:
        lp.close()
