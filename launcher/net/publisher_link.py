"""A subscriber's connection to one publisher of a topic (roscpp's TransportPublisherLink): the asyncio side of
`linkstate.PublisherLinkState`, and `connect_publisher`, which opens one and waits for its handshake."""

from __future__ import annotations

import asyncio
import logging
import socket
from collections.abc import Callable
from typing import Any

from launcher import compat
from launcher.net.connect import connect
from launcher.net.linkstate import BROKEN, PublisherLinkState
from launcher.net.tcpros import TcprosError, TopicType
from launcher.net.transport import new_connection_id, transport_info

log = logging.getLogger("launcher.tcpros")


class PublisherLink(asyncio.BufferedProtocol):
    """Our connection, as a subscriber, to one publisher of a topic: the asyncio side of a PublisherLinkState
    (a buffered protocol: the socket is read into the state's buffers, a large message straight into its own).
    `on_close(link)` is called once, however it ended (`ending`, `why`); `handshake` is settled with the
    publisher's header, or None if the link ended first (never with an exception: nobody need retrieve one)."""

    def __init__(self, topic: str, mtype: TopicType, callerid: str, publisher_uri: str,
                 on_message: Callable[[bytes | bytearray, PublisherLink], None],
                 on_close: Callable[[PublisherLink], None]):
        self.loop = asyncio.get_running_loop()
        self.state = PublisherLinkState(topic, mtype, callerid, publisher_uri, self.loop.time())
        self.topic = topic
        self.mtype = mtype
        self.callerid = callerid
        self.publisher_uri = publisher_uri
        self.on_message = on_message
        self.on_close = on_close
        self.id = new_connection_id()
        self.transport: asyncio.Transport | None = None
        self.closed = False
        self.info = "TCPROS connection"
        self.handshake: asyncio.Future = self.loop.create_future()
        self._deadline: asyncio.TimerHandle | None = None

    @property
    def header(self) -> dict[str, str] | None:
        return self.state.header

    @property
    def bytes_received(self) -> int:
        return self.state.bytes_received

    @property
    def messages_received(self) -> int:
        return self.state.messages_received

    @property
    def ending(self) -> str | None:
        return self.state.ending

    @property
    def why(self) -> str:
        return self.state.why

    # asyncio.Protocol
    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]
        self.info = transport_info(transport.get_extra_info("socket"))
        transport.write(self.state.request())  # type: ignore[attr-defined]
        self._deadline = self.loop.call_at(self.state.deadline, self._expire)

    def get_buffer(self, sizehint: int) -> memoryview:
        return self.state.get_buffer()

    def buffer_updated(self, nbytes: int) -> None:
        self._deliver(self.state.received(nbytes, self.loop.time()))

    def data_received(self, data: bytes) -> None:
        self._deliver(self.state.receive(data, self.loop.time()))

    def _expire(self) -> None:
        self._deadline = None
        self._deliver(self.state.expire(self.loop.time()))

    def _deliver(self, events: list[tuple[str, Any]]) -> None:
        for kind, value in events:
            if kind == "message":
                try:
                    self.on_message(value, self)
                except Exception:  # a bad message must not end the connection or the launcher
                    log.exception("handling a message on %s from %s", self.topic, self.publisher_uri)
            elif kind == "header":
                if self._deadline is not None:
                    self._deadline.cancel()
                    self._deadline = None
                if not self.handshake.done():
                    self.handshake.set_result(value)
            else:
                self._end()

    def connection_lost(self, exc: Exception | None) -> None:
        self.state.lost(self.loop.time())
        self._end()

    def close(self) -> None:
        """Close now (bytes already received have been delivered)."""
        self.state.close()
        self._end()

    def _end(self) -> None:
        if self._deadline is not None:
            self._deadline.cancel()
            self._deadline = None
        if not self.handshake.done():
            self.handshake.set_result(None)
        if self.transport is not None:
            self.transport.close()
        if not self.closed:
            self.closed = True
            self.on_close(self)

    @property
    def callerid_of_publisher(self) -> str:
        return (self.header or {}).get("callerid", "")


async def connect_publisher(host: str, port: int, link: PublisherLink, *,
                            timeout: float = 10.0) -> PublisherLink:
    """Open `link` to a publisher's TCPROS server (within `timeout`) and complete the handshake (by the link's
    own deadline); TcprosError(why, ending) if the link ended first."""
    loop = asyncio.get_running_loop()
    await compat.wait_for(connect(loop, lambda: link, host, port), timeout)
    sock = link.transport.get_extra_info("socket") if link.transport is not None and not link.closed else None
    if sock is not None:
        try:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        except OSError:  # (the link may have ended already: what came with the connection broke it)
            pass
    try:
        header = await asyncio.shield(link.handshake)
    except BaseException:  # cancelled: the subscription went
        link.close()
        raise
    if header is None:
        raise TcprosError(link.why, link.ending or BROKEN)
    return link
