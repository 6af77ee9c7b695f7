"""The page server's HTTP side (operate/webserver.py) on real loopback sockets, with a handler of the test's own: the
header deadline, the connection cap and whom it evicts, event streams dropped once a client leaves too much unread,
replies in order, and the page's guards and token refusal (operate/web.py's Page) without a launch."""

from __future__ import annotations

import asyncio
import json
import socket

import pytest

from helpers import until_async
from launcher.net.http import Request
from launcher.operate import web, webserver
from launcher.operate.webserver import PageServer, Reply, StreamReply


async def connect(port: int) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
    return await asyncio.open_connection("127.0.0.1", port)


async def answer(reader: asyncio.StreamReader, timeout: float = 5.0) -> bytes:
    """One whole response (its head and a Content-Length body)."""
    head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), timeout)
    length = [int(line.split(b":")[1]) for line in head.split(b"\r\n") if line.lower().startswith(b"content-length")]
    return head + (await asyncio.wait_for(reader.readexactly(length[0]), timeout) if length else b"")


async def closed(reader: asyncio.StreamReader, timeout: float = 5.0) -> bytes:
    """What the server sent until it closed the connection (ConnectionResetError counts as closed)."""
    try:
        return await asyncio.wait_for(reader.read(), timeout)
    except ConnectionResetError:
        return b""


def serve(handle, **kw):
    """A PageServer on a free loopback port, started and stopped around the test's coroutine."""
    def run(scenario):
        async def main():
            server = PageServer(handle, "127.0.0.1", 0, **kw)
            await server.start()
            try:
                return await scenario(server)
            finally:
                await server.stop()
        return asyncio.run(main())
    return run


def echo(request: Request):
    if request.target == b"/slow":
        async def later() -> Reply:
            await asyncio.sleep(0.2)
            return Reply(200, b"slow")
        return later()
    return Reply(200, b"%s %s %s" % (request.method, request.target, request.query))


def test_get_and_post_are_answered_in_order_on_one_connection_pipelined_or_not():
    async def scenario(server):
        reader, writer = await connect(server.port)
        writer.write(b"GET /slow HTTP/1.1\r\nHost: h\r\n\r\nGET /a?b=c HTTP/1.1\r\nHost: h\r\n\r\n"
                     b"POST /p HTTP/1.1\r\nHost: h\r\nContent-Length: 2\r\n\r\nhi")
        first, second, third = [await answer(reader) for _ in range(3)]
        writer.close()
        return first, second, third
    first, second, third = serve(echo)(scenario)
    assert first.startswith(b"HTTP/1.1 200 OK\r\n") and first.endswith(b"\r\n\r\nslow")
    assert second.endswith(b"GET /a b=c") and third.endswith(b"POST /p ")


def test_a_request_head_too_slow_to_arrive_gets_408_and_the_connection_closes(monkeypatch):
    async def scenario(server):
        reader, writer = await connect(server.port)
        writer.write(b"GET / HTTP/1.1\r\nHost: h\r\n")  # (never finished)
        return await closed(reader)
    # the master's deadline policy, shortened: a head within 0.3 s
    monkeypatch.setattr(webserver, "HEADER_TIMEOUT_S", 0.3)
    answer_ = serve(echo)(scenario)
    assert answer_.startswith(b"HTTP/1.1 408 Request Timeout")


def test_at_the_cap_a_new_client_evicts_the_oldest_slow_one_never_a_stream():
    async def scenario(server):
        stream_r, stream_w = await connect(server.port)
        stream_w.write(b"GET /events HTTP/1.1\r\nHost: h\r\n\r\n")
        assert (await asyncio.wait_for(stream_r.readuntil(b"first\n\n"), 5)).startswith(b"HTTP/1.1 200")
        slow = []
        for _ in range(3):  # the cap (4) reached: a stream and three slow heads
            r, w = await connect(server.port)
            w.write(b"GET / HTT")
            slow.append((r, w))
            await until_async(lambda n=len(slow) + 1: len(server.connections) == n, 5, what="connections held")
        reader, writer = await connect(server.port)  # a real client: the oldest slow one makes room
        writer.write(b"GET /now HTTP/1.1\r\nHost: h\r\n\r\n")
        got = await answer(reader)
        assert await closed(slow[0][0]) == b""
        assert len(server.connections) == 4
        stream_w.write(b"ignored")  # (the stream's client may write: it is not read into memory)
        return got, stream_r, slow
    got, stream_r, slow = serve(lambda r: StreamReply(b"first\n\n", lambda s: None, lambda s: None)
                                if r.target == b"/events" else echo(r), max_connections=4)(scenario)
    assert got.endswith(b"GET /now ")


