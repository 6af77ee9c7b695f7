"""`launcher check`: findings on every if/unless branch with file:line, clean files clean, the compat corpus."""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile

import pytest

from launcher import check
from launcher.packages import PackageIndex
from launcher.xml import resolve_launch_arguments

COMPAT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "shared", "compat")
PACKAGE_XML = ('<?xml version="1.0"?>\n<package format="2"><name>%s</name><version>0.0.1</version>'
               '<description>d</description><maintainer email="m@example.com">m</maintainer>'
               '<license>BSD</license></package>\n')


@pytest.fixture
def ws(tmp_path):
    pkg = tmp_path / "src" / "robot"
    (pkg / "config").mkdir(parents=True)
    (pkg / "package.xml").write_text(PACKAGE_XML % "robot")
    (pkg / "config" / "ok.yaml").write_text("gain: 2\n")
    (pkg / "config" / "bad.yaml").write_text("gain: [1, 2\n")
    node = pkg / "driver.py"
    node.write_text("#!/bin/sh\n")
    node.chmod(0o755)
    env = {k: v for k, v in os.environ.items() if not k.startswith("ROS_")}
    env.update(ROS_PACKAGE_PATH=str(tmp_path / "src"), ROS_HOME=str(tmp_path / "home"))
    return tmp_path, env


def write(tmp, name, body):
    path = tmp / name
    path.write_text('<?xml version="1.0"?>\n<launch>\n%s\n</launch>\n' % body)
    return str(path)


def run_check(env, *args):
    return subprocess.run([sys.executable, "-m", "launcher.tool", "check", *args], env=env, capture_output=True,
                          text=True, timeout=60)


def findings(env, path, *argv):
    return check.check([path], list(argv), environ=env, packages=PackageIndex(env))


def test_error_behind_if_arg_is_found_with_its_line_and_branch(ws):
    tmp, env = ws
    path = write(tmp, "robot.launch", '<arg name="sim" default="false"/>\n'   # line 3
                 '<node name="driver" pkg="robot" type="driver.py"/>\n'           # line 4
                 '<group if="$(arg sim)">\n'                                      # line 5
                 '  <node name="fake" pkg="robot" type="no_such_sim.py"/>\n'      # line 6
                 '</group>')
    p = run_check(env, path)
    assert p.returncode == 1, p.stdout + p.stderr
    assert "robot.launch:6: <node> [/fake]" in p.stdout and "no_such_sim.py" in p.stdout
    assert "on the branch sim:=true" in p.stdout
    # roslaunch's own load (the default branch) has nothing to say
    assert not [f for f in findings(env, path, "sim:=false") if f.severity == "error" and not f.branch
                and "no_such_sim" in f.message]


def test_condition_in_an_included_file_decided_by_a_top_level_arg(ws):
    tmp, env = ws
    inner = write(tmp, "inner.launch", '<arg name="sim"/>\n'
                  '<node if="$(arg sim)" name="fake" pkg="robot" type="no_such_sim.py"/>')   # line 4
    path = write(tmp, "outer.launch", '<arg name="use_sim" default="false"/>\n'
                 '<include file="%s"><arg name="sim" value="$(arg use_sim)"/></include>' % inner)  # line 4
    fs = [f for f in findings(env, path) if f.severity == "error"]
    assert len(fs) == 1 and fs[0].branch == ("use_sim:=true",), fs
    assert "inner.launch:4:" in fs[0].message and "included from %s:4" % path in fs[0].message


def test_unless_branch_yaml_and_undefined_arg(ws):
    tmp, env = ws
    path = write(tmp, "robot.launch", '<arg name="real" default="true"/>\n'
                 '<rosparam unless="$(arg real)" file="$(find robot)/config/bad.yaml"/>\n'   # line 4
                 '<param name="x" value="$(arg not_declared)"/>')                           # line 5
    fs = findings(env, path)
    errors = {(f.line, f.branch) for f in fs if f.severity == "error"}
    assert any("bad.yaml" in f.message and f.branch == ("real:=false",) for f in fs), fs
    assert (5, ()) in errors, fs
    assert any("not_declared" in f.message for f in fs)


