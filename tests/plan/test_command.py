"""node_command: the argv, environment and cwd of a node, as roslaunch builds them."""

from __future__ import annotations

import os
import sys

import pytest

from launcher.plan.command import node_command
from launcher.model.config import Node
from launcher.model.errors import LaunchError
from launcher.workspace.packages import PackageIndex, PackageNotFound

PACKAGE_XML = ('<?xml version="1.0"?><package format="2"><name>%s</name><version>0.0.1</version>'
               '<description>t</description><maintainer email="t@example.com">t</maintainer>'
               '<license>BSD</license></package>')


@pytest.fixture
def pkgs(tmp_path):
    d = tmp_path / "pkgs" / "tpkg"
    (d / "nodes" / "sub").mkdir(parents=True)
    (d / "package.xml").write_text(PACKAGE_XML % "tpkg")
    exe = d / "nodes" / "sub" / "talker"
    exe.write_text("#!/bin/sh\n")
    exe.chmod(0o755)
    (d / "nodes" / "not_exec").write_text("x")
    env = {"ROS_PACKAGE_PATH": str(tmp_path / "pkgs"), "CMAKE_PREFIX_PATH": "", "HOME": str(tmp_path),
           "ROS_HOME": str(tmp_path / "rhome"), "PATH": "/usr/bin:/bin"}
    return PackageIndex(env), env, str(exe)


def cmd(node, pkgs, **kw):
    index, env, _ = pkgs
    kw.setdefault("master_uri", "http://localhost:11311/")
    kw.setdefault("environ", env)
    return node_command(node, packages=index, **kw)


def test_full_command_line(pkgs):
    exe = pkgs[2]
    node = Node("tpkg", "talker", "n", namespace="/robot/", args="a 'b c'  d\\ e",
                remap_args=(("chatter", "/x"), ("~p", "q")), launch_prefix="gdb -ex run --args")
    c = cmd(node, pkgs)
    assert c.argv == ["gdb", "-ex", "run", "--args", exe, "a", "b c", "d e", "chatter:=/x", "~p:=q", "__name:=n"]
    assert c.format_args() == ('ROS_MASTER_URI="http://localhost:11311/" ROS_NAMESPACE="/robot" '
                               'gdb -ex run --args %s a b c d e chatter:=/x ~p:=q __name:=n' % exe)


def test_log_file_is_appended_last(pkgs):
    c = cmd(Node("tpkg", "talker", "n"), pkgs, log_file="/tmp/n-1.log")
    assert c.argv[-2:] == ["__name:=n", "__log:=/tmp/n-1.log"]


def test_environment_and_changes_in_roslaunch_order(pkgs):
    index, env, _ = pkgs
    env = dict(env, ROS_NAMESPACE="/old", KEEP="same", ROS_MASTER_URI="http://other:1/")
    node = Node("tpkg", "talker", "n", namespace="/ns/",
                env_args=(("KEEP", "same"), ("ZED", "z"), ("PATH", "/p"), ("ROS_NAMESPACE", "/explicit")))
    c = node_command(node, master_uri="http://m:2/", environ=env, packages=index)
    # unchanged vars are not listed; existing vars keep their position, new ones follow in order
    assert c.env_changes == [("PATH", "/p"), ("ROS_MASTER_URI", "http://m:2/"), ("ROS_NAMESPACE", "/explicit"),
                             ("ZED", "z")]
    assert c.env["ROS_NAMESPACE"] == "/explicit" and c.env["KEEP"] == "same" and c.env["HOME"] == env["HOME"]


def test_nodes_with_the_same_environment_share_one(pkgs):
    index, env, _ = pkgs
    shared: dict = {}

    def command(namespace="/", env_args=(), name="n"):
        return node_command(Node("tpkg", "talker", name, namespace=namespace, env_args=env_args),
                            master_uri="http://m:2/", environ=env, packages=index, shared_envs=shared)
    a, b = command(name="a"), command(name="b")
    assert a.env is b.env and a.env["ROS_MASTER_URI"] == "http://m:2/" and "ROS_NAMESPACE" not in a.env
    ns, other = command("/ns/"), command(env_args=(("ZED", "z"),))
    assert ns.env is not a.env and ns.env["ROS_NAMESPACE"] == "/ns" and ns.env_changes[-1] == ("ROS_NAMESPACE", "/ns")
    assert other.env is not a.env and other.env["ZED"] == "z" and "ZED" not in a.env
    assert command(env_args=(("ZED", "z"),)).env is other.env
    assert node_command(Node("tpkg", "talker", "c"), master_uri="http://m:2/", environ=env,
                        packages=index).env == a.env  # (what the nodes share is what each would have had)


