"""`launcher events -f` and `launcher status --watch` follow a running launch through its change stream (the
server's long poll, `launcher_changes`): each change shows as it happens, and once the launch has ended they
show what its files say (the events file's last lines, the last run's table) and end by themselves."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time

import pytest

from helpers import free_port, until
import running
from running import Launcher, make_package, write_launch

pytestmark = pytest.mark.integration

# a program that is no ROS node and dies now and then (respawned by the launch)
Crasher = "#!/bin/sh\nsleep 1.3\nexit 3\n"
Sleeper = "#!/bin/sh\nexec sleep 1000\n"


class Reader:
    """A tool's stdout read line by line by a thread, each line kept with the wall clock time it came."""

    def __init__(self, args: list[str], env: dict[str, str]):
        self.proc = subprocess.Popen([sys.executable, "-m", "launcher.cli.tool"] + args, env=env,
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self.lines: list[tuple[float, str]] = []
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            self.lines.append((time.time(), line.rstrip("\n")))

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait(10)
        self._thread.join(10)


@pytest.fixture
def launch(tmp_path, ros_env):
    pkgs = str(tmp_path / "pkgs")
    make_package(pkgs, "follow_tests", {"crasher": Crasher, "sleeper": Sleeper})
    env = running.ros_env(str(tmp_path), free_port(), pkgs)
    body = ('<node pkg="follow_tests" type="crasher" name="crasher" respawn="true" respawn_delay="0.7" '
            'registers="false"/>\n<node pkg="follow_tests" type="sleeper" name="sleeper" registers="false"/>')
    lp = Launcher([write_launch(str(tmp_path), body)], env, str(tmp_path))
    until(lambda: subprocess.run([sys.executable, "-m", "launcher.cli.tool", "status"], env=env,
                                 capture_output=True).returncode == 0, 60, what="the launch answers")
    yield lp, env
    lp.close()


def test_events_follow_prints_each_event_as_it_happens_then_the_files_end(launch, tmp_path):
    lp, env = launch
    began = time.time()
    reader = Reader(["events", "-f", "--json"], env)
    try:
        # the crasher dies every ~2 s: a few deaths and respawns, each printed when it happens
        until(lambda: sum('"respawning"' in line for _, line in reader.lines) >= 3, 30, what="three deaths")
        lp.signal(signal.SIGINT)
        assert lp.wait(30) == 0
        assert reader.proc.wait(30) == 0, reader.proc.stderr.read()  # (it ends by itself with the launch)
        printed = [json.loads(line) for _, line in reader.lines]
        run_dir = os.path.realpath(tmp_path / "log" / "latest")
        with open(os.path.join(run_dir, "launcher-events.jsonl")) as f:
            written = [json.loads(line) for line in f]
        assert printed == written  # every line of the file, once each, in its order
        assert printed[-1]["event"] == "launch_ended"
        # each change after the start came to the reader as it happened (a file read 5 times a second would lag)
        lags = [when - json.loads(line)["time"] for when, line in reader.lines
                if '"node"' in line and json.loads(line)["time"] > began + 1.0]
        late = [lag for lag in lags if lag > 0.1]
        assert len(lags) >= 6 and not late, lags
    finally:
        reader.close()


def test_status_watch_redraws_at_each_change_and_shows_the_last_run_at_the_end(launch, tmp_path):
    lp, env = launch
    reader = Reader(["status", "--watch", "--json"], env)
    try:
        until(lambda: len(reader.lines) >= 1, 30, what="the first snapshot")
        # each death of the crasher (its events' time) is in a snapshot drawn within 0.3 s of it
        with open(os.path.join(os.path.realpath(tmp_path / "log" / "latest"), "launcher-events.jsonl")) as f:
            start = len(f.readlines())

        def deaths() -> list[dict]:
            with open(os.path.join(os.path.realpath(tmp_path / "log" / "latest"), "launcher-events.jsonl")) as f:
                events = [json.loads(line) for line in f.readlines()[start:]]
            return [e for e in events if e.get("node") == "/crasher" and e.get("state") == "respawning"]

        def first_shown(death: dict) -> float | None:
            """When the reader got the first snapshot after `death` that shows it."""
            return next((when for when, line in list(reader.lines) if when >= death["time"] and next(
                n for n in json.loads(line)["nodes"] if n["name"] == "/crasher")["state"] == "respawning"), None)
        # (the file can have a death before the reader has read its snapshot: each is waited for)
        until(lambda: len(deaths()) >= 3 and all(first_shown(d) is not None for d in deaths()[:3]), 30,
              what="three deaths, each in a snapshot")
        for death in deaths()[:3]:
            assert first_shown(death) - death["time"] < 0.3, (death, first_shown(death))
        lp.signal(signal.SIGINT)
        assert lp.wait(30) == 0
        # (the launch is gone: as `launcher status` says then)
        assert reader.proc.wait(30) == 3, reader.proc.stderr.read()
        last = json.loads(reader.lines[-1][1])
        assert last["end_reason"] == "stopped by SIGINT" and last["ended_at"], last
        assert {n["name"]: n["state"] for n in last["nodes"]}["/sleeper"] == "stopped"
    finally:
        reader.close()
