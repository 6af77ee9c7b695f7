"""HTTP/1.1 framing for XML-RPC, sans I/O: bytes in, events out, no socket and no clock.

`RequestReader` is the server's side of one connection (requests in), and
`ResponseReader` the client's side of one call (a response in); both follow
h11's shape: `receive_data(bytes)` (b"" for end of stream), then
`next_event()` until it answers `NEED_DATA`. Framing errors raise `HttpError`
carrying the status a server answers with. Only what XML-RPC needs is spoken:
POST with a Content-Length (no chunked bodies; rospy, roscpp and rosjava never
send them), keep-alive, pipelining, `Expect: 100-continue`; a server that asks
(`RequestLimits(methods=..., fields=True)`: the live view's page server) also
gets GET requests, their query and their header fields. Time-outs and
socket handling belong to the callers (`launcher.net.xmlrpc_server` and the
clients in `launcher.net.xmlrpc`); this module imports no asyncio.
"""

from __future__ import annotations

from typing import NamedTuple

__all__ = [
    "NEED_DATA", "CONTINUE", "HttpError", "Request", "Response", "RequestLimits", "RequestReader",
    "ResponseReader", "format_request", "format_response",
]


class _Sentinel:
    def __init__(self, name: str):
        self.name = name

    def __repr__(self) -> str:
        return self.name


NEED_DATA = _Sentinel("NEED_DATA")  # no complete event yet: feed more bytes
CONTINUE = _Sentinel("CONTINUE")  # the client waits for "100 Continue" before it sends its body


class HttpError(ValueError):
    """Bad HTTP framing; `status`/`reason` are what a server answers with."""

    def __init__(self, status: int, reason: str):
        super().__init__(status, reason)
        self.status = status
        self.reason = reason

    def __str__(self) -> str:
        return "%d %s" % (self.status, self.reason)


class Request(NamedTuple):
    target: bytes  # the path, without query, also for an absolute-form target
    body: bytes
    keep_alive: bool
    method: bytes = b"POST"
    query: bytes = b""  # what follows the target's "?"
    fields: tuple = ()  # ((lower-case name, value), ...) when the limits keep them, in the order sent

    def field(self, name: bytes) -> bytes | None:
        """The value of header field `name` (lower case), the first if it was sent twice; None if absent."""
        for key, value in self.fields:
            if key == name:
                return value
        return None


class Response(NamedTuple):
    status: int
    body: bytes


class _Head(NamedTuple):
    target: bytes
    length: int
    keep_alive: bool
    expect_continue: bool
    method: bytes = b"POST"
    query: bytes = b""
    fields: tuple = ()


class RequestLimits:
    """The bounds of one server's requests, and the heads it has already parsed.

    Clients repeat the same few heads (only Content-Length moves), so each
    distinct head is parsed once per server (the cache holds `cache` of them;
    0: none, for a server whose clients' heads all differ). `methods` are the
    request methods served (others: 501); only POST must say its length.
    `fields`: each request keeps its header fields (`Request.fields`).
    """

    def __init__(self, max_body_size: int = 64 * 1024 * 1024, max_header_size: int = 16 * 1024,
                 max_header_count: int = 100, *, methods: tuple = (b"POST",), fields: bool = False,
                 cache: int = 1024):
        self.max_body_size = max_body_size
        self.max_header_size = max_header_size
        self.max_header_count = max_header_count
        self.methods = methods
        self.fields = fields
        self.cache = cache
        self.heads: dict[bytes, _Head] = {}


def _header_values(low_head: bytes, marker: bytes) -> list[bytes]:
    """Stripped values of every header line starting with `marker` (b"\\r\\nname:")."""
    out = []
    i = low_head.find(marker)
    while i >= 0:
        start = i + len(marker)
        end = low_head.find(b"\r\n", start)
        out.append(low_head[start:end if end >= 0 else len(low_head)].strip())
        i = low_head.find(marker, start)
    return out


def _parse_request_head(head: bytes, limits: RequestLimits) -> _Head:
    low = head.lower()  # header names are case-insensitive; only these few matter here
    nl = low.find(b"\r\n")
    request_line = (head if nl < 0 else head[:nl]).split()
    if len(request_line) != 3 or not request_line[2].startswith(b"HTTP/1."):
        raise HttpError(400, "Bad Request")
    method, target, version = request_line
    if low.count(b"\r\n") > limits.max_header_count:
        raise HttpError(431, "Request Header Fields Too Large")
    if method not in limits.methods:
        raise HttpError(501, "Unsupported method (%s)" % method.decode("latin-1")[:16])
    if b"\r\ntransfer-encoding:" in low:
        raise HttpError(501, "Transfer-Encoding not supported")
    values = _header_values(low, b"\r\ncontent-length:")
    if not values:
        if method == b"POST":
            raise HttpError(411, "Length Required")
        values = [b"0"]  # (a GET has no body unless it says so)
    try:
        lengths = {int(v) for v in values}
    except ValueError:
        raise HttpError(400, "Bad Request") from None
    if len(lengths) != 1:  # differing lengths: a request smuggling attempt or a broken client
        raise HttpError(400, "Bad Request")
    length = lengths.pop()
    if length < 0:
        raise HttpError(400, "Bad Request")
    if length > limits.max_body_size:
        raise HttpError(413, "Request Entity Too Large")
    keep_alive = version == b"HTTP/1.1"
    for v in _header_values(low, b"\r\nconnection:"):
        if b"close" in v:
            keep_alive = False
        elif b"keep-alive" in v:
            keep_alive = True
    expect_continue = b"100-continue" in _header_values(low, b"\r\nexpect:")
    query = b""
    if b"?" in target:
        target, query = target.split(b"?", 1)
    if target.startswith(b"http://"):  # absolute-form request target
        target = b"/" + target[7:].partition(b"/")[2]
    if not limits.fields:
        return _Head(target, length, keep_alive, expect_continue, method, query)
    fields = []
    for line in head.split(b"\r\n")[1:]:
        name, colon, value = line.partition(b":")
        if not colon or not name or name != name.strip():  # (no space before the colon: RFC 9112 5.1)
            raise HttpError(400, "Bad Request")
        fields.append((name.lower(), value.strip()))
    return _Head(target, length, keep_alive, expect_continue, method, query, tuple(fields))


