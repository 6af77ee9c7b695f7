"""A launch slow to answer is not a launch that has ended: the followers (`events -f`, `status --watch`, the web
page's server, the views) ask it again after a call that timed out, and end only once nothing listens at its
address. (A loaded robot computer, or a soak at a load of 150 on 2 cores, made every follower end on its first
timeout while the launch ran on.)"""

from __future__ import annotations

import asyncio
import socket
import threading

from launcher.net.xmlrpc_codec import dumps_response
from launcher.net import http
from launcher.operate import client, web


class HeldServer:
    """A server on a real socket: its first connection is read and never answered (the call times out), the second
    gets `answer`; then it stops listening (refused, as after the launch's end)."""

    def __init__(self, answer: bytes):
        self.listener = socket.socket()
        self.listener.bind(("127.0.0.1", 0))
        self.listener.listen(4)
        self.uri = "http://127.0.0.1:%d/" % self.listener.getsockname()[1]
        self.answer = answer
        self.held: list[socket.socket] = []
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self) -> None:
        for turn in range(2):
            conn, _ = self.listener.accept()
            conn.recv(65536)
            if turn == 0:
                self.held.append(conn)  # (read, never answered)
                continue
            conn.sendall(http.format_response(200, "OK", self.answer, False))
            conn.close()
        self.listener.close()

    def close(self) -> None:
        for conn in self.held:
            conn.close()
        self.listener.close()


def test_a_follower_asks_again_after_a_timeout_and_ends_when_refused(monkeypatch):
    monkeypatch.setattr(client, "ANSWER_MARGIN_S", 0.3)
    server = HeldServer(dumps_response([1, "changes", '{"seq":7,"complete":true,"changes":[{"seq":7}]}']))
    answers = []
    try:
        last = client.follow_changes(server.uri, 6, answers.append, wait=0.1)
    finally:
        server.close()
    assert answers == [{"seq": 7, "complete": True, "changes": [{"seq": 7}]}]
    assert last == 7


def test_a_call_that_times_out_is_no_answer_and_a_refused_one_no_launch(monkeypatch):
    monkeypatch.setattr(client, "ANSWER_MARGIN_S", 0.3)
    server = HeldServer(b"")
    try:
        try:
            client.changes(server.uri, 0, 0.1)
            raise AssertionError("answered")
        except client.ToolError as e:
            slow_one = e
    finally:
        server.close()
    assert isinstance(slow_one, client.NoAnswer) and slow_one.status == client.EXIT_NO_LAUNCH
    try:
        client.changes(server.uri, 0, 0.1)
        raise AssertionError("answered")
    except client.ToolError as e:
        gone = e
    assert not isinstance(gone, client.NoAnswer) and gone.status == client.EXIT_NO_LAUNCH


def test_the_page_server_keeps_reading_a_launch_slow_to_answer(monkeypatch):
    """Its readers count only failures that say the launch has ended: five timeouts in a row, then an answer,
    leave it serving; three refusals in a row end it (and its pages are told "gone")."""
    monkeypatch.setattr(web, "RETRY_S", 0.01)
    hub = web.Hub("http://127.0.0.1:1/", {"nodes": [], "uri": "http://x/"}, {})
    told = []
    monkeypatch.setattr(hub, "broadcast", told.append)

    async def scenario(failure: BaseException) -> int:
        hub.gone = asyncio.Event()
        calls = [0]

        async def body() -> None:
            calls[0] += 1
            if calls[0] <= 5:
                raise failure
            hub.gone.set()  # (answered: the test's end)
        await asyncio.wait_for(hub._loop(body), 10)
        return calls[0]
    assert asyncio.run(scenario(asyncio.TimeoutError())) == 6 and told == []
    assert asyncio.run(scenario(ConnectionRefusedError())) == 3 and told == [{"type": "gone"}]
