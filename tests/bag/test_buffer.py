"""record's buffer (-b): bounded in bytes, the oldest of the heaviest topic dropped first, a warning at most every
5 s (a fake clock)."""

from __future__ import annotations

import threading

from hypothesis import given
from hypothesis import strategies as st

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


def on(topic: str, n: int, size: int) -> Queued:
    return Queued(topic, {}, n, b"x" * size)


def test_a_flooding_topic_loses_its_own_oldest_not_a_slow_topics_messages():
    """rosbag drops the oldest of all, so one topic faster than the disk costs every topic its messages; here the
    topic holding the most of the buffer loses its oldest, and the writer still takes all in the order they came."""
    buf = Buffer(limit=10_000)
    n = 0
    for round_ in range(50):
        for _ in range(10):
            buf.put(on("/flood", n, 1000), now=0.0)
            n += 1
        buf.put(on("/slow", n, 10), now=0.0)
        n += 1
    got = buf.take()
    assert [i.stamp_ns for i in got if i.topic == "/slow"] == [11 * r + 10 for r in range(50)]  # every one
    assert [i.stamp_ns for i in got] == sorted(i.stamp_ns for i in got)
    assert buf.size == 0 and len(buf) == 0 and buf.total_dropped == 500 - 9


@given(st.lists(st.tuples(st.sampled_from(["/a", "/b", "/c"]), st.integers(0, 400), st.booleans()), max_size=60),
       st.integers(0, 1000))
def test_the_buffer_is_its_model(steps, limit):
    """Against a plain list: the same messages kept, in arrival order, the bound held after every put."""
    buf, model, taken, want, seen = Buffer(limit), [], [], [], []
    for n, (topic, size, take) in enumerate(steps):
        buf.put(on(topic, n, size), now=0.0)
        model.append((topic, n, size))
        seen += [topic] if topic not in seen else []
        while limit and sum(s for _, _, s in model) > limit:
            load = {t: sum(s for tt, _, s in model if tt == t) for t in seen}
            heaviest = max(seen, key=load.__getitem__)  # (a tie: the topic seen first)
            model.remove(next(m for m in model if m[0] == heaviest))
        assert buf.size == sum(s for _, _, s in model) and len(buf) == len(model)
        if take and len(buf):
            got = buf.take()
            taken += [(i.topic, i.stamp_ns) for i in got]
            want += [(t, m) for t, m, _ in model[:len(got)]]
            del model[:len(got)]
    assert taken == want
