"""TCPROS on the wire, sans I/O: connection headers, length-prefixed frames (`FrameDecoder`, `FrameCounter`,
`FrameReader`: a subscriber's socket read in place), a service's reply, the one frame limit, and `TopicType`, what
both ends of a topic connection agree on. Functions of bytes: no socket, no loop, no clock."""

from __future__ import annotations

import struct
from collections.abc import Mapping
from typing import NamedTuple

_LEN = struct.Struct("<I")

# The one limit of a frame's length, a connection header's and a message's alike, on every reader here (a
# subscriber's link, a watch, our publications' and services' clients): roscpp's, which takes a length over
# 10^9 bytes for lost framing (connection.cpp, transport_publisher_link.cpp). Large on purpose: a dense point
# cloud is tens of MB. A length is not trusted for memory: a frame costs what has come of it (FrameReader).
MAX_FRAME_SIZE = 1_000_000_000

# Any message type accepted (rospy's AnyMsg, rostopic before it knows the type).
ANY_MD5 = "*"


class TcprosError(Exception):
    """A peer broke the TCPROS protocol (bad header, absurd length, refused handshake); `ending`, where a link
    raises it: how its connection ended (see PublisherRetry)."""

    def __init__(self, why: str, ending: str = "broken"):
        super().__init__(why)
        self.ending = ending


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


class ScratchPool:
    """Scratch buffers of one size, lent for a read and given back once it is over: a buffer is in use only
    while a read fills it and its frames are cut from it, and the reads of one thread come one at a time
    (asyncio's get_buffer, recv_into, buffer_updated), so a few buffers serve any number of connections: a
    hundred nodes' /rosout links at rest hold none (a 64 KiB buffer each held 6.4 MB). One taken while all are
    out is made; one given back beyond `kept` is let go."""

    __slots__ = ("size", "kept", "_free")

    def __init__(self, size: int, kept: int = 2):
        self.size = size
        self.kept = kept
        self._free: list[bytearray] = []

    def take(self) -> bytearray:
        try:
            return self._free.pop()  # (a pop, not a test then a pop: another thread's loop may share the pool)
        except IndexError:
            return bytearray(self.size)

    def give(self, buf: bytearray) -> None:
        if len(self._free) < self.kept:
            self._free.append(buf)

    @property
    def free(self) -> int:
        """Buffers waiting to be lent."""
        return len(self._free)


class FrameReader:
    """Frames read in place, for asyncio's BufferedProtocol: the socket is read into `get_buffer()`, then
    `received(n)` says how much came. A frame larger than the scratch buffer is read straight into a
    bytearray of its own (grown as its bytes come: see TRUST_FACTOR), which is handed on as the frame (the
    kernel's copy: megabyte messages are not copied again); smaller frames are cut from the scratch buffer as
    bytes. The scratch buffer is the pool's (ScratchPool, by default the one all readers share), borrowed
    by get_buffer() and given back by received() as soon as it holds nothing of a frame: a reader between
    two frames holds no buffer; one in the middle of a small frame keeps its scratch buffer until the frame
    is whole."""

    __slots__ = ("limit", "failure", "pool", "_scratch", "_view", "_fill", "_body", "_size", "_got")

    SCRATCH = 64 * 1024

    def __init__(self, limit: int = MAX_FRAME_SIZE, pool: ScratchPool | None = None):
        self.limit = limit
        self.failure: TcprosError | None = None
        self.pool = SCRATCH_POOL if pool is None else pool
        self._scratch: bytearray | None = None  # the borrowed scratch buffer (None: none borrowed)
        self._view: memoryview | None = None
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
        view = self._view
        if view is None:
            self._scratch = self.pool.take()
            self._view = view = memoryview(self._scratch)
        return view[self._fill:]

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
        buf, view, pos, fill = self._scratch, self._view, 0, self._fill
        assert buf is not None and view is not None, "received() without get_buffer()"
        while fill - pos >= 4:
            (size,) = _LEN.unpack_from(buf, pos)
            if size > self.limit:
                self.failure = TcprosError("frame of %d bytes exceeds the %d byte limit" % (size, self.limit))
                if not frames:
                    raise self.failure
                return frames  # (those before it are whole and theirs: handed on, then `failure`)
            if fill - pos - 4 >= size:
                frames.append(bytes(view[pos + 4:pos + 4 + size]))
                pos += 4 + size
            elif size > self.SCRATCH - 4:
                # too big for the scratch buffer: the rest of it is read into a buffer of its own
                self._got = fill - pos - 4
                self._size = size
                self._body = bytearray(min(size, max(FIRST_BODY, self._got)))
                self._body[:self._got] = view[pos + 4:fill]
                pos = fill
                break
            else:
                break
        if pos:
            rest = fill - pos
            buf[:rest] = buf[pos:fill]  # (the start of a frame still coming: at most a scratch buffer)
            self._fill = rest
        if not self._fill:
            self._give_back()
        return frames

    def _give_back(self) -> None:
        """The scratch buffer holds nothing of a frame: back to the pool."""
        buf, self._scratch, self._view = self._scratch, None, None
        if buf is not None:
            self.pool.give(buf)

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
            (size,) = _LEN.unpack_from(self._scratch, 0)  # type: ignore[arg-type]  # (held while _fill)
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
            rest = bytes(self._view[:self._fill]) if self._view is not None else b""
        self._fill = 0
        self._give_back()
        return rest


# The scratch buffers every FrameReader borrows unless it is given a pool of its own.
SCRATCH_POOL = ScratchPool(FrameReader.SCRATCH)


def encode_service_response(ok: bool, payload: bytes) -> bytes:
    """A service reply: one ok byte, then the response (or the error text) framed."""
    return (b"\x01" if ok else b"\x00") + encode_frame(payload)


class TopicType(NamedTuple):
    """What both ends of a topic connection must agree on."""

    name: str        # e.g. rosgraph_msgs/Log
    md5sum: str
    definition: str