def test_duplicate_names_and_unknown_machine_on_a_branch(ws):
    tmp, env = ws
    path = write(tmp, "robot.launch", '<arg name="two" default="false"/>\n'
                 '<node name="driver" pkg="robot" type="driver.py"/>\n'
                 '<node if="$(arg two)" name="driver" pkg="robot" type="driver.py"/>\n'          # line 5
                 '<node name="remote" pkg="robot" type="driver.py" machine="nowhere"/>')        # line 6
    fs = findings(env, path)
    assert any(f.line == 5 and f.branch == ("two:=true",) and "multiple nodes named" in f.message for f in fs), fs
    assert any(f.line == 6 and f.branch == () and "machine [nowhere]" in f.message for f in fs), fs


def test_include_chain_and_missing_find_path(ws):
    tmp, env = ws
    inner = write(tmp, "inner.launch", '<rosparam file="$(find robot)/config/none.yaml"/>')
    path = write(tmp, "outer.launch", '<include file="%s"/>' % inner)
    p = run_check(env, path)
    assert p.returncode == 1
    assert "inner.launch:3:" in p.stdout and "included from %s:3" % path in p.stdout, p.stdout


def test_clean_file_gives_no_error_and_junit_says_so(ws):
    tmp, env = ws
    path = write(tmp, "robot.launch", '<arg name="sim" default="false"/>\n'
                 '<node name="driver" pkg="robot" type="driver.py">\n'
                 '  <rosparam file="$(find robot)/config/ok.yaml"/>\n</node>\n'
                 '<node if="$(arg sim)" name="sim_driver" pkg="robot" type="driver.py"/>')
    out = str(tmp / "junit" / "check.xml")
    p = run_check(env, path, "--junit-xml", out)
    assert p.returncode == 0, p.stdout + p.stderr
    with open(out) as f:
        text = f.read()
    assert 'tests="1" failures="0"' in text and 'classname="roslaunch.RoslaunchCheck"' in text


def test_junit_lists_the_errors(ws):
    tmp, env = ws
    path = write(tmp, "robot.launch", '<node name="d" pkg="robot" type="missing.py"/>')
    out = str(tmp / "check.xml")
    p = run_check(env, path, "--junit-xml", out)
    assert p.returncode == 1
    with open(out) as f:
        text = f.read()
    assert 'failures="1"' in text and "roslaunch check [%s] failed" % path in text and "missing.py" in text


def _corpus_cases():
    if not os.path.isdir(COMPAT):
        return []
    sys.path.insert(0, COMPAT)
    try:
        import compatlib
    finally:
        sys.path.remove(COMPAT)
    return [(compatlib, c) for c in compatlib.build_cases()]


def _check_case(compatlib, case, monkeypatch):
    monkeypatch.chdir(compatlib.COMPAT)
    with tempfile.TemporaryDirectory() as home:
        env = compatlib.case_env(case, home)
        packages = PackageIndex(env)
        files, args = resolve_launch_arguments([compatlib.expand(a) for a in case["argv"]], packages)
        return check.check(files, args, environ=env, packages=packages)


def test_compat_corpus(monkeypatch):
    """Every corpus case roslaunch loads gives no load error with the case's args; every case it refuses gives
    an error.

    Two kinds of error remain in files roslaunch loads, both on purpose:
    - the corpus is a loader corpus: some of its nodes name executables that do not exist here (ros_comm's
      example files run rospy's talker.py, which Debian does not ship; a node on an undeclared machine).
      roslaunch loads those files and then fails to run those nodes: `check` says so, as errors of kind "run";
    - errors on another branch, which is what `check` is for: if_unless.launch includes a file that does not
      exist when `off:=true`, ros_comm's example.launch runs a node of a missing package when
      `commandline_true_arg:=false`. Each names the args that reach it.
    """
    cases = _corpus_cases()
    if not cases:
        pytest.skip("../shared/compat is not beside this checkout")
    clean = refused = branch_errors = 0
    for compatlib, case in cases:
        golden = compatlib.load_golden(case["id"])
        try:
            fs = _check_case(compatlib, case, monkeypatch)
        except Exception as e:  # a LaunchError from the arguments themselves: roslaunch refuses those too
            assert golden["error"], (case["id"], e)
            refused += 1
            continue
        errors = [f for f in fs if f.severity == "error"]
        if golden["error"]:
            assert errors, case["id"]
            refused += 1
            continue
        clean += 1
        for f in errors:
            if f.branch:
                branch_errors += 1
                continue
            assert f.kind == "run", (case["id"], f.format())
            assert ("Cannot locate node" in f.message or "Resource not found" in f.message
                    or "which no <machine> tag declares" in f.message), (case["id"], f.format())
    assert clean > 100 and refused > 100 and branch_errors > 0
