"""`launch` through trouble on the machine: an executable briefly missing, a full log disk."""

from __future__ import annotations

import os
import signal
import subprocess

import pytest

from helpers import free_port, pid_alive, until
from running import Launcher, make_package, ros_env, write_launch


@pytest.fixture
def pkgs(tmp_path, ros_env):
    make_package(str(tmp_path / "pkgs"), "resilience_tests", {"sleeper": "#!/bin/sh\nexec sleep 100\n",
                                                                 "crasher": "#!/bin/sh\nexit 1\n"})
    return str(tmp_path / "pkgs")


def test_respawning_node_comes_back_after_its_executable_was_briefly_missing(tmp_path, pkgs):
    """A package reinstall removes the executable for a moment: the respawn is retried until it is back."""
    exe = os.path.join(pkgs, "resilience_tests", "sleeper")
    launch = write_launch(str(tmp_path), '<node pkg="resilience_tests" type="sleeper" name="s" respawn="true"/>')
    lp = Launcher([launch], ros_env(str(tmp_path), free_port(), pkgs), str(tmp_path))
    try:
        first = int(lp.wait_output(r"process\[s-2\]: started with pid \[(\d+)\]").group(1))
        os.rename(exe, exe + ".away")
        os.kill(first, signal.SIGKILL)
        lp.wait_output(r"\[s-2\] got a 'No such file or directory' error", stream="stderr")
        os.rename(exe + ".away", exe)
        until(lambda: lp.started_pids().get("s-2") not in (None, first) and pid_alive(lp.started_pids()["s-2"]), 20,
              what="s-2 started again")
        lp.signal(signal.SIGINT)
        assert lp.wait(30) == 0
    finally:
        lp.close()


@pytest.fixture
def small_log_disk(tmp_path):
    """A 256 KiB tmpfs (root only), unmounted afterwards."""
    path = tmp_path / "logdisk"
    path.mkdir()
    if os.geteuid() != 0 or subprocess.run(["mount", "-t", "tmpfs", "-o", "size=256k", "tmpfs", str(path)],
                                           capture_output=True).returncode != 0:
        pytest.skip("mounting a tmpfs needs root")
    try:
        yield str(path)
    finally:
        subprocess.run(["umount", "-l", str(path)], check=False)


def test_a_full_log_disk_is_a_warning_and_the_stop_is_clean(tmp_path, pkgs, small_log_disk):
    # the crash loop writes a few lines to the launch log ten times a second
    launch = write_launch(str(tmp_path), '<node pkg="resilience_tests" type="sleeper" name="s" output="screen"/>'
                                         '<node pkg="resilience_tests" type="crasher" name="c" respawn="true"/>')
    env = dict(ros_env(str(tmp_path), free_port(), pkgs), ROS_LOG_DIR=small_log_disk)
    lp = Launcher([launch], env, str(tmp_path))
    try:
        lp.wait_output(r"process\[s-2\]: started with pid")
        fd = os.open(os.path.join(small_log_disk, "filler"), os.O_WRONLY | os.O_CREAT)
        try:
            while True:  # until the disk is full
                os.write(fd, b"x" * 4096)
        except OSError:
            pass
        finally:
            os.close(fd)
        lp.wait_output(r"WARNING: cannot write the launch log .*No space left on device", stream="stderr")
        lp.signal(signal.SIGINT)
        assert lp.wait(30) == 0, lp.stderr
        assert "No space left on device" in lp.stderr and "WARNING" in lp.stderr
        assert "internal error" not in lp.stderr and "Traceback" not in lp.stderr
    finally:
        lp.close()
