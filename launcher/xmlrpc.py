"""XML-RPC for ROS 1: a hardened sans-I/O codec, an asyncio HTTP/1.1 server and a small client.

The codec turns bytes into values and back without touching a socket. Parsing
goes through expat with every DTD refused, so no entity can be declared: no
XXE, no entity expansion ("billion laughs"); nesting depth is bounded. The
server speaks HTTP/1.1 with keep-alive on `/` and `/RPC2` (what rospy, roscpp's
XmlRpc++ and rosjava expect), bounds header and body sizes, times out slow
clients and answers every malformed call with a fault or an HTTP error.
"""

from __future__ import annotations

import asyncio
import base64
import datetime
import inspect
import re
import socket
import sys
import urllib.parse
from typing import Any, Awaitable, Callable, Iterable
from xml.parsers import expat

__all__ = [
    "Encoded", "encode_value", "Fault", "XmlRpcError", "loads_request", "loads_response", "dumps_request",
    "dumps_response", "dumps_fault", "XmlRpcServer", "call", "multicall",
]

MAXINT = 2**31 - 1
MININT = -(2**31)
MAX_DEPTH = 200  # nested arrays/structs; deeper values are refused when parsed
MAX_RESPONSE_SIZE = 64 * 1024 * 1024  # what `call` accepts from a server
LARGE_REQUEST = 256 * 1024  # request bodies above this are parsed off the event loop
MULTICALL_CHUNK = 500  # calls of a system.multicall run between two turns of the event loop


class Fault(Exception):
    """An XML-RPC fault: raised by dispatch functions and by `loads_response`/`call`."""

    def __init__(self, faultCode: int, faultString: str):  # noqa: N803 (XML-RPC's names)
        super().__init__(faultCode, faultString)
        self.faultCode = faultCode
        self.faultString = faultString

    def __repr__(self) -> str:
        return "<Fault %s: %r>" % (self.faultCode, self.faultString)


class XmlRpcError(ValueError):
    """Malformed XML-RPC (bad XML, unknown tag, bad value) or a bad HTTP exchange."""


# ---------------------------------------------------------------------------
# encoding
# ---------------------------------------------------------------------------

def _escape(s: str) -> str:
    if "&" in s or "<" in s or ">" in s:
        return s.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")
    return s


class Encoded(str):
    """A `<value>...</value>` fragment that is already encoded: sent verbatim.

    Lets a server cache the encoding of large, rarely changing replies
    (getSystemState, getParamNames) piece by piece.
    """

    __slots__ = ()


def encode_value(value: Any) -> Encoded:
    """`value` as an Encoded fragment (raises OverflowError/TypeError if it cannot be sent)."""
    out: list[str] = []
    _encode_value(value, out)
    return Encoded("".join(out))


def _enc_encoded(v: Encoded, out: list[str]) -> None:
    out.append(v)


def _enc_str(v: str, out: list[str]) -> None:
    if "&" in v or "<" in v or ">" in v:
        v = v.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")
    out.append("<value><string>" + v + "</string></value>")


def _enc_int(v: int, out: list[str]) -> None:
    if v > MAXINT or v < MININT:
        # what Python's xmlrpc (and so rosmaster) does: such a value cannot be sent
        raise OverflowError("int exceeds XML-RPC limits")
    out.append("<value><int>%d</int></value>" % v)


def _enc_bool(v: bool, out: list[str]) -> None:
    out.append("<value><boolean>1</boolean></value>" if v else "<value><boolean>0</boolean></value>")


def _enc_float(v: float, out: list[str]) -> None:
    out.append("<value><double>%r</double></value>" % v)


def _enc_bytes(v: bytes | bytearray, out: list[str]) -> None:
    out.append("<value><base64>%s</base64></value>" % base64.b64encode(v).decode("ascii"))


def _enc_binary(v: Any, out: list[str]) -> None:  # an xmlrpc.client.Binary
    _enc_bytes(v.data, out)


def _enc_datetime(v: Any, out: list[str]) -> None:  # an xmlrpc.client.DateTime
    out.append("<value><dateTime.iso8601>%s</dateTime.iso8601></value>" % v.value)


def _enc_pydatetime(v: datetime.datetime, out: list[str]) -> None:
    out.append("<value><dateTime.iso8601>%s</dateTime.iso8601></value>" % v.strftime("%Y%m%dT%H:%M:%S"))


def _enc_list(v: list | tuple, out: list[str]) -> None:
    append = out.append
    append("<value><array><data>")
    for item in v:
        t = type(item)
        if t is str:  # the common case inline: names, URIs, messages
            if "&" in item or "<" in item or ">" in item:
                item = item.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")
            append("<value><string>" + item + "</string></value>")
            continue
        enc = _ENCODERS.get(t)
        if enc is None:
            enc = _encoder_for(item)
        enc(item, out)
    append("</data></array></value>")


