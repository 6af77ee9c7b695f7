"""record's buffer (-b): bounded in bytes, the oldest dropped first, a warning at most every 5 s (a fake clock)."""

from __future__ import annotations

import threading

from launcher.bag.buffer import BATCH_BYTES, WARN_EVERY_S, Buffer, Queued


def msg(n: int, size: int = 100) -> Queued:
    return Queued("/t", {}, n, b"%d " % n + b"x" * (size - len(b"%d " % n)))


def stamps(items: list[Queued]) -> list[int]:
    return [i.stamp_ns for i in items]


def test_the_oldest_are_dropped_past_the_limit_and_warned_of_once_per_period():
    buf = Buffer(limit=350)
    warnings = [buf.put(msg(n), now=10.0 + n) for n in range(3)]
    assert warnings == [0, 0, 0] and len(buf) == 3
    assert buf.put(msg(3), now=13.0) == 1        # 400 bytes > 350: message 0 goes, and is warned of
    assert buf.put(msg(4), now=14.0) == 0        # dropped too, but within 5 s of the warning
    assert buf.put(msg(5), now=13.0 + WARN_EVERY_S + 0.1) == 2   # the next warning counts both
    assert stamps(buf.take()) == [3, 4, 5] and buf.total_dropped == 3


def test_zero_is_unbounded():
    buf = Buffer(limit=0)
    for n in range(1000):
        assert buf.put(msg(n, 10_000), now=0.0) == 0
    assert len(buf) == 1000


def test_take_gives_batches_then_nothing_once_closed():
    buf = Buffer(limit=0)
    size = BATCH_BYTES // 4
    for n in range(6):
        buf.put(msg(n, size), now=0.0)
    assert stamps(buf.take()) == [0, 1, 2, 3]    # about BATCH_BYTES at a time
    buf.close()
    assert stamps(buf.take()) == [4, 5]          # what was left, after close
    assert buf.take() == []


def test_take_waits_for_a_message():
    buf = Buffer(limit=0)
    got: list[list[Queued]] = []
    writer = threading.Thread(target=lambda: got.append(buf.take()))
    writer.start()
    buf.put(msg(7), now=0.0)
    writer.join(10)
    assert not writer.is_alive() and stamps(got[0]) == [7]
