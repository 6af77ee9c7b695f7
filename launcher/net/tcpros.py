"""TCPROS: connection headers, message framing and both ends' handshakes (sans-I/O: `PublisherLinkState`,
`InboundState`, fed bytes and a clock), plus thin asyncio links for topics and services around them."""

from __future__ import annotations

import asyncio
import logging
import re
import socket
import struct
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

log = logging.getLogger("launcher.tcpros")

_LEN = struct.Struct("<I")

# The one limit of a frame's length, a connection header's and a message's alike, on every reader here (a
# subscriber's link, a watch, our publications' and services' clients): roscpp's, which takes a length over
# 10^9 bytes for lost framing (connection.cpp, transport_publisher_link.cpp). Large on purpose: a dense point
# cloud is tens of MB. A length is not trusted for memory: a frame costs what has come of it (FrameReader).
MAX_FRAME_SIZE = 1_000_000_000
# A publisher's connection header is due this long after we connect (roscpp and rospy wait for ever; the
# master gives an HTTP request's head the same 10 s).
HANDSHAKE_TIMEOUT_S = 10.0
# Above this many unsent bytes a subscriber is stalled: we drop what it cannot take rather than
# let one slow reader grow the launcher's memory (roscpp drops from its publish queue likewise).
MAX_WRITE_BACKLOG = 16 << 20
# Any message type accepted (rospy's AnyMsg, rostopic before it knows the type).
ANY_MD5 = "*"


class TcprosError(Exception):
    """A peer broke the TCPROS protocol (bad header, absurd length, refused handshake); `ending`, where a link
    raises it: how its connection ended (see PublisherRetry)."""

    def __init__(self, why: str, ending: str = "broken"):
        super().__init__(why)
        self.ending = ending


# --------------------------------------------------------------------------- sans-I/O codec

def encode_header(fields: Mapping[str, str]) -> bytes:
    """A connection header as sent on the wire: total length, then length-prefixed `key=value`s."""
    body = bytearray()
    for key, value in fields.items():
        item = ("%s=%s" % (key, value)).encode("utf-8")
        body += _LEN.pack(len(item))
        body += item
    return _LEN.pack(len(body)) + bytes(body)


def decode_header(payload: bytes | memoryview) -> dict[str, str]:
    """The fields of a connection header body (without its outer length)."""
    fields: dict[str, str] = {}
    view = memoryview(payload)
    pos, end = 0, len(view)
    while pos < end:
        if end - pos < 4:
            raise TcprosError("connection header truncated: %d stray bytes" % (end - pos))
        (size,) = _LEN.unpack_from(view, pos)
        pos += 4
        if size > end - pos:
            raise TcprosError("connection header field of %d bytes overruns the header" % size)
        item = bytes(view[pos:pos + size])
        pos += size
        key, eq, value = item.partition(b"=")
        if not eq:
            raise TcprosError("connection header field without '=': %r" % item[:64])
        try:
            fields[key.decode("utf-8")] = value.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise TcprosError("connection header field is not UTF-8: %r" % item[:64]) from exc
    return fields


def encode_frame(payload: bytes | memoryview) -> bytes:
    """One serialized message as sent on a topic connection: its length, then its bytes."""
    return _LEN.pack(len(payload)) + bytes(payload)


class FrameDecoder:
    """Splits a byte stream into length-prefixed frames; feed it whatever the socket gave."""

    __slots__ = ("_buf", "limit")

    def __init__(self, limit: int = MAX_FRAME_SIZE):
        self._buf = bytearray()
        self.limit = limit

    def feed(self, data: bytes) -> list[bytes]:
        """Complete frames now available, oldest first; raises TcprosError on an absurd length."""
        buf = self._buf
        buf += data
        frames: list[bytes] = []
        pos, end = 0, len(buf)
        # (frames are taken through a view: one copy each, not two; large messages are megabytes)
        with memoryview(buf) as view:
            while end - pos >= 4:
                (size,) = _LEN.unpack_from(buf, pos)
                if size > self.limit:
                    raise TcprosError("frame of %d bytes exceeds the %d byte limit" % (size, self.limit))
                if end - pos - 4 < size:
                    break
                frames.append(view[pos + 4:pos + 4 + size].tobytes())
                pos += 4 + size
        if pos:
            del buf[:pos]
        return frames

    @property
    def pending(self) -> int:
        """Bytes received that do not yet make a whole frame."""
        return len(self._buf)


