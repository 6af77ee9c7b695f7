"""The introspection options end to end through the CLI: output format, name resolution, exit codes."""

from __future__ import annotations

import textwrap

import pytest
import yaml

from helpers import ROOT

from launcher.cli.launch import main

PACKAGE_XML = ('<?xml version="1.0"?><package format="2"><name>%s</name><version>0.0.1</version>'
               '<description>t</description><maintainer email="t@example.com">t</maintainer>'
               '<license>BSD</license></package>')

MAIN = """
<launch>
  <arg name="robot" doc="robot name"/>
  <arg name="rate" default="10"/>
  <arg name="empty" default=""/>
  <arg name="const" value="c"/>
  <param name="robot" value="$(arg robot)"/>
  <param name="rate" value="$(arg rate)"/>
  <node name="drv" pkg="tpkg" type="talker" args="--rate $(arg rate)">
    <remap from="in" to="out"/>
    <env name="EXTRA" value="1"/>
    <param name="p" value="1.5"/>
  </node>
  <group ns="g">
    <node name="sub" pkg="tpkg" type="talker"/>
  </group>
  <test test-name="check" pkg="tpkg" type="talker"/>
  <include file="$(dirname)/inc.launch"/>
</launch>
"""


@pytest.fixture
def tree(tmp_path, monkeypatch):
    pkg = tmp_path / "pkgs" / "tpkg"
    (pkg / "scripts").mkdir(parents=True)
    (pkg / "launch").mkdir()
    (pkg / "package.xml").write_text(PACKAGE_XML % "tpkg")
    exe = pkg / "scripts" / "talker"
    exe.write_text("#!/bin/sh\n")
    exe.chmod(0o755)
    (pkg / "launch" / "main.launch").write_text(textwrap.dedent(MAIN))
    (pkg / "launch" / "inc.launch").write_text('<launch><param name="inc" value="yes"/></launch>')
    for k in ("ROS_NAMESPACE", "ROS_MASTER_URI", "CMAKE_PREFIX_PATH"):
        monkeypatch.delenv(k, raising=False)
    monkeypatch.setenv("ROS_PACKAGE_PATH", str(tmp_path / "pkgs"))
    monkeypatch.setenv("ROS_HOME", str(tmp_path / "home"))
    return {"main": str(pkg / "launch" / "main.launch"), "inc": str(pkg / "launch" / "inc.launch"),
            "exe": str(exe), "pkg": str(pkg)}


def run(capsys, *argv):
    rc = main(list(argv))
    out, err = capsys.readouterr()
    return rc, out, err


def test_nodes_lists_nodes_then_tests(tree, capsys):
    assert run(capsys, "--nodes", tree["main"], "robot:=r") == (0, "/drv\n/g/sub\n/check\n", "")


def test_nodes_with_namespace_from_cli(tree, capsys):
    rc, out, _ = run(capsys, "--nodes", tree["main"], "robot:=r", "__ns:=/x")
    assert out == "/x/drv\n/x/g/sub\n/x/check\n"


def test_args_prints_env_changes_and_command(tree, capsys):
    rc, out, _ = run(capsys, "--args", "/drv", tree["main"], "robot:=r")
    assert rc == 0
    assert out == ('ROS_MASTER_URI="http://localhost:11311/" EXTRA="1" %s --rate 10 in:=out __name:=drv\n'
                   % tree["exe"])


def test_args_resolves_relative_names_against_the_launch_namespace(tree, capsys, monkeypatch):
    monkeypatch.setenv("ROS_NAMESPACE", "/robot")
    rc, out, _ = run(capsys, "--args", "g/sub", tree["main"], "robot:=r")
    assert rc == 0 and out.endswith("__name:=sub\n") and 'ROS_NAMESPACE="/robot/g"' in out
    # ROS_MASTER_URI from the environment is not printed when unchanged
    monkeypatch.setenv("ROS_MASTER_URI", "http://elsewhere:1/")
    rc, out, _ = run(capsys, "--args", "/robot/drv", tree["main"], "robot:=r")
    assert rc == 0 and "ROS_MASTER_URI" not in out


def test_args_unknown_node_is_an_error_listing_the_nodes(tree, capsys):
    rc, out, err = run(capsys, "--args", "/nope", tree["main"], "robot:=r")
    assert rc == 1 and out == "" and "/nope" in err and " * /drv" in err


def test_args_and_find_node_of_an_unknown_node_suggest_the_close_one(tree, capsys):
    for option, status in (("--args", 1), ("--find-node", 0)):  # (roslaunch's statuses: see test_find_node)
        rc, out, err = run(capsys, option, "sub", tree["main"], "robot:=r")
        assert rc == status and err.endswith("\ndid you mean /g/sub?\n"), err


def test_find_node(tree, capsys):
    assert run(capsys, "--find-node", "drv", tree["main"], "robot:=r") == (0, tree["main"] + "\n", "")
    rc, out, err = run(capsys, "--find-node", "/missing", tree["main"], "robot:=r")
    # roslaunch's print_node_filename says so on stderr and returns: its exit status is 0 (--args' is 1)
    assert rc == 0 and out == "" and "ERROR: cannot find node named [/missing]. Run \n\tlaunch --nodes" in err


