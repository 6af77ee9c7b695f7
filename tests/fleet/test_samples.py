"""A node's recent resource samples: the last minute, oldest first, in little memory."""

from __future__ import annotations

import gc
import tracemalloc

from launcher.fleet import lifecycle as m
from launcher.fleet.lifecycle import Event
from launcher.fleet.samples import Samples
from launcher.fleet.state import HISTORY, Fleet


def test_the_last_samples_are_kept_oldest_first():
    kept = Samples(3)
    assert len(kept) == 0 and list(kept) == [] and not kept
    kept.append((1.5, 0.25, 100))
    kept.append((2.5, 0.5, 200))
    assert list(kept) == [(1.5, 0.25, 100), (2.5, 0.5, 200)] and kept
    for i in range(3, 8):
        kept.append((i + 0.5, i / 4, i * 100))
        assert [s[0] for s in kept] == [j + 0.5 for j in range(max(1, i - 2), i + 1)]
    assert list(kept) == [(5.5, 1.25, 500), (6.5, 1.5, 600), (7.5, 1.75, 700)] and len(kept) == 3
    assert all(isinstance(rss, int) for _t, _cpu, rss in kept)  # (bytes stay integers: JSON writes them so)


def test_a_minute_of_samples_of_a_node_costs_little():
    """A running node's samples, kept all the run for a late view's sparklines: 60 of them took 9 kB a node as
    a deque of tuples (4.6 MB for 500 nodes)."""
    fleet = Fleet()
    names = ["/n%d" % i for i in range(100)]
    for name in names:
        fleet.add(name)
        fleet.apply(name, Event(m.START))
        fleet.apply(name, Event(m.SPAWNED, pid=5))
    gc.collect()
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        for k in range(3 * HISTORY):
            for name in names:
                fleet.sample(name, 0.01 * k, 10_000_000 + 4096 * k, 0.01)
        gc.collect()
        per_node = (tracemalloc.get_traced_memory()[0] - before) / len(names)
    finally:
        tracemalloc.stop()
    assert per_node < 2500, "%.0f bytes a node" % per_node
    history = list(fleet.nodes["/n7"].history)
    assert len(history) == HISTORY and [cpu for _t, cpu, _rss in history] == [
        0.01 * k for k in range(2 * HISTORY, 3 * HISTORY)]
    assert history[-1][2] == 10_000_000 + 4096 * (3 * HISTORY - 1)