class RequestReader:
    """The requests of one server connection, in order (pipelined ones included).

    `next_event()` answers a `Request`, `CONTINUE` (once per request that asks
    for it, before its body), or `NEED_DATA`; it raises `HttpError` for a
    request that cannot be framed, after which the connection must be closed.
    """

    def __init__(self, limits: RequestLimits):
        self.limits = limits
        self._buf = bytearray()
        self._head: _Head | None = None  # the head of the request whose body is awaited
        self._body_start = 0
        self._continue_given = False

    @property
    def buffered(self) -> int:
        """Bytes received and not yet returned in a Request."""
        return len(self._buf)

    @property
    def head_pending(self) -> bool:
        """Part of a request head has arrived, not all of it."""
        return bool(self._buf) and self._head is None

    def receive_data(self, data: bytes) -> None:
        """Bytes from the client (raises HttpError 413 when more is buffered than a request may be)."""
        self._buf += data
        if len(self._buf) > self.limits.max_body_size + self.limits.max_header_size:
            # only reached when the caller stops asking for events (a reply is pending) and the
            # client keeps pipelining: the caller should have paused reading long before
            raise HttpError(413, "Request Entity Too Large")

    def next_event(self) -> Request | _Sentinel:
        buf = self._buf
        head = self._head
        if head is None:
            if not buf:
                return NEED_DATA
            end = buf.find(b"\r\n\r\n")
            limits = self.limits
            if end < 0:
                if len(buf) > limits.max_header_size:
                    raise HttpError(431, "Request Header Fields Too Large")
                return NEED_DATA
            if end > limits.max_header_size:
                raise HttpError(431, "Request Header Fields Too Large")
            raw = bytes(buf[:end])
            head = limits.heads.get(raw)
            if head is None:
                head = _parse_request_head(raw, limits)
                if limits.cache:
                    if len(limits.heads) >= limits.cache:
                        limits.heads.clear()
                    limits.heads[raw] = head
            self._head = head
            self._body_start = end + 4
            self._continue_given = False
        body_end = self._body_start + head.length
        if len(buf) < body_end:
            if head.expect_continue and not self._continue_given and len(buf) == self._body_start:
                self._continue_given = True
                return CONTINUE
            return NEED_DATA
        body = bytes(buf[self._body_start:body_end])
        del buf[:body_end]
        self._head = None
        return Request(head.target, body, head.keep_alive, head.method, head.query, head.fields)


