"""record's buffer between the sockets and the bag writer (rosbag record's `-b/--buffsize`): messages wait here
for the writer thread; past the limit the oldest are dropped, with a warning at most every WARN_EVERY_S."""

from __future__ import annotations

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
    payload: bytes | bytearray


class Buffer:
    """A queue of messages bounded in bytes (`limit`; 0: unbounded, as rosbag's `-b 0`), one writer taking them.

    `put` is called by the receiving side and never blocks on the writer; `take` by the writer, who waits
    for messages. `close` lets the writer take what is left, then tells it there is no more."""

    def __init__(self, limit: int):
        self.limit = limit
        self.items: deque[Queued] = deque()
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
            self.items.append(item)
            self.size += len(item.payload)
            while self.limit and self.size > self.limit:
                self.size -= len(self.items.popleft().payload)
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
            while not self.items and not self.closed:
                self._waiting = True
                self._ready.wait()
                self._waiting = False
            items: list[Queued] = []
            taken = 0
            while self.items and taken < BATCH_BYTES:
                item = self.items.popleft()
                items.append(item)
                taken += len(item.payload)
            self.size -= taken
            return items

    def close(self) -> None:
        with self._lock:
            self.closed = True
            self._ready.notify()

    def __len__(self) -> int:
        return len(self.items)
