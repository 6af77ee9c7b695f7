"""`launch` as PID 1 of a new PID namespace (as in `docker run IMAGE launch ...`): orphans re-parented to it are
reaped (no zombies pile up), and SIGTERM (docker stop) stops everything well within docker's 10 s."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

from helpers import ROOT, ROS_PATH, free_port, until
from running import SlowSpinner, make_package, master_proxy, write_launch
from running import ros_env as environment
from launcher.process.reaper import children, stat_fields

# a node that double-forks: its grandchild outlives it (re-parented to PID 1) and then ends
DoubleFork = "#!/bin/sh\n( sleep 2 & )\nexit 0\n"


def test_pid1_reaps_orphans_and_stops_at_sigterm_within_a_second(tmp_path, ros_env):
    pkgs = str(tmp_path / "pkgs")
    make_package(pkgs, "pid1_tests", {"slow_spinner": SlowSpinner, "double_fork": DoubleFork})
    (tmp_path / "stamps").mkdir()
    port = free_port()
    env = environment(str(tmp_path), port, pkgs)
    env.update(PATH=ROS_PATH + ":" + env["PATH"], PYTHONPATH=ROOT, STAMPS=str(tmp_path / "stamps"))
    body = ('<node pkg="pid1_tests" type="slow_spinner" name="n0" args="0 n0"/>\n'
            '<node pkg="pid1_tests" type="double_fork" name="forker"/>')
    out = open(tmp_path / "out.txt", "wb")
    proc = subprocess.Popen(["unshare", "--pid", "--fork", "--mount-proc", sys.executable, "-m", "launcher",
                             write_launch(str(tmp_path), body)], env=env, stdout=out, stderr=subprocess.STDOUT,
                            start_new_session=True)
    try:
        launch = until(lambda: (children(proc.pid) or [None])[0], 10, what="launch as PID 1")
        assert stat_fields(launch) is not None
        with open("/proc/%d/status" % launch) as f:
            assert any(line.startswith("NSpid:") and line.split()[-1] == "1" for line in f)
        until(lambda: master_proxy(port).lookupNode("/test", "/n0")[0] == 1, 60, what="n0 registered",
              errors=(OSError,))

        def orphan():  # the grandchild, now a child of PID 1
            for kid in children(launch):
                with open("/proc/%d/comm" % kid) as f:
                    if f.read().strip() == "sleep":
                        return kid
            return None
        grandchild = until(orphan, 10, what="the double-forked grandchild under PID 1")
        # it ends after 2 s: then it is reaped (gone), not left a zombie
        until(lambda: stat_fields(grandchild) is None, 10, what="the orphan reaped, not left a zombie")
        # and no zombie stays: one may be there for a moment (the launch's own `du`, run 2 s after the start, just
        # ended and not yet waited for by its runner), none for long
        until(lambda: not [k for k in children(launch) if (stat_fields(k) or ["?"])[0] == "Z"], 5,
              what="no zombie left under PID 1")

        started = time.monotonic()
        os.kill(launch, signal.SIGTERM)  # docker stop
        proc.wait(10)
        took = time.monotonic() - started
        assert took < 1.0, "SIGTERM to PID 1 took %.2fs to stop everything" % took
        assert proc.returncode == 0, open(tmp_path / "out.txt").read()
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        out.close()


# a node whose grandchild daemonizes (a session of its own, out of the node's process group) and lives on
Daemonizer = "#!/bin/sh\n( setsid sleep 1000 & )\nexec sleep 999\n"


def test_daemonized_grandchildren_are_stopped_with_the_launch(tmp_path, ros_env):
    pkgs = str(tmp_path / "pkgs")
    make_package(pkgs, "reap_tests", {"daemonizer": Daemonizer})
    port = free_port()
    env = environment(str(tmp_path), port, pkgs)
    env.update(PATH=ROS_PATH + ":" + env["PATH"], PYTHONPATH=ROOT)
    out = open(tmp_path / "out.txt", "wb")
    proc = subprocess.Popen([sys.executable, "-m", "launcher", "-p", str(port),
                             write_launch(str(tmp_path), '<node pkg="reap_tests" type="daemonizer" name="d"/>')],
                            env=env, stdout=out, stderr=subprocess.STDOUT)
    try:
        def daemon():  # the sleep in a session of its own, re-parented to the launch (its subreaper)
            for kid in children(proc.pid):
                fields = stat_fields(kid)
                if fields is not None and int(fields[2]) == kid:
                    with open("/proc/%d/cmdline" % kid, "rb") as f:
                        if f.read() == b"sleep\0" + b"1000\0":
                            return kid
            return None
        pid = until(daemon, 30, what="the daemonized grandchild under the launch")
        proc.send_signal(signal.SIGINT)
        assert proc.wait(30) == 0
        assert stat_fields(pid) is None, "the daemon %d outlived the launch" % pid
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        out.close()
