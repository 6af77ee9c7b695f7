"""The ssh command line and the words for its failures (no network: launcher.remote.ssh is pure)."""

from __future__ import annotations

import shlex

import pytest

from launcher.model.config import Machine
from launcher.model.errors import LaunchError
from launcher.remote import ssh

ARM = Machine("arm", "arm.local", env_loader="/opt/ros/env.sh", ssh_port=2222, user="robot", timeout=10.0,
              filename="/r/robot.launch", line=3)


def test_ssh_argv_is_the_users_ssh_in_batch_mode_with_a_pty():
    argv = ssh.ssh_argv(ARM, "true", {})
    assert argv[0] == "ssh" and "-tt" in argv
    opts = [argv[i + 1] for i, a in enumerate(argv) if a == "-o"]
    assert "BatchMode=yes" in opts and not any(o.startswith("StrictHostKeyChecking") for o in opts)
    assert argv[argv.index("-p") + 1] == "2222" and argv[argv.index("-l") + 1] == "robot"
    assert argv[-3:] == ["--", "arm.local", "true"]


def test_roslaunch_ssh_unknown_accepts_new_keys_only_and_the_command_can_be_replaced():
    argv = ssh.ssh_argv(ARM, "true", {"ROSLAUNCH_SSH_UNKNOWN": "1", "LAUNCHER_SSH_COMMAND": "ssh -F '/my cfg'"})
    assert argv[:3] == ["ssh", "-F", "/my cfg"]
    assert "StrictHostKeyChecking=accept-new" in argv


def test_remote_command_runs_roslaunchs_child_command_under_the_watch_loop():
    cmd = ssh.remote_command(ARM, "roslaunch", "arm.local-0", "http://10.0.0.1:4000/", "RID",
                             "http://10.0.0.1:11311/", 15.0, 2.0)
    argv = shlex.split(cmd)
    assert argv[:2] == ["sh", "-c"]
    # (marked with the watch loop's pid, which its stop looks for in /proc/*/environ)
    assert ("\nenv LAUNCHER_SESSION=$$ ROS_MASTER_URI=http://10.0.0.1:11311/ /opt/ros/env.sh roslaunch -c arm.local-0 "
                              "-u http://10.0.0.1:4000/ --run_id RID --sigint-timeout 15.0 --sigterm-timeout 2.0 & child=$!\n" in argv[2])


def test_password_and_missing_env_loader_are_errors_at_the_machine_tag():
    with pytest.raises(LaunchError, match=r"^/r/robot.launch:3: machine \[arm\]: password=.*use a key"):
        ssh.check_machine(ARM._replace(password="secret"))
    with pytest.raises(LaunchError, match=r"^/r/robot.launch:3: machine \[arm\]: env-loader is required"):
        ssh.check_machine(ARM._replace(env_loader=None))
    ssh.check_machine(ARM)


@pytest.mark.parametrize("output, status, expected", [
    ("robot@arm.local: Permission denied (publickey).", 255, r"authentication .*\[robot@arm.local:2222\] failed"),
    ("Host key verification failed.", 255, r"arm.local is not in your SSH known_hosts file.*ROSLAUNCH_SSH_UNKNOWN=1"),
    ("@@@ WARNING: REMOTE HOST IDENTIFICATION HAS CHANGED! @@@", 255, r"has changed.*ssh-keygen -R arm.local"),
    ("ssh: connect to host arm.local port 2222: Connection refused", 255, r"connection refused by \[robot@arm"),
    ("ssh: connect to host arm.local port 2222: Connection timed out", 255, r"unable to reach \[robot@arm.local"),
    ("ssh: Could not resolve hostname arm.local: Name or service not known", 255, r"unable to reach"),
    ("env: '/opt/ros/env.sh': No such file or directory", 127, r"env-loader \[/opt/ros/env.sh\] not found"),
    ("/opt/ros/env.sh: 5: exec: roslaunch: not found", 127, r"\[roslaunch\] is not installed on \[arm.local\]"),
])
def test_failures_in_words(output, status, expected):
    import re
    assert re.search(expected, ssh.explain_failure(ARM, output, status, "roslaunch"), re.S)