class FrameCounter:
    """Counts the length-prefixed frames of a byte stream without keeping their bytes: a watcher that only
    needs to know that messages come skips megabytes at the cost of one step per chunk read."""

    __slots__ = ("_skip", "_size", "_prefix", "limit")

    def __init__(self, limit: int = MAX_FRAME_SIZE):
        self._skip = 0  # payload bytes of the current frame still to come
        self._size = 0  # ...of its size
        self._prefix = b""  # the first bytes of a length prefix cut by a chunk's end
        self.limit = limit

    def partial(self) -> str:
        """The frame cut short if the stream ended now, in words ("" at a frame's boundary)."""
        if self._skip:
            return "%d of its %d bytes" % (self._size - self._skip, self._size)
        if self._prefix:
            return "%d of the 4 bytes of its length" % len(self._prefix)
        return ""

    def feed(self, data: bytes | memoryview) -> int:
        """Frames completed by `data`; raises TcprosError on an absurd length."""
        pos, end, done = 0, len(data), 0
        while True:
            if self._skip:
                step = min(self._skip, end - pos)
                self._skip -= step
                pos += step
                if self._skip:
                    return done
                done += 1
            if pos >= end:
                return done
            need = 4 - len(self._prefix)
            if end - pos < need:
                self._prefix += bytes(data[pos:end])
                return done
            if self._prefix:
                prefix, self._prefix = self._prefix + bytes(data[pos:pos + need]), b""
                (size,) = _LEN.unpack(prefix)
            else:
                (size,) = _LEN.unpack_from(data, pos)
            pos += need
            if size > self.limit:
                raise TcprosError("frame of %d bytes exceeds the %d byte limit" % (size, self.limit))
            if size == 0:
                done += 1
            self._skip = self._size = size


# A frame's length is trusted for memory only as far as its bytes bear it out: a large frame's buffer is
# FIRST_BODY bytes at first, then TRUST_FACTOR times what has come (at most the frame), a new buffer taking over
# what the last one holds (copies of a fifteenth of the frame in all). A camera image of 1-4 MB: one or two
# buffers; a peer that announces 900 MB and sends 100 kB holds 1 MiB. (roscpp's `new uint8_t[len]` is lazy
# likewise: its pages are taken as the bytes come.)
FIRST_BODY = 1 << 20
TRUST_FACTOR = 16


