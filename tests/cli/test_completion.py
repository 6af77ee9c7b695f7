"""Shell completion: the candidates for each position, and the real bash function using them."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from launcher.cli.completion import candidates

MANIFEST = ('<package format="2"><name>%s</name><version>1.0.0</version><description>d</description>'
            '<maintainer email="a@b.c">m</maintainer><license>BSD</license></package>')


@pytest.fixture
def env(tmp_path):
    for name in ("demo_pkg", "demo_other"):
        (tmp_path / "pkgs" / name / "launch").mkdir(parents=True)
        (tmp_path / "pkgs" / name / "package.xml").write_text(MANIFEST % name)
    (tmp_path / "pkgs/demo_pkg/launch/bringup.launch").write_text(
        '<launch><arg name="robot"/><arg name="rate" default="10"/><arg name="fixed" value="1"/>'
        '<node pkg="demo_pkg" type="x" name="x"/></launch>')
    (tmp_path / "pkgs/demo_pkg/launch/sim.test").write_text("<launch/>")
    (tmp_path / "pkgs/demo_pkg/launch/notes.txt").write_text("")
    return {"ROS_PACKAGE_PATH": str(tmp_path / "pkgs"), "ROS_HOME": str(tmp_path / "home"),
            "PATH": os.environ["PATH"]}


@pytest.mark.parametrize("line,expected", [
    ("launch demo_", ["demo_other", "demo_pkg"]),
    ("launch demo_pkg ", ["bringup.launch", "sim.test"]),
    ("launch demo_pkg bringup.launch ", ["rate:=", "robot:="]),
    ("launch demo_pkg bringup.launch ro", ["robot:="]),
    ("launch demo_pkg bringup.launch robot:", ["="]),  # bash completes the word after the ':'
    ("launch demo_pkg bringup.launch robot:=r2 ra", ["rate:="]),
    ("launch --scr", ["--screen"]),
    ("launcher comp", ["completion"]),
])
def test_candidates(env, line, expected):
    assert candidates(line, env) == expected


def test_the_bash_function(env, tmp_path):
    """The script `launcher completion bash` prints, run by bash as a TAB would run it."""
    shim = tmp_path / "bin" / "launcher"
    shim.parent.mkdir()
    shim.write_text("#!/bin/sh\nexec %s -m launcher.cli.tool \"$@\"\n" % sys.executable)
    shim.chmod(0o755)
    script = subprocess.run([sys.executable, "-m", "launcher.cli.tool", "completion", "bash"], capture_output=True,
                            text=True, check=True).stdout
    line = "launch demo_pkg bringup.launch ro"
    driver = script + '\ncomplete -p launch launcher\nCOMP_LINE="%s"; COMP_POINT=${#COMP_LINE}\n' \
                      '_launcher_complete\nprintf "<%%s>\\n" "${COMPREPLY[@]}"\n' % line
    out = subprocess.run(["bash", "-c", driver], capture_output=True, text=True, timeout=60,
                         env=dict(env, PATH="%s:%s" % (shim.parent, env["PATH"]))).stdout
    assert "complete -F _launcher_complete launch" in out
    assert out.strip().splitlines()[-1] == "<robot:=>"