class ResponseReader:
    """The response to one client call: interim 1xx responses skipped, the body framed by
    Content-Length or by the end of the stream, everything bounded."""

    def __init__(self, max_body_size: int = 64 * 1024 * 1024, max_header_size: int = 64 * 1024,
                 max_header_count: int = 200):
        self.max_body_size = max_body_size
        self.max_header_size = max_header_size
        self.max_header_count = max_header_count
        self._buf = bytearray()
        self._eof = False
        self._status = 0
        self._length: int | None = None  # None: the body ends with the stream
        self._body_start = -1  # where the body begins in the buffer; -1 while in the head

    def receive_data(self, data: bytes) -> None:
        """Bytes from the server; b"" when it has closed the connection."""
        if not data:
            self._eof = True
        else:
            self._buf += data

    def next_event(self) -> Response | _Sentinel:
        while self._body_start < 0:
            if not self._read_head():
                return NEED_DATA
        buf = self._buf
        body_len = len(buf) - self._body_start
        if self._length is not None:
            if body_len >= self._length:
                return Response(self._status, bytes(buf[self._body_start:self._body_start + self._length]))
            if self._eof:
                raise HttpError(502, "connection closed before the reply was complete")
            return NEED_DATA
        if body_len > self.max_body_size:
            raise HttpError(502, "reply is too large")
        if self._eof:
            return Response(self._status, bytes(buf[self._body_start:]))
        return NEED_DATA

    def _read_head(self) -> bool:
        """Parse one response head if it is complete (a 1xx one is dropped); False if more is needed."""
        buf = self._buf
        end = buf.find(b"\r\n\r\n")
        if end < 0 or end > self.max_header_size:
            if len(buf) > self.max_header_size:
                raise HttpError(502, "reply header is too large")
            if self._eof:
                raise HttpError(502, "connection closed before the reply was complete" if buf
                                else "connection closed without a reply")
            return False
        lines = bytes(buf[:end]).split(b"\r\n")
        if len(lines) > self.max_header_count:
            raise HttpError(502, "reply has too many header lines")
        parts = lines[0].split(None, 2)
        if len(parts) < 2 or not parts[0].startswith(b"HTTP/1.") or not parts[1].isdigit():
            raise HttpError(502, "not an HTTP response")
        status = int(parts[1])
        if 100 <= status < 200:  # "100 Continue" and the like: the real response follows
            del buf[:end + 4]
            return True
        length: int | None = None
        for line in lines[1:]:
            name, _, value = line.partition(b":")
            name = name.strip().lower()
            if name == b"content-length":
                value = value.strip()
                if not value.isdigit() or (length is not None and int(value) != length):
                    raise HttpError(502, "bad Content-Length in the reply")
                length = int(value)
                if length > self.max_body_size:
                    raise HttpError(502, "reply is too large (%d bytes)" % length)
            elif name == b"transfer-encoding" and value.strip().lower() != b"identity":
                raise HttpError(502, "Transfer-Encoding %s is not supported"
                                % value.strip().decode("latin-1")[:32])
        self._status = status
        self._length = length
        self._body_start = end + 4
        return True


def format_request(target: str, host: str, body: bytes) -> bytes:
    """A POST of `body` (text/xml), closing the connection after the reply (one call per connection)."""
    return b"".join((
        ("POST %s HTTP/1.1\r\nHost: %s\r\nContent-Type: text/xml\r\nUser-Agent: launcher-xmlrpc\r\n"
         "Content-Length: %d\r\nConnection: close\r\n\r\n" % (target, host, len(body))).encode("latin-1"),
        body,
    ))


_OK_HEAD = b"HTTP/1.1 200 OK\r\nServer: launcher-xmlrpc\r\nContent-Type: text/xml\r\nContent-Length: "


def format_response(status: int, reason: str, body: bytes, keep_alive: bool,
                    content_type: bytes = b"text/xml") -> bytes:
    """A whole response; `Connection: close` when the connection ends after it."""
    if status == 200 and keep_alive and content_type == b"text/xml":
        return b"".join((_OK_HEAD, b"%d" % len(body), b"\r\n\r\n", body))  # the common reply
    return b"".join((
        b"HTTP/1.1 %d %s\r\nServer: launcher-xmlrpc\r\nContent-Type: %s\r\nContent-Length: %d\r\n"
        % (status, reason.encode("ascii", "replace"), content_type, len(body)),
        b"" if keep_alive else b"Connection: close\r\n",
        b"\r\n", body,
    ))


class Uri(NamedTuple):
    """The parts of a URI a client and a master need, as `urllib.parse.urlsplit` reads them."""

    scheme: str
    netloc: str
    hostname: str | None  # lower case, an IPv6 address without its brackets
    port: int | None
    path: str


_SCHEME_CHARS = frozenset("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789+-.")


def split_uri(uri: str) -> Uri:
    """`uri`'s parts as `urllib.parse.urlsplit(uri)` gives them; ValueError where reading its port does (not a
    number, out of range) or its brackets do not match. (Not urllib.parse itself: with ipaddress, which it imports
    since 3.11.4, it is ~0.4 MB of a launch's memory, for the host and port of a few URIs.)"""
    uri = uri.lstrip("".join(map(chr, range(33)))).replace("\t", "").replace("\r", "").replace("\n", "")
    scheme = ""
    head, colon, rest = uri.partition(":")
    if colon and head and head[0].isascii() and head[0].isalpha() and all(c in _SCHEME_CHARS for c in head):
        scheme, uri = head.lower(), rest
    netloc = ""
    if uri[:2] == "//":
        end = len(uri)
        for c in "/?#":
            i = uri.find(c, 2)
            if i >= 0:
                end = min(end, i)
        netloc, uri = uri[2:end], uri[end:]
        if ("[" in netloc) != ("]" in netloc):
            raise ValueError("Invalid IPv6 URL")
    path = uri.partition("#")[0].partition("?")[0]
    host_port = netloc.rpartition("@")[2]
    _, bracket, bracketed = host_port.partition("[")
    if bracket:
        host, _, after = bracketed.partition("]")
        port_text = after.partition(":")[2]
    else:
        host, _, port_text = host_port.partition(":")
    port = None
    if port_text:
        if not (port_text.isdigit() and port_text.isascii()):
            raise ValueError("Port could not be cast to integer value as %r" % port_text)
        port = int(port_text)
        if not 0 <= port <= 65535:
            raise ValueError("Port out of range 0-65535")
    host, percent, zone = host.partition("%")  # (an IPv6 address's zone keeps its case)
    return Uri(scheme, netloc, host.lower() + percent + zone if host or percent else None, port, path)
