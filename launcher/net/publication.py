"""A topic this node publishes (roscpp's Publication) and each subscriber connected to it (its SubscriberLink):
a message framed once and written to every subscriber, latching, roscpp's publisher queue per subscriber."""

from __future__ import annotations

from collections import deque
from typing import TYPE_CHECKING, Protocol

from launcher.net.tcpros import TopicType, encode_frame

if TYPE_CHECKING:
    import asyncio

# Above this many unsent bytes a subscriber is stalled: we drop what it cannot take rather than
# let one slow reader grow the launcher's memory (roscpp drops from its publish queue likewise).
MAX_WRITE_BACKLOG = 16 << 20


class Publication:
    """A topic we publish, and the subscribers connected to it."""

    # (a plain class: `dataclasses` would be imported at every launch's start for it, ~0.15 MB kept)
    __slots__ = ("topic", "mtype", "callerid", "latch", "queue_size", "links", "messages_published", "last")

    def __init__(self, topic: str, mtype: TopicType, callerid: str, latch: bool = False,
                 queue_size: int | None = None):
        self.topic = topic
        self.mtype = mtype
        self.callerid = callerid
        self.latch = latch
        # roscpp's publisher queue: messages per subscriber waiting for its socket, the oldest dropped past it
        # (0: unbounded); None: no queue of ours, a subscriber MAX_WRITE_BACKLOG bytes behind loses new messages
        self.queue_size = queue_size
        self.links: list[SubscriberLink] = []
        self.messages_published = 0
        self.last: bytes | None = None

    def publish(self, payload: bytes | memoryview) -> None:
        """Send one serialized message to every connected subscriber."""
        self.messages_published += 1
        if not self.links and not self.latch:
            return  # nobody listening: don't even build the frame
        frame = encode_frame(payload)
        if self.latch:
            self.last = frame
        for link in self.links:
            link.send(frame)


class SubscriberConnection(Protocol):
    """What a SubscriberLink needs of its connection (`tcpros_server.InboundConnection`, which holds the link)."""

    id: int
    info: str
    transport: asyncio.Transport | None
    writing_paused: bool  # asyncio's flow control: the socket and the transport's buffer are full
    bytes_sent: int
    messages_sent: int
    drops: int


class SubscriberLink:
    """One subscriber connected to one of our publications. With a queue size, frames wait in `outbox` while the
    connection's writing is paused (as in roscpp's publisher queue: the oldest dropped when it is full)."""

    __slots__ = ("conn", "callerid", "queue_size", "outbox")

    def __init__(self, conn: SubscriberConnection, callerid: str, queue_size: int | None = None):
        self.conn = conn
        self.callerid = callerid
        self.queue_size = queue_size
        self.outbox: deque[bytes] = deque()

    def send(self, frame: bytes) -> None:
        transport = self.conn.transport
        if transport is None or transport.is_closing():
            return
        if self.queue_size is not None:
            if self.conn.writing_paused or self.outbox:
                if self.queue_size and len(self.outbox) >= self.queue_size:
                    self.outbox.popleft()
                    self.conn.drops += 1
                self.outbox.append(frame)
                return
        elif transport.get_write_buffer_size() > MAX_WRITE_BACKLOG:
            self.conn.drops += 1
            return
        self._write(transport, frame)

    def _write(self, transport: asyncio.Transport, frame: bytes) -> None:
        transport.write(frame)
        self.conn.bytes_sent += len(frame)
        self.conn.messages_sent += 1

    def flush(self) -> None:
        """Hand the outbox to the socket while it takes it."""
        transport = self.conn.transport
        while self.outbox and not self.conn.writing_paused and transport is not None and not transport.is_closing():
            self._write(transport, self.outbox.popleft())

    @property
    def pending(self) -> bool:
        """Something not yet on its way to the subscriber (in the outbox, or in the transport's buffer)."""
        transport = self.conn.transport
        return bool(self.outbox) or (transport is not None and bool(transport.get_write_buffer_size()))

    @property
    def id(self) -> int:
        return self.conn.id

    @property
    def info(self) -> str:
        return self.conn.info
