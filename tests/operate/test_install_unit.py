"""`launcher install`: the unit is a function of the options; what --dry-run prints is what is written, and the
units (system and user) pass Debian's `systemd-analyze verify` without a word on stderr."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys

import pytest

from helpers import ROOT
from launcher.operate import install

EXPECTED = """\
# Written by `launcher install` (launcher {version}); `launcher uninstall robot` removes it.
# launch files: /ws/robot.launch
[Unit]
Description=ROS launch /ws/robot.launch
Wants=network-online.target
After=network-online.target can.service
StartLimitIntervalSec=120
StartLimitBurst=5

[Service]
Type=notify
NotifyAccess=main
User=robot
Environment=PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin
Environment=PYTHONUNBUFFERED=1
Environment=ROS_HOME=/home/robot/.ros
Environment=ROS_MASTER_URI=http://base:11311
Environment="GREETING=50%% of $$HOME"
EnvironmentFile=/etc/robot.env
ExecStart=/bin/bash -c "source /ws/devel/setup.bash && export ROS_IP=\\"$$(ip -4 -o addr show dev eth0 scope global \
| awk '{{sub(\\"/.*\\", \\"\\", $$4); print $$4; exit}}')\\" && {{ [ -n \\"$$ROS_IP\\" ] || {{ echo 'no IPv4 address on eth0' >&2; \
exit 1; }}; }} && exec /usr/bin/launch /ws/robot.launch sim:=false --wait"
ExecReload=/usr/bin/launcher reload --launch $MAINPID
KillSignal=SIGINT
KillMode=mixed
TimeoutStartSec=120
TimeoutStopSec=12
WatchdogSec=30
Restart=on-failure
RestartSec=2
LogRateLimitIntervalSec=0

