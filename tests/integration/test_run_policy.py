"""`launch` with a restart policy: backoff, FATAL, on_fatal, respawn_on, min uptime, stop timeouts, spawn delay.

Delays are measured from the events file (`launcher-events.jsonl` in the run's log directory): from the
event that a run ended (respawning) to the event of the next start (running). The lower bound is tight
(a delay is never shortened); the upper one allows for a loaded machine.
"""

from __future__ import annotations

import json
import os
import signal
import time

import pytest

from helpers import free_port, until
from running import Launcher, make_package, master_up, ros_env

SLACK = 0.35  # how much later than planned a start may come on a busy 2-core machine


@pytest.fixture
def pkgs(tmp_path, ros_env):
    make_package(str(tmp_path / "pkgs"), "policy_tests", {
        "sleeper": "#!/bin/sh\nexec sleep 100\n",
        "crasher": "#!/bin/sh\nexit 1\n",
        "exiter": "#!/bin/sh\nexit \"$1\"\n",  # exits with the code given as its first argument
        # counts its runs in the file given as its first argument; the third run lasts 1.5 s
        "flaky": "#!/bin/sh\nn=$(cat \"$1\" 2>/dev/null || echo 0)\nn=$((n+1))\necho $n > \"$1\"\n"
                 "if [ $n -eq 3 ]; then sleep 1.5; fi\nexit 1\n",
        # ignores SIGINT (and SIGTERM with a first argument of "both") until killed
        "stubborn": "#!/bin/sh\ntrap '' INT\nif [ \"$1\" = both ]; then trap '' TERM; fi\n"
                    "echo ready\nwhile true; do sleep 0.05; done\n",
    })
    return str(tmp_path / "pkgs")


def launch_file(tmp_path, text: str) -> str:
    path = os.path.join(str(tmp_path), "policy.launch")
    with open(path, "w") as f:
        f.write('<?xml version="1.0"?>\n' + text.strip() + "\n")
    return path


def events(tmp_path) -> list[dict]:
    path = os.path.join(str(tmp_path), "log", "latest", "launcher-events.jsonl")
    try:
        with open(path) as f:
            lines = f.read().splitlines()
    except OSError:
        return []
    return [json.loads(line) for line in lines if line.endswith("}")]


def node_events(tmp_path, node: str) -> list[dict]:
    return [e for e in events(tmp_path) if e.get("node") == node]


def restart_delays(evs: list[dict]) -> list[float]:
    """The time from each end of a run (respawning) to the next start (running)."""
    out = []
    for a, b in zip(evs, evs[1:]):
        if a["state"] == "respawning" and b["state"] == "running":
            out.append(b["time"] - a["time"])
    return out


def assert_delays(measured: list[float], planned: list[float]) -> None:
    assert len(measured) == len(planned), (measured, planned)
    for got, want in zip(measured, planned):
        assert want - 0.02 <= got <= want + SLACK, (measured, planned)


def test_backoff_then_fatal_while_the_launch_goes_on(tmp_path, pkgs):
    # the group's defaults (backoff 2, 9 retries) with the node's own retries overriding them
    launch = launch_file(tmp_path, """
        <launch>
          <group respawn_backoff="2" respawn_max_retries="9">
            <node pkg="policy_tests" type="crasher" name="crasher" respawn="true" respawn_delay="0.2"
                  respawn_max_retries="4"/>
          </group>
          <node pkg="policy_tests" type="sleeper" name="sleeper"/>
          <node pkg="policy_tests" type="sleeper" name="late" spawn_delay="6"/>
        </launch>""")
    port = free_port()
    lp = Launcher([launch], ros_env(str(tmp_path), port, pkgs), str(tmp_path))
    try:
        lp.wait_output(r"\[crasher-2\] FATAL: failed 5 starts in a row \(respawn_max_retries=4\), not restarted",
                       timeout=30, stream="stderr")
        # the launch goes on: its master answers, and a node due later still starts
        assert master_up(port)
        lp.wait_output(r"process\[late-4\]: started with pid", timeout=30)
        assert lp.proc.poll() is None
        evs = node_events(tmp_path, "/crasher")
        assert [e["state"] for e in evs] == ["running", "respawning"] * 4 + ["running", "fatal"]
        assert_delays(restart_delays(evs), [0.2, 0.4, 0.8, 1.6])
        assert [e["failures"] for e in evs if e["state"] != "running"] == [1, 2, 3, 4, 5]
        fatal = evs[-1]
        assert fatal["exit_code"] == 1 and fatal["restarts"] == 4 and "respawn_max_retries=4" in fatal["reason"]
        for e in evs:  # every event carries the fields a reader relies on
            assert {"time", "node", "state", "pid", "exit_code", "exit_signal", "restarts", "reason"} <= set(e)
        assert "[crasher-2] respawning in 0.4 s (2 failed starts in a row)" in lp.stdout
        lp.signal(signal.SIGINT)
        assert lp.wait(30) == 0, lp.stderr
        # it stayed FATAL: five runs, no start after the FATAL
        assert lp.stdout.count("process[crasher-2]: started with pid") == 5
        assert node_events(tmp_path, "/crasher")[-1]["state"] == "fatal"
    finally:
        lp.close()


