"""The post-mortem of a run, read from log directories laid out as `launch` and roslaunch leave them: how the run
ended (`done` last in the launch log, a launch_ended event, or nothing: killed), each node's last state, a node's
output file by node or process name, and a roslaunch run told apart."""

from __future__ import annotations

import json
import os
import time

import pytest

from launcher.operate import lastrun
from launcher.operate.client import ToolError

T0 = time.mktime((2024, 5, 1, 12, 0, 0, 0, 0, -1))


def stamp(t: float) -> str:
    return "[%s.%03d]" % (time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(t)), int(t * 1000) % 1000)


def event(t: float, node: str, state: str, **kw) -> dict:
    return dict({"time": t, "node": node, "host": "localhost", "state": state, "pid": 100, "exit_code": None,
                 "exit_signal": None, "restarts": 0, "failures": 0, "next_start": None, "over_limit": {},
                 "reason": ""}, **kw)


def make_run(root, run_id: str, events: list[dict], log_lines: list[str], pid: int = 4242,
             host: str = "otherhost") -> str:
    d = root / run_id
    d.mkdir(parents=True)
    (d / lastrun.EVENTS_FILE).write_text("".join(json.dumps(e) + "\n" for e in events))
    (d / ("roslaunch-%s-%d.log" % (host, pid))).write_text("".join(line + "\n" for line in log_lines))
    return str(d)


def test_a_run_that_ended_by_itself(tmp_path):
    run = make_run(tmp_path, "run-1", [event(T0 + 1, "/a", "running"), event(T0 + 5, "/a", "stopped", exit_code=0),
                                       event(T0 + 2, "/g/b", "running"), event(T0 + 3, "/g/b", "fatal", exit_code=1)],
                   ["%s ... logging to x" % stamp(T0), "%s shutting down processing monitor..." % stamp(T0 + 6),
                    "%s done" % stamp(T0 + 6.25)])
    last = lastrun.read(run)
    assert last.ended_at == pytest.approx(T0 + 6.25, abs=1e-3) and not last.still_running and last.pid == 4242
    assert last.headline() == "the last run, run-1, ended at %s\nits logs: %s" % (lastrun.when(T0 + 6), run)
    assert [(n["name"], n["state"], n["exit_code"]) for n in last.nodes()] == [("/a", "stopped", 0),
                                                                               ("/g/b", "fatal", 1)]
    assert lastrun.read(run, latest=False).headline().startswith("the run, run-1, ended at ")


def test_a_run_killed_ended_without_a_word(tmp_path):
    run = make_run(tmp_path, "run-2", [event(T0 + 1, "/a", "running"), event(T0 + 2, "/b", "running")],
                   ["%s ... logging to x" % stamp(T0), "%s [launch] node [/b] (process b-2) is running" % stamp(T0 + 2)])
    last = lastrun.read(run)
    assert last.ended_at is None and not last.still_running
    assert last.headline().split("\n")[0] == ("the last run, run-2, ended without a word after its last event at "
                                              "%s: its launch (pid 4242) was killed" % lastrun.when(T0 + 2))
    # its nodes went with it (its watchdog kills them): never shown running
    assert [(n["state"], n["reason"]) for n in last.nodes()] == [("stopped", "the launch was killed")] * 2


def test_a_killed_launch_leaves_the_nodes_that_were_down_as_they_were(tmp_path):
    run = make_run(tmp_path, "run-2b", [event(T0 + 1, "/a", "running"), event(T0 + 2, "/a", "respawning", exit_code=3),
                                        event(T0 + 1, "/b", "fatal", exit_code=1, reason="failed 3 starts")],
                   ["%s ... logging to x" % stamp(T0)])
    nodes = lastrun.read(run).nodes()
    assert [(n["name"], n["state"], n["reason"]) for n in nodes] == [("/a", "stopped", "the launch was killed"),
                                                                     ("/b", "fatal", "failed 3 starts")]


def test_each_nodes_last_exit_is_kept_from_its_events(tmp_path):
    """The events file has no last_exit_*: the run's end of each node is where its exit fields are set anew."""
    run = make_run(tmp_path, "run-2c", [event(T0 + 1, "/a", "running"), event(T0 + 2, "/a", "respawning", exit_code=3),
                                        event(T0 + 3, "/a", "running", pid=101, restarts=1),
                                        event(T0 + 4, "/a", "respawning", pid=101, exit_signal=11, restarts=1),
                                        event(T0 + 5, "/a", "running", pid=102, restarts=2),
                                        event(T0 + 1, "/b", "running"), event(T0 + 9, "/b", "stopped", exit_code=0),
                                        {"event": "launch_ended", "time": T0 + 10, "reason": "SIGINT"}],
                   ["%s ... logging to x" % stamp(T0)])
    a, b = lastrun.read(run).nodes()
    assert (a["state"], a["exit_code"], a["last_exit_code"], a["last_exit_signal"], a["last_exit_at"]) == (
        "running", None, None, 11, T0 + 4)
    assert (b["last_exit_code"], b["last_exit_signal"], b["last_exit_at"]) == (0, None, T0 + 9)