def test_dump_params_is_yaml_of_the_flat_dict(tree, capsys):
    rc, out, err = run(capsys, "--dump-params", tree["main"], "robot:=r")
    assert rc == 0 and out.endswith("\n\n")
    assert yaml.safe_load(out) == {"/robot": "r", "/rate": 10, "/drv/p": 1.5, "/inc": "yes"}


def test_dump_params_empty_and_binfile(tree, capsys, tmp_path):
    empty = tmp_path / "empty.launch"
    empty.write_text("<launch/>")
    assert run(capsys, "--dump-params", str(empty)) == (0, "{}\n\n", "")
    (tmp_path / "b.bin").write_bytes(b"\x00")
    binf = tmp_path / "bin.launch"
    binf.write_text('<launch>\n<param name="blob" binfile="%s"/>\n</launch>' % (tmp_path / "b.bin"))
    rc, out, err = run(capsys, "--dump-params", str(binf))
    assert rc == 1 and out == "" and "%s:2:" % binf in err and "blob" in err


def test_files_lists_absolute_paths_including_includes(tree, capsys):
    rc, out, _ = run(capsys, "--files", tree["main"], "robot:=r")
    assert rc == 0 and sorted(out.split()) == sorted([tree["main"], tree["inc"]])


def test_ros_args(tree, capsys):
    rc, out, _ = run(capsys, "--ros-args", tree["main"])
    assert rc == 0
    assert out == ("Required Arguments:\n  empty: undocumented\n  robot: robot name\n"
                   "Optional Arguments:\n  rate (default \"10\"): undocumented\n")


def test_ros_args_no_arguments(tmp_path, capsys, tree):
    f = tmp_path / "none.launch"
    f.write_text("<launch/>")
    assert run(capsys, "--ros-args", str(f)) == (0, "No arguments.\n", "")


def test_package_form(tree, capsys):
    rc, out, _ = run(capsys, "--nodes", "tpkg", "main.launch", "robot:=r")
    assert rc == 0 and out.startswith("/drv\n")
    rc, out, err = run(capsys, "--nodes", "tpkg", "nope.launch")
    assert rc == 1 and "nope.launch" in err


def test_missing_file_and_load_error_exit_1_without_traceback(tree, capsys, tmp_path):
    rc, out, err = run(capsys, "--nodes", str(tmp_path / "missing.launch"))
    assert rc == 1 and "is not a launch file name" in err and "Traceback" not in err
    rc, out, err = run(capsys, "--nodes", tree["main"])  # robot not given
    assert rc == 1 and "%s:7:" % tree["main"] in err and "robot" in err and "Traceback" not in err


def test_warnings_go_to_stderr_with_file_and_line(tree, capsys, tmp_path):
    f = tmp_path / "w.launch"
    f.write_text("<launch>\n<bogus/>\n</launch>")
    rc, out, err = run(capsys, "--nodes", str(f))
    assert rc == 0 and out == "\n" and "%s:2:" % f in err and "bogus" in err


def test_option_precedence_is_roslaunchs(tree, capsys):
    # --args wins over --nodes and --dump-params; --dump-params over --files; --files over --ros-args
    rc, out, _ = run(capsys, "--nodes", "--dump-params", "--args", "/drv", tree["main"], "robot:=r")
    assert rc == 0 and out.endswith("__name:=drv\n")
    rc, out, _ = run(capsys, "--files", "--dump-params", tree["main"], "robot:=r")
    assert rc == 0 and yaml.safe_load(out)["/robot"] == "r"
    rc, out, _ = run(capsys, "--ros-args", "--files", tree["main"], "robot:=r")
    assert rc == 0 and sorted(out.split()) == sorted([tree["main"], tree["inc"]])


# What a parse does not need, so that it does not pay for its import (issue 36: `--nodes` and
# `--dump-params` of a large launch within a tenth of roslaunch's time): typing (~3 ms, and its
# NamedTuple's annotations compiled), the console and its writer thread's threading (a run's),
# <param command>'s module and the $(eval) sandbox when the launch has neither.
PARSE_NEEDS_NONE_OF = ("typing", "threading", "argparse", "yaml", "launcher.output.console",
                       "launcher.xml.commands", "launcher.xml.sandbox", "launcher.run", "launcher.plan")


@pytest.mark.parametrize("option", ["--nodes", "--dump-params"])
def test_a_parse_imports_only_what_it_uses(tree, option):
    import json
    import os
    import subprocess
    import sys
    code = ("import sys, json\nfrom launcher.cli.launch import main\nstatus = main(sys.argv[1:])\n"
            "sys.stderr.write(json.dumps([status, sorted(sys.modules)]))")
    r = subprocess.run([sys.executable, "-c", code, option, tree["main"], "robot:=r2"],
                       capture_output=True, text=True, env=dict(os.environ, PYTHONPATH=ROOT), timeout=60)
    status, modules = json.loads(r.stderr.splitlines()[-1])
    assert status == 0 and ("/g/sub" in r.stdout if option == "--nodes" else "/robot: r2" in r.stdout), r
    assert "launcher.xml.loader" in modules  # (what a parse does import)
    assert [m for m in modules if any(m == n or m.startswith(n + ".") for n in PARSE_NEEDS_NONE_OF)] == []