class FrameReader:
    """Frames read in place, for asyncio's BufferedProtocol: the socket is read into `get_buffer()`, then
    `received(n)` says how much came. A frame larger than the scratch buffer is read straight into a
    bytearray of its own (grown as its bytes come: see TRUST_FACTOR), which is handed on as the frame (the
    kernel's copy: megabyte messages are not copied again); smaller frames are cut from the scratch buffer as
    bytes."""

    __slots__ = ("limit", "failure", "_scratch", "_view", "_fill", "_body", "_size", "_got")

    SCRATCH = 64 * 1024

    def __init__(self, limit: int = MAX_FRAME_SIZE):
        self.limit = limit
        self.failure: TcprosError | None = None
        self._scratch = bytearray(self.SCRATCH)
        self._view = memoryview(self._scratch)
        self._fill = 0                          # bytes in the scratch buffer
        self._body: bytearray | None = None     # a large frame being read: its buffer so far, its size,
        self._size = 0                          # and how much of it came
        self._got = 0

    def get_buffer(self) -> memoryview:
        body = self._body
        if body is not None:
            if self._got == len(body):  # full, and the frame is not: a buffer of TRUST_FACTOR times what came
                grown = bytearray(min(self._size, TRUST_FACTOR * self._got))
                grown[:self._got] = body
                self._body = body = grown
            return memoryview(body)[self._got:]
        return self._view[self._fill:]

    def received(self, n: int) -> list[bytes | bytearray]:
        """The frames completed by `n` more bytes, oldest first; raises TcprosError on an absurd length (or, if
        frames came whole before it, returns those and keeps the error as `failure`, raised by the next call)."""
        if self.failure is not None:
            raise self.failure
        if self._body is not None:
            self._got += n
            if self._got < self._size:
                return []
            body, self._body = self._body, None
            return [body]
        self._fill += n
        frames: list[bytes | bytearray] = []
        buf, pos, fill = self._scratch, 0, self._fill
        while fill - pos >= 4:
            (size,) = _LEN.unpack_from(buf, pos)
            if size > self.limit:
                self.failure = TcprosError("frame of %d bytes exceeds the %d byte limit" % (size, self.limit))
                if not frames:
                    raise self.failure
                return frames  # (those before it are whole and theirs: handed on, then `failure`)
            if fill - pos - 4 >= size:
                frames.append(bytes(self._view[pos + 4:pos + 4 + size]))
                pos += 4 + size
            elif size > self.SCRATCH - 4:
                # too big for the scratch buffer: the rest of it is read into a buffer of its own
                self._got = fill - pos - 4
                self._size = size
                self._body = bytearray(min(size, max(FIRST_BODY, self._got)))
                self._body[:self._got] = self._view[pos + 4:fill]
                pos = fill
                break
            else:
                break
        if pos:
            rest = fill - pos
            buf[:rest] = buf[pos:fill]  # (the start of a frame still coming: at most a scratch buffer)
            self._fill = rest
        return frames

    @property
    def pending(self) -> int:
        """Bytes received that do not yet make a whole frame."""
        return self._fill + (4 + self._got if self._body is not None else 0)

    @property
    def held(self) -> int:
        """Bytes of memory the frame being read holds (its buffer so far)."""
        return len(self._body) if self._body is not None else 0

    def partial(self) -> str:
        """The frame cut short if the stream ended now, in words ("" at a frame's boundary)."""
        if self._body is not None:
            return "%d of its %d bytes" % (self._got, self._size)
        if self._fill >= 4:
            (size,) = _LEN.unpack_from(self._scratch, 0)
            return "%d of its %d bytes" % (self._fill - 4, size)
        if self._fill:
            return "%d of the 4 bytes of its length" % self._fill
        return ""

    def take_pending(self) -> bytes:
        """The bytes of the incomplete frame, its length first, handed on (to a FrameCounter) and forgotten here."""
        if self._body is not None:
            rest = _LEN.pack(self._size) + bytes(self._body[:self._got])
            self._body, self._got = None, 0
        else:
            rest = bytes(self._view[:self._fill])
        self._fill = 0
        return rest


def encode_service_response(ok: bool, payload: bytes) -> bytes:
    """A service reply: one ok byte, then the response (or the error text) framed."""
    return (b"\x01" if ok else b"\x00") + encode_frame(payload)


def transport_info(sock: socket.socket | None) -> str:
    """roscpp's connection description, which `rosnode info` parses for ports and socket."""
    if sock is None:
        return "TCPROS connection"
    try:
        local_port = sock.getsockname()[1]
        host, port = sock.getpeername()[:2]
        return "TCPROS connection on port %d to [%s:%d on socket %d]" % (
            local_port, host, port, sock.fileno())
    except OSError:
        return "TCPROS connection"


# --------------------------------------------------------------------------- asyncio layer

_next_connection_id = 0


def _new_connection_id() -> int:
    global _next_connection_id
    _next_connection_id += 1
    return _next_connection_id


@dataclass
class TopicType:
    """What both ends of a topic connection must agree on."""

    name: str        # e.g. rosgraph_msgs/Log
    md5sum: str
    definition: str


# --------------------------------------------------------------------------- sans-I/O links

HEADER, MESSAGES, FAILED = "header", "messages", "failed"  # the phases of a topic connection

# How a connection to a publisher ended, which decides when it is tried again (PublisherRetry):
ENDED = "ended"        # the publisher closed it between two frames
BROKEN = "broken"      # a broken frame, no header in time, a close in the middle of a frame, no connection at all
REFUSED = "refused"    # an error header, or a header we must not take (no type or md5sum, another type)
CLOSED = "closed"      # we closed it (the subscription ended, or the master no longer lists the publisher)

