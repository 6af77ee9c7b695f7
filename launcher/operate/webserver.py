"""The live view's page server, its HTTP side: one asyncio loop for every client, bounded in connections, time and
memory, whatever the clients do.

The old server (the standard library's threading one) made a thread per
connection: 3,000 slow connections were 3,000 threads and 125 MB, kept after
they left. Here a connection is a small asyncio protocol: requests are framed
by `launcher.net.http`'s sans-I/O RequestReader (GET and POST, heads and bodies
bounded), its deadlines are `net.xmlrpc_server.Deadlines` (a request head
within HEADER_TIMEOUT_S, as the master's), and the server holds at most
`max_connections`: a new client takes the place of the oldest connection that
has not sent a whole request yet (a slow one), else of the one idle longest.
An event stream (server-sent events) is written to without waiting: a client
that does not read lets its unsent bytes grow, and past STREAM_BUFFER it is
dropped (its page reconnects and starts over), so a stream costs at most that
much. The accepting is ours, so that room is made under the cap before a
connection is taken. Once half the connections have gone, what they used is
handed back to the system (a collection, then glibc's malloc_trim). What a
request gets is the caller's `handle(request)`: a `Reply`, an awaitable of
one, or a `StreamReply`.
"""

from __future__ import annotations

import asyncio
import ctypes
import gc
import logging
import os
import socket
import struct
from http import HTTPStatus
from typing import Any, Awaitable, Callable, NamedTuple, Union

from launcher.net.http import CONTINUE, NEED_DATA, HttpError, Request, RequestLimits, RequestReader
from launcher.net.open_files import connection_cap
from launcher.net.xmlrpc_server import Deadlines

log = logging.getLogger("launcher.web")

HEADER_TIMEOUT_S = 10.0  # a request head must arrive within this (the master's own deadline)
REQUEST_TIMEOUT_S = 30.0  # and its body within this
IDLE_TIMEOUT_S = 60.0  # a keep-alive connection without a request for this long is closed
MAX_CONNECTIONS = 1024  # at once, event streams included (fewer under a low open-file limit)
MAX_HEADER_SIZE = 8 * 1024
MAX_BODY_SIZE = 64 * 1024  # a POST's body (a node pattern)
STREAM_BUFFER = 64 * 1024  # an event stream's unsent bytes past which it is dropped (beyond its first event's size)
STREAM_SNDBUF = 32 * 1024  # the kernel's send buffer of an event stream: a client that does not read shows soon
LISTEN_BACKLOG = 1024  # connections the kernel holds for us while we are busy (a flood's bursts)
ACCEPT_BATCH = 64  # accepted per turn of the loop, before they are made (the cap may be passed by this, for a moment)
ACCEPT_BACKOFF_S = 0.5  # no accepting for this long after accept() failed (out of files)
TRIM_AFTER_S = 1.0  # after clients leave, the C heap's free pages are given back this much later (at most so often)


def _malloc_trim() -> Callable[[], Any] | None:
    """glibc's malloc_trim(0), or None (another C library). Clients' buffers are freed into the C heap, where
    glibc keeps the pages of free chunks below a live one: 500 streams' unsent bytes stayed 40 MB of RSS
    after the streams had gone. malloc_trim gives every free page back."""
    try:
        trim = ctypes.CDLL(None).malloc_trim
    except (OSError, AttributeError):
        return None
    trim.argtypes = [ctypes.c_size_t]
    trim.restype = ctypes.c_int
    return lambda: trim(0)


class Reply(NamedTuple):
    status: int
    body: bytes
    content_type: str = "text/plain; charset=utf-8"


class StreamReply(NamedTuple):
    """An event stream: `first` written at once, then `attach(stream)`; `detach(stream)` when it ends."""

    first: bytes
    attach: Callable[["EventStream"], None]
    detach: Callable[["EventStream"], None]


Handle = Callable[[Request], Union[Reply, StreamReply, Awaitable[Reply]]]


def format_head(status: int, content_type: str, length: int | None, keep_alive: bool, headers: bytes) -> bytes:
    """A response's status line and header fields; `length` None: the body ends with the connection."""
    try:
        reason = HTTPStatus(status).phrase
    except ValueError:
        reason = "Status"
    return b"".join((
        b"HTTP/1.1 %d %s\r\nServer: launcher-web\r\nContent-Type: %s\r\n" % (status, reason.encode("ascii"),
                                                                            content_type.encode("latin-1")),
        b"" if length is None else b"Content-Length: %d\r\n" % length,
        b"" if keep_alive else b"Connection: close\r\n",
        headers, b"\r\n"))