def _enc_dict(v: dict, out: list[str]) -> None:
    append = out.append
    append("<value><struct>")
    for key, item in v.items():
        if type(key) is not str:
            if isinstance(key, str):
                key = str(key)
            else:
                raise TypeError("dictionary key must be string")
        if "&" in key or "<" in key or ">" in key:
            key = _escape(key)
        append("<member><name>" + key + "</name>")
        enc = _ENCODERS.get(type(item))
        if enc is None:
            enc = _encoder_for(item)
        enc(item, out)
        append("</member>")
    append("</struct></value>")


def _enc_none(v: None, out: list[str]) -> None:
    # rosmaster's marshaller has allow_none off: a None cannot be sent
    raise TypeError("cannot marshal None unless allow_none is enabled")


_ENCODERS: dict[type, Callable[[Any, list[str]], None]] = {
    str: _enc_str, int: _enc_int, bool: _enc_bool, float: _enc_float,
    bytes: _enc_bytes, bytearray: _enc_bytes, datetime.datetime: _enc_pydatetime,
    list: _enc_list, tuple: _enc_list, dict: _enc_dict, type(None): _enc_none,
    Encoded: _enc_encoded,
}


def _encoder_for(value: Any) -> Callable[[Any, list[str]], None]:
    """Encoder for subclasses (an IntEnum, an OrderedDict, ...), by the first matching base."""
    for base in type(value).__mro__:
        enc = _ENCODERS.get(base)
        if enc is not None:
            return enc
    # xmlrpc.client's Binary and DateTime: that module (http.client, email, ...) is not imported
    # at every launch's start for them; a value of its types means the caller has loaded it.
    client = sys.modules.get("xmlrpc.client")
    if client is not None and client.Binary not in _ENCODERS:
        _ENCODERS[client.Binary] = _enc_binary
        _ENCODERS[client.DateTime] = _enc_datetime
        return _encoder_for(value)
    raise TypeError("cannot marshal %s objects" % type(value))


def _encode_value(value: Any, out: list[str]) -> None:
    enc = _ENCODERS.get(type(value))
    if enc is None:
        enc = _encoder_for(value)
    enc(value, out)


_RESPONSE_HEAD = "<?xml version='1.0'?>\n<methodResponse>\n<params>\n<param>\n"
_RESPONSE_TAIL = "\n</param>\n</params>\n</methodResponse>\n"


def dumps_response(value: Any) -> bytes:
    """The body of a methodResponse carrying `value` (raises OverflowError/TypeError if unsendable)."""
    out = [_RESPONSE_HEAD]
    _encode_value(value, out)
    out.append(_RESPONSE_TAIL)
    return "".join(out).encode("utf-8", "xmlcharrefreplace")


def dumps_fault(code: int, message: str) -> bytes:
    """The body of a methodResponse carrying a fault."""
    return ("<?xml version='1.0'?>\n<methodResponse>\n<fault>\n<value><struct>"
            "<member><name>faultCode</name><value><int>%d</int></value></member>"
            "<member><name>faultString</name><value><string>%s</string></value></member>"
            "</struct></value>\n</fault>\n</methodResponse>\n" % (int(code), _escape(str(message)))
            ).encode("utf-8", "xmlcharrefreplace")


def dumps_request(method: str, params: Iterable[Any]) -> bytes:
    """The body of a methodCall."""
    out = ["<?xml version='1.0'?>\n<methodCall>\n<methodName>", _escape(method), "</methodName>\n<params>\n"]
    for p in params:
        out.append("<param>\n")
        _encode_value(p, out)
        out.append("\n</param>\n")
    out.append("</params>\n</methodCall>\n")
    return "".join(out).encode("utf-8", "xmlcharrefreplace")


# ---------------------------------------------------------------------------
# decoding
# ---------------------------------------------------------------------------

def _refuse_dtd(*_args: Any) -> None:
    raise XmlRpcError("DTDs and entity declarations are not allowed in XML-RPC")


_VALUE_TAGS = frozenset((
    "value", "i1", "i2", "i4", "i8", "int", "bigint", "biginteger", "boolean", "string",
    "double", "float", "bigdecimal", "dateTime.iso8601", "base64", "array", "struct",
    "data", "member", "name", "nil",
))
_INT_TAGS = frozenset(("i1", "i2", "i4", "i8", "int", "bigint", "biginteger"))
_FLOAT_TAGS = frozenset(("double", "float", "bigdecimal"))


