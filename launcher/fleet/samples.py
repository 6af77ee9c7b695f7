"""A node's recent resource samples, (time, cpu, rss), kept in typed arrays: what a late view draws its
sparklines from (the server's `launcher_samples` with history).

A minute of samples of every node is kept all along, so its form counts: a
deque of tuples took 150 bytes a sample (9 kB a node, 4.5 MB for 500 nodes);
three arrays used as one ring take 24.
"""

from __future__ import annotations

from array import array
from typing import Iterator


class Samples:
    """The last `kept` samples, oldest first: appended, iterated as (time, cpu, rss) tuples, counted."""

    __slots__ = ("kept", "_times", "_cpu", "_rss", "_next")

    def __init__(self, kept: int):
        self.kept = kept
        self._times = array("d")
        self._cpu = array("d")
        self._rss = array("q")
        self._next = 0  # where the next sample goes once the ring is full (there the oldest is)

    def append(self, sample: tuple[float, float, int]) -> None:
        t, cpu, rss = sample
        if len(self._times) < self.kept:
            self._times.append(t)
            self._cpu.append(cpu)
            self._rss.append(rss)
            return
        i = self._next
        self._times[i], self._cpu[i], self._rss[i] = t, cpu, rss
        self._next = (i + 1) % self.kept

    def __len__(self) -> int:
        return len(self._times)

    def __iter__(self) -> Iterator[tuple[float, float, int]]:
        n, start = len(self._times), self._next
        for k in range(n):
            i = (start + k) % n
            yield self._times[i], self._cpu[i], self._rss[i]

    def __repr__(self) -> str:
        return "Samples(%r)" % list(self)
