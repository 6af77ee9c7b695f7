"""The XML-RPC HTTP/1.1 server (asyncio) of the master and the nodes' slave APIs, and `system.multicall`.

It speaks HTTP/1.1 with keep-alive on `/` and `/RPC2` (what rospy, roscpp's
XmlRpc++ and rosjava expect); the framing is `launcher.net.http`'s sans-I/O
RequestReader (header and body sizes bounded there), and this module adds the
sockets: accepting (backing off when out of files), deadlines for slow
clients, a connection cap with eviction, in-order replies. Every malformed call
gets a fault or an HTTP error. The
codec it uses (`launcher.net.xmlrpc`) stays free of asyncio, so that a launch can
talk to a running master before it starts its event loop.
"""

from __future__ import annotations

import asyncio
import errno
import functools
import inspect
import logging
import os
import socket
import time
from typing import Any, Awaitable, Callable, NamedTuple

from launcher import compat
from launcher.net.http import CONTINUE, NEED_DATA, HttpError, RequestLimits, RequestReader, format_response
from launcher.net.open_files import connection_cap
from launcher.net.xmlrpc_codec import (Fault, XmlRpcError, dumps_fault, dumps_response, loads_request)

log = logging.getLogger("launcher.xmlrpc_server")

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
# HTTP/1.1 server: a thin asyncio protocol around launcher.net.http.RequestReader
# ---------------------------------------------------------------------------

RPC_PATHS = (b"/", b"/RPC2")
ACCEPT_BATCH = 100  # connections accepted per turn of the event loop
ACCEPT_BACKOFF = 0.5  # seconds without accepting after accept() failed (out of files)
_OUT_OF_FILES = (errno.EMFILE, errno.ENFILE, errno.ENOBUFS, errno.ENOMEM)


class Deadlines(NamedTuple):
    """A connection's deadline policy, pure: from what the connection is doing and a time, when its next
    deadline is, and what passing it means. Seconds: a request head within `header`, its body within
    `request`, an idle keep-alive connection lasts `idle`."""

    header: float
    request: float
    idle: float

    def next(self, *, now: float, busy: bool, partial_since: float | None, body_pending: bool,
             last_activity: float) -> float:
        if busy:
            return now + self.request  # our own reply is pending: not the client's fault
        if partial_since is not None:
            return partial_since + (self.request if body_pending else self.header)
        return last_activity + self.idle

    def verdict(self, now: float, deadline: float, *, busy: bool, buffered: bool) -> str:
        """"wait" (not yet), "408" (a request was arriving too slowly: Request Timeout), or "close"."""
        if now < deadline:
            return "wait"
        return "408" if buffered and not busy else "close"