class EventStream:
    """One client's event stream, as its source sees it: `send` writes an event at once, or drops a client that
    has left STREAM_BUFFER bytes unread."""

    def __init__(self, connection: "_Connection", first: int = 0):
        self._connection = connection
        self.open = True
        # (a large launch's first event, the whole table, may still be on its way when the next one comes)
        self.bound = STREAM_BUFFER + first

    def send(self, data: bytes) -> bool:
        """Write `data`; False once the stream is closed (dropped now, or before)."""
        connection = self._connection
        transport = connection.transport
        if not self.open or transport is None or connection.closing:
            self.open = False
            return False
        if transport.get_write_buffer_size() > self.bound:
            self.open = False
            connection.drop()  # (the bytes it did not read are freed now, not when it reads them)
            return False
        transport.write(data)
        return True


class _Connection(asyncio.Protocol):
    """One client: requests answered in order, its deadlines, or an event stream once it asked for one."""

    def __init__(self, server: "PageServer"):
        self.server = server
        self.transport: asyncio.Transport | None = None
        self.reader = RequestReader(server.limits)
        self.busy: asyncio.Future | None = None  # the reply being awaited
        self.stream: EventStream | None = None
        self.detach: Callable[[EventStream], None] | None = None
        self.closing = False
        self.paused = False  # reading paused: a reply is awaited, or the client does not read ours
        self.blocked = False  # the client does not read our replies (asyncio's flow control)
        self.partial_since: float | None = None
        self.last_activity = 0.0
        self.timer: asyncio.TimerHandle | None = None
        self.eof = False

    # -- asyncio's callbacks ---------------------------------------------------------------------------------
    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]
        server = self.server  # (room was made for it at accept)
        server.connections.add(self)
        server._most = max(server._most, len(server.connections))
        server.fresh[self] = None
        now = server.loop.time()
        self.last_activity = self.partial_since = now  # (its first head is due within the header deadline)
        self.timer = server.loop.call_at(now + server.deadlines.header, self._on_timer)

    def connection_lost(self, exc: Exception | None) -> None:
        self.closing = True
        server = self.server
        server.connections.discard(self)
        server.fresh.pop(self, None)
        server.left()
        if self.timer is not None:
            self.timer.cancel()
            self.timer = None
        if self.busy is not None:
            self.busy.cancel()  # (a read the client no longer waits for)
            self.busy = None
        if self.stream is not None:
            self.stream.open = False
            if self.detach is not None:
                self.detach(self.stream)
            self.stream = self.detach = None
        self.transport = None
        self.reader = None  # type: ignore[assignment]

    def data_received(self, data: bytes) -> None:
        if self.closing or self.stream is not None:
            return  # (a stream's client has nothing more to say: read, so that its leaving is seen at once)
        try:
            self.reader.receive_data(data)
        except HttpError as e:
            self._error(e)
            return
        self._process()

    def eof_received(self) -> bool:
        self.eof = True
        if self.busy is not None:
            return True  # its reply is still written, then the connection closes
        return False

    def pause_writing(self) -> None:
        if self.stream is None:  # (a stream is bounded by STREAM_BUFFER instead)
            self.blocked = True
            self._pause(True)

    def resume_writing(self) -> None:
        if self.stream is None:
            self.blocked = False
            self._pause(self.busy is not None)
            self._process()

    # -- requests ---------------------------------------------------------------------------------------------
    def _pause(self, paused: bool) -> None:
        if paused != self.paused and self.transport is not None and not self.closing:
            self.paused = paused
            if paused:
                self.transport.pause_reading()
            else:
                self.transport.resume_reading()

    def _process(self) -> None:
        server = self.server
        while self.busy is None and self.stream is None and not self.closing and not self.blocked:
            try:
                event = self.reader.next_event()
            except HttpError as e:
                self._error(e)
                return
            if event is NEED_DATA:
                if self.reader.buffered and self.partial_since is None:
                    self._partial_started()
                if self.eof:
                    self._close()
                return
            if event is CONTINUE:
                self.transport.write(b"HTTP/1.1 100 Continue\r\n\r\n")  # type: ignore[union-attr]
                continue
            server.fresh.pop(self, None)
            self.partial_since = None
            self.last_activity = server.loop.time()
            try:
                answer = server.handle(event)
            except Exception:  # noqa: BLE001 - a broken page handler answers 500, the server goes on
                log.exception("the page server's handler failed")
                answer = Reply(500, b"internal error\n")
            if isinstance(answer, StreamReply):
                self._stream(answer)
            elif isinstance(answer, Reply):
                self._reply(answer, event.keep_alive)
            else:
                self.busy = asyncio.ensure_future(answer)
                self._pause(True)  # (pipelined requests wait in the socket, not in memory)
                self.busy.add_done_callback(lambda task, keep=event.keep_alive: self._done(task, keep))

    def _done(self, task: asyncio.Future, keep_alive: bool) -> None:
        if task is not self.busy:  # (the client left: cancelled at connection_lost, or done just before)
            if not task.cancelled():
                task.exception()  # (retrieved: nobody waits for it)
            return
        self.busy = None
        if task.cancelled():
            return
        error = task.exception()
        if error is not None:
            log.error("the page server's handler failed: %r", error)
            answer = Reply(500, b"internal error\n")
        else:
            answer = task.result()
        self.last_activity = self.server.loop.time()
        self._reply(answer, keep_alive and not self.eof)
        if not self.closing:
            self._pause(self.blocked)
            self._process()

    def _reply(self, reply: Reply, keep_alive: bool) -> None:
        if self.closing or self.transport is None:
            return
        self.transport.write(format_head(reply.status, reply.content_type, len(reply.body), keep_alive,
                                         self.server.headers) + reply.body)
        if not keep_alive:
            self._close()

    def _stream(self, reply: StreamReply) -> None:
        transport = self.transport
        assert transport is not None
        if self.timer is not None:  # (no deadline: a stream lasts while its client reads it)
            self.timer.cancel()
            self.timer = None
        sock = transport.get_extra_info("socket")
        if sock is not None:
            try:
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, STREAM_SNDBUF)
            except OSError:
                pass
        transport.write(format_head(200, "text/event-stream", None, False, self.server.headers) + reply.first)
        self.stream = EventStream(self, len(reply.first))
        self.detach = reply.detach
        self.reader = None  # type: ignore[assignment]  # (what a stream's client sends is not read into memory)
        reply.attach(self.stream)

    def _error(self, e: HttpError) -> None:
        self._reply(Reply(e.status, ("%d %s\n" % (e.status, e.reason)).encode("ascii", "replace")), False)

    def _close(self) -> None:
        if not self.closing and self.transport is not None:
            self.closing = True
            self.transport.close()

    def drop(self) -> None:
        """Close at once, unsent bytes discarded, the kernel's too: a reset, not a FIN that would wait behind the
        bytes a client does not read (an orphaned socket holding them for minutes)."""
        if self.transport is not None:
            self.closing = True
            sock = self.transport.get_extra_info("socket")
            if sock is not None:
                try:
                    sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
                except OSError:
                    pass
            self.transport.abort()

    # -- deadlines (net.xmlrpc_server.Deadlines decides) ------------------------------------------------------
    def _partial_started(self) -> None:
        now = self.server.loop.time()
        self.partial_since = now
        deadline = now + self.server.deadlines.header
        if self.timer is None or self.timer.when() > deadline:
            if self.timer is not None:
                self.timer.cancel()
            self.timer = self.server.loop.call_at(deadline, self._on_timer)

    def _on_timer(self) -> None:
        self.timer = None
        if self.closing or self.transport is None or self.stream is not None:
            return
        deadlines = self.server.deadlines
        now = self.server.loop.time()
        reader = self.reader
        busy = self.busy is not None
        deadline = deadlines.next(now=now, busy=busy, partial_since=self.partial_since,
                                  body_pending=bool(reader.buffered) and not reader.head_pending,
                                  last_activity=self.last_activity)
        verdict = deadlines.verdict(now, deadline, busy=busy, buffered=bool(reader.buffered))
        if verdict == "408":
            self._error(HttpError(408, "Request Timeout"))
        elif verdict == "close":
            self._close()
        else:
            self.timer = self.server.loop.call_at(deadline, self._on_timer)


