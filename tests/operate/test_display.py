"""What the operator's commands show, as functions of what the launch sends: no resources for a node that does
not run, no colour codes for a reader that is no terminal, a run's own events, and which registered launches
an operator can mean."""

from __future__ import annotations

import pytest

from launcher.operate import client, logs
from launcher.operate.events import describe
from launcher.operate.status import table


def node(name: str, state: str, **kw) -> dict:
    return dict({"name": name, "state": state, "pid": 123, "uptime": None, "restarts": 0, "exit_code": None,
                 "exit_signal": None, "cpu": None, "rss": 31 << 20, "host": "localhost", "over_limit": {}}, **kw)


@pytest.mark.parametrize("state", ["stopped", "respawning", "fatal", "exited", "waiting", "hung"])
def test_a_node_that_does_not_run_shows_no_pid_cpu_or_rss(state):
    """The state model keeps the last sample of a run that ended: it is no node's use now."""
    rows = table({"nodes": [node("/a", "running", cpu=0.25, uptime=5.0), node("/b", state, cpu=0.5)]}).splitlines()[1:]
    assert rows[1].split() == ["/a", "running", "no", "123", "5s", "0", "-", "25%", "32.5MB", "localhost"]
    assert rows[2].split() == ["/b", state, "no" if state == "hung" else "-", "-", "-", "0", "-", "-", "-",
                               "localhost"]


def test_registered_is_shown_apart_from_running():
    rows = table({"nodes": [node("/a", "running", registered=True, uri="http://h:1/"),
                            node("/b", "running", registered=False), node("/c", "waiting")]}).splitlines()[1:]
    assert rows[0].split()[:3] == ["NODE", "STATE", "REG"]
    assert [r.split()[2] for r in rows[1:]] == ["yes", "no", "-"]


def test_colour_codes_are_taken_out_even_when_cut_between_two_reads():
    data = (b"\x1b[0m[ INFO] [1.5]: tick 1\x1b[0m\n\x1b[33m[ WARN] [1.6]: careful\x1b[0m\n"
            b"\x1b]0;a title\x07plain \x1b[1;31mbold red\x1b[0m\n")
    expected = b"[ INFO] [1.5]: tick 1\n[ WARN] [1.6]: careful\nplain bold red\n"
    for size in (1, 2, 3, 7, len(data)):
        out: list[bytes] = []
        write = logs.Uncoloured(out.append)
        for i in range(0, len(data), size):
            write(data[i:i + size])
        assert b"".join(out) == expected, size
    out = []
    unended = b"text \x1b]" + b"x" * 300  # (no escape is that long: written as it is, not held for ever)
    logs.Uncoloured(out.append)(unended)
    assert b"".join(out) == unended


def test_a_launch_ended_event_reads_as_the_runs_end():
    assert describe({"event": "launch_ended", "time": 0.5, "reason": "Ctrl-C"}).endswith(".500 launch ended (Ctrl-C)")


def test_the_launches_an_operator_can_mean():
    def r(key: str, kind: str, nodes: int = 0, files: tuple = ("a.launch",)) -> client.Registered:
        info = {"nodes": [{}] * nodes, "launch_files": list(files)} if kind == "ours" else {}
        return client.Registered(key, "http://h:%s/" % key, kind, info)
    roscore, stale, ours, core = r("1", "roslaunch"), r("2", "gone"), r("3", "ours", 2), r("4", "ours", 0, ())
    starting = r("6", "ours", 0)
    candidates = client.candidates
    assert candidates([roscore, stale, ours, core]) == [ours]  # roscore, a kill -9'd launch, a bare core: not it
    assert candidates([roscore, core]) == [core]  # a bare `launch --core` when it is the only one of ours
    assert candidates([core, starting]) == [starting]  # a launch before its nodes exist, beside the core it uses
    assert candidates([core, starting, ours]) == [ours]
    assert candidates([roscore, stale]) == []
    assert candidates([ours, r("5", "ours", 1)]) == [ours, r("5", "ours", 1)]  # two of ours: ask


def test_status_names_the_nodes_the_master_cannot_reach():
    from launcher.operate.status import table as status_table
    info = {"nodes": [node("/a", "running")], "unresponsive": [
        {"names": ["/wedged"], "api": "http://h:1/", "failures": 4, "failing_s": 31.5, "last_error": "timed out",
         "queued": 1}]}
    last = status_table(info).splitlines()[-1]
    assert last == ("WARNING: the master cannot reach /wedged (http://h:1/): 4 failed callback(s) over 32 s, "
                    "the last: timed out; 1 waiting")
    assert "WARNING" not in status_table({"nodes": [node("/a", "running")], "unresponsive": []})
