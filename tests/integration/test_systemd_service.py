"""A real systemd supervising `launch`: systemd runs as PID 1 of a new PID and mount namespace (with a /run of its
own and a boot target that starts nothing else), a unit `launcher install` wrote runs a launch of real rospy nodes.

Shown: `active` only once the nodes registered, the STATUS= text in `systemctl show`, a `kill -9` of launch
restarted, a launch whose loop is held (gdb) restarted by the watchdog, and `systemctl stop` stopping every node
within TimeoutStopSec, a bound node before the node it is bound to."""

from __future__ import annotations

import glob
import json
import os
import shlex
import shutil
import signal
import subprocess
import sys
import time

import pytest

from helpers import ROOT, free_port, pid_alive, until
from running import SlowSpinner, make_package, master_proxy, write_launch

SYSTEMD = "/lib/systemd/systemd"
# The namespace's systemd must not touch the machine it shares: a /run, /tmp and /var/tmp of its own (the test's
# directory bound back in, and the checkout and its venv when they are there too), and every unit a boot target
# wants is masked (systemd-tmpfiles would empty the shared /tmp, systemd-sysctl set the kernel's knobs,
# systemd-sysusers edit /etc/passwd ...).
BOOT = """#!/bin/bash
set -e
mount -t tmpfs tmpfs /run
mkdir -p /run/systemd
%(keep)s
mount -t tmpfs tmpfs /tmp
mount -t tmpfs tmpfs /var/tmp
%(restore)s
SYSTEMD_UNIT_PATH=%(units)s: exec %(systemd)s --system --unit=launcher-test.target --log-target=null
"""


def _kept(tmp: str) -> dict:
    """The boot's lines that keep `tmp`, and the checkout and its venv if they are under /tmp or /var/tmp, through
    the new /tmp and /var/tmp."""
    dirs = [tmp]
    for d in (ROOT, sys.prefix):
        if d.startswith(("/tmp/", "/var/tmp/")) and not any(d == k or d.startswith(k + "/") for k in dirs):
            dirs.append(d)
    keep = "".join("mkdir -p /run/keep/%d\nmount --bind %s /run/keep/%d\n" % (i, shlex.quote(d), i)
                   for i, d in enumerate(dirs))
    restore = "".join("mkdir -p %s\nmount --bind /run/keep/%d %s\n" % (shlex.quote(d), i, shlex.quote(d))
                      for i, d in enumerate(dirs))
    return {"keep": keep, "restore": restore}
TARGET = "[Unit]\nDescription=a boot that starts nothing but the test's units\nDefaultDependencies=no\n"
# the boot's targets, made empty here (a unit's default dependencies still name them)
EMPTY_TARGETS = ("sysinit.target", "basic.target", "local-fs.target", "local-fs-pre.target", "swap.target",
                 "sockets.target", "timers.target", "paths.target", "network.target", "network-online.target",
                 "multi-user.target")