class PageServer:
    """The server on the running loop: `handle(request)` answers each request; `headers` (raw header lines)
    go with every response. At `max_connections` (from the open-file limit unless given, at most
    MAX_CONNECTIONS), a new client evicts the oldest connection without a whole request, else the one idle
    longest; if every one is a stream or awaits its reply, the newcomer is closed."""

    def __init__(self, handle: Handle, host: str, port: int, *, headers: bytes = b"",
                 max_connections: int | None = None):
        self.handle = handle
        self.host = host
        self.port = port
        self.headers = headers
        self.max_connections = min(MAX_CONNECTIONS, connection_cap()) if max_connections is None else max_connections
        # GET and POST; the heads are not cached (browsers' heads differ: a cache would be memory for nothing)
        self.limits = RequestLimits(MAX_BODY_SIZE, MAX_HEADER_SIZE, 100, methods=(b"GET", b"POST"), fields=True,
                                    cache=0)
        self.deadlines = Deadlines(HEADER_TIMEOUT_S, REQUEST_TIMEOUT_S, IDLE_TIMEOUT_S)
        self.connections: set[_Connection] = set()
        self.fresh: dict[_Connection, None] = {}  # those without a whole request yet, oldest first
        self.loop: asyncio.AbstractEventLoop = None  # type: ignore[assignment]
        self._server: Any = None
        self._listeners: list[socket.socket] = []
        self._accepting = 0  # accepted, not made yet
        self._accept_failures: set = set()  # the errnos already said
        self._trim = _malloc_trim()
        self._most = 0  # the most connections held since the last trim
        self._trimming: asyncio.TimerHandle | None = None

    def left(self) -> None:
        """A connection closed: once the server holds half as many as it did at most since the last trim, their
        memory goes back to the system soon (once for many that leave together; not while a flood churns at
        the cap, where it would be used again at once)."""
        if (self._trim is not None and self._trimming is None and self.loop is not None
                and len(self.connections) <= self._most // 2):
            self._trimming = self.loop.call_later(TRIM_AFTER_S, self._trimmed)

    def _trimmed(self) -> None:
        self._trimming = None
        self._most = len(self.connections)
        gc.collect()  # (what the clients left in reference cycles is freed now, not at some later collection)
        self._trim()  # type: ignore[misc]

    def evict(self) -> bool:
        """Close a connection to make room: the oldest without a whole request (a slow client), else the one
        idle longest; False if none may go (streams and awaited replies stay)."""
        victim = next(iter(self.fresh), None)
        if victim is None:
            idle = [c for c in self.connections if c.busy is None and c.stream is None and not c.closing]
            if not idle:
                return False
            victim = min(idle, key=lambda c: c.last_activity)
        self.connections.discard(victim)
        self.fresh.pop(victim, None)
        victim.drop()
        return True

    async def start(self) -> None:
        """Listen (OSError when the address is taken); `port` is then the one bound."""
        self.loop = loop = asyncio.get_running_loop()
        self._server = await loop.create_server(lambda: _Connection(self), self.host, self.port, reuse_address=True,
                                                backlog=LISTEN_BACKLOG, start_serving=False)
        # asyncio binds; the accepting is ours (as net.xmlrpc_server's): room is made under the cap before a
        # connection is accepted, not after (asyncio accepts a whole backlog before it makes any), and running
        # out of files backs off with one line, not a traceback per attempt
        for bound in self._server.sockets:
            listener = socket.socket(fileno=os.dup(bound.fileno()))
            listener.setblocking(False)
            listener.listen(LISTEN_BACKLOG)
            self._listeners.append(listener)
            loop.add_reader(listener.fileno(), self._accept, listener)
        self.port = self._server.sockets[0].getsockname()[1]

    def _accept(self, listener: socket.socket) -> None:
        loop = self.loop
        for _ in range(ACCEPT_BATCH):
            try:
                conn, _addr = listener.accept()
            except (BlockingIOError, InterruptedError, ConnectionAbortedError):
                return
            except OSError as e:  # (out of files: the clients wait in the backlog meanwhile)
                if e.errno not in self._accept_failures:
                    self._accept_failures.add(e.errno)
                    log.warning("the page server on port %d: accept() failed (%s); new connections wait",
                                self.port, e.strerror)
                loop.remove_reader(listener.fileno())
                loop.call_later(ACCEPT_BACKOFF_S, self._resume_accepting, listener)
                return
            if len(self.connections) + self._accepting >= self.max_connections and not self.evict():
                conn.close()  # every connection is a stream or awaits a reply: the newcomer waits its turn
                continue
            conn.setblocking(False)
            self._accepting += 1
            task = loop.create_task(loop.connect_accepted_socket(lambda: _Connection(self), conn))
            task.add_done_callback(lambda t, c=conn: self._made(t, c))

    def _made(self, task: asyncio.Future, conn: socket.socket) -> None:
        self._accepting -= 1
        if task.cancelled() or task.exception() is not None:  # (reset meanwhile, or the server stopping)
            conn.close()

    def _resume_accepting(self, listener: socket.socket) -> None:
        if listener in self._listeners:
            self.loop.add_reader(listener.fileno(), self._accept, listener)

    async def stop(self) -> None:
        """Stop listening; every connection closed once what was written to it is sent (a page's last event)."""
        for listener in self._listeners:
            self.loop.remove_reader(listener.fileno())
            listener.close()
        self._listeners = []
        if self._server is not None:
            self._server.close()
        for connection in list(self.connections):
            connection._close()
        self._server = None
        if self._trimming is not None:
            self._trimming.cancel()
        await asyncio.sleep(0.1)
