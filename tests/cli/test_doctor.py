"""`launcher doctor`: each set-up mistake found, with its fix, and exit status 1; a sound set-up passes."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from launcher.cli.doctor import _local_addresses

MANIFEST = ('<package format="2"><name>%s</name><version>1.0.0</version><description>d</description>'
            '<maintainer email="a@b.c">m</maintainer><license>BSD</license></package>')


def doctor(env, *args):
    r = subprocess.run([sys.executable, "-m", "launcher.cli.tool", "doctor", *args], capture_output=True, text=True,
                       timeout=60, env=env)
    return r.returncode, r.stdout


@pytest.fixture
def env(tmp_path):
    pkg = tmp_path / "ws" / "doc_pkg"
    pkg.mkdir(parents=True)
    (pkg / "package.xml").write_text(MANIFEST % "doc_pkg")
    scripts = {"good": "#!/bin/sh\nexit 0\n", "no_x": "#!/bin/sh\nexit 0\n",
               "bad_interp": "#!/nonexistent/python9\nprint(1)\n", "bad_env": "#!/usr/bin/env no-such-python\n",
               "crlf": "#!/bin/sh\r\nexit 0\r\n"}
    for name, text in scripts.items():
        (pkg / name).write_text(text)
        (pkg / name).chmod(0o644 if name == "no_x" else 0o755)
    (tmp_path / "empty").mkdir()
    port = 1  # nothing answers there on this machine
    return {"PATH": os.environ["PATH"], "HOME": str(tmp_path), "ROS_HOME": str(tmp_path / "home"),
            "ROS_PACKAGE_PATH": str(tmp_path / "ws"), "ROS_MASTER_URI": "http://127.0.0.1:%d/" % port}


def test_a_sound_setup_passes(env):
    rc, out = doctor(env)
    assert rc == 0, out
    assert "0 problems found" in out and "launch` will start one" in out


def test_it_says_which_python_runs_the_launcher(env):
    rc, out = doctor(env)
    assert "ok       the launcher runs on Python %d.%d.%d (%s)" % (sys.version_info[:3] + (sys.executable,)) in out, out


def test_a_reader_that_leaves_is_no_error(env):
    """`launcher doctor | true`: no traceback when the reader has gone before the first line."""
    r = subprocess.run("%s -m launcher.cli.tool doctor | true" % sys.executable, shell=True, capture_output=True,
                       text=True, timeout=60, env=env)
    assert r.stderr == "", r.stderr


def test_ros_ip_that_is_not_ours(env):
    assert "192.0.2.77" not in _local_addresses()  # (TEST-NET-1: never an address of this machine)
    rc, out = doctor(dict(env, ROS_IP="192.0.2.77"))
    assert rc == 1 and "problem  ROS_IP [192.0.2.77] is no address of this machine" in out


def test_ros_hostname_that_does_not_resolve(env):
    rc, out = doctor(dict(env, ROS_HOSTNAME="no-such-host.invalid"))
    assert rc == 1 and "ROS_HOSTNAME [no-such-host.invalid] does not resolve" in out and "fix:" in out


def test_master_host_that_does_not_resolve(env):
    rc, out = doctor(dict(env, ROS_MASTER_URI="http://no-such-master.invalid:11311/"))
    assert rc == 1 and "its host [no-such-master.invalid] does not resolve" in out


def test_package_path_without_packages(env, tmp_path):
    rc, out = doctor(dict(env, ROS_PACKAGE_PATH="%s:%s" % (env["ROS_PACKAGE_PATH"], tmp_path / "empty")))
    assert rc == 1 and "[%s] holds no package" % (tmp_path / "empty") in out and "setup.bash" in out


def test_each_broken_node_executable(env, tmp_path):
    launch = tmp_path / "robot.launch"
    launch.write_text("<launch>\n" + "".join(
        '<node pkg="doc_pkg" type="%s" name="%s"/>\n' % (t, t)
        for t in ("good", "no_x", "bad_interp", "bad_env", "crlf", "missing")) + "</launch>\n")
    rc, out = doctor(env, str(launch))
    assert rc == 1
    problems = [line for line in out.splitlines() if line.startswith("problem")]
    assert len(problems) == 5, out
    assert "robot.launch:3: node [/no_x]" in out and "chmod +x %s" % (tmp_path / "ws/doc_pkg/no_x") in out
    # the file is there: roslaunch's "Make sure file exists" would send the user looking for it
    no_x = [line for line in problems if "[/no_x]" in line][0]
    assert no_x.endswith("node [/no_x]: the file [%s] is there but not executable" % (tmp_path / "ws/doc_pkg/no_x"))
    assert "[/nonexistent/python9], which does not exist" in out
    assert "no [no-such-python] is on PATH" in out
    assert "Windows line endings" in out
    assert "robot.launch:7: node [/missing]: Cannot locate node of type [missing]" in out
    assert "node [/good]" not in out


ROSPY_NODE = "#!/usr/bin/env python3\nimport rospy\nfrom std_msgs.msg import String\nrospy.init_node('talker')\n"


@pytest.mark.parametrize("first_on_path", ["venv", "shim"])
def test_env_python3_that_cannot_import_rospy(env, tmp_path, ros_env, first_on_path):
    """A rospy node script starting with `#!/usr/bin/env python3` while a real venv's bin (or a version manager's
    shim, here a pyenv-like script in front of another real interpreter) comes first on PATH: that python3 cannot
    import rospy, the system's can. Doctor names the node, the interpreter, the modules and the fix."""
    script = tmp_path / "ws" / "doc_pkg" / "talker"
    script.write_text(ROSPY_NODE)
    script.chmod(0o755)
    launch = tmp_path / "robot.launch"
    launch.write_text('<launch>\n<node pkg="doc_pkg" type="talker" name="talker"/>\n'
                      '<node pkg="doc_pkg" type="good" name="plain"/>\n</launch>\n')
    if first_on_path == "venv":
        subprocess.run([ros_env["python"], "-m", "venv", "--without-pip", str(tmp_path / "venv")], check=True)
        bin_dir = tmp_path / "venv" / "bin"
    else:
        bin_dir = tmp_path / "shims"
        bin_dir.mkdir()
        (bin_dir / "python3").write_text('#!/bin/sh\nexec %s "$@"\n' % sys.executable)
        (bin_dir / "python3").chmod(0o755)
    rc, out = doctor(dict(env, PATH="%s:%s" % (bin_dir, ros_env["path"])), str(launch))
    assert rc == 1, out
    problems = [line for line in out.splitlines() if line.startswith("problem")]
    assert problems == [
        "problem  %s:2: node [/talker] (%s): '#!/usr/bin/env python3' finds %s/python3 first on "
        "PATH; that cannot import rospy, std_msgs (%s can)" % (launch, script, bin_dir, ros_env["python"])], out
    assert "fix: take %s off PATH: put only `launch` and `launcher` on it" % bin_dir in out
    assert out.count("fix: take") == 1 and "fix: as above" in out  # (the note above has the same fix)
    # without a launch file: a note, as any rospy node would meet it
    assert "note     python3 on PATH is %s/python3, which cannot import rospy" % bin_dir in doctor(
        dict(env, PATH="%s:%s" % (bin_dir, ros_env["path"])))[1]
    # the system's python3 first: the same node is sound
    rc, out = doctor(dict(env, PATH=ros_env["path"]), str(launch))
    assert rc == 0 and "python3 on PATH" not in out, out


