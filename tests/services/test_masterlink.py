"""masterlink: which port a core listens on, roscore's version parameters, a busy port."""

from __future__ import annotations

import os
import socket
import subprocess
import sys

import pytest

from launcher.services import masterlink
from launcher.model.errors import LaunchError


def test_port_from_option_then_ros_master_uri_then_default():
    assert masterlink.master_port(11500, {"ROS_MASTER_URI": "http://h:11400/"}) == 11500
    assert masterlink.master_port(None, {"ROS_MASTER_URI": "http://h:11400/"}) == 11400
    assert masterlink.master_port(None, {"ROS_MASTER_URI": "http://h/"}) == 11311
    assert masterlink.master_port(None, {}) == 11311
    with pytest.raises(LaunchError):
        masterlink.master_port(None, {"ROS_MASTER_URI": "http://h:notaport/"})


def test_version_parameters_come_from_roslaunch_package_xml(tmp_path):
    pkg = tmp_path / "roslaunch"
    pkg.mkdir()
    (pkg / "package.xml").write_text("<package><name>roslaunch</name><version>9.8.7</version></package>")
    env = {"ROS_PACKAGE_PATH": str(tmp_path)}
    assert masterlink.ros_version_params(env) == ("9.8.7\n", "Debian\n")  # what rosversion -d says without ROS_DISTRO
    assert masterlink.ros_version_params(dict(env, ROS_DISTRO="noetic")) == ("9.8.7\n", "noetic\n")


def test_version_parameters_without_ros(tmp_path, monkeypatch):
    monkeypatch.setattr(masterlink, "_roslaunch_package_xml", lambda environ: None)
    assert masterlink.ros_version_params({}) == (masterlink.DEFAULT_ROSVERSION + "\n", masterlink.DEFAULT_ROSDISTRO + "\n")


def test_busy_port_exits_1_with_a_message(tmp_path):
    with socket.socket() as s:
        s.bind(("0.0.0.0", 0))
        s.listen(1)
        port = s.getsockname()[1]
        out = subprocess.run([sys.executable, "-m", "launcher", "--core", "-p", str(port)], capture_output=True,
                             text=True, timeout=60, env=dict(os.environ, ROS_HOME=str(tmp_path)))
    assert out.returncode == 1
    assert "already running" in out.stderr and "Traceback" not in out.stderr


def test_a_new_run_id_is_a_random_uuid():
    import uuid
    ids = {masterlink.new_run_id() for _ in range(200)}
    assert len(ids) == 200
    for run_id in ids:
        u = uuid.UUID(run_id)
        assert str(u) == run_id and u.version == 4 and u.variant == uuid.RFC_4122
