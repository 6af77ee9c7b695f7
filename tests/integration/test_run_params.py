"""`launch file.launch` with real rospy and roscpp nodes: parameters are on the master before any node starts."""

from __future__ import annotations

import os
import re
import subprocess

import pytest

from helpers import ROS_PYTHON, free_port, until
from running import (Launcher, RosMaster, compile_roscpp, get_param, make_package, master_proxy, master_up, ros_env,
                     write_launch)

RospyParamNode = """#!%s
import os, rospy
rospy.init_node("param_node")
out = rospy.get_param("~out")
priv = rospy.get_param("~value", "<unset>")
glob = rospy.get_param("/shared/value", "<unset>")
stale = "present" if rospy.has_param("~stale") else "absent"
with open(out + ".tmp", "w") as f:
    f.write("private=%%s\\nglobal=%%s\\nstale=%%s\\n" %% (priv, glob, stale))
os.rename(out + ".tmp", out)
rospy.spin()
""" % ROS_PYTHON


@pytest.fixture
def pkgs(tmp_path, ros_env):
    pkg = make_package(str(tmp_path / "pkgs"), "run_tests", {"param_py": RospyParamNode})
    compile_roscpp("param_node.cpp", os.path.join(pkg, "param_cpp"))
    return str(tmp_path / "pkgs")


LAUNCH = """
  <param name="shared/value" value="from-launch"/>
  <rosparam param="~literal">{{a: 1}}</rosparam>
  <node pkg="run_tests" type="param_py" name="py_node" clear_params="true">
    <param name="value" value="py-private"/>
    <param name="out" value="{tmp}/py.txt"/>
  </node>
  <node pkg="run_tests" type="param_cpp" name="cpp_node" ns="robot" clear_params="true">
    <param name="value" value="cpp-private"/>
    <param name="out" value="{tmp}/cpp.txt"/>
  </node>
"""


def read_seen(path: str) -> dict[str, str]:
    with open(path) as f:
        return dict(line.split("=", 1) for line in f.read().split())


@pytest.mark.parametrize("master", ["embedded", "external"])
def test_params_visible_to_nodes_before_they_start(tmp_path, pkgs, master):
    ext = RosMaster(str(tmp_path)) if master == "external" else None
    port = ext.port if ext else free_port()
    if ext:
        # stale values under the nodes' namespaces: clear_params must remove them before the nodes start
        master_proxy(port).setParam("/test", "/py_node/stale", 1)
        master_proxy(port).setParam("/test", "/robot/cpp_node/stale", 1)
    launch = write_launch(str(tmp_path), LAUNCH.format(tmp=tmp_path))
    lp = Launcher([launch], ros_env(str(tmp_path), port, pkgs), str(tmp_path))
    try:
        until(lambda: os.path.exists(tmp_path / "py.txt") and os.path.exists(tmp_path / "cpp.txt"), 60,
              what="both nodes wrote what they saw")
        assert read_seen(str(tmp_path / "py.txt")) == {"private": "py-private", "global": "from-launch",
                                                       "stale": "absent"}
        assert read_seen(str(tmp_path / "cpp.txt")) == {"private": "cpp-private", "global": "from-launch",
                                                        "stale": "absent"}
        run_id = get_param(port, "/run_id")
        assert run_id and re.fullmatch(r"[0-9a-f-]{36}", run_id)
        # a launch-level ~name is passed on as it is, and resolved by the master against roslaunch's caller id
        assert get_param(port, "/roslaunch/literal") == {"a": 1} and get_param(port, "/literal") is None
        # roscore.xml's parameters, which roslaunch sets on every master, its own or one found running
        env = ros_env(str(tmp_path), port, pkgs)
        for key, argv in (("/rosversion", ["rosversion", "roslaunch"]), ("/rosdistro", ["rosversion", "-d"])):
            said = subprocess.run(argv, env=env, capture_output=True, text=True, timeout=30).stdout
            assert said.strip() and get_param(port, key) == said, key
        assert "setting /run_id to %s" % run_id in lp.stdout
        assert ("auto-starting new master" in lp.stdout) is (master == "embedded")
        assert lp.wait_output(r"PARAMETERS\n(?: \* .*\n)* \* /shared/value: from-launch\n")
        assert "  /robot/\n    cpp_node (run_tests/param_cpp)\n" in lp.stdout
        lp.signal(2)
        assert lp.wait(20) == 0
        assert lp.stdout.rstrip().endswith("done")
        # our master goes away with us; an external one stays up
        assert master_up(port) is (master == "external")
    finally:
        lp.close()
        if ext:
            ext.stop()


def test_params_set_in_one_multicall_on_external_master(tmp_path, pkgs):
    """Many parameters still go up before the first node starts (one round trip, as roslaunch)."""
    ext = RosMaster(str(tmp_path))
    body = "\n".join('<param name="many/p%d" value="%d"/>' % (i, i) for i in range(300))
    body += ('\n<node pkg="run_tests" type="param_py" name="last_reader">'
             '<param name="out" value="%s/last.txt"/></node>' % tmp_path)
    body += '\n<param name="shared/value" value="v"/>'
    launch = write_launch(str(tmp_path), body)
    lp = Launcher([launch], ros_env(str(tmp_path), ext.port, pkgs), str(tmp_path))
    try:
        until(lambda: os.path.exists(tmp_path / "last.txt"), 60, what="node wrote its params")
        assert read_seen(str(tmp_path / "last.txt"))["global"] == "v"
        assert get_param(ext.port, "/many") == {"p%d" % i: i for i in range(300)}
    finally:
        lp.close()
        ext.stop()
