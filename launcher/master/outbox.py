"""The callbacks the master owes each node, and when each may go: order, coalescing, slots, back-off (pure).

A node gets its callbacks one at a time and in the order the master made
them; nodes waiting for a slot take turns by topic (or parameter key), so a
publisher with a thousand subscribers to tell delays no other topic's
subscribers. The calls in flight are capped, and so is the share of them
going to nodes whose last call failed: a hung or vanished node holds one slot
at a time, and all of them together a small lane, so they only delay
themselves. A node whose call timed out keeps it and gets it again after a
back-off that doubles up to a cap; a refused call is dropped, as rosmaster
drops it (that node has gone). A newer publisherUpdate for a topic replaces a
queued one (the list is complete); while a node does not answer, a newer
paramUpdate for a key drops the queued one too, and what it is owed is
dropped once it is no longer registered (`forget`). A node that answers or
refuses gets every callback once (a superseded publisherUpdate aside), as
from rosmaster. No I/O, no clock: events (`put`, `take`, `done`, `forget`)
drive it, `take` and `done` carry the time; `launcher.master.notify.Notifier`
runs it on the loop.
"""

from __future__ import annotations

import collections
import heapq
from typing import Any, Callable, Hashable, NamedTuple

# a node whose call timed out is tried again after BACKOFF_FIRST_S, doubling up to BACKOFF_MAX_S
BACKOFF_FIRST_S = 1.0
BACKOFF_MAX_S = 30.0


class Callback:
    """One call owed to a node. `key` says which later callback supersedes it (None: none does);
    a `once` callback is not sent again after a failure (the node it was for is gone)."""

    __slots__ = ("method", "params", "on_result", "key", "once", "dead")

    def __init__(self, method: str, params: list, on_result: Callable[[Any], None] | None = None,
                 key: Hashable | None = None, once: bool = False):
        self.method = method
        self.params = params
        self.on_result = on_result
        self.key = key
        self.once = once
        self.dead = False  # superseded while queued: skipped when its turn comes


class Unreachable(NamedTuple):
    """A node whose last callback failed, for the status report."""

    api: str
    failures: int  # consecutive
    since: float  # when the first of them failed (the caller's clock)
    last_error: str
    queued: int  # callbacks waiting for it


class _Node:
    __slots__ = ("queue", "pending", "live", "sending", "failures", "hung", "since", "last_error", "retry_at",
                 "scheduled", "registered", "in_lane")

    def __init__(self) -> None:
        self.queue: collections.deque[Callback] = collections.deque()
        self.pending: dict[Hashable, Callback] = {}  # key -> the queued callback with that key
        self.live = 0  # queued callbacks not superseded
        self.sending: Callback | None = None
        self.failures = 0
        self.hung = False  # its last call timed out
        self.since = 0.0
        self.last_error = ""
        self.retry_at = 0.0
        self.scheduled = False  # in the ready queue or the back-off heap
        self.registered = True  # False after forget(): nothing is sent again after a failure
        self.in_lane = False  # its call in flight counts in the failing nodes' lane


