"""XML-RPC clients for ROS 1, asyncio and blocking, on the sans-I/O codec of `launcher.net.xmlrpc_codec`.

Both clients frame the HTTP reply with `launcher.net.http.ResponseReader`. The
codec's names (Fault, XmlRpcError, encode_value, dumps_*/loads_*) are importable
from here too, for the callers that both call and encode. The HTTP server is
`launcher.net.xmlrpc_server`. This module does not import asyncio (~25 ms): a
launch talks to a running master with `call_blocking` and spawns its nodes
before it starts an event loop.
"""

from __future__ import annotations

import socket
from typing import Any, Iterable

from launcher.net import http
from launcher.net.connect import connect, lookup_name
from launcher.net.xmlrpc_codec import (MAX_DEPTH, MAXINT, MININT, Encoded, Fault, XmlRpcError, dumps_fault,
                                       dumps_request, dumps_response, encode_value, loads_request,
                                       loads_response)

__all__ = [
    "Encoded", "encode_value", "Fault", "XmlRpcError", "loads_request", "loads_response", "dumps_request",
    "dumps_response", "dumps_fault", "call", "call_blocking", "MAXINT", "MININT", "MAX_DEPTH",
]

MAX_RESPONSE_SIZE = 64 * 1024 * 1024  # what `call` accepts from a server


def _http_request(uri: str, method: str, params: Iterable[Any]) -> tuple[str, int, bytes]:
    """(host, port, the whole HTTP request) for one call."""
    u = http.split_uri(uri)
    if u.scheme != "http" or not u.hostname:
        raise XmlRpcError("not an http:// XML-RPC URI: %r" % uri)
    host_header = u.netloc.rsplit("@", 1)[-1]
    return u.hostname, u.port or 80, http.format_request(u.path or "/", host_header, dumps_request(method, params))


def _reply(uri: str, reader: http.ResponseReader) -> Any:
    """The value of the complete response in `reader`."""
    event = reader.next_event()
    assert isinstance(event, http.Response)
    if event.status != 200:
        raise XmlRpcError("HTTP %d from %s" % (event.status, uri))
    return loads_response(event.body)


def _bad_response(uri: str, e: http.HttpError) -> XmlRpcError:
    return XmlRpcError("bad HTTP response from %s: %s" % (uri, e.reason))


async def call(uri: str, method: str, *params: Any, timeout: float | None = 10.0,
               connect_timeout: float | None = None) -> Any:
    """Call `method(*params)` at an XML-RPC `uri` (one connection per call), on the running loop.

    `timeout` bounds the whole call, `connect_timeout` the connection alone.
    Returns the value; raises Fault, XmlRpcError (bad HTTP/XML), OSError
    (TimeoutError when there is no connection in time) or asyncio.TimeoutError.
    """
    import asyncio

    from launcher import compat
    loop = asyncio.get_running_loop()
    host, port, request = _http_request(uri, method, params)
    reply = loop.create_future()
    deadline = None if timeout is None else loop.time() + timeout
    exchange = _Exchange(uri, request, reply)
    connecting = connect(loop, lambda: exchange, host, port)
    limit = timeout if connect_timeout is None else connect_timeout if timeout is None else min(timeout,
                                                                                                 connect_timeout)
    timer = None
    try:
        if limit is None:
            await connecting
        else:
            try:
                await compat.wait_for(connecting, limit)
            except asyncio.TimeoutError:
                if limit == timeout:
                    raise
                raise TimeoutError("no connection to %s within %g s" % (uri, limit)) from None
        if deadline is not None:
            timer = loop.call_at(deadline, _expire, reply)
        return await reply
    finally:
        # (also when the call was cancelled as its connection was made: that connection is closed, and its
        # reply, which nobody reads now, gets no error to be reported as never retrieved)
        reply.cancel()
        exchange.close()
        if timer is not None:
            timer.cancel()


def _expire(reply: Any) -> None:
    if not reply.done():
        import asyncio
        reply.set_exception(asyncio.TimeoutError())


class _Exchange:
    """One call's connection (an asyncio protocol): the request written once connected, the reply framed.

    Plain callbacks, no stream objects or tasks: the master makes a thousand of
    these at once to nodes, on the loop that answers its own clients.
    """

    def __init__(self, uri: str, request: bytes, reply: Any):
        self.uri = uri
        self.request = request
        self.reply = reply
        self.reader = http.ResponseReader(MAX_RESPONSE_SIZE)
        self.transport: Any = None

    def connection_made(self, transport: Any) -> None:
        self.transport = transport
        transport.write(self.request)

    def close(self) -> None:
        if self.transport is not None:
            self.transport.close()

    def data_received(self, data: bytes) -> None:
        self._feed(data)

    def eof_received(self) -> None:
        self._feed(b"")

    def connection_lost(self, exc: Exception | None) -> None:
        if not self.reply.done():
            self.reply.set_exception(exc or XmlRpcError("bad HTTP response from %s: connection closed" % self.uri))

    def pause_writing(self) -> None:
        pass  # one request, written once: the transport buffers it

    def resume_writing(self) -> None:
        pass

    def _feed(self, data: bytes) -> None:
        if self.reply.done():
            return
        reader = self.reader
        try:
            reader.receive_data(data)
            if reader.next_event() is http.NEED_DATA:
                return
            self.reply.set_result(_reply(self.uri, reader))
        except http.HttpError as e:
            self.reply.set_exception(_bad_response(self.uri, e))
        except (Fault, XmlRpcError) as e:
            self.reply.set_exception(e)
        self.transport.close()


def call_blocking(uri: str, method: str, *params: Any, timeout: float = 10.0) -> Any:
    """`call`, blocking this thread: for the steps of a launch that run before its event loop.

    `timeout` bounds the connection and each read (socket.timeout is an OSError).
    Returns the value; raises Fault, XmlRpcError (bad HTTP/XML) or OSError.
    """
    host, port, request = _http_request(uri, method, params)
    reader = http.ResponseReader(MAX_RESPONSE_SIZE)
    with socket.create_connection((lookup_name(host), port), timeout=timeout) as sock:
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.sendall(request)
        try:
            while reader.next_event() is http.NEED_DATA:
                reader.receive_data(sock.recv(65536))
        except http.HttpError as e:
            raise _bad_response(uri, e) from None
    return _reply(uri, reader)