class Systemd:
    """systemd as PID 1 of new PID and mount namespaces; systemctl run inside them."""

    def __init__(self, tmp: str):
        self.units = os.path.join(tmp, "units")
        os.makedirs(self.units)
        for target in ("launcher-test.target",) + EMPTY_TARGETS:
            with open(os.path.join(self.units, target), "w") as f:
                f.write(TARGET)
        for wants in glob.glob("/lib/systemd/system/*.wants") + glob.glob("/usr/lib/systemd/system/*.wants") + \
                glob.glob("/etc/systemd/system/*.wants"):
            for unit in os.listdir(wants):
                mask = os.path.join(self.units, unit)
                if not os.path.lexists(mask):
                    os.symlink("/dev/null", mask)
        boot = os.path.join(tmp, "boot.sh")
        with open(boot, "w") as f:
            f.write(BOOT % dict(_kept(tmp), units=self.units, systemd=SYSTEMD))
        os.chmod(boot, 0o755)
        self.proc = subprocess.Popen(["unshare", "--pid", "--fork", "--mount", "--mount-proc", "--kill-child", boot],
                                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        self.pid = until(self._pid1, 20, what="systemd as PID 1")
        until(lambda: self.ctl("is-system-running").stdout.strip() in ("running", "degraded"), 60,
              what="systemd booted")

    def _pid1(self) -> int | None:
        for pid in subprocess.run(["pgrep", "-P", str(self.proc.pid)], capture_output=True, text=True).stdout.split():
            with open("/proc/%s/status" % pid) as f:
                if any(line.startswith("NSpid:") and line.split()[-1] == "1" for line in f):
                    return int(pid)
        return None

    def ctl(self, *args: str, timeout: float = 60) -> subprocess.CompletedProcess:
        return subprocess.run(["nsenter", "-t", str(self.pid), "-m", "-p", "systemctl", *args], capture_output=True,
                              text=True, timeout=timeout)

    def show(self, unit: str, prop: str) -> str:
        return self.ctl("show", "-p", prop, "--value", unit).stdout.strip()

    def host_pid(self, ns_pid: str) -> int | None:
        """The pid seen here of a process of the namespace (systemctl speaks of the namespace's pids)."""
        for pid in os.listdir("/proc"):
            if pid.isdigit():
                try:
                    with open("/proc/%s/status" % pid) as f:
                        nspid = next((line.split() for line in f if line.startswith("NSpid:")), [])
                except OSError:
                    continue
                if len(nspid) == 3 and nspid[1] == pid and nspid[2] == ns_pid and self._inside(int(pid)):
                    return int(pid)
        return None

    def _inside(self, pid: int) -> bool:
        try:
            return os.readlink("/proc/%d/ns/pid" % pid) == os.readlink("/proc/%d/ns/pid" % self.pid)
        except OSError:
            return False

    def close(self) -> None:
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGKILL)  # --kill-child: the whole namespace goes with it
            self.proc.wait(20)


@pytest.fixture
def systemd(tmp_path, ros_env):
    if os.geteuid() != 0 or not os.path.exists(SYSTEMD) or shutil.which("nsenter") is None:
        pytest.fail("a real systemd needs root, %s and nsenter (Debian's systemd and util-linux)" % SYSTEMD)
    sd = Systemd(str(tmp_path))
    yield sd
    sd.close()


def nodes_pids(sd: Systemd, unit: str) -> set[int]:
    """The pids (here) of the unit's processes other than its main one."""
    main = sd.show(unit, "MainPID")
    procs = set()
    for line in sd.ctl("status", "--no-pager", "-l", unit).stdout.splitlines():
        parts = line.replace("├─", " ").replace("└─", " ").split()
        if parts and parts[0].isdigit() and parts[0] != main:
            procs.add(parts[0])
    return {p for p in (sd.host_pid(x) for x in procs) if p is not None}


