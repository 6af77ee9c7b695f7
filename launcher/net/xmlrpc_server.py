"""The XML-RPC HTTP/1.1 server (asyncio) of the master and the nodes' slave APIs, and `system.multicall`.

It speaks HTTP/1.1 with keep-alive on `/` and `/RPC2` (what rospy, roscpp's
XmlRpc++ and rosjava expect), bounds header and body sizes, times out slow
clients and answers every malformed call with a fault or an HTTP error. The
codec it uses (`launcher.net.xmlrpc`) stays free of asyncio, so that a launch can
talk to a running master before it starts its event loop.
"""

from __future__ import annotations

import asyncio
import inspect
import socket
from typing import Any, Awaitable, Callable

from launcher.net.xmlrpc import (Fault, XmlRpcError, dumps_fault, dumps_response, loads_request)

__all__ = ["XmlRpcServer", "multicall", "Dispatch"]

LARGE_REQUEST = 256 * 1024  # request bodies above this are parsed off the event loop
MULTICALL_CHUNK = 500  # calls of a system.multicall run between two turns of the event loop

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