def test_on_fatal_shutdown_ends_the_launch_with_status_1(tmp_path, pkgs):
    launch = launch_file(tmp_path, """
        <launch>
          <node pkg="policy_tests" type="crasher" name="crasher" respawn="true" respawn_delay="0.05"
                respawn_max_retries="1" on_fatal="shutdown"/>
          <node pkg="policy_tests" type="sleeper" name="sleeper"/>
        </launch>""")
    lp = Launcher([launch], ros_env(str(tmp_path), free_port(), pkgs), str(tmp_path))
    try:
        assert lp.wait(30) == 1
        assert "FATAL process [crasher-2] has failed" in lp.stderr and "Initiating shutdown!" in lp.stderr
        assert node_events(tmp_path, "/crasher")[-1]["state"] == "fatal"
        assert node_events(tmp_path, "/sleeper")[-1]["state"] == "stopped"
    finally:
        lp.close()


def test_respawn_on_failure_and_success_exit_codes(tmp_path, pkgs):
    launch = launch_file(tmp_path, """
        <launch respawn_on="failure">
          <node pkg="policy_tests" type="exiter" name="clean" args="0" respawn="true"/>
          <group success_exit_codes="0 3">
            <node pkg="policy_tests" type="exiter" name="three" args="3" respawn="true"/>
            <node pkg="policy_tests" type="exiter" name="four" args="4" respawn="true" respawn_delay="0.2"/>
          </group>
          <node pkg="policy_tests" type="exiter" name="always" args="0" respawn="true" respawn_on="always"
                respawn_delay="0.2"/>
        </launch>""")
    lp = Launcher([launch], ros_env(str(tmp_path), free_port(), pkgs), str(tmp_path))
    try:
        lp.wait_output(r"\[clean-2\] not restarted: exit code 0 counts as success \(respawn_on=\"failure\"\)")
        lp.wait_output(r"\[three-3\] not restarted: exit code 3 counts as success")
        # a failure still respawns, and so does a success with respawn_on="always" (the node's own setting)
        until(lambda: lp.stdout.count("process[four-4]: started with pid") >= 2, 20, what="four-4 restarted")
        until(lambda: lp.stdout.count("process[always-5]: started with pid") >= 2, 20, what="always-5 restarted")
        assert lp.stdout.count("process[clean-2]: started with pid") == 1
        assert lp.stdout.count("process[three-3]: started with pid") == 1
        assert [e["state"] for e in node_events(tmp_path, "/clean")] == ["running", "exited"]
        assert node_events(tmp_path, "/three")[-1]["exit_code"] == 3
    finally:
        lp.close()


def test_a_run_longer_than_min_uptime_resets_the_backoff(tmp_path, pkgs):
    counter = os.path.join(str(tmp_path), "runs")
    launch = launch_file(tmp_path, """
        <launch>
          <node pkg="policy_tests" type="flaky" name="flaky" args="%s" respawn="true" respawn_delay="0.2"
                respawn_backoff="2" respawn_min_uptime="1"/>
        </launch>""" % counter)
    lp = Launcher([launch], ros_env(str(tmp_path), free_port(), pkgs), str(tmp_path))
    try:
        until(lambda: len(restart_delays(node_events(tmp_path, "/flaky"))) >= 5, timeout=30, what="5 restarts")
        evs = node_events(tmp_path, "/flaky")
        # runs 1, 2 fail at once (0.2, 0.4); run 3 lasts 1.5 s > 1 s: back to 0.2 (not 0.8), then growing again
        assert_delays(restart_delays(evs)[:5], [0.2, 0.4, 0.2, 0.2, 0.4])
        assert [e["failures"] for e in evs if e["state"] == "respawning"][:5] == [1, 2, 0, 1, 2]
    finally:
        lp.close()


