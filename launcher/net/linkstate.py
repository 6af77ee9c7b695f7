"""The states of TCPROS connections, pure (fed bytes, a header and a clock; no socket, no loop): our end, as a
subscriber, of a connection to a publisher (`PublisherLinkState`: its handshake, its frames, how it ended), when
that publisher is tried again (`PublisherRetry`), and what a connection a peer opened to our server is
(`InboundState`: a subscriber of a publication, a service's client, or refused)."""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any

from launcher.net.tcpros import ANY_MD5, FrameReader, TcprosError, TopicType, decode_header, encode_header

# A publisher's connection header is due this long after we connect (roscpp and rospy wait for ever; the
# master gives an HTTP request's head the same 10 s).
HANDSHAKE_TIMEOUT_S = 10.0

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
