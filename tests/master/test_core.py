"""`launch --core` pieces: which port, which log dir, roscore's version parameters."""

from __future__ import annotations

import argparse
import os
import socket
import subprocess
import sys

import pytest

from launcher import core
from launcher.errors import LaunchError


def _opts(**kw):
    return argparse.Namespace(**kw)


def test_port_from_option_then_ros_master_uri_then_default():
    assert core.master_port(_opts(port=11500), {"ROS_MASTER_URI": "http://h:11400/"}) == 11500
    assert core.master_port(_opts(port=None), {"ROS_MASTER_URI": "http://h:11400/"}) == 11400
    assert core.master_port(_opts(port=None), {"ROS_MASTER_URI": "http://h/"}) == 11311
    assert core.master_port(_opts(port=None), {}) == 11311
    with pytest.raises(LaunchError):
        core.master_port(_opts(port=None), {"ROS_MASTER_URI": "http://h:notaport/"})


def test_log_dir_follows_ros_log_dir_then_ros_home(tmp_path):
    assert core.log_dir({"ROS_LOG_DIR": "/l", "ROS_HOME": "/h"}, "r") == "/l/r"
    assert core.log_dir({"ROS_HOME": "/h"}, "r") == "/h/log/r"
    assert core.log_dir({}, "r") == os.path.join(os.path.expanduser("~"), ".ros", "log", "r")


def test_version_parameters_come_from_roslaunch_package_xml(tmp_path):
    pkg = tmp_path / "roslaunch"
    pkg.mkdir()
    (pkg / "package.xml").write_text("<package><name>roslaunch</name><version>9.8.7</version></package>")
    env = {"ROS_PACKAGE_PATH": str(tmp_path)}
    assert core.ros_version_params(env) == ("9.8.7\n", "Debian\n")  # what rosversion -d says without ROS_DISTRO
    assert core.ros_version_params(dict(env, ROS_DISTRO="noetic")) == ("9.8.7\n", "noetic\n")


def test_version_parameters_without_ros(tmp_path, monkeypatch):
    monkeypatch.setattr(core, "_roslaunch_package_xml", lambda environ: None)
    assert core.ros_version_params({}) == (core.DEFAULT_ROSVERSION + "\n", core.DEFAULT_ROSDISTRO + "\n")


def test_busy_port_exits_1_with_a_message(tmp_path):
    with socket.socket() as s:
        s.bind(("0.0.0.0", 0))
        s.listen(1)
        port = s.getsockname()[1]
        out = subprocess.run([sys.executable, "-m", "launcher", "--core", "-p", str(port)], capture_output=True,
                             text=True, timeout=60, env=dict(os.environ, ROS_HOME=str(tmp_path)))
    assert out.returncode == 1
    assert "already running" in out.stderr and "Traceback" not in out.stderr
