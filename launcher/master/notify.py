"""Master -> node callbacks (publisherUpdate, paramUpdate, shutdown): asynchronous and bounded.

Each node API has its own ordered queue drained by one task, so a node sees
its notifications in the order the master made them, while a node that hangs
or has vanished only ever delays itself: every call has a time-out, the
number of calls in flight is capped, and a queued publisherUpdate that a newer
one for the same topic supersedes is replaced (the newer list is complete).
"""

from __future__ import annotations

import asyncio
import collections
import logging
from typing import Any, Callable

from launcher.master.masterlog import mlog  # master.log, in rosmaster's lines
from launcher.net import xmlrpc

log = logging.getLogger("launcher.master")


MASTER_CALLER_ID = "/master"


class _Item:
    __slots__ = ("method", "params", "on_result", "topic")

    def __init__(self, method: str, params: list, on_result: Callable[[Any], None] | None, topic: str | None):
        self.method = method
        self.params = params
        self.on_result = on_result
        self.topic = topic


class Notifier:
    """Queues callbacks per node API and sends them on the running loop."""

    def __init__(self, *, timeout: float = 15.0, max_in_flight: int = 256, max_queued_per_api: int = 10000):
        self.timeout = timeout
        self.max_queued_per_api = max_queued_per_api
        self._queues: dict[str, collections.deque[_Item]] = {}
        self._workers: dict[str, asyncio.Task] = {}
        self._pending_pub: dict[tuple[str, str], _Item] = {}  # queued (not yet sent) publisherUpdates
        self._slots = asyncio.Semaphore(max_in_flight)
        self._closed = False

    # -- what the master queues --------------------------------------------------
    def publisher_update(self, api: str, topic: str, pub_uris: list[str]) -> None:
        item = self._pending_pub.get((api, topic))
        if item is not None:
            item.params[2] = pub_uris  # not sent yet: the newer, complete list replaces it
            return
        item = _Item("publisherUpdate", [MASTER_CALLER_ID, topic, pub_uris], None, topic)
        if self._queue(api, item):
            self._pending_pub[(api, topic)] = item

    def param_update(self, api: str, key: str, value: Any, on_result: Callable[[Any], None] | None = None) -> None:
        self._queue(api, _Item("paramUpdate", [MASTER_CALLER_ID, key, value], on_result, None))

    def shutdown_node(self, api: str, caller_id: str, reason: str) -> None:
        self._queue(api, _Item("shutdown", [MASTER_CALLER_ID, "[%s] Reason: %s" % (caller_id, reason)], None, None))

    # -- machinery ----------------------------------------------------------------
    def _queue(self, api: str, item: _Item) -> bool:
        if self._closed or not api.startswith("http://"):
            return False  # rosrpc:// APIs cannot take XML-RPC calls
        q = self._queues.get(api)
        if q is None:
            q = self._queues[api] = collections.deque()
            self._workers[api] = asyncio.get_running_loop().create_task(self._drain(api, q))
        elif len(q) >= self.max_queued_per_api:
            dropped = q.popleft()
            if dropped.topic is not None:
                self._pending_pub.pop((api, dropped.topic), None)
            log.warning("dropping a %s to %s: too many queued callbacks", dropped.method, api)
        q.append(item)
        return True

    async def _drain(self, api: str, q: collections.deque[_Item]) -> None:
        try:
            while q:
                item = q.popleft()
                if item.topic is not None:
                    self._pending_pub.pop((api, item.topic), None)
                async with self._slots:
                    if item.method == "paramUpdate":
                        mlog.info("paramUpdate[%s]", item.params[1])
                    logged = item.method == "publisherUpdate" and mlog.enabled
                    if logged:
                        what = "publisherUpdate[%s] -> %s %s" % (item.topic, api, item.params[2])
                        mlog.info(what)
                        started = asyncio.get_running_loop().time()
                    try:
                        result = await xmlrpc.call(api, item.method, *item.params, timeout=self.timeout)
                        if logged:
                            mlog.info("%s: sec=%0.2f, result=%s", what, asyncio.get_running_loop().time() - started,
                                      result)
                    except asyncio.CancelledError:
                        raise
                    except asyncio.TimeoutError:
                        log.warning("%s to %s timed out", item.method, api)
                        if logged:
                            mlog.info("%s: sec=%0.2f, exception=timed out", what, self.timeout)
                        continue
                    except Exception as e:  # noqa: BLE001 - a node that is gone or answers garbage
                        log.info("%s to %s failed: %s", item.method, api, e)
                        if logged:
                            mlog.info("%s: sec=%0.2f, exception=%s", what,
                                      asyncio.get_running_loop().time() - started, e)
                        continue
                if item.on_result is not None:
                    try:
                        item.on_result(result)
                    except Exception:  # noqa: BLE001
                        log.exception("handling the reply of %s from %s", item.method, api)
        finally:
            if self._queues.get(api) is q:
                del self._queues[api]
                del self._workers[api]
            if q:  # cancelled with callbacks still queued: forget them
                for item in q:
                    if item.topic is not None:
                        self._pending_pub.pop((api, item.topic), None)
                q.clear()

    def pending(self) -> int:
        """Callbacks queued or in flight (for tests and shutdown)."""
        return sum(len(q) for q in self._queues.values()) + len(self._workers)

    async def close(self) -> None:
        """Cancel everything still queued or in flight."""
        self._closed = True
        workers = list(self._workers.values())
        for t in workers:
            t.cancel()
        if workers:
            await asyncio.gather(*workers, return_exceptions=True)
        self._queues.clear()
        self._workers.clear()
        self._pending_pub.clear()