[Install]
WantedBy=multi-user.target
"""


def test_unit_text_of_every_option():
    opts = install.UnitOptions(
        name="robot", launch=("/usr/bin/launch", "/ws/robot.launch", "sim:=false", "--wait"),
        files=("/ws/robot.launch",), user="robot", ros_home="/home/robot/.ros", setup="/ws/devel/setup.bash",
        env=(("GREETING", "50% of $HOME"),), env_files=("/etc/robot.env",), ros_ip_from="eth0",
        after=("can.service",), master="http://base:11311", system=True, sigint_timeout=5.0, sigterm_timeout=2.0)
    assert install.unit_text(opts) == EXPECTED.format(version=install.__version__)


def test_stop_timeout_outlasts_the_launch_escalation():
    assert install.timeout_stop(install.UnitOptions("a", ())) == 15 + 2 + install.STOP_MARGIN_S
    assert install.timeout_stop(install.UnitOptions("a", (), sigint_timeout=0.5, sigterm_timeout=0.2)) == 6


def tool(*args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "launcher.cli.tool", *args], capture_output=True, text=True,
                          env=dict(os.environ, PYTHONPATH=ROOT, **(env or {})), timeout=60)


@pytest.fixture
def launch_file(tmp_path):
    path = tmp_path / "robot.launch"
    path.write_text('<launch><node pkg="rospy_tutorials" type="talker" name="talker"/></launch>\n')
    setup = tmp_path / "setup.bash"
    setup.write_text("export FROM_SETUP=1\n")
    return path, setup


@pytest.mark.parametrize("kind", ["--system", "--user-unit"])
def test_written_unit_is_the_dry_run_and_passes_systemd_analyze(tmp_path, launch_file, kind):
    if shutil.which("systemd-analyze") is None:
        pytest.fail("systemd-analyze is missing (Debian's package systemd)")
    path, setup = launch_file
    common = [str(path), "rate:=10", "--name", "robot", kind, "--setup", str(setup), "--ros-ip-from", "eth0",
              "--env", "ROBOT=r2", "--env-file", str(tmp_path / "robot.env"), "--after", "can.service"]
    if kind == "--system":
        common += ["--run-as", "root"]
    dry = tool("install", *common, "--dry-run")
    assert dry.returncode == 0, dry.stderr
    units = tmp_path / "units"
    done = tool("install", *common, "--unit-dir", str(units))
    assert done.returncode == 0, done.stderr
    unit = units / "robot.service"
    assert unit.read_text() == dry.stdout
    assert "daemon-reload" in done.stdout and "enable --now robot" in done.stdout  # offered, not done
    runtime = tmp_path / "xdg"
    runtime.mkdir(mode=0o700)
    verify = subprocess.run(["systemd-analyze"] + (["--user"] if kind == "--user-unit" else []) + ["verify", str(unit)],
                            capture_output=True, text=True, timeout=60,
                            env=dict(os.environ, XDG_RUNTIME_DIR=str(runtime)))
    assert (verify.returncode, verify.stderr) == (0, ""), verify.stderr
    assert ("WantedBy=multi-user.target" if kind == "--system" else "WantedBy=default.target") in dry.stdout
    listed = tool("installed", "--unit-dir", str(units), kind)
    assert listed.stdout.startswith("robot\t%s\t" % ("system" if kind == "--system" else "user")), listed
    assert listed.stdout.rstrip().endswith(str(path))
    gone = tool("uninstall", "robot", "--unit-dir", str(units), kind)
    assert gone.returncode == 0 and not unit.exists(), gone.stderr


def test_a_unit_not_ours_is_not_replaced(tmp_path, launch_file):
    path, _ = launch_file
    units = tmp_path / "units"
    units.mkdir()
    (units / "robot.service").write_text("[Service]\nExecStart=/bin/true\n")
    done = tool("install", str(path), "--unit-dir", str(units), "--system")
    assert done.returncode == 1 and "not written by launcher" in done.stderr
    assert (units / "robot.service").read_text() == "[Service]\nExecStart=/bin/true\n"
    gone = tool("uninstall", "robot", "--unit-dir", str(units))
    assert gone.returncode == 1 and (units / "robot.service").exists()


def test_a_dry_run_writes_the_unit_for_a_user_this_machine_does_not_have(tmp_path, launch_file):
    """The README's `--run-as robot --dry-run`, on a machine without that user: the unit for the machine that has
    it (its home taken as /home/USER), and a warning naming the user; a real install still refuses."""
    path, _ = launch_file
    user = "no-such-user-x"
    dry = tool("install", str(path), "--run-as", user, "--system", "--dry-run")
    assert dry.returncode == 0, dry.stderr
    assert "\nUser=%s\n" % user in dry.stdout and "\nEnvironment=ROS_HOME=/home/%s/.ros\n" % user in dry.stdout
    assert dry.stderr.count("\n") == 1 and "warning: no user '%s' on this machine" % user in dry.stderr
    done = tool("install", str(path), "--run-as", user, "--system", "--unit-dir", str(tmp_path / "units"))
    assert done.returncode == 2 and "no user '%s' on this machine" % user in done.stderr
    assert not (tmp_path / "units").exists()


def test_installed_says_when_there_is_none(tmp_path):
    units = tmp_path / "units"
    listed = tool("installed", "--unit-dir", str(units), "--system")
    assert (listed.returncode, listed.stdout) == (0, "no unit written by `launcher install` in %s\n" % units)
    units.mkdir()
    (units / "other.service").write_text("[Service]\nExecStart=/bin/true\n")  # (not ours: not listed)
    assert tool("installed", "--unit-dir", str(units)).stdout.startswith("no unit written by `launcher install`")


def test_bad_options_are_said(tmp_path, launch_file):
    path, _ = launch_file
    assert "no user" in tool("install", str(path), "--run-as", "no-such-user-x", "--system").stderr
    assert "KEY=VALUE" in tool("install", str(path), "--env", "NOEQUALS", "--dry-run").stderr
    assert "--run-as is for a system unit" in tool("install", str(path), "--run-as", "root", "--user-unit",
                                                   "--dry-run").stderr


def test_start_timeout_stays_above_the_launch_ready_timeout(tmp_path, launch_file):
    assert install.timeout_start(install.UnitOptions("a", ())) == install.START_TIMEOUT_S
    assert install.timeout_start(install.UnitOptions("a", (), ready_timeout=300.5)) == 301 + install.START_MARGIN_S
    path, _ = launch_file
    dry = tool("install", str(path), "--system", "--ready-timeout", "200", "--dry-run")
    assert dry.returncode == 0, dry.stderr
    assert "TimeoutStartSec=%d\n" % (200 + install.START_MARGIN_S) in dry.stdout
    exec_start = next(line for line in dry.stdout.splitlines() if line.startswith("ExecStart="))
    assert exec_start.endswith("--screen --ready-timeout 200")  # the launch is told the same timeout
    assert "TimeoutStartSec=120\n" in tool("install", str(path), "--system", "--dry-run").stdout
    assert "greater than zero" in tool("install", str(path), "--ready-timeout", "0", "--dry-run").stderr


def test_install_metrics_puts_the_address_on_the_launch_command(launch_file):
    path, _ = launch_file
    dry = tool("install", str(path), "--user-unit", "--metrics", "0.0.0.0:9180", "--dry-run")
    assert dry.returncode == 0, dry.stderr
    exec_start = next(line for line in dry.stdout.splitlines() if line.startswith("ExecStart="))
    assert exec_start.endswith(" --screen --metrics 0.0.0.0:9180"), exec_start
    bad = tool("install", str(path), "--user-unit", "--metrics", "localhost:http", "--dry-run")
    assert bad.returncode == 2 and "--metrics: the address is [ADDR:]PORT" in bad.stderr