def test_per_node_stop_timeouts(tmp_path, pkgs):
    # the CLI's defaults (15 s + 2 s) would hold the stop for 17 s; each node's own settle it
    launch = launch_file(tmp_path, """
        <launch>
          <node pkg="policy_tests" type="stubborn" name="both" args="both" output="screen"
                sigint_timeout="0.5" sigterm_timeout="0.5"/>
          <group rosmon-stop-timeout="1">
            <node pkg="policy_tests" type="stubborn" name="int_only" args="int" output="screen"/>
          </group>
        </launch>""")
    lp = Launcher([launch], ros_env(str(tmp_path), free_port(), pkgs), str(tmp_path))
    try:
        until(lambda: lp.stdout.count("ready") >= 2, 20, what="both nodes ready")
        began = time.monotonic()
        lp.signal(signal.SIGINT)
        assert lp.wait(30) == 0
        took = time.monotonic() - began
        assert 1.0 <= took < 6.0, took
        err = lp.stderr
        assert "[both-2] escalating to SIGTERM" in err and "[both-2] escalating to SIGKILL" in err
        assert "[int_only-3] escalating to SIGTERM" in err and "[int_only-3] escalating to SIGKILL" not in err
    finally:
        lp.close()


def test_spawn_delay_holds_the_start(tmp_path, pkgs):
    launch = launch_file(tmp_path, """
        <launch rosmon-spawn-delay="1">
          <node pkg="policy_tests" type="sleeper" name="now" spawn_delay="0"/>
          <node pkg="policy_tests" type="sleeper" name="later"/>
        </launch>""")
    lp = Launcher([launch], ros_env(str(tmp_path), free_port(), pkgs), str(tmp_path))
    try:
        lp.wait_output(r"process\[later-3\]: started with pid", timeout=30)
        assert "[later-3] waiting 1 s before starting (spawn_delay)" in lp.stdout
        # (the events file's line and the screen's come from two threads: the screen's may be first)
        later = until(lambda: [e for e in node_events(tmp_path, "/later") if e["state"] != "waiting"] and
                      node_events(tmp_path, "/later"), 10, what="/later's start in the events file")
        assert [e["state"] for e in later] == ["waiting", "running"]
        assert 0.98 <= later[1]["time"] - later[0]["time"] <= 1.0 + SLACK
        assert [e["state"] for e in node_events(tmp_path, "/now")] == ["running"]
        lp.signal(signal.SIGINT)
        assert lp.wait(30) == 0
    finally:
        lp.close()


def test_a_node_waiting_at_shutdown_is_stopped(tmp_path, pkgs):
    launch = launch_file(tmp_path, """
        <launch><node pkg="policy_tests" type="sleeper" name="s" spawn_delay="60"/></launch>""")
    lp = Launcher([launch], ros_env(str(tmp_path), free_port(), pkgs), str(tmp_path))
    try:
        lp.wait_output(r"\[s-2\] waiting 60 s before starting")
        until(lambda: node_events(tmp_path, "/s"), 20, what="waiting event")
        lp.signal(signal.SIGINT)
        assert lp.wait(30) == 0
        assert [e["state"] for e in node_events(tmp_path, "/s")] == ["waiting", "stopped"]
        assert "process[s-2]: started" not in lp.stdout
    finally:
        lp.close()


def test_bad_value_is_an_error_with_file_and_line(tmp_path, pkgs):
    launch = launch_file(tmp_path, """
        <launch>
          <node pkg="policy_tests" type="sleeper" name="s" respawn="true" respawn_backoff="fast"/>
        </launch>""")
    lp = Launcher([launch], ros_env(str(tmp_path), free_port(), pkgs), str(tmp_path))
    try:
        assert lp.wait(30) == 1
        assert ("%s:3: Invalid <node> tag: invalid value for respawn_backoff: 'fast' (expected a factor of 1 or more)"
                % launch) in lp.stderr
        assert "Traceback" not in lp.stderr
    finally:
        lp.close()