class _Unmarshaller:
    """Collects values from expat events with an explicit stack (no recursion, bounded depth)."""

    __slots__ = ("stack", "marks", "data", "value_open", "method", "kind", "fault", "seen_root")

    def __init__(self) -> None:
        self.stack: list[Any] = []
        self.marks: list[int] = []
        self.data: list[str] = []
        self.value_open = False  # a <value> was opened and no element started inside it yet
        self.method: str | None = None
        self.kind: str | None = None
        self.fault = False
        self.seen_root = False

    def start(self, tag: str, attrs: Any) -> None:
        if ":" in tag:  # namespaced tags (ex:nil, ex:i8) as apache xmlrpc sends them
            tag = tag.rsplit(":", 1)[1]
        if not self.seen_root:
            if tag not in ("methodCall", "methodResponse"):
                raise XmlRpcError("not an XML-RPC message: root element <%s>" % tag)
            self.seen_root = True
            self.kind = tag
        elif tag == "array" or tag == "struct":
            if len(self.marks) >= MAX_DEPTH:
                raise XmlRpcError("XML-RPC value nested deeper than %d levels" % MAX_DEPTH)
            self.marks.append(len(self.stack))
        elif tag == "fault":
            self.fault = True
        if self.value_open and tag not in _VALUE_TAGS:
            raise XmlRpcError("unknown tag <%s> in an XML-RPC value" % tag)
        self.data = []
        self.value_open = tag == "value"

    def chars(self, text: str) -> None:
        self.data.append(text)

    def end(self, tag: str) -> None:
        if ":" in tag:
            tag = tag.rsplit(":", 1)[1]
        data = "".join(self.data)
        self.data = []
        if tag == "value":
            if self.value_open:  # <value>text</value>: an untyped string, as XmlRpc++ sends
                self.stack.append(data)
            self.value_open = False
        elif tag == "string" or tag == "name":
            self.stack.append(data)
        elif tag in _INT_TAGS:
            try:
                self.stack.append(int(data))
            except ValueError:
                raise XmlRpcError("bad integer value %r" % data[:64]) from None
        elif tag == "boolean":
            if data == "0":
                self.stack.append(False)
            elif data == "1":
                self.stack.append(True)
            else:
                raise XmlRpcError("bad boolean value %r" % data[:64])
        elif tag in _FLOAT_TAGS:
            try:
                self.stack.append(float(data))
            except ValueError:
                raise XmlRpcError("bad double value %r" % data[:64]) from None
        elif tag == "array":
            mark = self.marks.pop()
            items = self.stack[mark:]
            del self.stack[mark:]
            self.stack.append(items)
        elif tag == "struct":
            mark = self.marks.pop()
            items = self.stack[mark:]
            del self.stack[mark:]
            if len(items) % 2:
                raise XmlRpcError("malformed struct")
            d = {}
            for i in range(0, len(items), 2):
                key = items[i]
                if type(key) is not str:
                    raise XmlRpcError("struct member name must be a string")
                d[key] = items[i + 1]
            self.stack.append(d)
        elif tag == "base64":
            try:
                self.stack.append(base64.b64decode(data.encode("ascii")))
            except (ValueError, UnicodeEncodeError):
                raise XmlRpcError("bad base64 value") from None
        elif tag == "dateTime.iso8601":
            from xmlrpc.client import DateTime  # rare in ROS: loaded on first use
            self.stack.append(DateTime(data.strip()))
        elif tag == "nil":
            self.stack.append(None)
        elif tag == "methodName":
            self.method = data
        self.value_open = False


def _parse(data: bytes) -> _Unmarshaller:
    u = _Unmarshaller()
    p = expat.ParserCreate()
    p.StartDoctypeDeclHandler = _refuse_dtd
    p.EntityDeclHandler = _refuse_dtd
    p.UnparsedEntityDeclHandler = _refuse_dtd
    p.ExternalEntityRefHandler = _refuse_dtd
    p.SetParamEntityParsing(expat.XML_PARAM_ENTITY_PARSING_NEVER)
    p.buffer_text = True
    p.StartElementHandler = u.start
    p.EndElementHandler = u.end
    p.CharacterDataHandler = u.chars
    try:
        p.Parse(data, True)
    except expat.ExpatError as e:
        raise XmlRpcError("malformed XML: %s" % e) from None
    except RecursionError:
        raise XmlRpcError("XML nested too deeply") from None
    return u


# The shape nearly every call has (flat scalar params, as rospy, roscpp and the
# ROS tools send them) is read with two regular expressions; anything else
# (arrays, structs, entities, other encodings, CR characters, ...) goes through
# expat. The fast path accepts nothing expat would read differently.
_FAST_CALL = re.compile(
    r"(?:<\?xml version=(['\"])1\.0\1(?:\s+encoding=(['\"])(?:utf-8|UTF-8)\2)?\s*\?>)?\s*"
    r"<methodCall>\s*<methodName>([^<&\s]+)</methodName>\s*(?:<params>(.*)</params>\s*|<params/>\s*)?"
    r"</methodCall>\s*\Z", re.S)
_FAST_PARAM = re.compile(
    r"\s*<param>\s*<value>(?:<(string|int|i4|double|boolean)>([^<&]*)</\1>|([^<&]*))</value>\s*</param>")