class _Connection(asyncio.Protocol):
    """One client connection: requests framed by a RequestReader, replies in order, deadlines."""

    def __init__(self, server: "XmlRpcServer"):
        self.server = server
        self.transport: asyncio.Transport | None = None
        self.reader = RequestReader(server.limits)
        self.busy = False            # an asynchronous reply is being awaited
        self.closing = False
        self.reading_paused = False
        self.writing_paused = False
        self.partial_since: float | None = None  # when the pending, incomplete request began
        self.last_activity = 0.0     # when the connection was made or last completed a request
        self.requests_done = 0
        self.timer: asyncio.TimerHandle | None = None
        self.eof = False

    # -- asyncio callbacks --------------------------------------------------
    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]
        server = self.server
        if server.stopped:
            # accepted as the server stopped (its transport made after): closed unanswered, as those before it
            # were, rather than served a call that the loop's end would cancel
            self.closing = True
            transport.close()
            return
        if len(server._connections) >= server.max_connections and not server._evict():
            self.closing = True  # refused: every connection is busy with a reply
            transport.close()
            return
        server._connections.add(self)
        server._fresh[self] = None
        now = server._loop.time()
        self.last_activity = now
        # its first request head must arrive within header_timeout, like any later one
        self.partial_since = now
        self.timer = server._loop.call_at(now + server.header_timeout, self._on_timer)

    def connection_lost(self, exc: Exception | None) -> None:
        self.closing = True
        self.server._connections.discard(self)
        self.server._fresh.pop(self, None)
        if self.timer is not None:
            self.timer.cancel()
            self.timer = None

    def data_received(self, data: bytes) -> None:
        if self.closing:
            return
        try:
            self.reader.receive_data(data)
        except HttpError as e:
            self._http_error(e.status, e.reason)
            return
        if self.busy:
            self._update_reading()  # pipelined requests wait in the socket, not in memory
            return
        self._process()

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
        if not self.busy:
            self._process()

    # -- request handling -----------------------------------------------------
    def _update_reading(self) -> None:
        should_pause = self.writing_paused or (self.busy and self.reader.buffered > self.server.limits.max_header_size)
        if should_pause != self.reading_paused and self.transport is not None and not self.closing:
            self.reading_paused = should_pause
            if should_pause:
                self.transport.pause_reading()
            else:
                self.transport.resume_reading()

    def _process(self) -> None:
        """Answer every complete request received, in order."""
        reader = self.reader
        while not self.busy and not self.closing and not self.writing_paused:
            try:
                event = reader.next_event()
            except HttpError as e:
                self._http_error(e.status, e.reason)
                return
            if event is NEED_DATA:
                if reader.buffered and self.partial_since is None:
                    self._partial_started()
                return
            if event is CONTINUE:
                self.transport.write(b"HTTP/1.1 100 Continue\r\n\r\n")
                continue
            self.last_activity = self.server._loop.time()
            if not self.requests_done:
                self.server._fresh.pop(self, None)
            self.requests_done += 1
            self.partial_since = None
            if event.target not in RPC_PATHS:
                self._reply(format_response(404, "Not Found", b"No such page", event.keep_alive,
                                            b"text/plain"), event.keep_alive)
                continue
            self._handle(event.body, event.keep_alive)

    def _handle(self, body: bytes, keep_alive: bool) -> None:
        on_call = self.server.on_call
        if on_call is None:
            self._answer(body, keep_alive)
            return
        started = time.perf_counter()
        method = self._answer(body, keep_alive)
        if method is not None:
            on_call(method, time.perf_counter() - started)

    def _answer(self, body: bytes, keep_alive: bool) -> str | None:
        """Reply to one request (or start its reply); the method called, None for a request that was none or is
        answered later (a large one, an awaitable's answer)."""
        server = self.server
        if len(body) > LARGE_REQUEST:
            # parsed in a worker thread, so that other clients are served meanwhile
            self.busy = True
            task = asyncio.ensure_future(self._handle_large(body))
            task.add_done_callback(lambda t: self._async_done(t, keep_alive))
            return None
        try:
            method, params = loads_request(body)
        except XmlRpcError as e:
            self._reply(format_response(200, "OK", dumps_fault(
                1, "<class 'xml.parsers.expat.ExpatError'>:%s" % e), keep_alive), keep_alive)
            return None
        try:
            if method == "system.multicall" and server.multicall:
                result = multicall(server.dispatch, params[0] if len(params) == 1 else None)
            else:
                result = server.dispatch(method, params)
        except Exception as e:  # noqa: BLE001 - a failing method answers with a fault
            f = _exception_fault(e)
            self._reply(format_response(200, "OK", dumps_fault(f.faultCode, f.faultString), keep_alive),
                        keep_alive)
            return method
        if type(result) is not tuple and inspect.isawaitable(result):
            self.busy = True
            task = asyncio.ensure_future(result)
            task.add_done_callback(lambda t: self._async_done(t, keep_alive))
            return None
        self._reply(format_response(200, "OK", self._encode(result), keep_alive), keep_alive)
        return method

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
        self._reply(format_response(200, "OK", body, keep_alive), keep_alive)
        self._update_reading()
        if not self.closing:
            self._process()
        if self.eof and not self.busy and not self.closing and self.transport is not None:
            self.closing = True
            self.transport.close()

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
        self._reply(format_response(status, reason, body, False, b"text/plain"), False)

    # -- deadlines ----------------------------------------------------------------
    def _partial_started(self) -> None:
        """A request began arriving: its head is due within header_timeout."""
        now = self.server._loop.time()
        self.partial_since = now
        deadline = now + self.server.header_timeout
        timer = self.timer
        if timer is None or timer.when() > deadline:
            # the timer may be set for the (much later) idle deadline: bring it forward
            if timer is not None:
                timer.cancel()
            self.timer = self.server._loop.call_at(deadline, self._on_timer)

    def _on_timer(self) -> None:
        """Close a connection whose request head or body is too slow to arrive, or that idles too long."""
        self.timer = None
        if self.closing or self.transport is None:
            return
        server = self.server
        now = server._loop.time()
        reader = self.reader
        deadline = server.deadlines.next(now=now, busy=self.busy, partial_since=self.partial_since,
                                         body_pending=bool(reader.buffered) and not reader.head_pending,
                                         last_activity=self.last_activity)
        verdict = server.deadlines.verdict(now, deadline, busy=self.busy, buffered=bool(reader.buffered))
        if verdict == "408":
            self._http_error(408, "Request Timeout")
        elif verdict == "close":
            self.closing = True
            self.transport.close()
        else:
            self.timer = server._loop.call_at(deadline, self._on_timer)