_MD5 = re.compile(r"[0-9a-f]{32}")
_TYPE = re.compile(r"[A-Za-z][\w]*/[A-Za-z]\w*")


class PublisherLinkState:
    """Our end, as a subscriber, of one connection to a publisher: fed bytes and a clock, it says what came.

    Phases: `header` (our header sent, theirs due by `deadline`: checked for an error field, a type and an
    md5sum) -> `messages` -> `failed`, once the connection is over for any reason: then `ending` says how
    (ENDED, BROKEN, REFUSED, CLOSED) and `why` says it in one line naming the publisher and the topic.
    It counts bytes and messages and keeps the time of the last message."""

    def __init__(self, topic: str, mtype: TopicType, callerid: str, publisher_uri: str, now: float):
        self.topic = topic
        self.mtype = mtype
        self.callerid = callerid
        self.publisher_uri = publisher_uri
        self.phase = HEADER
        self.header: dict[str, str] | None = None
        self.reader = FrameReader()
        self.bytes_received = 0
        self.messages_received = 0
        self.opened_at = now
        self.deadline = now + HANDSHAKE_TIMEOUT_S
        self.last_message_at: float | None = None
        self.ending: str | None = None
        self.why = ""
        self.their_callerid = ""  # as their header says, taken or not

    def request(self) -> bytes:
        """The connection header we send first."""
        return encode_header({"callerid": self.callerid, "topic": self.topic, "type": self.mtype.name,
                              "md5sum": self.mtype.md5sum, "message_definition": self.mtype.definition,
                              "tcp_nodelay": "1"})

    @property
    def publisher(self) -> str:
        """The publisher as a line names it: its URI, and its caller id once its header said it."""
        callerid = self.their_callerid
        return "publisher %s%s" % (self.publisher_uri, " (%s)" % callerid if callerid else "")

    def receive(self, data: bytes, now: float) -> list[tuple[str, Any]]:
        """What `data` brings, in order: ("header", dict), ("message", payload), or ("failed", why), after
        which nothing more is read."""
        out: list[tuple[str, Any]] = []
        view = memoryview(data)
        pos = 0
        while pos < len(view) and self.phase != FAILED:
            buf = self.get_buffer()
            n = min(len(buf), len(view) - pos)
            buf[:n] = view[pos:pos + n]
            pos += n
            out += self.received(n, now)
        return out

    def get_buffer(self) -> memoryview:
        """Where the next bytes from the socket go (see FrameReader)."""
        return self.reader.get_buffer()

    def received(self, n: int, now: float) -> list[tuple[str, Any]]:
        """What `n` more bytes in get_buffer() bring: as `receive`."""
        if self.phase == FAILED:
            return []
        self.bytes_received += n
        try:
            frames = self.reader.received(n)
        except TcprosError as exc:
            return [self._failed(BROKEN, "%s" % exc)]
        out: list[tuple[str, Any]] = []
        for payload in frames:
            if self.phase == HEADER:
                out.append(self._header(payload))
                if self.phase == FAILED:
                    break
            else:
                self.messages_received += 1
                self.last_message_at = now
                out.append(("message", payload))
        if self.reader.failure is not None and self.phase != FAILED:
            out.append(self._failed(BROKEN, "%s" % self.reader.failure))
        return out

    def expire(self, now: float) -> list[tuple[str, Any]]:
        """The clock reached `now`: ("failed", why) if the header is overdue (see HANDSHAKE_TIMEOUT_S)."""
        if self.phase != HEADER or now < self.deadline:
            return []
        return [self._failed(BROKEN, "sent no whole connection header in %g s (%d bytes came)" % (
            HANDSHAKE_TIMEOUT_S, self.bytes_received))]

    def lost(self, now: float) -> str:
        """The publisher closed the connection (or it broke): how it ended, and `why` says what was cut."""
        if self.phase != FAILED:
            cut = self.reader.partial()
            if self.phase == HEADER:
                self._failed(BROKEN, "closed the connection in the middle of a frame (its connection header: %s)"
                             % cut if cut else "closed the connection before sending a connection header")
            elif cut:
                self._failed(BROKEN, "closed the connection in the middle of a frame (%s)" % cut)
            else:
                self._failed(ENDED, "closed the connection")
        return self.ending or ENDED

    def close(self) -> None:
        """We close the connection ourselves."""
        if self.phase != FAILED:
            self._failed(CLOSED, "closed by us")

    def _header(self, payload: bytes) -> tuple[str, Any]:
        try:
            header = decode_header(payload)
        except TcprosError as exc:
            return self._failed(BROKEN, "%s" % exc)
        self.their_callerid = header.get("callerid", "")[:200]
        if "error" in header:
            return self._failed(REFUSED, "refused the connection: %s" % header["error"])
        for required in ("type", "md5sum"):
            if required not in header:
                return self._failed(REFUSED, "sent a connection header without '%s'" % required)
        theirs, kind = header["md5sum"], header["type"]
        if theirs != ANY_MD5 and not _MD5.fullmatch(theirs) or kind != "*" and not _TYPE.fullmatch(kind):
            return self._failed(REFUSED, "sent type %r, md5sum %r: not a message type and its md5sum" % (
                kind[:80], theirs[:80]))
        if self.mtype.md5sum != ANY_MD5 and theirs not in (self.mtype.md5sum, ANY_MD5):
            return self._failed(REFUSED, "sends %s [%s], we expect %s [%s]" % (
                kind, theirs, self.mtype.name, self.mtype.md5sum))
        self.header = header
        self.phase = MESSAGES
        return ("header", header)

    def _failed(self, ending: str, what: str) -> tuple[str, Any]:
        self.phase = FAILED
        self.ending = ending
        self.why = "%s on %s: %s" % (self.publisher, self.topic, what)
        return ("failed", self.why)


