"""Stalled topics: a node alive whose own publication of a watched topic went silent or too slow.

A node with `watch_topic` (its names resolved as the node resolves them, at
load) is watched once its run has registered (the fleet's record says so, and at
which URI: health/registration.py): the launcher asks the node
itself for each topic (`requestTopic`, as any subscriber does) and subscribes
over TCPROS with any type (`*`: no message package, nothing deserialized), so
another publisher on the same topic cannot hide a stall. The messages are
counted, not kept (`net.topic_watch.CountingLink`): the socket wakes the loop once 64 kB
wait, and each verdict first drains it, so a quiet topic costs a read per
verdict and a 30 MB/s one a read per 256 kB. `TopicWatch` decides,
fed the times of the messages and a clock:

- no message for `watch_timeout` s (counted from the run's registration
  until a first message comes: a node publishes nothing before it has
  registered, and a rospy node takes a second or more to get there): stalled;
- fewer than `watch_min_rate` Hz over the last `watch_window` s (once a whole
  window has passed): stalled;
- with neither set, silence for `watch_window` s is a stall.

A stalled node is reported and killed, and its end goes the way of any run's
(the restart policy: set `respawn`); with `on_stall="warn"` it is only
reported, and back to running when every watched topic is healthy again.
Watching is subscribing: a lazy publisher starts to publish because of it,
and the watch of a node on another machine crosses the network (only nodes
of this machine are watched).
"""

from __future__ import annotations

import asyncio
import collections
from typing import TYPE_CHECKING, Callable

from launcher.fleet.state import LOCAL_HOST, Change

if TYPE_CHECKING:  # (annotations only)
    from launcher.fleet.runner import ChildProcess, Runner, RunningNode

CALLER_ID = "/launcher_stall_watch"
MAX_PERIOD_S = 1.0


class TopicWatch:
    """One watched topic of one run: the messages' times in, a verdict out (pure)."""

    def __init__(self, topic: str, started_at: float, timeout: float | None, min_rate: float | None,
                 window: float):
        self.topic = topic
        self.started_at = started_at
        self.timeout = timeout if timeout is not None or min_rate is not None else window
        self.min_rate = min_rate
        self.window = window
        # the window's messages as gulps, (when read, how many): one entry a read, not one a message (a 10 kHz
        # topic over a 5 s window held 50,000 of them)
        self.times: collections.deque[float] = collections.deque()
        self.counts: collections.deque[int] = collections.deque()
        self.count = 0  # the messages in the window
        self.last: float | None = None

    def message(self, now: float) -> None:
        self.messages(1, now)

    def messages(self, count: int, now: float) -> None:
        """`count` messages read at `now` (a watch reads what has come in gulps)."""
        self.last = now
        if count > 0:
            self.times.append(now)
            self.counts.append(count)
            self.count += count
        self._trim(now)

    def _trim(self, now: float) -> None:
        while self.times and self.times[0] <= now - self.window:
            self.times.popleft()
            self.count -= self.counts.popleft()

    def verdict(self, now: float) -> str:
        """Why the topic is stalled now, in words; "" while it is healthy."""
        self._trim(now)
        if self.timeout is not None:
            since = self.last if self.last is not None else self.started_at
            if now - since >= self.timeout:
                what = "since its last message" if self.last is not None else "since the node registered"
                return "no message on %s for %.1f s %s (watch_timeout %g)" % (self.topic, now - since, what,
                                                                              self.timeout)
        if self.min_rate is not None and now - self.started_at >= self.window:
            rate = self.count / self.window
            if rate < self.min_rate:
                return "%s at %.1f Hz over the last %g s, under watch_min_rate %g" % (self.topic, rate, self.window,
                                                                                      self.min_rate)
        return ""

    def rate(self, now: float) -> float:
        """Messages a second over the last `window` seconds (over the time since the run started, when shorter)."""
        self._trim(now)
        return self.count / max(min(self.window, now - self.started_at), 1e-3)

    def period(self) -> float:
        """How often the verdict is worth asking for."""
        shortest = min(x for x in (self.timeout, self.window) if x is not None)
        return max(0.05, min(MAX_PERIOD_S, shortest / 4))