def test_root_namespace_sets_no_ros_namespace(pkgs):
    index, env, _ = pkgs
    c = node_command(Node("tpkg", "talker", "n"), master_uri="http://localhost:11311/",
                     environ=dict(env, ROS_NAMESPACE="/was"), packages=index)
    assert "ROS_NAMESPACE" not in c.env
    assert c.env_changes == [("ROS_MASTER_URI", "http://localhost:11311/")]


def test_cwd(pkgs):
    index, env, exe = pkgs
    assert cmd(Node("tpkg", "talker", "n", cwd="node"), pkgs).cwd == os.path.dirname(exe)
    assert cmd(Node("tpkg", "talker", "n"), pkgs).cwd == env["ROS_HOME"]
    no_home = {k: v for k, v in env.items() if k != "ROS_HOME"}
    c = node_command(Node("tpkg", "talker", "n", cwd="ROS_HOME"), master_uri="u", environ=no_home, packages=index)
    assert c.cwd == os.path.join(os.path.expanduser("~"), ".ros")


@pytest.mark.parametrize("pkg,type_,word", [
    ("tpkg", "no_such", "Cannot locate node of type [no_such]"),
    ("tpkg", "not_exec", "Cannot locate node of type [not_exec]"),
    ("no_pkg", "talker", "no_pkg"),
])
def test_missing_executable_names_the_node_and_its_line(pkgs, pkg, type_, word):
    node = Node(pkg, type_, "n", namespace="/g/", filename="/f.launch", line=7)
    with pytest.raises(LaunchError) as e:
        cmd(node, pkgs)
    assert "node [/g/n]" in str(e.value) and word in str(e.value)
    assert (e.value.filename, e.value.line) == ("/f.launch", 7)


def test_unbalanced_quotes_are_a_clean_error(pkgs):
    with pytest.raises(LaunchError, match="args"):
        cmd(Node("tpkg", "talker", "n", args="'unclosed"), pkgs)


def test_what_runs_is_the_command_args_prints(pkgs, tmp_path):
    """The supervisor runs the very NodeCommand that `--args` prints (plus only the __log:= it adds)."""
    from launcher.model.config import LaunchConfig
    from launcher.model.runopts import RunOptions
    from launcher.plan.specs import node_specs
    index, env, exe = pkgs
    node = Node("tpkg", "talker", "t", namespace="/ns/", args="-x 'a b'", remap_args=(("in", "out"),))
    (spec,), failed = node_specs(LaunchConfig(nodes=(node,)), "http://localhost:11311/", env, index,
                                 lambda n: False, opts=RunOptions(), run_dir=str(tmp_path / "log"), first_number=1,
                                 log=print, log_error=print)
    printed = cmd(node, pkgs).format_args()
    assert not failed and spec.name == "ns/t-2"
    assert spec.command.format_args() == printed + " __log:=%s" % (tmp_path / "log" / "ns-t-2.log")
    assert spec.argv is spec.command.argv


def test_rosbag_record_and_play_are_ours_where_no_rosbag_is_found(pkgs, monkeypatch):
    index, env, _ = pkgs
    real = index._resource_dirs

    def without_rosbag(pkg):  # (this machine may have Debian's rosbag, which package lookup always sees)
        if pkg == "rosbag":
            raise PackageNotFound(pkg)
        return real(pkg)
    monkeypatch.setattr(index, "_resource_dirs", without_rosbag)
    for kind in ("record", "play"):
        c = cmd(Node("rosbag", kind, "bagger", args="-O x.bag /a"), pkgs)
        assert c.argv == [sys.executable, "-m", "launcher.bag", kind, "-O", "x.bag", "/a", "__name:=bagger"]
    with pytest.raises(LaunchError):  # nothing else of rosbag's is built in
        cmd(Node("rosbag", "reindex", "r"), pkgs)


def test_an_installed_rosbag_runs_as_with_roslaunch(tmp_path, pkgs):
    index, env, _ = pkgs
    d = tmp_path / "pkgs" / "rosbag"
    d.mkdir()
    (d / "package.xml").write_text(PACKAGE_XML % "rosbag")
    exe = d / "record"
    exe.write_text("#!/bin/sh\n")
    exe.chmod(0o755)
    c = cmd(Node("rosbag", "record", "bagger"), (PackageIndex(env), env, ""))
    # ours, or Debian's where it is installed (catkin's lib dir comes first, as with roslaunch)
    assert c.argv[0] in (str(exe), "/usr/lib/rosbag/record") and c.argv[1:] == ["__name:=bagger"]