# PublisherRetry's delays: the first, doubled at each broken connection in a row up to the last (rospy
# doubles from 1 s to 32 s, roscpp from 0.1 s to 20 s).
RETRY_FIRST_S = 1.0
RETRY_MAX_S = 30.0


class PublisherRetry:
    """When to connect again to one publisher of a topic once a connection to it ended (pure: how it ended
    and a clock in, a time out; `delay` is its state).

    | ended    | next attempt                                    | delay after        |
    |----------|-------------------------------------------------|--------------------|
    | REFUSED  | none until the publisher is listed again        | unchanged          |
    | BROKEN   | after the delay, doubled (the first: 1 s)       | min(2 * delay, 30) |
    | ENDED    | after RETRY_FIRST_S                             | RETRY_FIRST_S      |
    | CLOSED   | none (ours)                                     | unchanged          |

    A connection that lived RETRY_MAX_S or more before it broke starts the doubling over."""

    def __init__(self) -> None:
        self.delay = 0.0        # the last delay waited (0: none yet)
        self.refused = False    # waiting for the publisher to be listed again

    def ended(self, how: str, opened_at: float, now: float) -> float | None:
        """The time of the next attempt after a connection opened at `opened_at` ended `how` (None: none)."""
        if how == CLOSED:
            return None
        if how == REFUSED:
            self.refused = True
            return None
        if how == ENDED or now - opened_at >= RETRY_MAX_S:
            self.delay = 0.0
        self.delay = min(2 * self.delay, RETRY_MAX_S) if how == BROKEN and self.delay else RETRY_FIRST_S
        return now + self.delay

    def listed(self) -> bool:
        """The master lists the publisher again (a publisherUpdate): True if it refused and is to be tried now."""
        was, self.refused = self.refused, False
        return was