def test_when_every_connection_is_a_stream_a_newcomer_is_closed():
    async def scenario(server):
        streams = []
        for _ in range(2):
            r, w = await connect(server.port)
            w.write(b"GET /events HTTP/1.1\r\nHost: h\r\n\r\n")
            await asyncio.wait_for(r.readuntil(b"first\n\n"), 5)
            streams.append((r, w))
        reader, writer = await connect(server.port)
        writer.write(b"GET / HTTP/1.1\r\nHost: h\r\n\r\n")
        return await closed(reader), len(server.connections)
    got, held = serve(lambda r: StreamReply(b"first\n\n", lambda s: None, lambda s: None), max_connections=2)(scenario)
    assert got == b"" and held == 2


def test_a_stream_whose_client_does_not_read_is_dropped_past_its_bound_and_a_reading_one_is_not():
    streams = []

    async def scenario(server):
        idle = socket.socket()
        idle.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        idle.connect(("127.0.0.1", server.port))
        idle.sendall(b"GET /events HTTP/1.1\r\nHost: h\r\n\r\n")  # and never reads
        reader, writer = await connect(server.port)
        writer.write(b"GET /events HTTP/1.1\r\nHost: h\r\n\r\n")
        await until_async(lambda: len(streams) == 2, 5, what="two streams")
        event = b"data: " + b"x" * 4000 + b"\n\n"
        got = 0
        for _ in range(200):  # 800 kB: far past the kernel's buffers and STREAM_BUFFER for the one not reading
            for s in list(streams):
                if not s.send(event):
                    streams.remove(s)
            while True:  # the reading client reads everything sent so far
                try:
                    got += len(await asyncio.wait_for(reader.read(1 << 20), 0.01))
                except asyncio.TimeoutError:
                    break
        left = len(streams)
        idle.close()
        writer.close()
        return left, got, server
    left, got, server = serve(lambda r: StreamReply(b"", streams.append, lambda s: None))(scenario)
    assert left == 1  # the reading stream alone
    assert got > 200 * 4000  # (it got every event)


@pytest.fixture
def page(tmp_path):
    token_file = tmp_path / "launcher-token"
    token_file.write_text("0123456789abcdef0123456789abcdef\n")
    hub = web.Hub("http://127.0.0.1:1/", {"token_file": str(token_file), "nodes": [], "uri": "http://x/"}, {})
    return web.Page(hub, "127.0.0.1", [8765])


def request(target: bytes, method: bytes = b"GET", fields: tuple = ((b"host", b"127.0.0.1:8765"),)) -> Request:
    return Request(target, b"", True, method, b"", fields)


def test_a_control_without_the_token_is_refused_saying_where_the_token_file_is(page, tmp_path):
    refusal = page.handle(request(b"/api/stop", b"POST"))
    assert refusal.status == 403 and str(tmp_path / "launcher-token") in refusal.body.decode()
    assert page.handle(request(b"/api/shutdown", b"POST")).status == 404


def test_the_page_has_an_icon_and_refuses_foreign_hosts_and_origins(page):
    icon = page.handle(request(b"/favicon.ico"))
    assert icon.status == 200 and icon.content_type == "image/svg+xml" and icon.body.startswith(b"<svg")
    assert page.handle(request(b"/icon.svg")).body == icon.body
    assert b'href="/icon.svg"' in page.handle(request(b"/")).body
    assert page.handle(request(b"/", fields=((b"host", b"evil.example:8765"),))).status == 403
    assert page.handle(request(b"/", fields=((b"host", b"127.0.0.1:8765"), (b"origin", b"http://evil.example")))
                       ).status == 403
    assert page.handle(request(b"/nothing")).status == 404


def test_the_address_carries_the_token_only_to_a_terminal(tmp_path):
    token_file = tmp_path / "launcher-token"
    token_file.write_text("0123456789abcdef0123456789abcdef\n")
    to_terminal = web.address_line("http://x:1/", "http://127.0.0.1:8765/", str(token_file), True)
    assert "http://127.0.0.1:8765/#token=0123456789abcdef0123456789abcdef\n" in to_terminal
    elsewhere = web.address_line("http://x:1/", "http://127.0.0.1:8765/", str(token_file), False)
    assert "0123456789abcdef" not in elsewhere and str(token_file) in elsewhere
    assert "http://127.0.0.1:8765/ " in elsewhere
    # a token file this user cannot read: the plain address there too
    unreadable = web.address_line("http://x:1/", "http://127.0.0.1:8765/", str(tmp_path / "none"), True)
    assert "#token" not in unreadable


def test_a_new_page_first_gets_the_table_then_each_broadcast(page):
    class Sink:
        def __init__(self):
            self.data = []

        def send(self, data):
            self.data.append(data)
            return True
    reply = page.handle(request(b"/events"))
    assert isinstance(reply, StreamReply)
    first = json.loads(reply.first.decode()[len("data: "):])
    assert first["type"] == "snapshot" and first["uri"] == "http://x/"
    sink = Sink()
    reply.attach(sink)
    page.hub.broadcast({"type": "changes", "changes": []})
    reply.detach(sink)
    page.hub.broadcast({"type": "gone"})
    assert [json.loads(d.decode()[6:])["type"] for d in sink.data] == ["changes"]
