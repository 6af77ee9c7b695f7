"""The recent /rosout warnings the live views read: numbered, the newest kept, within a bound of lines and text."""

from __future__ import annotations

import gc
import tracemalloc

from launcher.services.rosouttail import KEPT, KEPT_CHARS, RosoutTail


def test_a_reader_gets_the_lines_after_its_number_and_one_behind_gets_the_oldest_kept_on():
    tail = RosoutTail(kept=3)
    assert tail.since(0) == []
    for i in range(1, 6):
        tail.add(4 if i % 2 else 8, "/n%d" % i, "line %d" % i)
    assert tail.seq == 5
    assert tail.since(3) == [("/n4", "ERROR", "line 4"), ("/n5", "WARN", "line 5")]
    assert tail.since(0) == [("/n3", "WARN", "line 3"), ("/n4", "ERROR", "line 4"), ("/n5", "WARN", "line 5")]
    assert tail.since(5) == []


def test_long_lines_are_kept_within_a_bound_of_text_the_newest_whole():
    tail = RosoutTail(kept=100, kept_chars=25)
    for i in range(10):
        tail.add(8, "/chatty", "%d" % i * 10)  # ten characters each
    assert tail.since(0) == [("/chatty", "ERROR", "8" * 10), ("/chatty", "ERROR", "9" * 10)]
    assert tail.chars == 20
    tail.add(16, "/huge", "x" * 100)  # (larger than the bound alone: kept, whole, and alone)
    assert tail.since(0) == [("/huge", "FATAL", "x" * 100)] and tail.since(10) == [("/huge", "FATAL", "x" * 100)]
    tail.add(4, "/small", "ok")
    assert tail.since(0) == [("/small", "WARN", "ok")] and tail.chars == 2


def test_a_node_logging_large_warnings_does_not_grow_the_tail_past_its_bound():
    """5,000 warnings of 10 kB: the tail holds about KEPT_CHARS of them (the newest), not KEPT lines of 10 kB
    (10 MB)."""
    tail = RosoutTail()
    gc.collect()
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        for i in range(5000):
            tail.add(8, "/driver", ("%05d" % i) * 2000)
        gc.collect()
        grown = tracemalloc.get_traced_memory()[0] - before
    finally:
        tracemalloc.stop()
    assert grown < KEPT_CHARS * 1.2, "%d bytes" % grown
    kept = tail.since(0)
    assert kept[-1][2] == "04999" * 2000 and len(kept) == KEPT_CHARS // 10000 < KEPT