class InboundState:
    """A connection a peer opened to our TCPROS server, before it is a subscriber or a service client: its
    header decides which (or a refusal). `offer(header)` answers with ("subscriber", publication, reply
    header), ("service", service, reply header, probe), or ("refuse", why); the lookups are the caller's."""

    def __init__(self, callerid: str, publications: Mapping[str, Any], services: Mapping[str, Any]):
        self.callerid = callerid
        self.publications = publications
        self.services = services

    def offer(self, header: dict[str, str]) -> tuple:
        if "service" in header:
            return self._service(header)
        for required in ("topic", "md5sum", "callerid"):
            if required not in header:
                return ("refuse", "Missing required '%s' field" % required)
        pub = self.publications.get(header["topic"])
        if pub is None:
            return ("refuse", "[%s] is not a publisher of [%s]. Topics are %s" % (
                self.callerid, header["topic"], [[p.topic, p.mtype.name] for p in self.publications.values()]))
        md5 = header["md5sum"]
        if md5 != ANY_MD5 and md5 != pub.mtype.md5sum:
            wanted = header.get("type", pub.mtype.name)
            if wanted != pub.mtype.name:
                return ("refuse", "topic types do not match: [%s] vs. [%s]" % (wanted, pub.mtype.name))
            return ("refuse", "Client [%s] wants topic [%s] to have datatype/md5sum [%s/%s], but our version has "
                    "[%s/%s]. Dropping connection." % (header["callerid"], pub.topic, wanted, md5, pub.mtype.name,
                                                       pub.mtype.md5sum))
        return ("subscriber", pub, {"callerid": pub.callerid, "md5sum": pub.mtype.md5sum,
                                    "message_definition": pub.mtype.definition,
                                    "latching": "1" if pub.latch else "0", "topic": pub.topic,
                                    "type": pub.mtype.name})

    def _service(self, header: dict[str, str]) -> tuple:
        srv = self.services.get(header["service"])
        if srv is None:
            return ("refuse", "request from [%s]: service [%s] is not provided by this node" % (
                header.get("callerid", "?"), header["service"]))
        md5 = header.get("md5sum", "")
        if md5 not in (ANY_MD5, srv.md5sum):
            return ("refuse", "request from [%s]: md5sums do not match: [%s] vs. [%s]" % (
                header.get("callerid", "?"), md5, srv.md5sum))
        return ("service", srv, {"callerid": srv.callerid, "md5sum": srv.md5sum, "request_type": srv.request_type,
                                 "response_type": srv.response_type, "type": srv.type_name},
                header.get("probe") == "1")


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
        self.id = _new_connection_id()
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
    await asyncio.wait_for(loop.create_connection(lambda: link, host, port), timeout)
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


# A watcher's socket wakes the loop only once this many bytes wait (SO_RCVLOWAT): a busy topic is read in
# gulps, a quiet one when its watch drains it (`CountingLink.drain`, at each verdict).
WATCH_LOWAT = 64 << 10
WATCH_CHUNK = 256 << 10


class CountingLink:
    """A subscriber's connection that only counts the publisher's messages (`on_messages(n)`), reading
    into one buffer of its own: no bytes kept, no object per message, few wake-ups (see WATCH_LOWAT).
    Once it is closed, `ending` and `why` say how (as PublisherLinkState's)."""

    def __init__(self, sock: socket.socket, counter: FrameCounter, on_messages: Callable[[int], None],
                 state: PublisherLinkState | None = None, on_close: Callable[[CountingLink], None] | None = None):
        self.loop = asyncio.get_running_loop()
        self.sock = sock
        self.counter = counter
        self.on_messages = on_messages
        self.state = state
        self.on_close = on_close
        self.closed = False
        self.ending: str | None = None
        self.why = ""
        self._buf = bytearray(WATCH_CHUNK)
        self._view = memoryview(self._buf)
        self.loop.add_reader(sock.fileno(), self.drain)

    def drain(self) -> None:
        """Count what the socket holds now (the loop calls this when WATCH_LOWAT bytes wait; a watch at
        each verdict, for a quiet topic's last few messages)."""
        if self.closed:
            return
        done = 0
        try:
            while True:
                got = self.sock.recv_into(self._buf)
                if not got:  # the publisher closed it
                    cut = self.counter.partial()
                    self._close(BROKEN if cut else ENDED, "closed the connection in the middle of a frame (%s)" % cut
                                if cut else "closed the connection")
                    break
                done += self.counter.feed(self._view[:got])
                if got < WATCH_CHUNK:
                    break
        except (BlockingIOError, InterruptedError):
            pass
        except (OSError, TcprosError) as exc:
            self._close(BROKEN, str(exc))
        if done:
            self.on_messages(done)

    def _close(self, ending: str, what: str) -> None:
        if not self.closed:
            who = self.state.publisher + " on " + self.state.topic if self.state is not None else str(self.sock)
            self.ending, self.why = ending, "%s: %s" % (who, what)
            self._release()
            if self.on_close is not None:
                self.on_close(self)

    def close(self) -> None:
        self._close(CLOSED, "closed by us")

    def _release(self) -> None:
        self.closed = True
        self.loop.remove_reader(self.sock.fileno())
        self.sock.close()


