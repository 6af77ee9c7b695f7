"""The XML-RPC codec of ROS 1, sans I/O: values to bytes and bytes to values, requests, responses and faults.

Pure: it touches no socket and no clock, so its tests feed it bytes alone. Parsing
goes through expat with every DTD refused, so no entity can be declared: no
XXE, no entity expansion ("billion laughs"); nesting depth is bounded. The
clients that send these bytes are `launcher.net.xmlrpc`; the server,
`launcher.net.xmlrpc_server`.
"""

from __future__ import annotations

import binascii  # (base64's b64encode/b64decode are these; that module is ~50 kB more of a launch's memory)
import re
import sys
from typing import Any, Callable, Iterable
from xml.parsers import expat

__all__ = [
    "Encoded", "encode_value", "Fault", "XmlRpcError", "loads_request", "loads_response", "dumps_request",
    "dumps_response", "dumps_fault", "MAXINT", "MININT", "MAX_DEPTH",
]

MAXINT = 2**31 - 1
MININT = -(2**31)
MAX_DEPTH = 200  # nested arrays/structs; deeper values are refused when parsed


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
    out.append("<value><base64>%s</base64></value>" % binascii.b2a_base64(v, newline=False).decode("ascii"))


def _enc_binary(v: Any, out: list[str]) -> None:  # an xmlrpc.client.Binary
    _enc_bytes(v.data, out)


def _enc_datetime(v: Any, out: list[str]) -> None:  # an xmlrpc.client.DateTime
    out.append("<value><dateTime.iso8601>%s</dateTime.iso8601></value>" % v.value)


def _enc_pydatetime(v: Any, out: list[str]) -> None:
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
            enc = encoder_for(item)
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
            enc = encoder_for(item)
        enc(item, out)
        append("</member>")
    append("</struct></value>")


def _enc_none(v: None, out: list[str]) -> None:
    # rosmaster's marshaller has allow_none off: a None cannot be sent
    raise TypeError("cannot marshal None unless allow_none is enabled")


_ENCODERS: dict[type, Callable[[Any, list[str]], None]] = {
    str: _enc_str, int: _enc_int, bool: _enc_bool, float: _enc_float,
    bytes: _enc_bytes, bytearray: _enc_bytes,
    list: _enc_list, tuple: _enc_list, dict: _enc_dict, type(None): _enc_none,
    Encoded: _enc_encoded,
}


def encoder_for(value: Any) -> Callable[[Any, list[str]], None]:
    """Encoder for subclasses (an IntEnum, an OrderedDict, ...), by the first matching base."""
    for base in type(value).__mro__:
        enc = _ENCODERS.get(base)
        if enc is not None:
            return enc
    # datetime, and xmlrpc.client's Binary and DateTime: those modules (~0.2 MB; http.client, email, ...)
    # are not imported at every launch's start for them; a value of their types means the caller loaded them.
    datetime = sys.modules.get("datetime")
    if datetime is not None and datetime.datetime not in _ENCODERS:
        _ENCODERS[datetime.datetime] = _enc_pydatetime
        return encoder_for(value)
    client = sys.modules.get("xmlrpc.client")
    if client is not None and client.Binary not in _ENCODERS:
        _ENCODERS[client.Binary] = _enc_binary
        _ENCODERS[client.DateTime] = _enc_datetime
        return encoder_for(value)
    raise TypeError("cannot marshal %s objects" % type(value))


def unsendable(value: Any) -> str:
    """Why `value` could not be sent back over XML-RPC ("" if it can), anywhere inside it: what the codec reads but
    cannot write (an <i8> outside 32 bits, a <nil/>), or what a launch's YAML made that no codec writes (a date)."""
    stack = [value]
    while stack:
        v = stack.pop()
        t = type(v)
        if t is str or t is float or t is bool:
            pass
        elif t is int:
            if not MININT <= v <= MAXINT:
                return "the integer %d is outside the 32-bit range XML-RPC can send" % v
        elif isinstance(v, dict):
            stack.extend(v.values())
        elif isinstance(v, (list, tuple)):
            stack.extend(v)
        elif v is None:
            return "a nil value cannot be sent over XML-RPC"
        else:
            try:
                encoder_for(v)  # (bytes, Binary, a datetime: written as they are)
            except TypeError:
                hint = " (in YAML, quote it to keep it a string)" if t.__name__ == "date" else ""
                return "a value of type %s (%s) cannot be sent over XML-RPC%s" % (t.__name__, v, hint)
    return ""


def _encode_value(value: Any, out: list[str]) -> None:
    enc = _ENCODERS.get(type(value))
    if enc is None:
        enc = encoder_for(value)
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
                self.stack.append(binascii.a2b_base64(data.encode("ascii")))
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
# (arrays, structs, entities, other encodings, a CR in a value, ...) goes through
# expat. The fast path accepts nothing expat would read differently.
_FAST_CALL = re.compile(
    r"(?:<\?xml version=(['\"])1\.0\1(?:\s+encoding=(['\"])(?:utf-8|UTF-8)\2)?\s*\?>)?\s*"
    r"<methodCall>\s*<methodName>([^<&\s]+)</methodName>\s*(?:<params>(.*)</params>\s*|<params/>\s*)?"
    r"</methodCall>\s*\Z", re.S)
_FAST_PARAM = re.compile(
    r"\s*<param>\s*<value>(?:<(string|int|i4|double|boolean)>([^<&]*)</\1>|([^<&]*))</value>\s*</param>")
_FAST_SPACE = re.compile(r"\s*\Z")
# what expat refuses in character data (C0 controls but TAB/LF/CR, U+FFFE, U+FFFF, "]]>"): requests with any of
# these go to expat. A CR is whitespace between tags (XmlRpc++, roscpp's client, ends its lines with CRLF), but XML
# turns one in a value into LF: a value with a CR goes to expat too.
_CONTROL_BYTES = bytes(c for c in range(32) if c not in (9, 10, 13))


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
        crs = "\r" in body
        while pos < end:
            pm = match(body, pos)
            if pm is None:
                if _FAST_SPACE.match(body, pos):
                    break
                return None
            if crs and "\r" in (pm.group(2) or pm.group(3) or ""):
                return None  # (expat reads it as LF)
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
