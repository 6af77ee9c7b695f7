"""`launcher events -f` when it falls behind the change stream's backlog (the launch keeps its last minute): the
events the stream dropped are read from the events file, each event printed once, in order."""

from __future__ import annotations

import json

from launcher.operate import client, events


def line(seq: int, state: str = "running") -> str:
    return json.dumps({"seq": seq, "time": 1000.0 + seq, "node": "/n", "host": "localhost", "state": state,
                       "pid": 100 + seq, "restarts": seq}, separators=(",", ":"))


def test_a_reader_behind_the_backlog_gets_the_dropped_events_from_the_file(tmp_path, monkeypatch, capsys):
    path = tmp_path / "launcher-events.jsonl"
    path.write_text("".join(line(i) + "\n" for i in (1, 2, 3)))
    monkeypatch.setattr(client, "live_or_last", lambda opts, fetch: (("http://h:1/", 3, {"events_file": str(path)}),
                                                                      None))

    def follow_changes(uri, since, on_answer, wait=1.0):
        assert since == 3
        # the launch went on while this reader slept: 4 to 9 in the file (9's line half-written), 8 and 9 kept
        with open(path, "a") as f:
            f.write("".join(line(i) + "\n" for i in range(4, 9)) + line(9)[:20])
        on_answer({"seq": 9, "complete": False,
                   "changes": [dict(json.loads(line(8)), phase="starting", internal=True), json.loads(line(8)),
                               json.loads(line(9))]})
        on_answer({"seq": 10, "complete": True, "changes": [json.loads(line(10, "stopped"))]})
        with open(path, "a") as f:  # (the rest of 9's line, 10's, and the launch's end)
            f.write(line(9)[20:] + "\n" + line(10, "stopped") + "\n" + json.dumps(
                {"seq": 11, "event": "launch_ended", "time": 1011.0, "reason": "stopped"}) + "\n")
        return 10
    monkeypatch.setattr(client, "follow_changes", follow_changes)
    assert events._main(["-f", "--json"]) == client.EXIT_OK
    printed = [json.loads(text) for text in capsys.readouterr().out.splitlines()]
    assert [e["seq"] for e in printed] == list(range(1, 12))
    assert printed[9]["state"] == "stopped" and printed[-1]["event"] == "launch_ended"