_FAST_SPACE = re.compile(r"\s*\Z")
# what expat refuses in character data (C0 controls but TAB/LF, U+FFFE, U+FFFF, "]]>") and CR,
# which XML turns into LF: requests with any of these go to expat
_CONTROL_BYTES = bytes(c for c in range(32) if c not in (9, 10))


def _plain_xml_text(data: bytes) -> bool:
    return (len(data.translate(None, _CONTROL_BYTES)) == len(data) and b"]]>" not in data
            and b"\xef\xbf\xbe" not in data and b"\xef\xbf\xbf" not in data)


def _loads_request_fast(data: bytes) -> tuple[str, list[Any]] | None:
    """The common flat request, or None when expat must decide."""
    if not _plain_xml_text(data):
        return None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        return None
    m = _FAST_CALL.match(text)
    if m is None:
        return None
    body = m.group(4)
    params: list[Any] = []
    if body:
        pos = 0
        end = len(body)
        match = _FAST_PARAM.match
        while pos < end:
            pm = match(body, pos)
            if pm is None:
                if _FAST_SPACE.match(body, pos):
                    break
                return None
            tag = pm.group(1)
            if tag is None:
                params.append(pm.group(3))
            else:
                value = pm.group(2)
                if tag == "string":
                    params.append(value)
                elif tag == "boolean":
                    if value == "1":
                        params.append(True)
                    elif value == "0":
                        params.append(False)
                    else:
                        return None
                else:
                    try:
                        params.append(float(value) if tag == "double" else int(value))
                    except ValueError:
                        return None
            pos = pm.end()
    return m.group(3), params


def loads_request(data: bytes) -> tuple[str, list[Any]]:
    """Parse a methodCall: `(method_name, params)`; raises XmlRpcError if it is not one."""
    if len(data) < 4096:
        fast = _loads_request_fast(data)
        if fast is not None:
            return fast
    u = _parse(data)
    if u.kind != "methodCall" or u.method is None:
        raise XmlRpcError("not an XML-RPC methodCall")
    if u.marks:
        raise XmlRpcError("malformed XML-RPC value")
    return u.method, u.stack


def loads_response(data: bytes) -> Any:
    """Parse a methodResponse: its value; raises Fault for a fault, XmlRpcError if malformed."""
    u = _parse(data)
    if u.kind != "methodResponse" or u.marks:
        raise XmlRpcError("not an XML-RPC methodResponse")
    if u.fault:
        f = u.stack[0] if len(u.stack) == 1 else None
        if not isinstance(f, dict):
            raise XmlRpcError("malformed XML-RPC fault")
        raise Fault(f.get("faultCode", 0), f.get("faultString", ""))
    if len(u.stack) != 1:
        raise XmlRpcError("an XML-RPC response carries exactly one value, got %d" % len(u.stack))
    return u.stack[0]


# ---------------------------------------------------------------------------
# dispatch helpers
# ---------------------------------------------------------------------------

Dispatch = Callable[[str, list], Any]


def _exception_fault(exc: BaseException) -> Fault:
    if isinstance(exc, Fault):
        return exc
    # the text Python's SimpleXMLRPCServer (rosmaster's server) puts in such faults
    return Fault(1, "%s:%s" % (type(exc), exc))


def multicall(dispatch: Dispatch, calls: Any) -> Any:
    """`system.multicall`: run each `{methodName, params}` through `dispatch`.

    Returns the list of results (`[value]` or a fault struct per call), or an
    awaitable of it when some call answers asynchronously.
    """
    if not isinstance(calls, list):
        raise Fault(1, "system.multicall expects an array of calls")
    if len(calls) > MULTICALL_CHUNK:
        return _multicall_chunked(dispatch, calls)
    return _multicall_part(dispatch, calls)


async def _multicall_chunked(dispatch: Dispatch, calls: list) -> list[Any]:
    """A long multicall in slices, letting other clients in between (still in order for its caller)."""
    results: list[Any] = []
    for start in range(0, len(calls), MULTICALL_CHUNK):
        part = _multicall_part(dispatch, calls[start:start + MULTICALL_CHUNK])
        if inspect.isawaitable(part):
            part = await part
        results.extend(part)
        await asyncio.sleep(0)
    return results


