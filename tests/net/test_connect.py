"""net.connect: a connection to a host by name, looked up without the idna codec, each address tried in turn, one
lookup for a burst of calls, asked again when the kept addresses no longer take a connection."""

from __future__ import annotations

import asyncio
import socket
import subprocess
import sys

import pytest

from launcher.net import connect as C


class Counting(asyncio.Protocol):
    def __init__(self) -> None:
        self.transport = None

    def connection_made(self, transport) -> None:
        self.transport = transport


def listener(host: str = "127.0.0.1") -> socket.socket:
    sock = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET)
    sock.bind((host, 0))
    sock.listen(128)
    return sock


@pytest.fixture(autouse=True)
def fresh_kept():
    C._kept.clear()
    C._asked.clear()
    yield
    C._kept.clear()
    C._asked.clear()


def test_an_ascii_name_is_looked_up_as_bytes_and_another_as_it_is():
    assert C.lookup_name("robot-1.local") == b"robot-1.local"
    assert C.lookup_name("roböter") == "roböter"


def test_a_launch_process_never_loads_the_idna_codec_for_its_names():
    """The codec and unicodedata are 0.7 MB of a launch's memory: a call by name, async and blocking, loads none."""
    code = (
        "import asyncio, socket, sys, threading\n"
        "from launcher.net import xmlrpc\n"
        "s = socket.socket(); s.bind(('127.0.0.1', 0)); s.listen(8); port = s.getsockname()[1]\n"
        "def serve():\n"
        "    for _ in range(2):\n"
        "        c, _ = s.accept(); c.recv(65536)\n"
        "        body = xmlrpc.dumps_response([1, 'ok', 7])\n"
        "        c.sendall(b'HTTP/1.1 200 OK\\r\\nContent-Length: %d\\r\\n\\r\\n' % len(body) + body); c.close()\n"
        "threading.Thread(target=serve, daemon=True).start()\n"
        "uri = 'http://localhost:%d/' % port\n"
        "assert xmlrpc.call_blocking(uri, 'getPid', '/x') == [1, 'ok', 7]\n"
        "assert asyncio.run(xmlrpc.call(uri, 'getPid', '/x')) == [1, 'ok', 7]\n"
        "print(sorted(m for m in sys.modules if m in ('encodings.idna', 'stringprep', 'unicodedata')))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"


def test_each_address_of_a_name_is_tried_until_one_takes_the_connection(monkeypatch):
    """localhost as ::1 first and 127.0.0.1 after, the server on the second only (a node bound to IPv4)."""
    with listener() as server:
        port = server.getsockname()[1]
        closed = socket.socket()
        closed.bind(("127.0.0.1", 0))
        refusing = closed.getsockname()  # (bound, not listening: refused)

        def getaddrinfo(host, _port, family=0, kind=0, proto=0, flags=0):
            assert host == b"robot" and _port is None
            return [(socket.AF_INET, socket.SOCK_STREAM, 6, "", ("127.0.0.2", 0)),
                    (socket.AF_INET, socket.SOCK_STREAM, 6, "", ("127.0.0.1", 0))]
        monkeypatch.setattr(socket, "getaddrinfo", getaddrinfo)

        async def go():
            loop = asyncio.get_running_loop()
            transport, protocol = await C.connect(loop, Counting, "robot", port)
            assert transport.get_extra_info("peername") == ("127.0.0.1", port) and protocol.transport is transport
            transport.close()
            with pytest.raises(OSError):  # (no address takes it: the error of the address tried)
                await C.connect(loop, Counting, "robot", refusing[1])
        asyncio.run(go())
        closed.close()


def test_a_burst_of_calls_to_one_name_is_one_lookup_and_a_cancelled_caller_leaves_the_others(monkeypatch):
    looked_up = []

    def getaddrinfo(host, *args, **kw):
        looked_up.append(host)
        return [(socket.AF_INET, socket.SOCK_STREAM, 6, "", ("127.0.0.1", 0))]
    monkeypatch.setattr(socket, "getaddrinfo", getaddrinfo)
    with listener() as server:
        port = server.getsockname()[1]

        async def go():
            loop = asyncio.get_running_loop()
            calls = [asyncio.ensure_future(C.connect(loop, Counting, "robot", port)) for _ in range(50)]
            await asyncio.sleep(0)
            calls[0].cancel()  # (while the lookup is in flight: the 49 others still connect)
            done = await asyncio.gather(*calls, return_exceptions=True)
            assert isinstance(done[0], asyncio.CancelledError)
            for transport, _ in done[1:]:
                transport.close()
            assert looked_up == [b"robot"]
            transport, _ = await C.connect(loop, Counting, "robot", port)  # (kept: no lookup)
            transport.close()
            assert looked_up == [b"robot"]
        asyncio.run(go())


def test_kept_addresses_that_no_longer_take_the_connection_are_looked_up_again(monkeypatch):
    """A host that moved within KEPT_S: its old address refuses, the name is asked again, the new one answers."""
    with listener() as server:
        port = server.getsockname()[1]
        answers = [("127.0.0.2", 0), ("127.0.0.1", 0)]
        looked_up = []

        def getaddrinfo(host, *args, **kw):
            looked_up.append(host)
            return [(socket.AF_INET, socket.SOCK_STREAM, 6, "", answers[len(looked_up) - 1])]
        monkeypatch.setattr(socket, "getaddrinfo", getaddrinfo)

        async def go():
            loop = asyncio.get_running_loop()
            C._kept[b"robot"] = (float("inf"), getaddrinfo(b"robot"))  # (the old address, kept)
            transport, _ = await C.connect(loop, Counting, "robot", port)
            assert transport.get_extra_info("peername") == ("127.0.0.1", port)
            transport.close()
            assert looked_up == [b"robot", b"robot"] and C._kept[b"robot"][1][0][4] == ("127.0.0.1", 0)
        asyncio.run(go())


def test_a_numeric_address_is_not_looked_up(monkeypatch):
    monkeypatch.setattr(socket, "getaddrinfo", lambda *a, **k: pytest.fail("looked up"))
    with listener() as server:
        port = server.getsockname()[1]

        async def go():
            transport, _ = await C.connect(asyncio.get_running_loop(), Counting, "127.0.0.1", port)
            transport.close()
        asyncio.run(go())