class XmlRpcServer:
    """An XML-RPC server on the running asyncio loop.

    `dispatch(method, params)` returns the reply value, or an awaitable of it;
    raising `Fault` answers with that fault, any other exception with fault 1.
    Parts of a reply may be `Encoded` fragments (sent as they are).

    A client must send each request head within `header_timeout` (its first one
    counted from the connection) and the body within `request_timeout`; an idle
    keep-alive connection lasts `idle_timeout`. At `max_connections` (derived
    from the open-file limit unless given), a new client takes the place of the
    connection idle the longest, those that never completed a request first.
    """

    def __init__(self, dispatch: Dispatch, host: str | None = "0.0.0.0", port: int = 0, *,
                 multicall: bool = False, max_request_size: int = 64 * 1024 * 1024,
                 max_header_size: int = 16 * 1024, max_header_count: int = 100,
                 header_timeout: float = 10.0, request_timeout: float = 30.0, idle_timeout: float = 3600.0,
                 max_connections: int | None = None, allow: Callable[[str], bool] | None = None,
                 on_call: Callable[[str, float], None] | None = None):
        self.dispatch = dispatch
        # told each call answered at once: its method and the seconds from its complete request to its reply
        # written (the master's latency histogram, master/callstats.py)
        self.on_call = on_call
        # who may connect (launcher.net.allow): others are closed at accept, unanswered
        self.allow = allow
        self.host = host
        self.port = port
        self.multicall = multicall
        self.limits = RequestLimits(max_request_size, max_header_size, max_header_count)
        self.header_timeout = min(header_timeout, request_timeout)
        self.request_timeout = request_timeout
        self.idle_timeout = idle_timeout
        self.deadlines = Deadlines(self.header_timeout, request_timeout, idle_timeout)
        self.max_connections = connection_cap() if max_connections is None else max_connections
        self._server: asyncio.base_events.Server | None = None
        self._listeners: list[socket.socket] = []
        self._connections: set[_Connection] = set()
        # the connections that have not completed a request yet, oldest first: the first evicted
        self._fresh: dict[_Connection, None] = {}
        self._accept_failures: set[int | None] = set()  # the errnos already warned about
        self._loop: asyncio.AbstractEventLoop = None  # type: ignore[assignment]
        self.stopped = False

    def _protocol(self) -> asyncio.Protocol:
        return _Connection(self)

    def _evict(self) -> bool:
        """Close the connection idle the longest to make room, preferring those that never completed
        a request (a flood of idle or half-sent connections must not lock real clients out);
        False if every connection awaits a reply."""
        oldest = next(iter(self._fresh), None)  # (never busy: a reply needs a complete request)
        if oldest is None:
            idle = [c for c in self._connections if not c.busy and not c.closing]
            if not idle:
                return False
            oldest = min(idle, key=lambda c: c.last_activity)
        oldest.closing = True
        self._connections.discard(oldest)
        self._fresh.pop(oldest, None)
        if oldest.transport is not None:
            oldest.transport.close()
        return True

    async def start(self) -> None:
        """Listen; raises OSError when the port is taken."""
        self._loop = loop = asyncio.get_running_loop()
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
            self._server = await loop.create_server(self._protocol, sock=sock, start_serving=False)
        else:
            self._server = await loop.create_server(self._protocol, self.host, self.port,
                                                    reuse_address=True, backlog=1024, start_serving=False)
        # asyncio binds; the accepting is ours, so that running out of files backs off quietly
        # (asyncio's own accept loop logs a traceback per attempt, hundreds of thousands in a flood)
        for ts in self._server.sockets:
            listener = socket.socket(fileno=os.dup(ts.fileno()))
            listener.listen(1024)  # (asyncio listens only when it serves itself)
            self._listeners.append(listener)
            loop.add_reader(listener.fileno(), self._accept, listener)
        self.port = self._server.sockets[0].getsockname()[1]

    def _accept(self, listener: socket.socket) -> None:
        loop = self._loop
        for _ in range(ACCEPT_BATCH):
            try:
                conn, addr = listener.accept()
            except (BlockingIOError, InterruptedError, ConnectionAbortedError):
                return
            except OSError as e:
                # out of files (or another failure): stop accepting for a while, warning once per
                # cause; clients wait in the listen backlog meanwhile
                if e.errno not in self._accept_failures:
                    self._accept_failures.add(e.errno)
                    log.warning("XML-RPC server on port %d: %s (%s); new connections wait",
                                self.port, "out of open files" if e.errno in _OUT_OF_FILES
                                else "accept() failed", e.strerror)
                loop.remove_reader(listener.fileno())
                loop.call_later(ACCEPT_BACKOFF, self._resume_accepting, listener)
                return
            if self.allow is not None and not self.allow(addr[0]):
                conn.close()
                continue
            conn.setblocking(False)
            task = loop.create_task(loop.connect_accepted_socket(self._protocol, conn))
            task.add_done_callback(functools.partial(_accepted, conn))

    def _resume_accepting(self, listener: socket.socket) -> None:
        if listener in self._listeners:
            self._loop.add_reader(listener.fileno(), self._accept, listener)

    async def stop(self) -> None:
        """Stop listening and close every connection (and any accepted but not yet made one, as it is made)."""
        self.stopped = True
        for listener in self._listeners:
            self._loop.remove_reader(listener.fileno())
            listener.close()
        self._listeners = []
        if self._server is not None:
            self._server.close()
        for conn in list(self._connections):
            conn.closing = True
            if conn.transport is not None:
                conn.transport.close()
        if self._server is not None:
            try:
                await compat.wait_for(self._server.wait_closed(), 2.0)
            except asyncio.TimeoutError:
                pass
            self._server = None


def _accepted(conn: socket.socket, task: asyncio.Future) -> None:
    """A connection that failed to become a transport (reset meanwhile, server stopping) is closed."""
    if task.cancelled() or task.exception() is not None:
        conn.close()