def _multicall_part(dispatch: Dispatch, calls: list) -> Any:
    results: list[Any] = []
    pending: list[tuple[int, Awaitable]] = []
    for call_ in calls:
        try:
            if not isinstance(call_, dict):
                raise Fault(1, "system.multicall: each call must be a struct")
            name = call_.get("methodName")
            params = call_.get("params", [])
            if not isinstance(name, str) or not isinstance(params, list):
                raise Fault(1, "system.multicall: a call needs methodName and params")
            if name == "system.multicall":
                raise Fault(1, "system.multicall cannot be nested")
            r = dispatch(name, params)
        except Exception as e:  # noqa: BLE001 - every failure becomes that call's fault
            f = _exception_fault(e)
            results.append({"faultCode": f.faultCode, "faultString": f.faultString})
            continue
        if inspect.isawaitable(r):
            pending.append((len(results), r))
            results.append(None)
        else:
            results.append([r])
    if not pending:
        return results

    async def finish() -> list[Any]:
        for index, aw in pending:
            try:
                results[index] = [await aw]
            except Exception as e:  # noqa: BLE001
                f = _exception_fault(e)
                results[index] = {"faultCode": f.faultCode, "faultString": f.faultString}
        return results

    return finish()


# ---------------------------------------------------------------------------
# HTTP/1.1 server
# ---------------------------------------------------------------------------

RPC_PATHS = (b"/", b"/RPC2")


def _http_response(status: int, reason: str, body: bytes, keep_alive: bool,
                   content_type: bytes = b"text/xml") -> bytes:
    return b"".join((
        b"HTTP/1.1 %d %s\r\nServer: launcher-xmlrpc\r\nContent-Type: %s\r\nContent-Length: %d\r\n"
        % (status, reason.encode("ascii"), content_type, len(body)),
        b"" if keep_alive else b"Connection: close\r\n",
        b"\r\n", body,
    ))


_OK_HEAD = b"HTTP/1.1 200 OK\r\nServer: launcher-xmlrpc\r\nContent-Type: text/xml\r\nContent-Length: "


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


class _HttpError(Exception):
    def __init__(self, status: int, reason: str):
        super().__init__(status, reason)
        self.status = status
        self.reason = reason