def test_a_launch_ended_event_marks_the_end(tmp_path):
    """The launch may write {"event": "launch_ended", ...} last: that is the end, and no node's state."""
    run = make_run(tmp_path, "run-3", [event(T0 + 1, "/a", "running"), event(T0 + 4, "/a", "stopped"),
                                       {"event": "launch_ended", "time": T0 + 5, "reason": "required node /a exited"}],
                   ["%s ... logging to x" % stamp(T0)])  # (a launch log cut short: the event decides)
    last = lastrun.read(run)
    assert last.ended_at == T0 + 5 and last.end_reason == "required node /a exited"
    assert last.headline().startswith("the last run, run-3, ended at %s (required node /a exited)" % lastrun.when(T0 + 5))
    assert [n["name"] for n in last.nodes()] == ["/a"]
    assert lastrun.final_states(last.events) == {"/a": last.events[1]}


def test_a_launch_that_still_runs_is_not_said_to_have_ended(tmp_path):
    import socket
    import subprocess
    import sys
    # a process whose command line names `launch` stands for the launch that cannot be reached
    proc = subprocess.Popen([sys.executable, "-c", "print('up', flush=True); import sys; sys.stdin.read()", "launch"],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE)
    try:
        assert proc.stdout.readline() == b"up\n"  # (its command line is readable once it runs: not while in exec)
        run = make_run(tmp_path, "run-4", [event(T0, "/a", "running")], ["%s ... logging to x" % stamp(T0)],
                       pid=proc.pid, host=socket.gethostname())
        last = lastrun.read(run)
        assert last.still_running and last.headline().startswith(
            "the last run, run-4, has not ended: its launch (pid %d) still runs, but cannot be reached" % proc.pid)
    finally:
        proc.communicate(b"")
    assert not lastrun.read(run).still_running


def test_a_roslaunch_run_is_said_to_be_one(tmp_path):
    d = tmp_path / "run-5"
    d.mkdir()
    (d / "roslaunch-host-77.log").write_text("[roslaunch][INFO] 2024-05-01 12:00:00,000: Checking log directory\n")
    with pytest.raises(ToolError) as e:
        lastrun.read(str(d))
    assert str(e.value) == ("the last run, run-5, is roslaunch's (or roscore's), not a run of `launch`: it has no "
                            "launcher-events.jsonl, and `launcher` cannot tell its nodes' states; its logs are in %s" % d)
    assert (e.value.run_id, e.value.run_dir) == ("run-5", str(d))  # (what `status --json` prints of it)


def test_latest_or_a_named_run(tmp_path):
    env = {"ROS_LOG_DIR": str(tmp_path)}
    with pytest.raises(ToolError) as e:
        lastrun.find_run(env)
    assert e.value.status == 3 and "no run has logged in %s" % tmp_path in str(e.value)
    run = make_run(tmp_path, "0a1b-run", [], ["%s done" % stamp(T0)])
    os.symlink(run, tmp_path / "latest")
    assert lastrun.find_run(env) == run and lastrun.find_run(env, "0a1b-run") == run
    with pytest.raises(ToolError) as e:
        lastrun.find_run(env, "0a1c-run")
    assert str(e.value) == "no run [0a1c-run] in %s; did you mean 0a1b-run?" % tmp_path and e.value.status == 1


def test_a_nodes_output_file_by_node_or_process_name(tmp_path):
    run = make_run(tmp_path, "run-6", [event(T0, "/r2/talker", "stopped")], ["%s done" % stamp(T0)])
    for name in ("r2-talker-3-stdout.log", "listener-2-stdout.log", "rosout-1-stdout.log"):
        open(os.path.join(run, name), "w").close()
    last = lastrun.read(run)
    for asked in ("/r2/talker", "r2/talker", "r2/talker-3"):
        assert last.stdout_log(asked) == os.path.join(run, "r2-talker-3-stdout.log")
    with pytest.raises(ToolError) as e:
        last.stdout_log("talker")
    assert str(e.value) == "unknown node [talker]: it has no output file in %s; did you mean /r2/talker?" % run
