"""Stalled topics: a node alive whose own publication of a watched topic went silent or too slow.

A node with `watch_topic` (its names resolved as the node resolves them, at
load) is watched once its run has registered: the launcher asks the node
itself for each topic (`requestTopic`, as any subscriber does) and subscribes
over TCPROS with any type (`*`: no message package, nothing deserialized), so
another publisher on the same topic cannot hide a stall. The messages are
counted, not kept (`tcpros.CountingLink`): the socket wakes the loop once 64 kB
wait, and each verdict first drains it, so a quiet topic costs a read per
verdict and a 30 MB/s one a read per 256 kB. `TopicWatch` decides,
fed the times of the messages and a clock:

- no message for `watch_timeout` s (counted from the run's start until a
  first message comes): stalled;
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
import urllib.parse
from typing import Any

from launcher.net import tcpros, xmlrpc
from launcher.health.hang import registered_uri

CALLER_ID = "/launcher_stall_watch"
REGISTRATION_POLL_S = 0.25
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
        self.times: collections.deque[float] = collections.deque()
        self.last: float | None = None

    def message(self, now: float) -> None:
        self.messages(1, now)

    def messages(self, count: int, now: float) -> None:
        """`count` messages read at `now` (a watch reads what has come in gulps)."""
        self.last = now
        self.times.extend([now] * count)
        self._trim(now)

    def _trim(self, now: float) -> None:
        while self.times and self.times[0] <= now - self.window:
            self.times.popleft()

    def verdict(self, now: float) -> str:
        """Why the topic is stalled now, in words; "" while it is healthy."""
        self._trim(now)
        if self.timeout is not None:
            since = self.last if self.last is not None else self.started_at
            if now - since >= self.timeout:
                what = "since its last message" if self.last is not None else "since the node started"
                return "no message on %s for %.1f s %s (watch_timeout %g)" % (self.topic, now - since, what,
                                                                              self.timeout)
        if self.min_rate is not None and now - self.started_at >= self.window:
            rate = len(self.times) / self.window
            if rate < self.min_rate:
                return "%s at %.1f Hz over the last %g s, under watch_min_rate %g" % (self.topic, rate, self.window,
                                                                                      self.min_rate)
        return ""

    def rate(self, now: float) -> float:
        """Messages a second over the last `window` seconds (over the time since the run started, when shorter)."""
        self._trim(now)
        return len(self.times) / max(min(self.window, now - self.started_at), 1e-3)

    def period(self) -> float:
        """How often the verdict is worth asking for."""
        shortest = min(x for x in (self.timeout, self.window) if x is not None)
        return max(0.05, min(MAX_PERIOD_S, shortest / 4))


class StallWatch:
    """Watches the watched topics of every running node of a supervisor (a watcher: `started`, `exiting`)."""

    def __init__(self, master_uri: str, supervisor: Any):
        self.master_uri = master_uri
        self.supervisor = supervisor
        self.loop = asyncio.get_running_loop()
        self.tasks: dict[Any, asyncio.Task] = {}  # NodeProcess -> the watch of its current run
        # node name -> its watched topics' TopicWatch, while its run is watched (what launch --metrics reads)
        self.watches: dict[str, dict[str, TopicWatch]] = {}

    def started(self, proc: Any) -> None:
        if proc.spec.policy.watch_topics:
            self._cancel(proc)
            self.tasks[proc] = self.loop.create_task(self._watch(proc, proc.popen))

    def exiting(self, proc: Any) -> None:
        self._cancel(proc)

    def close(self) -> None:
        for task in self.tasks.values():
            task.cancel()
        self.tasks.clear()

    def _cancel(self, proc: Any) -> None:
        task = self.tasks.pop(proc, None)
        if task is not None:
            task.cancel()

    def _current(self, proc: Any, popen: Any) -> bool:
        return proc.popen is popen and proc.alive and not proc.stopping and not self.supervisor.shutting_down

    async def _watch(self, proc: Any, popen: Any) -> None:
        policy = proc.spec.policy
        started_at = self.loop.time()
        watches = {t: TopicWatch(t, started_at, policy.watch_timeout, policy.watch_min_rate, policy.watch_window)
                   for t in policy.watch_topics}
        links: dict[str, tcpros.CountingLink] = {}
        period = min(w.period() for w in watches.values())
        stalled = False
        self.watches[proc.spec.node_name] = watches
        try:
            uri = await registered_uri(self.master_uri, proc, lambda: self._current(proc, popen), REGISTRATION_POLL_S)
            while uri is not None and self._current(proc, popen):
                for topic, watch in watches.items():
                    link = links.get(topic)
                    if link is None or link.closed:
                        links[topic] = await self._subscribe(uri, topic, watch, period) or link
                    else:
                        link.drain()  # (a quiet topic's messages wait under the socket's low-water mark)
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
                if link is not None:
                    link.close()

    async def _subscribe(self, uri: str, topic: str, watch: TopicWatch, timeout: float) -> Any:
        """A link to the node's own publisher of `topic` (None: it does not publish it yet)."""
        try:
            code, _msg, proto = await xmlrpc.call(uri, "requestTopic", CALLER_ID, topic, [["TCPROS"]],
                                                  timeout=max(timeout, 0.5))
        except (OSError, asyncio.TimeoutError, xmlrpc.Fault, xmlrpc.XmlRpcError, ValueError, TypeError):
            return None
        if code != 1 or not isinstance(proto, list) or len(proto) < 3 or proto[0] != "TCPROS":
            return None
        host, port = proto[1], proto[2]
        try:
            return await tcpros.watch_publisher(host or urllib.parse.urlsplit(uri).hostname, int(port), topic,
                                                CALLER_ID, uri, lambda n: watch.messages(n, self.loop.time()),
                                                timeout=max(timeout, 0.5))
        except (OSError, asyncio.TimeoutError, tcpros.TcprosError, ValueError):
            return None
