"""The fleet's change stream as a long-polling reader gets it, and what keeping it costs the launch."""

from __future__ import annotations

import gc
import json
import tracemalloc

from launcher.fleet import lifecycle as m
from launcher.fleet import state
from launcher.fleet.lifecycle import Event, Rules

NODES = ["/robot/node_%02d" % i for i in range(30)]


class Clock:
    """The fleet's clock, moved by the test."""

    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def started(clock: Clock, path: str | None = None) -> state.Fleet:
    fleet = state.Fleet(path, clock=clock)
    for name in NODES:
        fleet.add(name, rules=Rules(respawn=True))
        fleet.apply(name, Event(m.START))
        fleet.apply(name, Event(m.SPAWNED, pid=1))
        fleet.apply(name, Event(m.REGISTERED, uri="http://127.0.0.1:1/"))
    return fleet


def crash_loop(fleet: state.Fleet, clock: Clock, changes: int, step: float) -> None:
    """Nodes killed and respawned one after another (4 changes each: respawning, starting, running, registered),
    the clock moving `step` s a change: the soak's chaos (benchmarks/soak.py) without processes."""
    pid = 1000
    while True:
        for name in NODES:
            pid += 1
            died = "process has died [pid %d, exit code -9]" % pid
            for event in (Event(m.PROCESS_EXITED, exit_signal=9, detail=died),
                          Event(m.DUE), Event(m.SPAWNED, pid=pid),
                          Event(m.REGISTERED, uri="http://127.0.0.1:%d/" % (30000 + pid % 30000))):
                fleet.apply(name, event)
                clock.now += step
                changes -= 1
                if changes == 0:
                    return


def growth(fleet: state.Fleet, clock: Clock, warm_up: int, changes: int, step: float) -> int:
    """The bytes Python holds more after `changes` changes of a crash loop than after the first `warm_up` (traced
    from the start: what a change frees is counted as well as what it takes)."""
    tracemalloc.start()
    try:
        crash_loop(fleet, clock, warm_up, step)
        gc.collect()
        before = tracemalloc.get_traced_memory()[0]
        crash_loop(fleet, clock, changes, step)
        gc.collect()
        return tracemalloc.get_traced_memory()[0] - before
    finally:
        tracemalloc.stop()


def test_a_kept_change_costs_its_json_line_not_the_objects_it_was_made_of():
    """Each change the backlog keeps is the line a reader is served (~330 bytes), not the records, event,
    actions and dict it came from (1.3 kB each when they were kept: 13 MB for a full backlog)."""
    clock = Clock()
    fleet = started(clock)
    n = 4000
    per_change = growth(fleet, clock, 240, n, 0.0) / n  # (nothing ages out: every change is kept)
    assert len(fleet.changes) >= n
    assert per_change < 600, "%.0f bytes a kept change" % per_change


def test_a_crash_loops_backlog_stays_bounded():
    """An hour of the soak's chaos (16 changes a second) does not grow the backlog past its last minute: what
    a reader polling every second needs."""
    clock = Clock()
    fleet = started(clock)
    grown = growth(fleet, clock, 2000, 12000, 1 / 16)  # (in the first two minutes the backlog fills)
    assert grown < 200_000, "%d bytes more after 12,000 changes" % grown
    assert len(fleet.changes) <= 16 * 61


def test_a_reader_within_the_backlog_gets_every_change_and_one_behind_it_reads_the_status_again(tmp_path):
    clock = Clock()
    path = tmp_path / "events.jsonl"
    fleet = started(clock, str(path))
    first = fleet.seq
    crash_loop(fleet, clock, 16 * 90, 1 / 16)  # a minute and a half of changes
    fleet.run_event("master_restarted", reason="why")
    fleet.close()
    # the oldest changes are a minute old: a reader that saw them all up to 30 s ago gets the rest, complete
    since = fleet.seq - 16 * 30
    served, complete = fleet.changes_since(since)
    assert complete and [c["seq"] for c in served] == list(range(since + 1, fleet.seq + 1))
    # served as the events file has them (the steps it leaves out marked internal), the run's own line too
    written = [json.loads(line) for line in path.read_text().splitlines()]
    assert [c for c in served if not c.get("internal")] == [w for w in written if w["seq"] > since]
    assert {c["phase"] for c in served if c.get("internal")} == {m.STARTING}
    assert served[-1]["event"] == "master_restarted"
    # one that last read before the kept minute is told its list is incomplete: it reads the status again
    served, complete = fleet.changes_since(first)
    assert not complete and served[0]["seq"] > first + 1 and served[-1]["seq"] == fleet.seq
    assert len(served) == 16 * 60 + 1  # (what is kept: the changes of the last minute, 16 a second, both ends in)
    # as text, the same changes (what the launch's server answers with, unparsed)
    text, complete = fleet.changes_json(since)
    assert complete and json.loads(text) == fleet.changes_since(since)[0]
    assert fleet.changes_json(fleet.seq) == ("[]", True)