class Outbox:
    """Per-node queues of Callbacks and the decision which to send now.

    `max_in_flight` caps the calls in flight; `max_failing` caps those among
    them to nodes whose last call failed; `max_queued` caps one node's queue
    (the oldest is dropped beyond it).
    """

    def __init__(self, *, max_in_flight: int = 1024, max_failing: int = 64, max_queued: int = 10000,
                 backoff_first: float = BACKOFF_FIRST_S, backoff_max: float = BACKOFF_MAX_S):
        self.max_in_flight = max_in_flight
        self.max_failing = max_failing
        self.max_queued = max_queued
        self.backoff_first = backoff_first
        self.backoff_max = backoff_max
        self.in_flight = 0
        self.in_flight_failing = 0
        self.dropped = 0  # callbacks dropped because a queue was full
        self._nodes: dict[str, _Node] = {}
        # healthy nodes with something to send, grouped by what their next callback is about (a topic, a
        # parameter key) and taken from the groups in turn: a topic with a thousand subscribers to tell
        # does not hold up one with a single subscriber
        self._groups: dict[Hashable, collections.deque[str]] = {}
        self._turns: collections.deque[Hashable] = collections.deque()
        self._ready_failing: collections.deque[str] = collections.deque()  # failing ones, back-off over
        self._backoff: list[tuple[float, int, str]] = []  # (retry_at, seq, api) of failing nodes
        self._seq = 0

    # -- events ---------------------------------------------------------------------
    def put(self, api: str, cb: Callback) -> None:
        """Queue `cb` for the node at `api` (replacing or dropping what it supersedes)."""
        node = self._nodes.get(api)
        if node is None:
            node = self._nodes[api] = _Node()
        if not cb.once:
            node.registered = True  # the master only owes these to registered nodes
        if cb.key is not None:
            older = node.pending.get(cb.key)
            if older is not None:
                if cb.method == "publisherUpdate":
                    # topics are independent: the complete, newer list takes the older one's turn
                    older.params, older.on_result = cb.params, cb.on_result
                    return
                if node.hung:
                    # every value is sent while the node answers (as rosmaster sends them); to one that
                    # does not, only the last: a parameter key may overlap others queued between the two,
                    # so the newer goes last
                    older.dead = True
                    node.live -= 1
            node.pending[cb.key] = cb
        if node.live >= self.max_queued:
            self._drop_oldest(node)
        node.queue.append(cb)
        node.live += 1
        self._schedule(api, node)

    def take(self, now: float, limit: int) -> list[tuple[str, Callback]]:
        """Up to `limit` (api, callback) pairs to send now; each is in flight until its `done`."""
        backoff = self._backoff
        while backoff and backoff[0][0] <= now:
            _, _, api = heapq.heappop(backoff)
            node = self._nodes.get(api)
            if node is not None and node.scheduled and node.retry_at <= now:
                self._ready_failing.append(api)
        out: list[tuple[str, Callback]] = []
        while len(out) < limit and self.in_flight < self.max_in_flight:
            if self._turns:
                group = self._turns.popleft()
                waiting = self._groups[group]
                api = waiting.popleft()
                if waiting:
                    self._turns.append(group)
                else:
                    del self._groups[group]
                lane = False
            elif self._ready_failing and self.in_flight_failing < self.max_failing:
                api = self._ready_failing.popleft()
                lane = True
            else:
                break
            node = self._nodes[api]
            node.scheduled = False
            cb = self._next(node)
            if cb is None:
                self._discard_if_idle(api, node)
                continue
            node.sending = cb
            node.in_lane = lane
            self.in_flight += 1
            if lane:
                self.in_flight_failing += 1
            out.append((api, cb))
        return out

    def done(self, api: str, cb: Callback, now: float, error: str | None = None, timed_out: bool = False) -> int:
        """The call `cb` to `api` ended: answered (`error` None) or failed (why).

        A call that `timed_out` (a hung node, or a host gone from the network)
        is kept and the node waits out a back-off; any other failure (refused,
        reset: the node has gone) drops the call, as rosmaster does, and the
        node's next ones go at once. Returns the node's consecutive failures
        now (1: it has just become unreachable).
        """
        node = self._nodes[api]
        node.sending = None
        self.in_flight -= 1
        if node.in_lane:
            self.in_flight_failing -= 1
            node.in_lane = False
        node.hung = error is not None and timed_out
        if error is None:
            node.failures = 0
            node.last_error = ""
        else:
            if not node.failures:
                node.since = now
            node.failures += 1
            node.last_error = error
            if not timed_out:
                node.retry_at = now  # a refusal holds nobody up, and nothing is kept for a process gone
            elif not node.registered:
                self._drop_retryable(node)  # hung, and nobody by that API any more
            else:
                node.retry_at = now + min(self.backoff_max, self.backoff_first * 2 ** (node.failures - 1))
                if not cb.once and (cb.key is None or cb.key not in node.pending):
                    # not sent and not superseded: it goes again first (a node that comes back learns it)
                    node.queue.appendleft(cb)
                    node.live += 1
                    if cb.key is not None:
                        node.pending[cb.key] = cb
        failures = node.failures
        self._schedule(api, node)
        self._discard_if_idle(api, node)
        return failures

    def forget(self, api: str) -> None:
        """`api` is no longer a registered node's: nothing it is owed is sent again after a failure, and
        if it does not answer, what it is owed is dropped (a shutdown for it stays: sent once)."""
        node = self._nodes.get(api)
        if node is None:
            return
        node.registered = False
        if node.hung:
            self._drop_retryable(node)
        self._discard_if_idle(api, node)

    # -- reading ----------------------------------------------------------------------
    def next_wakeup(self) -> float | None:
        """When a failing node's back-off ends next (None: no node waits for one)."""
        return self._backoff[0][0] if self._backoff else None

    def can_take(self) -> bool:
        """`take` could start a call now."""
        return self.in_flight < self.max_in_flight and bool(
            self._turns or (self._ready_failing and self.in_flight_failing < self.max_failing))

    def queued(self) -> int:
        """Callbacks queued and in flight."""
        return sum(n.live for n in self._nodes.values()) + self.in_flight

    def unreachable(self) -> list[Unreachable]:
        """The nodes whose last callback failed, longest failing first."""
        out = [Unreachable(api, n.failures, n.since, n.last_error, n.live)
               for api, n in self._nodes.items() if n.failures and n.registered]
        out.sort(key=lambda u: u.since)
        return out

    def clear(self) -> None:
        self._nodes.clear()
        self._groups.clear()
        self._turns.clear()
        self._ready_failing.clear()
        self._backoff.clear()
        self.in_flight = self.in_flight_failing = 0

    # -- machinery --------------------------------------------------------------------
    def _next(self, node: _Node) -> Callback | None:
        q = node.queue
        while q:
            cb = q.popleft()
            if cb.dead:
                continue
            node.live -= 1
            if cb.key is not None and node.pending.get(cb.key) is cb:
                del node.pending[cb.key]
            return cb
        return None

    def _drop_retryable(self, node: _Node) -> None:
        kept = [cb for cb in node.queue if not cb.dead and cb.once]
        node.queue = collections.deque(kept)
        node.pending = {cb.key: cb for cb in kept if cb.key is not None}
        node.live = len(kept)

    def _drop_oldest(self, node: _Node) -> None:
        while node.queue:
            cb = node.queue.popleft()
            if cb.dead:
                continue
            node.live -= 1
            if cb.key is not None and node.pending.get(cb.key) is cb:
                del node.pending[cb.key]
            self.dropped += 1
            return

    def _schedule(self, api: str, node: _Node) -> None:
        if node.scheduled or node.sending is not None or not node.live:
            return
        node.scheduled = True
        if not node.failures:
            group = next(cb.key or cb.method for cb in node.queue if not cb.dead)
            waiting = self._groups.get(group)
            if waiting is None:
                waiting = self._groups[group] = collections.deque()
                self._turns.append(group)
            waiting.append(api)
        else:
            self._seq += 1
            heapq.heappush(self._backoff, (node.retry_at, self._seq, api))

    def _discard_if_idle(self, api: str, node: _Node) -> None:
        # a healthy node with nothing to send costs nothing to forget; a failing one keeps its record
        # (back-off, report) until it answers or is no longer registered
        if node.sending is None and not node.live and (node.failures == 0 or not node.registered):
            if node.scheduled:
                return  # a stale entry in a ready queue or the heap finds it gone and skips it
            del self._nodes[api]