class _Connection(asyncio.Protocol):
    """One client connection: buffered HTTP/1.1 parsing, in-order replies, bounded everything."""

    def __init__(self, server: "XmlRpcServer"):
        self.server = server
        self.transport: asyncio.Transport | None = None
        self.buf = bytearray()
        self.busy = False            # an asynchronous reply is being awaited
        self.closing = False
        self.reading_paused = False
        self.writing_paused = False
        self.partial_since: float | None = None  # when the pending, incomplete request began
        self.last_activity = 0.0
        self.timer: asyncio.TimerHandle | None = None
        self.eof = False

    # -- asyncio callbacks --------------------------------------------------
    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]
        if len(self.server._connections) >= self.server.max_connections and not self.server._evict_idle():
            self.closing = True  # refused: every connection is in use
            transport.close()
            return
        self.server._connections.add(self)
        self.last_activity = self.server._loop.time()
        self._arm_timer()

    def connection_lost(self, exc: Exception | None) -> None:
        self.closing = True
        self.server._connections.discard(self)
        if self.timer is not None:
            self.timer.cancel()
            self.timer = None
        self.buf = bytearray()

    def data_received(self, data: bytes) -> None:
        if self.closing:
            return
        server = self.server
        if not self.buf and not self.busy and not self.writing_paused:
            # the usual case: this chunk is exactly one request whose head was seen before
            end = data.find(b"\r\n\r\n")
            if end >= 0:
                parsed = server._head_cache.get(data[:end])
                if parsed is not None and len(data) == end + 4 + parsed[1] and parsed[0] in RPC_PATHS:
                    self.last_activity = server._loop.time()
                    self._handle(data[end + 4:], parsed[2])
                    return
        buf = self.buf
        if not buf and self.partial_since is None:
            self._partial_started(server._loop.time())
        buf += data
        if len(buf) > self.server.max_request_size + self.server.max_header_size:
            self._http_error(413, "Request Entity Too Large")
            return
        if not self.busy:
            self._process()
        else:
            self._update_reading()  # pipelined requests wait in the socket, not in memory

    def eof_received(self) -> bool:
        """The client will send no more: answer what is pending, then close."""
        self.eof = True
        if self.busy:
            return True  # keep the transport open for the asynchronous reply
        return False

    def pause_writing(self) -> None:
        # a client that does not read its replies stops being read from
        self.writing_paused = True
        self._update_reading()

    def resume_writing(self) -> None:
        self.writing_paused = False
        self._update_reading()
        if not self.busy and self.buf:
            self._process()

    # -- request handling -----------------------------------------------------
    def _update_reading(self) -> None:
        should_pause = self.writing_paused or (self.busy and len(self.buf) > self.server.max_header_size)
        if should_pause != self.reading_paused and self.transport is not None and not self.closing:
            self.reading_paused = should_pause
            if should_pause:
                self.transport.pause_reading()
            else:
                self.transport.resume_reading()

    def _process(self) -> None:
        """Answer every complete request in the buffer, in order."""
        server = self.server
        while self.buf and not self.busy and not self.closing and not self.writing_paused:
            buf = self.buf
            end = buf.find(b"\r\n\r\n")
            if end < 0:
                if len(buf) > server.max_header_size:
                    self._http_error(431, "Request Header Fields Too Large")
                return
            if end > server.max_header_size:
                self._http_error(431, "Request Header Fields Too Large")
                return
            head = bytes(buf[:end])
            parsed = server._head_cache.get(head)
            if parsed is None:
                # clients repeat the same few heads (only Content-Length moves): parse each once
                try:
                    parsed = self._parse_head(head)
                except _HttpError as e:
                    self._http_error(e.status, e.reason)
                    return
                if len(server._head_cache) >= 1024:
                    server._head_cache.clear()
                server._head_cache[head] = parsed
            path, length, keep_alive, expect_continue = parsed
            body_start = end + 4
            if len(buf) < body_start + length:
                if expect_continue and len(buf) == body_start:
                    self.transport.write(b"HTTP/1.1 100 Continue\r\n\r\n")
                return  # wait for the rest of the body
            body = bytes(buf[body_start:body_start + length])
            del buf[:body_start + length]
            now = server._loop.time()
            self.last_activity = now
            self.partial_since = None
            if buf:
                self._partial_started(now)
            if path not in RPC_PATHS:
                self._reply(_http_response(404, "Not Found", b"No such page", keep_alive, b"text/plain"),
                            keep_alive)
                continue
            self._handle(body, keep_alive)

    def _parse_head(self, head: bytes) -> tuple[bytes, int, bool, bool]:
        """(path, content length, keep-alive, expects 100-continue) of a request head."""
        low = head.lower()  # header names are case-insensitive; only these few matter here
        nl = low.find(b"\r\n")
        request_line = (head if nl < 0 else head[:nl]).split()
        if len(request_line) != 3 or not request_line[2].startswith(b"HTTP/1."):
            raise _HttpError(400, "Bad Request")
        method, target, version = request_line
        if low.count(b"\r\n") > self.server.max_header_count:
            raise _HttpError(431, "Request Header Fields Too Large")
        if method != b"POST":
            raise _HttpError(501, "Unsupported method (%s)" % method.decode("latin-1")[:16])
        if b"\r\ntransfer-encoding:" in low:
            raise _HttpError(501, "Transfer-Encoding not supported")
        values = _header_values(low, b"\r\ncontent-length:")
        if not values:
            raise _HttpError(411, "Length Required")
        try:
            lengths = {int(v) for v in values}
        except ValueError:
            raise _HttpError(400, "Bad Request") from None
        if len(lengths) != 1:
            raise _HttpError(400, "Bad Request")
        length = lengths.pop()
        if length < 0:
            raise _HttpError(400, "Bad Request")
        if length > self.server.max_request_size:
            raise _HttpError(413, "Request Entity Too Large")
        keep_alive = version == b"HTTP/1.1"
        if b"\r\nconnection:" in low:
            for v in _header_values(low, b"\r\nconnection:"):
                if b"close" in v:
                    keep_alive = False
                elif b"keep-alive" in v:
                    keep_alive = True
        expect_continue = b"\r\nexpect:" in low and b"100-continue" in _header_values(low, b"\r\nexpect:")
        if b"?" in target:
            target = target.split(b"?", 1)[0]
        if target.startswith(b"http://"):  # absolute-form request target
            target = b"/" + target[7:].partition(b"/")[2]
        return target, length, keep_alive, expect_continue

    def _handle(self, body: bytes, keep_alive: bool) -> None:
        server = self.server
        if len(body) > LARGE_REQUEST:
            # parsed in a worker thread, so that other clients are served meanwhile
            self.busy = True
            task = asyncio.ensure_future(self._handle_large(body))
            task.add_done_callback(lambda t: self._async_done(t, keep_alive))
            return
        try:
            method, params = loads_request(body)
        except XmlRpcError as e:
            self._reply_body(dumps_fault(1, "<class 'xml.parsers.expat.ExpatError'>:%s" % e), keep_alive)
            return
        try:
            if method == "system.multicall" and server.multicall:
                result = multicall(server.dispatch, params[0] if len(params) == 1 else None)
            else:
                result = server.dispatch(method, params)
        except Exception as e:  # noqa: BLE001 - a failing method answers with a fault
            f = _exception_fault(e)
            self._reply_body(dumps_fault(f.faultCode, f.faultString), keep_alive)
            return
        if type(result) is not tuple and inspect.isawaitable(result):
            self.busy = True
            task = asyncio.ensure_future(result)
            task.add_done_callback(lambda t: self._async_done(t, keep_alive))
            return
        self._reply_body(self._encode(result), keep_alive)

    async def _handle_large(self, body: bytes) -> Any:
        server = self.server
        try:
            method, params = await asyncio.get_running_loop().run_in_executor(None, loads_request, body)
        except XmlRpcError as e:
            raise Fault(1, "<class 'xml.parsers.expat.ExpatError'>:%s" % e) from None
        if method == "system.multicall" and server.multicall:
            result = multicall(server.dispatch, params[0] if len(params) == 1 else None)
        else:
            result = server.dispatch(method, params)
        if inspect.isawaitable(result):
            result = await result
        return result

    @staticmethod
    def _encode(result: Any) -> bytes:
        try:
            return dumps_response(result)
        except Exception as e:  # noqa: BLE001 - e.g. an int outside int32, as rosmaster faults
            f = _exception_fault(e)
            return dumps_fault(f.faultCode, f.faultString)

    def _async_done(self, task: asyncio.Future, keep_alive: bool) -> None:
        self.busy = False
        if self.closing:
            if not task.cancelled():
                task.exception()  # consumed: the client is gone
            return
        if task.cancelled():
            body = dumps_fault(1, "call cancelled")
        elif task.exception() is not None:
            f = _exception_fault(task.exception())  # type: ignore[arg-type]
            body = dumps_fault(f.faultCode, f.faultString)
        else:
            body = self._encode(task.result())
        self._reply_body(body, keep_alive)
        self._update_reading()
        if not self.closing:
            self._process()
        if self.eof and not self.busy and not self.closing and self.transport is not None:
            self.closing = True
            self.transport.close()

    def _reply_body(self, body: bytes, keep_alive: bool) -> None:
        if keep_alive and not self.closing:
            # the common reply, without formatting a head
            self.transport.write(b"".join((_OK_HEAD, b"%d" % len(body), b"\r\n\r\n", body)))
            return
        self._reply(_http_response(200, "OK", body, keep_alive), keep_alive)

    def _reply(self, data: bytes, keep_alive: bool) -> None:
        if self.closing or self.transport is None:
            return
        self.transport.write(data)
        if not keep_alive:
            self.closing = True
            self.transport.close()

    def _http_error(self, status: int, reason: str) -> None:
        reason = reason.encode("ascii", "replace").decode("ascii")
        body = ("%d %s\n" % (status, reason)).encode("ascii")
        self._reply(_http_response(status, reason, body, False, b"text/plain"), False)

    # -- time-outs ----------------------------------------------------------------
    def _partial_started(self, now: float) -> None:
        """A request began arriving: it must be complete within request_timeout."""
        self.partial_since = now
        deadline = now + self.server.request_timeout
        timer = self.timer
        if timer is None or timer.when() > deadline:
            # the timer may be set for the (much later) idle deadline: bring it forward
            if timer is not None:
                timer.cancel()
            self.timer = self.server._loop.call_at(deadline, self._on_timer)

    def _arm_timer(self) -> None:
        server = self.server
        self.timer = server._loop.call_later(min(server.request_timeout, server.idle_timeout), self._on_timer)

    def _on_timer(self) -> None:
        """Close a connection whose request is too slow to arrive, or that idles too long."""
        self.timer = None
        if self.closing or self.transport is None:
            return
        server = self.server
        now = server._loop.time()
        if self.busy:
            deadline = now + server.request_timeout  # our own reply is pending: not the client's fault
        elif self.buf and self.partial_since is not None:
            deadline = self.partial_since + server.request_timeout
        else:
            deadline = self.last_activity + server.idle_timeout
        if now >= deadline:
            if self.buf and not self.busy:
                self._http_error(408, "Request Timeout")
            else:
                self.closing = True
                self.transport.close()
            return
        self.timer = server._loop.call_later(deadline - now, self._on_timer)


