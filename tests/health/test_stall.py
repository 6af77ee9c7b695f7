"""The stalled-topic verdict as a pure function of the messages' times and a clock."""

from __future__ import annotations

from launcher.health.stall import TopicWatch


def test_silence_after_the_last_message_and_before_the_first():
    w = TopicWatch("/image", started_at=0.0, timeout=2.0, min_rate=None, window=5.0)
    assert w.verdict(1.9) == ""  # (a node gets watch_timeout from its start to send a first message)
    assert w.verdict(2.0).startswith("no message on /image for 2.0 s since the node registered")
    for t in (2.1, 2.2, 2.3):
        w.message(t)
    assert w.verdict(4.2) == ""
    assert w.verdict(4.3) == "no message on /image for 2.0 s since its last message (watch_timeout 2)"


def test_a_rate_under_the_minimum_over_a_whole_window():
    w = TopicWatch("/scan", started_at=0.0, timeout=None, min_rate=10.0, window=2.0)
    t = 0.0
    while t < 4.0:  # 20 Hz
        w.message(t)
        t += 0.05
    assert w.verdict(4.0) == ""
    while t < 8.0:  # 4 Hz
        w.message(t)
        t += 0.25
    assert w.verdict(8.0) == "/scan at 4.0 Hz over the last 2 s, under watch_min_rate 10"
    assert TopicWatch("/x", 0.0, None, 10.0, 2.0).verdict(1.0) == ""  # (not before a whole window)


def test_a_watch_with_neither_bound_stalls_after_a_window_of_silence():
    w = TopicWatch("/t", started_at=10.0, timeout=None, min_rate=None, window=5.0)
    assert w.verdict(14.9) == "" and w.verdict(15.0) != ""
    assert 0.05 <= w.period() <= 1.0


def test_a_fast_topics_window_is_kept_as_its_reads_not_its_messages():
    """100,000 messages a second, read in gulps of 1,000: the 5 s window holds 500 reads (it held 500,000 times,
    4 MB a watched topic), and the rate is the messages'."""
    import gc
    import tracemalloc
    w = TopicWatch("/points", started_at=0.0, timeout=1.0, min_rate=50000.0, window=5.0)
    gc.collect()
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        for i in range(1000):  # 10 s
            w.messages(1000, i * 0.01)
        gc.collect()
        grown = tracemalloc.get_traced_memory()[0] - before
    finally:
        tracemalloc.stop()
    assert grown < 100_000, "%d bytes" % grown
    assert w.rate(9.99) == 100000.0 and w.verdict(9.99) == ""
    for i in range(1000, 1500):  # 5 s at a tenth of that: under the minimum once the window has only them
        w.messages(100, i * 0.01)
    assert w.verdict(14.99) == "/points at 10000.0 Hz over the last 5 s, under watch_min_rate 50000"