def test_a_real_systemd_supervises_the_launch(tmp_path, systemd):
    sd = systemd
    pkgs = str(tmp_path / "pkgs")
    make_package(pkgs, "sd_service", {"slow_spinner": SlowSpinner})
    stamps = tmp_path / "stamps"
    stamps.mkdir()
    port = free_port()
    # n1 is bound to n0 (as a spawner to its controller manager): started after it, stopped before it
    body = "\n".join('<node pkg="sd_service" type="slow_spinner" name="n%d" args="%s n%d" respawn_min_uptime="20"%s/>'
                     % (i, delay, i, bound) for i, delay, bound in ((0, 0.5, ""), (1, 2.0, ' bind_to="n0"')))
    launch_file = write_launch(str(tmp_path), body)
    env = {"PYTHONPATH": ROOT, "ROS_MASTER_URI": "http://127.0.0.1:%d/" % port, "ROS_PACKAGE_PATH": pkgs,
           "ROS_HOME": str(tmp_path / "home"), "ROS_LOG_DIR": str(tmp_path / "log"), "ROS_IP": "127.0.0.1",
           "STAMPS": str(stamps)}
    args = [launch_file, "--name", "robot", "--system", "--unit-dir", sd.units,
            "--watchdog-sec", "3", "--sigint-timeout", "5", "--sigterm-timeout", "2"]
    for kv in env.items():
        args += ["--env", "%s=%s" % kv]
    done = subprocess.run([sys.executable, "-m", "launcher.cli.tool", "install", *args], capture_output=True, text=True,
                          env=dict(os.environ, PYTHONPATH=ROOT), timeout=60)
    assert done.returncode == 0, done.stderr
    assert sd.ctl("daemon-reload").returncode == 0
    assert sd.ctl("start", "--no-block", "robot").returncode == 0

    # active only once both nodes registered (the second is 2 s late)
    seen = []

    def active():
        state = sd.show("robot", "ActiveState")
        seen.append(state)
        return time.time() if state == "active" else None
    became_active = until(active, 90, period=0.05, what="robot.service active")
    assert "activating" in seen, seen
    for i in range(2):
        assert became_active > float((stamps / ("n%d" % i)).read_text())
        assert master_proxy(port).lookupNode("/test", "/n%d" % i)[0] == 1
    until(lambda: sd.show("robot", "StatusText") == "2/2 nodes running", 10, what="STATUS= in systemctl show")
    assert "Status: \"2/2 nodes running\"" in sd.ctl("status", "--no-pager", "robot").stdout

    # kill -9 of launch: systemd starts it again
    first = sd.show("robot", "MainPID")
    os.kill(sd.host_pid(first), signal.SIGKILL)
    until(lambda: sd.show("robot", "MainPID") not in ("0", first) and sd.show("robot", "ActiveState") == "active",
          90, what="launch started again after kill -9")
    assert sd.show("robot", "NRestarts") == "1"

    # its loop held for longer than WatchdogSec (3 s): the watchdog restarts it
    second = sd.show("robot", "MainPID")
    subprocess.Popen(["gdb", "-p", str(sd.host_pid(second)), "-batch", "-ex", "call (unsigned int)sleep(30)"],
                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    until(lambda: sd.show("robot", "MainPID") not in ("0", second) and sd.show("robot", "ActiveState") == "active",
          90, what="launch restarted by the watchdog")
    assert sd.show("robot", "Result") in ("watchdog", "success"), sd.show("robot", "Result")
    assert sd.show("robot", "NRestarts") == "2"

    # systemctl reload: ExecReload= has the launch read its file again (`launcher reload`); the node added starts,
    # the others keep their pids, and the unit stays active (RELOADING=1, then READY=1)
    until(lambda: len(nodes_pids(sd, "robot")) >= 2, 30, what="both nodes running again")
    before = nodes_pids(sd, "robot")
    with open(launch_file) as f:
        text = f.read()
    with open(launch_file, "w") as f:
        f.write(text.replace("</launch>", '<node pkg="sd_service" type="slow_spinner" name="n2" args="0.1 n2"/>\n'
                                          "</launch>"))
    reloaded = sd.ctl("reload", "robot")
    assert reloaded.returncode == 0, reloaded.stderr + sd.ctl("status", "--no-pager", "-l", "robot").stdout
    until(lambda: master_proxy(port).lookupNode("/test", "/n2")[0] == 1, 60, what="the node added registered")
    assert before < nodes_pids(sd, "robot") and sd.show("robot", "ActiveState") == "active"
    assert sd.show("robot", "NRestarts") == "2"

    # systemctl stop: every node stopped, within TimeoutStopSec
    nodes = nodes_pids(sd, "robot")
    assert len(nodes) >= 2, sd.ctl("status", "--no-pager", "robot").stdout
    started = time.monotonic()
    assert sd.ctl("stop", "robot").returncode == 0
    took = time.monotonic() - started
    assert took < 5 + 2 + 5, took
    assert sd.show("robot", "ActiveState") in ("inactive", "failed")
    assert not [p for p in nodes if pid_alive(p)]
    # in the launch's order: the bound node first (the last run's events file)
    events = max(glob.glob(str(tmp_path / "log" / "*" / "launcher-events.jsonl")), key=os.path.getmtime)
    with open(events) as f:
        stopped = [e["node"] for e in map(json.loads, f) if e.get("state") == "stopped"]
    assert sorted(stopped) == ["/n0", "/n1", "/n2"] and stopped.index("/n1") < stopped.index("/n0"), stopped
