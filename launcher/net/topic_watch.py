"""A watch of a publisher's messages (the stall check's `watch_topic`): a subscriber's connection of any type that
counts the frames and keeps none of their bytes (`CountingLink`), opened by `watch_publisher` once the publisher's
header has come, and asked for again as the node's publisher comes and goes (`PublisherWatch`).

The stall check (health/stall.py) imports this module when it first watches a topic: a launch that watches none
loads no TCPROS code for it."""

from __future__ import annotations

import asyncio
import logging
import socket
from collections.abc import Callable

from launcher import compat
from launcher.net import linkstate, xmlrpc
from launcher.net.connect import lookup_name
from launcher.net.http import split_uri
from launcher.net.linkstate import BROKEN, CLOSED, ENDED, FAILED, HEADER, PublisherLinkState
from launcher.net.tcpros import ANY_MD5, FrameCounter, ScratchPool, TcprosError, TopicType

log = logging.getLogger("launcher.stall")

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


class PublisherWatch:
    """The watch's connection to a node's own publisher of one topic, opened in the background (a verdict never
    waits for a handshake). A node that does not publish the topic yet, or whose port does not answer, is asked
    again at the next verdict; a connection that ended is tried again as linkstate.PublisherRetry says (a refusal
    or a header of no message type: not in this run of the node), each lie one warning line naming the publisher
    and the topic."""

    def __init__(self, uri: str, topic: str, callerid: str, on_messages: Callable[[int], None], timeout: float):
        self.loop = asyncio.get_running_loop()
        self.uri = uri
        self.topic = topic
        self.callerid = callerid
        self.on_messages = on_messages
        self.timeout = timeout
        self.retry = linkstate.PublisherRetry()
        self.link: CountingLink | None = None
        self.task: asyncio.Task | None = None
        self.timer: asyncio.TimerHandle | None = None   # the next attempt after a connection ended
        self.given_up = False                           # refused: none in this run
        self.closed = False

    def check(self) -> None:
        """At each verdict: count what came (a quiet topic's messages wait under the socket's low-water mark), or
        ask for the topic if nothing is under way."""
        if self.link is not None:
            self.link.drain()
        elif self.task is None and self.timer is None and not self.given_up:
            self._open_soon()

    def _open_soon(self) -> None:
        self.timer = None
        if not self.closed and self.task is None:
            self.task = self.loop.create_task(self._open())

    async def _open(self) -> None:
        opened = self.loop.time()
        try:
            try:
                code, _msg, proto = await xmlrpc.call(self.uri, "requestTopic", self.callerid, self.topic, [["TCPROS"]],
                                                      timeout=self.timeout)
            except (OSError, asyncio.TimeoutError, xmlrpc.Fault, xmlrpc.XmlRpcError, ValueError, TypeError):
                return
            if code != 1 or not isinstance(proto, list) or len(proto) < 3 or proto[0] != "TCPROS":
                return  # (not published yet: asked again at the next verdict)
            host = proto[1] or split_uri(self.uri).hostname
            link = await watch_publisher(host, int(proto[2]), self.topic, self.callerid, self.uri, self.on_messages,
                                         timeout=self.timeout, on_close=self._closed)
            if self.closed:
                link.close()
            else:
                self.link = link
        except TcprosError as exc:
            self._ended(exc.ending, opened, str(exc))
        except (OSError, asyncio.TimeoutError, ValueError, TypeError) as exc:
            # no connection at all (a node starting under load, or going): no lie, asked again at the next verdict
            log.debug("cannot connect to publisher %s of %s: %s", self.uri, self.topic, exc)
        finally:
            self.task = None

    def _closed(self, link: CountingLink) -> None:
        if link is self.link:
            self.link = None
        assert link.state is not None
        self._ended(link.ending or linkstate.ENDED, link.state.opened_at, link.why)

    def _ended(self, how: str, opened_at: float, why: str) -> None:
        if self.closed or how == linkstate.CLOSED:
            return
        now = self.loop.time()
        due = self.retry.ended(how, opened_at, now)
        if due is None:
            self.given_up = True
            what = "%s; dropping the connection, not watched again until the node starts again" % why
        else:
            self.timer = self.loop.call_at(due, self._open_soon)
            what = "%s; dropping the connection, trying again in %g s" % (why, due - now)
        log.log(logging.DEBUG if how == linkstate.ENDED else logging.WARNING, "%s", what)

    def close(self) -> None:
        self.closed = True
        if self.timer is not None:
            self.timer.cancel()
        if self.task is not None:
            self.task.cancel()
        if self.link is not None:
            self.link.close()
