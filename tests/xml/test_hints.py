"""Names a user almost got right, in the loader's errors: each says what exists close to it."""

from __future__ import annotations

import pytest

from launcher.model import errors
from launcher.model.errors import LaunchError
from launcher.workspace.packages import PackageIndex
from launcher.xml import resolve_launch_arguments


def test_arg_with_a_typo(ld):
    e = ld.error("""
        <launch>
          <arg name="robot" default="r1"/>
          <param name="p" value="$(arg robto)"/>
        </launch>""")
    assert "main.launch:3: arg 'robto' is not defined (did you mean robot?): declare it" in str(e)


def test_command_line_arg_with_a_typo_is_warned_with_the_close_one(ld):
    warnings = []
    ld.load('<launch><arg name="robot" default="r1"/></launch>', ["robto:=r3"], warn=warnings.append)
    assert warnings == ["command-line argument [robto:=r3] is not declared by an <arg> in the launch file(s) "
                        "and is ignored (did you mean robot?)"]


def test_package_with_a_typo_in_find_and_in_a_node(ld):
    e = ld.error('<launch><param name="p" value="$(find tpgk)/config"/></launch>')
    assert str(e).splitlines()[0].endswith("main.launch:1: Resource not found: tpgk (did you mean tpkg?)")
    with pytest.raises(LaunchError) as e:
        PackageIndex(ld.environ).find_node("tpgk", "talker")
    assert str(e.value).startswith("Resource not found: tpgk (did you mean tpkg?)\nROS path [0]=")


def test_node_type_with_a_typo(ld):
    with pytest.raises(LaunchError) as e:
        PackageIndex(ld.environ).find_node("tpkg", "talkr")
    assert str(e.value).splitlines()[1] == "There is no executable [talkr] in package [tpkg]: did you mean talker?"


def test_included_file_with_a_typo(ld):
    ld.write("robot.launch", "<launch/>")
    e = ld.error('<launch><include file="$(dirname)/robto.launch"/></launch>')
    assert "included file [%s/robto.launch] does not exist (did you mean robot.launch?)" % ld.launch in str(e)


def test_package_or_launch_file_with_a_typo_on_the_command_line(ld):
    ld.write("../pkgs/tpkg/launch/bringup.launch", "<launch/>")
    packages = PackageIndex(ld.environ)
    with pytest.raises(LaunchError) as e:
        resolve_launch_arguments(["tpgk", "bringup.launch"], packages)
    assert str(e.value) == ("[bringup.launch] is neither a launch file in package [tpgk] nor is [tpgk] a launch "
                            "file name (no package [tpgk]: did you mean tpkg?)")
    with pytest.raises(LaunchError) as e:
        resolve_launch_arguments(["tpkg", "bringup.lanch"], packages)
    assert str(e.value).endswith("(package [tpkg] has no [bringup.lanch]: did you mean bringup.launch?)")
    ld.write("robot.launch", "<launch/>")
    with pytest.raises(LaunchError) as e:
        resolve_launch_arguments([str(ld.launch / "robot.lanch")], packages)
    assert str(e.value) == "[%s/robot.lanch] is not a launch file name (did you mean robot.launch?)" % ld.launch


def test_an_arg_without_its_colon_is_a_usage_error(ld):
    main = ld.write("main.launch", "<launch/>")
    with pytest.raises(errors.UsageError) as e:
        resolve_launch_arguments([main, "robot=r3"], PackageIndex(ld.environ))
    assert str(e.value) == "The following input files do not exist: robot=r3 (did you mean robot:=r3?)"