def test_one_cause_is_said_once_with_its_fix_naming_the_nodes_it_concerns(env, tmp_path, ros_env):
    """Five rospy nodes behind one python3 on PATH that cannot import rospy, and two nodes of one script that is
    not executable: one problem each, its fix once, and every node it concerns named under it."""
    pkg = tmp_path / "ws" / "doc_pkg"
    names = ["talker%d" % i for i in range(5)]
    for name in names:
        (pkg / name).write_text(ROSPY_NODE)
        (pkg / name).chmod(0o755)
    launch = tmp_path / "robot.launch"
    launch.write_text("<launch>\n" + "".join('<node pkg="doc_pkg" type="%s" name="%s"/>\n' % (n, n) for n in names)
                      + '<node pkg="doc_pkg" type="no_x" name="x1"/>\n<node pkg="doc_pkg" type="no_x" name="x2"/>\n'
                      + "</launch>\n")
    shims = tmp_path / "shims"
    shims.mkdir()
    (shims / "python3").write_text('#!/bin/sh\nexec %s "$@"\n' % sys.executable)
    (shims / "python3").chmod(0o755)
    rc, out = doctor(dict(env, PATH="%s:%s" % (shims, ros_env["path"])), str(launch))
    assert rc == 1, out
    lines = out.splitlines()
    problems = [line for line in lines if line.startswith("problem")]
    assert problems == [
        "problem  '#!/usr/bin/env python3' finds %s/python3 first on PATH; that cannot import rospy, std_msgs (%s "
        "can): 5 nodes" % (shims, ros_env["python"]),
        "problem  the file [%s] is there but not executable: 2 nodes" % (pkg / "no_x")], out
    first = lines.index(problems[0])
    assert lines[first + 1:first + 7] == ["           %s:%d: node [/%s] (%s)" % (launch, i + 2, n, pkg / n)
                                          for i, n in enumerate(names)] + ["           fix: as above"], out
    second = lines.index(problems[1])
    assert lines[second + 1:second + 4] == ["           %s:7: node [/x1]" % launch, "           %s:8: node [/x2]" % launch,
                                            "           fix: chmod +x %s" % (pkg / "no_x")], out
    assert out.count("fix: take %s off PATH" % shims) == 1 and out.count("fix:") == 3  # (the note's, then these)
    assert lines[-1] == "2 problems found"
