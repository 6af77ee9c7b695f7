"""A watch of a publisher's messages (the stall check's `watch_topic`): a subscriber's connection of any type that
counts the frames and keeps none of their bytes (`CountingLink`), opened by `watch_publisher` once the publisher's
header has come."""

from __future__ import annotations

import asyncio
import socket
from collections.abc import Callable

from launcher import compat
from launcher.net import linkstate
from launcher.net.connect import lookup_name
from launcher.net.linkstate import BROKEN, CLOSED, ENDED, FAILED, HEADER, PublisherLinkState
from launcher.net.tcpros import ANY_MD5, FrameCounter, ScratchPool, TcprosError, TopicType

# A watcher's socket wakes the loop only once this many bytes wait (SO_RCVLOWAT): a busy topic is read in
# gulps, a quiet one when its watch drains it (`CountingLink.drain`, at each verdict).
WATCH_LOWAT = 64 << 10
WATCH_CHUNK = 256 << 10
# The buffer a drain reads into, borrowed for the drain: a counter keeps none of the bytes, so the watches of
# a launch share one (a buffer each held 256 KiB a watch).
WATCH_BUFFERS = ScratchPool(WATCH_CHUNK, kept=1)


class CountingLink:
    """A subscriber's connection that only counts the publisher's messages (`on_messages(n)`), reading
    into a buffer borrowed for each drain (WATCH_BUFFERS): no bytes kept, no object per message, few wake-ups
    (see WATCH_LOWAT).
    Once it is closed, `ending` and `why` say how (as PublisherLinkState's)."""

    def __init__(self, sock: socket.socket, counter: FrameCounter, on_messages: Callable[[int], None],
                 state: PublisherLinkState | None = None, on_close: Callable[[CountingLink], None] | None = None):
        self.loop = asyncio.get_running_loop()
        self.sock = sock
        self.counter = counter
        self.on_messages = on_messages
        self.state = state
        self.on_close = on_close
        self.closed = False
        self.ending: str | None = None
        self.why = ""
        self.loop.add_reader(sock.fileno(), self.drain)

    def drain(self) -> None:
        """Count what the socket holds now (the loop calls this when WATCH_LOWAT bytes wait; a watch at
        each verdict, for a quiet topic's last few messages)."""
        if self.closed:
            return
        done = 0
        buf = WATCH_BUFFERS.take()
        view = memoryview(buf)
        try:
            while True:
                got = self.sock.recv_into(buf)
                if not got:  # the publisher closed it
                    cut = self.counter.partial()
                    self._close(BROKEN if cut else ENDED, "closed the connection in the middle of a frame (%s)" % cut
                                if cut else "closed the connection")
                    break
                done += self.counter.feed(view[:got])
                if got < WATCH_CHUNK:
                    break
        except (BlockingIOError, InterruptedError):
            pass
        except (OSError, TcprosError) as exc:
            self._close(BROKEN, str(exc))
        finally:
            WATCH_BUFFERS.give(buf)
        if done:
            self.on_messages(done)

    def _close(self, ending: str, what: str) -> None:
        if not self.closed:
            who = self.state.publisher + " on " + self.state.topic if self.state is not None else str(self.sock)
            self.ending, self.why = ending, "%s: %s" % (who, what)
            self._release()
            if self.on_close is not None:
                self.on_close(self)

    def close(self) -> None:
        self._close(CLOSED, "closed by us")

    def _release(self) -> None:
        self.closed = True
        self.loop.remove_reader(self.sock.fileno())
        self.sock.close()


async def watch_publisher(host: str, port: int, topic: str, callerid: str, publisher_uri: str,
                          on_messages: Callable[[int], None], *, timeout: float = 10.0,
                          on_close: Callable[[CountingLink], None] | None = None) -> CountingLink:
    """A CountingLink to a publisher's TCPROS server, any type, once its header has come: the connection within
    `timeout`, the header by linkstate.HANDSHAKE_TIMEOUT_S; TcprosError(why, ending) if the publisher failed it."""
    loop = asyncio.get_running_loop()
    state = PublisherLinkState(topic, TopicType("*", ANY_MD5, ""), callerid, publisher_uri, loop.time())
    family, kind, proto, _, addr = (await loop.getaddrinfo(lookup_name(host), port, type=socket.SOCK_STREAM))[0]
    sock = socket.socket(family, kind, proto)
    try:
        sock.setblocking(False)
        await compat.wait_for(loop.sock_connect(sock, addr), timeout)
        state.deadline = loop.time() + linkstate.HANDSHAKE_TIMEOUT_S
        await compat.wait_for(loop.sock_sendall(sock, state.request()), linkstate.HANDSHAKE_TIMEOUT_S)
        early = 0  # messages that came with the header
        while state.phase == HEADER:
            try:
                data = await compat.wait_for(loop.sock_recv(sock, 65536), max(0.0, state.deadline - loop.time()))
            except asyncio.TimeoutError:
                data, events = None, state.expire(max(loop.time(), state.deadline))
            except OSError:
                data, events = b"", []
            if data is not None:
                events = state.receive(data, loop.time()) if data else []
                if not data:
                    state.lost(loop.time())
            if state.phase == FAILED:
                raise TcprosError(state.why, state.ending or BROKEN)
            early += sum(what == "message" for what, _ in events)
        counter = FrameCounter()
        early += counter.feed(state.reader.take_pending())
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVLOWAT, WATCH_LOWAT)
    except BaseException:
        sock.close()
        raise
    link = CountingLink(sock, counter, on_messages, state, on_close)
    if early:
        on_messages(early)
    return link
