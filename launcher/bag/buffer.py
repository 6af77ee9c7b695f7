"""record's buffer between the sockets and the bag writer (rosbag record's `-b/--buffsize`): messages wait here
for the writer thread; past the limit the oldest message of the topic holding the most of the buffer is dropped
(so a topic faster than the disk loses its own oldest messages, not a slow topic's), with rosbag's warning at
most every WARN_EVERY_S."""

from __future__ import annotations

import heapq
import threading
from collections import deque
from typing import Any, NamedTuple

# rosbag record warns of dropped messages once per 5 s at most.
WARN_EVERY_S = 5.0
# The writer takes messages in batches of about this many bytes (one lock round per batch, not per message; a
# batch in the writer's hands is out of the buffer, so it stays small next to any -b).
BATCH_BYTES = 1 << 20


class Queued(NamedTuple):
    topic: str
    header: dict[str, str]
    stamp_ns: int
    payload: Any  # bytes, bytearray or mmap (net.tcpros.FrameReader)


class Buffer:
    """A queue of messages bounded in bytes (`limit`; 0: unbounded, as rosbag's `-b 0`), one writer taking them
    in the order they came.

    Each topic's messages wait in a queue of their own (`topics`), and a heap of the topics' oldest arrivals
    (`heads`: one entry per topic with messages, its number no later than that topic's oldest) gives the writer
    the oldest of all. Past the limit, the topic holding the most bytes loses its oldest: rosbag drops the oldest
    of all, so one flooding topic there costs every other topic its messages too.

    `put` is called by the receiving side and never blocks on the writer; `take` by the writer, who waits
    for messages. `close` lets the writer take what is left, then tells it there is no more."""

    def __init__(self, limit: int):
        self.limit = limit
        self.topics: dict[str, deque[tuple[int, Queued]]] = {}
        self.topic_bytes: dict[str, int] = {}
        self.heads: list[tuple[int, str]] = []
        self.in_heads: set[str] = set()
        self.arrivals = 0                 # the number of the next message put
        self.count = 0
        self.size = 0
        self.dropped = 0                  # messages dropped since the last warning
        self.total_dropped = 0
        self.warned_at: float | None = None
        self.closed = False
        self._lock = threading.Lock()
        self._ready = threading.Condition(self._lock)
        self._waiting = False             # the writer waits in take: only then is it woken (most puts find it busy)

    def put(self, item: Queued, now: float) -> int:
        """Queue `item`; the number of messages dropped to make room that are to be warned of now (else 0)."""
        with self._lock:
            queue = self.topics.get(item.topic)
            if queue is None:
                queue = self.topics[item.topic] = deque()
                self.topic_bytes[item.topic] = 0
            queue.append((self.arrivals, item))
            if item.topic not in self.in_heads:
                heapq.heappush(self.heads, (self.arrivals, item.topic))
                self.in_heads.add(item.topic)
            self.arrivals += 1
            self.count += 1
            size = len(item.payload)
            self.size += size
            self.topic_bytes[item.topic] += size
            while self.limit and self.size > self.limit:
                heaviest = max(self.topic_bytes, key=self.topic_bytes.__getitem__)
                _, old = self.topics[heaviest].popleft()  # (its entry in `heads` is put right by take)
                self.size -= len(old.payload)
                self.topic_bytes[heaviest] -= len(old.payload)
                self.count -= 1
                self.dropped += 1
                self.total_dropped += 1
            if self._waiting:
                self._ready.notify()
            if self.dropped and (self.warned_at is None or now > self.warned_at + WARN_EVERY_S):
                self.warned_at = now
                dropped, self.dropped = self.dropped, 0
                return dropped
            return 0

    def take(self) -> list[Queued]:
        """The oldest queued messages (at least one, about BATCH_BYTES), waiting for one; [] once closed and empty."""
        with self._lock:
            while not self.count and not self.closed:
                self._waiting = True
                self._ready.wait()
                self._waiting = False
            items: list[Queued] = []
            taken = 0
            while self.count and taken < BATCH_BYTES:
                number, topic = heapq.heappop(self.heads)
                queue = self.topics[topic]
                if not queue:
                    self.in_heads.discard(topic)
                    continue
                if queue[0][0] != number:  # its oldest was dropped: its entry is put right
                    heapq.heappush(self.heads, (queue[0][0], topic))
                    continue
                _, item = queue.popleft()
                if queue:
                    heapq.heappush(self.heads, (queue[0][0], topic))
                else:
                    self.in_heads.discard(topic)
                items.append(item)
                size = len(item.payload)
                taken += size
                self.topic_bytes[topic] -= size
                self.count -= 1
            self.size -= taken
            return items

    def close(self) -> None:
        with self._lock:
            self.closed = True
            self._ready.notify()

    def __len__(self) -> int:
        return self.count