class XmlRpcServer:
    """An XML-RPC server on the running asyncio loop.

    `dispatch(method, params)` returns the reply value, or an awaitable of it;
    raising `Fault` answers with that fault, any other exception with fault 1.
    Parts of a reply may be `Encoded` fragments (sent as they are).
    """

    def __init__(self, dispatch: Dispatch, host: str | None = "0.0.0.0", port: int = 0, *,
                 multicall: bool = False, max_request_size: int = 64 * 1024 * 1024,
                 max_header_size: int = 16 * 1024, max_header_count: int = 100,
                 request_timeout: float = 30.0, idle_timeout: float = 3600.0,
                 max_connections: int = 4096):
        self.dispatch = dispatch
        self.host = host
        self.port = port
        self.multicall = multicall
        self.max_request_size = max_request_size
        self.max_header_size = max_header_size
        self.max_header_count = max_header_count
        self.request_timeout = request_timeout
        self.idle_timeout = idle_timeout
        self.max_connections = max_connections
        self._server: asyncio.base_events.Server | None = None
        self._connections: set[_Connection] = set()
        self._head_cache: dict[bytes, tuple[bytes, int, bool, bool]] = {}
        self._loop: asyncio.AbstractEventLoop = None  # type: ignore[assignment]

    def _protocol(self) -> asyncio.Protocol:
        return _Connection(self)

    def _evict_idle(self) -> bool:
        """Close the connection idle the longest to make room (a flood of idle sockets must not
        lock real clients out); False if none is idle."""
        idle = [c for c in self._connections if not c.busy and not c.buf and not c.closing]
        if not idle:
            return False
        oldest = min(idle, key=lambda c: c.last_activity)
        oldest.closing = True
        self._connections.discard(oldest)
        if oldest.transport is not None:
            oldest.transport.close()
        return True

    async def start(self) -> None:
        """Listen; raises OSError when the port is taken."""
        self._loop = asyncio.get_running_loop()
        if self.host == "::":
            # every address, IPv4 included, on one dual-stack socket (as Python's socketserver
            # gives rospy/rosmaster under ROS_IPV6=on); asyncio would make it IPv6-only
            sock = socket.socket(socket.AF_INET6, socket.SOCK_STREAM)
            try:
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                sock.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 0)
                sock.bind(("::", self.port))
                sock.listen(1024)
                sock.setblocking(False)
            except OSError:
                sock.close()
                raise
            self._server = await self._loop.create_server(self._protocol, sock=sock)
        else:
            self._server = await self._loop.create_server(self._protocol, self.host, self.port,
                                                          reuse_address=True, backlog=1024)
        self.port = self._server.sockets[0].getsockname()[1]

    async def stop(self) -> None:
        """Stop listening and close every connection."""
        if self._server is not None:
            self._server.close()
        for conn in list(self._connections):
            conn.closing = True
            if conn.transport is not None:
                conn.transport.close()
        if self._server is not None:
            try:
                await asyncio.wait_for(self._server.wait_closed(), 2.0)
            except asyncio.TimeoutError:
                pass
            self._server = None


