"""The TCP port where subscribers and service clients reach this node (roscpp's ConnectionManager): each
connection's header read, `linkstate.InboundState` deciding what it is, then a subscriber handed to its
publication or a service's requests answered."""

from __future__ import annotations

import asyncio
import logging
import socket
from typing import Any

from launcher.net.linkstate import InboundState
from launcher.net.publication import Publication, SubscriberLink
from launcher.net.service import ServiceServer
from launcher.net.tcpros import FrameDecoder, TcprosError, decode_header, encode_header
from launcher.net.transport import new_connection_id, transport_info

log = logging.getLogger("launcher.tcpros")


class InboundConnection(asyncio.Protocol):
    """A connection a peer opened to our TCPROS server: a subscriber or a service client."""

    def __init__(self, server: TcprosServer):
        self.server = server
        self.id = new_connection_id()
        self.transport: asyncio.Transport | None = None
        self.decoder = FrameDecoder()
        self.header: dict[str, str] | None = None
        self.publication: Publication | None = None
        self.service: ServiceServer | None = None
        self.info = "TCPROS connection"
        self.bytes_sent = 0
        self.messages_sent = 0
        self.drops = 0
        self.link: SubscriberLink | None = None
        self.writing_paused = False       # asyncio's flow control: the socket and our buffer are full

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]
        sock = transport.get_extra_info("socket")
        self.info = transport_info(sock)
        self.server.connections.add(self)

    def data_received(self, data: bytes) -> None:
        try:
            frames = self.decoder.feed(data)
        except TcprosError as exc:
            log.warning("TCPROS client %s: %s; dropping it", self._peer(), exc)
            self.close()
            return
        for payload in frames:
            if self.header is None:
                self._accept_header(payload)
            elif self.service is not None:
                self._serve(payload)
            # Anything a subscriber sends after its header is meaningless; ignore it.
            if self.transport is None or self.transport.is_closing():
                return

    def _peer(self) -> str:
        if self.transport is None:
            return "?"
        peer = self.transport.get_extra_info("peername")
        return "%s:%s" % tuple(peer[:2]) if peer else "?"

    def _refuse(self, why: str) -> None:
        log.warning("refusing TCPROS client %s: %s", self._peer(), why)
        assert self.transport is not None
        self.transport.write(encode_header({"error": why}))
        self.close()

    def _accept_header(self, payload: bytes) -> None:
        try:
            header = decode_header(payload)
        except TcprosError as exc:
            log.warning("TCPROS client %s: %s; dropping it", self._peer(), exc)
            self.close()
            return
        self.header = header
        server = self.server
        verdict = InboundState(server.callerid, server.publications, server.services).offer(header)
        if verdict[0] == "refuse":
            self._refuse(verdict[1])
            return
        assert self.transport is not None
        if verdict[0] == "service":
            _, srv, reply, probe = verdict
            self.transport.write(encode_header(reply))
            if probe:  # rosservice's type probe only wants our header
                self.close()
                return
            self.service = srv
            return
        _, pub, reply = verdict
        sock = self.transport.get_extra_info("socket")
        if sock is not None and header.get("tcp_nodelay") == "1":
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.transport.write(encode_header(reply))
        self.publication = pub
        link = SubscriberLink(self, header["callerid"], pub.queue_size)
        self.link = link
        pub.links.append(link)
        if pub.latch and pub.last is not None:
            link.send(pub.last)

    def _serve(self, request: bytes) -> None:
        assert self.service is not None and self.transport is not None
        self.transport.write(self.service.respond(request))
        if self.header is not None and self.header.get("persistent") != "1":
            self.close()

    def close(self) -> None:
        if self.transport is not None and not self.transport.is_closing():
            self.transport.close()
        self._forget()

    def _forget(self) -> None:
        self.server.connections.discard(self)
        if self.publication is not None:
            self.publication.links[:] = [l for l in self.publication.links if l.conn is not self]

    def connection_lost(self, exc: Exception | None) -> None:
        self._forget()

    def pause_writing(self) -> None:
        self.writing_paused = True

    def resume_writing(self) -> None:
        self.writing_paused = False
        if self.link is not None:
            self.link.flush()


class TcprosServer:
    """The TCP port where subscribers and service clients reach this node."""

    def __init__(self, callerid: str, host: str = "127.0.0.1"):
        self.callerid = callerid
        self.host = host
        self.port = 0
        self.publications: dict[str, Publication] = {}
        self.services: dict[str, ServiceServer] = {}
        self.connections: set[InboundConnection] = set()
        self._server: asyncio.base_events.Server | None = None

    async def start(self, bind_host: str | None = None) -> None:
        loop = asyncio.get_running_loop()
        self._server = await loop.create_server(lambda: InboundConnection(self),
                                                bind_host or self.host, 0)
        self.port = self._server.sockets[0].getsockname()[1]

    async def stop(self) -> None:
        if self._server is not None:
            self._server.close()
        for conn in list(self.connections):
            conn.close()
        if self._server is not None:
            await self._server.wait_closed()
            self._server = None

    def stats(self) -> Any:
        return [[p.topic, [[l.id, l.conn.bytes_sent, l.conn.bytes_sent, l.conn.messages_sent, 0]
                           for l in p.links]] for p in self.publications.values()]