async def watch_publisher(host: str, port: int, topic: str, callerid: str, publisher_uri: str,
                          on_messages: Callable[[int], None], *, timeout: float = 10.0,
                          on_close: Callable[[CountingLink], None] | None = None) -> CountingLink:
    """A CountingLink to a publisher's TCPROS server, any type, once its header has come: the connection within
    `timeout`, the header by HANDSHAKE_TIMEOUT_S; TcprosError(why, ending) if the publisher failed it."""
    loop = asyncio.get_running_loop()
    state = PublisherLinkState(topic, TopicType("*", ANY_MD5, ""), callerid, publisher_uri, loop.time())
    family, kind, proto, _, addr = (await loop.getaddrinfo(host, port, type=socket.SOCK_STREAM))[0]
    sock = socket.socket(family, kind, proto)
    try:
        sock.setblocking(False)
        await asyncio.wait_for(loop.sock_connect(sock, addr), timeout)
        state.deadline = loop.time() + HANDSHAKE_TIMEOUT_S
        await asyncio.wait_for(loop.sock_sendall(sock, state.request()), HANDSHAKE_TIMEOUT_S)
        early = 0  # messages that came with the header
        while state.phase == HEADER:
            try:
                data = await asyncio.wait_for(loop.sock_recv(sock, 65536), max(0.0, state.deadline - loop.time()))
            except asyncio.TimeoutError:
                data, events = None, state.expire(max(loop.time(), state.deadline))
            except OSError:
                data, events = b"", []
            if data is not None:
                events = state.receive(data, loop.time()) if data else []
                if not data:
                    state.lost(loop.time())
            if state.phase == FAILED:
                raise TcprosError(state.why, state.ending or BROKEN)
            early += sum(what == "message" for what, _ in events)
        counter = FrameCounter()
        early += counter.feed(state.reader.take_pending())
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVLOWAT, WATCH_LOWAT)
    except BaseException:
        sock.close()
        raise
    link = CountingLink(sock, counter, on_messages, state, on_close)
    if early:
        on_messages(early)
    return link


@dataclass
class Publication:
    """A topic we publish, and the subscribers connected to it."""

    topic: str
    mtype: TopicType
    callerid: str
    latch: bool = False
    # roscpp's publisher queue: messages per subscriber waiting for its socket, the oldest dropped past it
    # (0: unbounded); None: no queue of ours, a subscriber MAX_WRITE_BACKLOG bytes behind loses new messages
    queue_size: int | None = None
    links: list[SubscriberLink] = field(default_factory=list)
    messages_published: int = 0
    last: bytes | None = None

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


@dataclass
class ServiceServer:
    """A service we serve: `handler(request_bytes) -> response_bytes`, raising to report failure."""

    name: str
    type_name: str
    md5sum: str
    request_type: str
    response_type: str
    callerid: str
    handler: Callable[[bytes], bytes]


class InboundConnection(asyncio.Protocol):
    """A connection a peer opened to our TCPROS server: a subscriber or a service client."""

    def __init__(self, server: TcprosServer):
        self.server = server
        self.id = _new_connection_id()
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
        try:
            reply = encode_service_response(True, self.service.handler(request))
        except Exception as exc:  # the service failed: the client gets the reason, we carry on
            reply = encode_service_response(False, str(exc).encode("utf-8"))
        self.transport.write(reply)
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


class SubscriberLink:
    """One subscriber connected to one of our publications. With a queue size, frames wait in `outbox` while the
    connection's writing is paused (as in roscpp's publisher queue: the oldest dropped when it is full)."""

    __slots__ = ("conn", "callerid", "queue_size", "outbox")

    def __init__(self, conn: InboundConnection, callerid: str, queue_size: int | None = None):
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