class StallWatch:
    """Watches the watched topics of every running node of a supervisor once its run has registered (a
    watcher: `started`, `exiting`; and a listener of the supervisor's fleet)."""

    def __init__(self, supervisor: Runner):
        self.supervisor = supervisor
        self.loop = asyncio.get_running_loop()
        self.tasks: dict[RunningNode, asyncio.Task] = {}  # NodeProcess -> the watch of its current run
        # node name -> its watched topics' TopicWatch, while its run is watched (what launch --metrics reads)
        self.watches: dict[str, dict[str, TopicWatch]] = {}
        self.watched: set[RunningNode] = set()  # the NodeProcesses whose current run is watched once registered
        supervisor.fleet.listeners.append(self._changed)

    def started(self, proc: RunningNode) -> None:
        if proc.spec.policy.watch_topics:
            self._cancel(proc)
            self.watched.add(proc)

    def exiting(self, proc: RunningNode) -> None:
        self._cancel(proc)
        self.watched.discard(proc)

    def close(self) -> None:
        if self._changed in self.supervisor.fleet.listeners:
            self.supervisor.fleet.listeners.remove(self._changed)
        for task in self.tasks.values():
            task.cancel()
        self.tasks.clear()

    def _changed(self, change: Change) -> None:
        old, new = change.old, change.new
        if (new.registered, new.uri) == (old.registered, old.uri) or new.host != LOCAL_HOST:
            return
        proc = self.supervisor.node(new.name)
        if proc is None or proc not in self.watched:
            return
        self._cancel(proc)
        if new.registered and self._current(proc, proc.popen):  # (silence counts from here)
            self.tasks[proc] = self.loop.create_task(self._watch(proc, proc.popen, new.uri, self.loop.time()))

    def _cancel(self, proc: RunningNode) -> None:
        task = self.tasks.pop(proc, None)
        if task is not None:
            task.cancel()

    def _current(self, proc: RunningNode, popen: ChildProcess | None) -> bool:
        return proc.popen is popen and proc.alive and not proc.stopping and not self.supervisor.shutting_down

    def _counter(self, watch: TopicWatch) -> Callable[[int], None]:
        """What a topic's connection calls with each count of messages read: its watch told when."""
        return lambda count: watch.messages(count, self.loop.time())

    async def _watch(self, proc: RunningNode, popen: ChildProcess | None, uri: str, started_at: float) -> None:
        policy = proc.spec.policy
        watches = {t: TopicWatch(t, started_at, policy.watch_timeout, policy.watch_min_rate, policy.watch_window)
                   for t in policy.watch_topics}
        # (imported here: the TCPROS client is loaded by a launch that watches a topic, not by every launch)
        from launcher.net.topic_watch import PublisherWatch
        links: dict[str, PublisherWatch] = {}
        period = min(w.period() for w in watches.values())
        stalled = False
        self.watches[proc.spec.node_name] = watches
        try:
            while self._current(proc, popen):
                for topic, watch in watches.items():
                    link = links.get(topic)
                    if link is None:
                        link = links[topic] = PublisherWatch(uri, topic, CALLER_ID, self._counter(watch),
                                                             max(period, 0.5))
                    link.check()
                now = self.loop.time()
                why = "; ".join(v for v in (w.verdict(now) for w in watches.values()) if v)
                if not self._current(proc, popen):
                    return
                if why and not stalled:
                    stalled = True
                    self.supervisor.stalled(proc, why)
                elif not why and stalled:
                    stalled = False
                    self.supervisor.unstalled(proc, "every watched topic is published as it should be")
                await asyncio.sleep(period)
        finally:
            if self.watches.get(proc.spec.node_name) is watches:
                del self.watches[proc.spec.node_name]
            for link in links.values():
                link.close()