# ---------------------------------------------------------------------------
# client
# ---------------------------------------------------------------------------

async def call(uri: str, method: str, *params: Any, timeout: float | None = 10.0) -> Any:
    """Call `method(*params)` at an XML-RPC `uri` (one connection per call).

    Returns the value; raises Fault, XmlRpcError (bad HTTP/XML), OSError or
    asyncio.TimeoutError.
    """
    if timeout is None:
        return await _call(uri, method, params)
    return await asyncio.wait_for(_call(uri, method, params), timeout)


async def _call(uri: str, method: str, params: tuple) -> Any:
    u = urllib.parse.urlsplit(uri)
    if u.scheme != "http" or not u.hostname:
        raise XmlRpcError("not an http:// XML-RPC URI: %r" % uri)
    port = u.port or 80
    body = dumps_request(method, params)
    host_header = u.netloc.rsplit("@", 1)[-1]
    head = ("POST %s HTTP/1.1\r\nHost: %s\r\nContent-Type: text/xml\r\nUser-Agent: launcher-xmlrpc\r\n"
            "Content-Length: %d\r\nConnection: close\r\n\r\n" % (u.path or "/", host_header, len(body)))
    reader, writer = await asyncio.open_connection(u.hostname, port)
    try:
        writer.write(head.encode("latin-1") + body)
        status_line = await reader.readline()
        parts = status_line.split(None, 2)
        if len(parts) < 2 or not parts[0].startswith(b"HTTP/"):
            raise XmlRpcError("bad HTTP response from %s" % uri)
        status = int(parts[1]) if parts[1].isdigit() else 0
        length = -1
        for _ in range(200):  # a bounded number of header lines
            line = await reader.readline()
            if line in (b"\r\n", b"\n", b""):
                break
            name, _, value = line.partition(b":")
            if name.strip().lower() == b"content-length" and value.strip().isdigit():
                length = int(value.strip())
        if length > MAX_RESPONSE_SIZE:
            raise XmlRpcError("reply from %s is too large (%d bytes)" % (uri, length))
        if length >= 0:
            data = await reader.readexactly(length)
        else:  # no Content-Length: the body ends with the connection (bounded all the same)
            chunks: list[bytes] = []
            size = 0
            while size <= MAX_RESPONSE_SIZE:
                more = await reader.read(MAX_RESPONSE_SIZE + 1 - size)
                if not more:
                    break
                chunks.append(more)
                size += len(more)
            data = b"".join(chunks)
            if size > MAX_RESPONSE_SIZE:
                raise XmlRpcError("reply from %s is too large" % uri)
        if status != 200:
            raise XmlRpcError("HTTP %d from %s" % (status, uri))
        return loads_response(data)
    except asyncio.IncompleteReadError:
        raise XmlRpcError("connection closed by %s before the reply was complete" % uri) from None
    except ValueError as e:  # a header line longer than the stream's limit
        if isinstance(e, XmlRpcError):
            raise
        raise XmlRpcError("bad HTTP response from %s: %s" % (uri, e)) from None
    finally:
        writer.close()
