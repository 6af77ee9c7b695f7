"""The master's calls counted by method, with their latency in histogram buckets: what `launch --metrics` exports.

Pure: `observe(method, seconds)` is one dict lookup and a bisect, on the loop,
after each reply; a scrape copies the counts (`copy`) and formats them
elsewhere. A method the master does not have is counted as "other", so that a
client sending made-up names cannot grow the table (and the scrape) without end.
"""

from __future__ import annotations

import bisect
from typing import Iterable, NamedTuple

# Upper bounds, in seconds: a master call takes ~50-500 µs (getSystemState of a big graph: milliseconds), so
# Prometheus's default buckets (5 ms and up) would put nearly every call in the first one.
BUCKETS = (0.0001, 0.00025, 0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5)
OTHER = "other"


class MethodStats(NamedTuple):
    """One method's calls: the count in each bucket (not cumulative; the last is above the largest bound), and
    the sum of their durations."""

    buckets: tuple[int, ...]
    total: float

    @property
    def count(self) -> int:
        return sum(self.buckets)


class CallStats:
    """Counts and latency histograms of the calls one master answered, by method."""

    def __init__(self, methods: Iterable[str] = ()):
        self.methods = frozenset(methods)  # the names counted under their own label; empty: every name
        self._counts: dict[str, list[int]] = {}
        self._sums: dict[str, float] = {}

    def observe(self, method: str, seconds: float) -> None:
        if self.methods and method not in self.methods:
            method = OTHER
        counts = self._counts.get(method)
        if counts is None:
            counts = self._counts[method] = [0] * (len(BUCKETS) + 1)
            self._sums[method] = 0.0
        counts[bisect.bisect_left(BUCKETS, seconds)] += 1
        self._sums[method] += seconds

    def copy(self) -> dict[str, MethodStats]:
        """The calls so far, by method (a copy: the caller may read it in another thread)."""
        return {m: MethodStats(tuple(c), self._sums[m]) for m, c in self._counts.items()}
