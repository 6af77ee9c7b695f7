"""A ROS node living inside the launcher: its slave XML-RPC API, master registrations and topic links."""

from __future__ import annotations

import asyncio
import logging
import os
import socket
from collections.abc import Callable, Mapping
from typing import Any

from launcher import compat
from launcher.net.hostname import listen_address
from launcher.net.open_files import connection_cap
from launcher.net.xmlrpc import call
from launcher.net.xmlrpc_server import XmlRpcServer
from launcher.net.linkstate import BROKEN, CLOSED, ENDED, REFUSED, PublisherRetry
from launcher.net.publication import Publication
from launcher.net.publisher_link import PublisherLink, connect_publisher
from launcher.net.service import ServiceServer
from launcher.net.tcpros import TcprosError, TopicType
from launcher.net.tcpros_server import TcprosServer

log = logging.getLogger("launcher.slave")


def default_host(environ: Mapping[str, str] | None = None) -> str:
    """The address other nodes use to reach us, chosen the way rospy/roscpp choose it."""
    env = os.environ if environ is None else environ
    return env.get("ROS_HOSTNAME") or env.get("ROS_IP") or socket.gethostname()


class Subscription:
    """A topic we subscribe to, and our connections to its publishers.

    A connection that ends is tried again as PublisherRetry says (its back-off is per publisher, kept while the
    master lists it): a refusal or a header we must not take waits for the next publisherUpdate that lists the
    publisher; a broken one is retried after 1, 2, 4 ... 30 s. Each publisher that lied is one warning line."""

    def __init__(self, node: SlaveNode, topic: str, mtype: TopicType,
                 callback: Callable[[bytes, PublisherLink], None]):
        self.node = node
        self.topic = topic
        self.mtype = mtype
        self.callback = callback
        self.links: dict[str, PublisherLink] = {}
        self.connecting: dict[str, asyncio.Task] = {}
        self.retries: dict[str, PublisherRetry] = {}       # every publisher listed, by URI
        self.timers: dict[str, asyncio.TimerHandle] = {}   # the next attempt of those waiting for one
        # the header fields its publishers send alike, by md5sum, kept once: a hundred /rosout links keep one
        # rosgraph_msgs/Log definition (1.5 kB with roscpp's comments), not a hundred
        self.alike: dict[str, dict[str, str]] = {}
        self.closed = False

    def update(self, publisher_uris: list[str], *, additive: bool = False) -> None:
        """Follow the master's list of publishers: connect to new ones, drop the ones that left
        (unless `additive`: the list may be older than a publisherUpdate already applied; nor is it a
        publisher advertising again)."""
        if self.closed:
            return
        wanted = set(publisher_uris) if not additive else set(publisher_uris) | set(self.retries)
        for uri in list(self.retries):
            if uri not in wanted:
                self._forget(uri)
        for uri in publisher_uris:
            retry = self.retries.get(uri)
            if retry is None:
                self.retries[uri] = PublisherRetry()
                self._start(uri)
            elif not additive and retry.listed():
                self._start(uri)

    def _forget(self, uri: str) -> None:
        self.retries.pop(uri, None)
        timer = self.timers.pop(uri, None)
        if timer is not None:
            timer.cancel()
        task = self.connecting.pop(uri, None)
        if task is not None:
            task.cancel()
        link = self.links.pop(uri, None)
        if link is not None:
            link.close()

    def _start(self, uri: str) -> None:
        timer = self.timers.pop(uri, None)
        if timer is not None:
            timer.cancel()
        if uri not in self.links and uri not in self.connecting:
            self.connecting[uri] = asyncio.get_running_loop().create_task(self._connect(uri))

    async def _connect(self, uri: str) -> None:
        loop = asyncio.get_running_loop()
        opened = loop.time()
        link = None
        try:
            reply = await call(uri, "requestTopic", self.node.name, self.topic, [["TCPROS"]],
                               timeout=10.0)
            code, status, proto = reply
            if code != 1 or not isinstance(proto, list) or len(proto) < 3 or proto[0] != "TCPROS":
                self._ended(uri, REFUSED, opened, "publisher %s on %s offers no TCPROS: %s" % (
                    uri, self.topic, str(status)[:200]))
                return
            link = PublisherLink(self.topic, self.mtype, self.node.name, uri,
                                 self.callback, self._link_closed)
            await connect_publisher(str(proto[1]), int(proto[2]), link)
        except asyncio.CancelledError:
            raise
        except TcprosError:
            return  # the link ended in its handshake: _link_closed has said why and what next
        except Exception as exc:  # one unreachable publisher must not affect the others
            if link is not None:
                if link.closed:
                    return  # (as above)
                link.close()
            # Short-lived nodes (rosservice, rostopic) come and go all the time: not a warning.
            self._ended(uri, BROKEN, opened, "cannot connect to publisher %s of %s: %s" % (uri, self.topic, exc),
                        quiet=True)
            return
        finally:
            if self.connecting.get(uri) is asyncio.current_task():
                del self.connecting[uri]
        if self.closed or uri not in self.retries or link.closed:
            link.close()  # (if it ended meanwhile, _link_closed has seen to it)
            return
        self.links[uri] = link
        self._share_alike(link.header)

    def _share_alike(self, header: dict[str, str] | None) -> None:
        """The fields of a publisher's header that another publisher of its md5sum sent alike: the first's."""
        if header is None:
            return
        alike = self.alike.setdefault(header.get("md5sum", ""), {})
        for key in ("type", "md5sum", "message_definition"):
            value = header.get(key)
            if value is not None:
                first = alike.setdefault(key, value)
                if first == value:
                    header[key] = first

    def _link_closed(self, link: PublisherLink) -> None:
        uri = link.publisher_uri
        if self.links.get(uri) is link:
            del self.links[uri]
        self._ended(uri, link.ending or ENDED, link.state.opened_at, link.why, quiet=link.ending == ENDED)

    def _ended(self, uri: str, how: str, opened_at: float, why: str, quiet: bool = False) -> None:
        """A connection to `uri` ended `how`: say so, and when it is tried again."""
        retry = self.retries.get(uri)
        if how == CLOSED or retry is None or self.closed:
            return
        loop = asyncio.get_running_loop()
        now = loop.time()
        at = retry.ended(how, opened_at, now)
        if at is None:
            log.log(logging.DEBUG if quiet else logging.WARNING,
                    "%s; dropping the connection until it advertises again", why)
            return
        log.log(logging.DEBUG if quiet else logging.WARNING, "%s; dropping the connection, trying again in %g s",
                why, at - now)
        self.timers[uri] = loop.call_at(at, self._start, uri)

    async def drain(self, rounds: int = 50) -> None:
        """Let the loop read what the kernel already holds for us, so nothing received is lost."""
        for _ in range(rounds):
            before = sum(l.bytes_received for l in self.links.values())
            await asyncio.sleep(0)
            if sum(l.bytes_received for l in self.links.values()) == before:
                return

    def close(self) -> None:
        self.closed = True
        for uri in list(self.retries):
            self._forget(uri)


class SlaveNode:
    """The parts of a ROS node that the graph sees: slave API, registrations, TCPROS server."""

    def __init__(self, name: str, master_uri: str, *, host: str | None = None,
                 in_process: dict[str, Callable[[str, list], Any]] | None = None):
        """`in_process`: where a master of this process finds the APIs it calls without a request (its
        `in_process_apis`): this node's is there while its server runs."""
        self.name = name
        self.master_uri = master_uri
        self.host = host or default_host()
        self.uri = ""
        self.tcpros = TcprosServer(name, self.host)
        self.subscriptions: dict[str, Subscription] = {}
        self.param_callbacks: dict[str, Callable[[Any], None]] = {}
        self.shutdown_requested = compat.Event()
        self.shutdown_reason = ""
        self._xmlrpc: Any = None
        self._in_process = in_process

    @property
    def publications(self) -> dict[str, Publication]:
        return self.tcpros.publications

    # ------------------------------------------------------------------ lifecycle
    async def start(self) -> None:
        bind = listen_address(self.host)
        await self.tcpros.start(bind)
        # a node's API gets few clients (the master, rostopic/rosnode): a quarter of the master's
        # share of files, so that both servers flooded at once still leave the launcher its files
        self._xmlrpc = XmlRpcServer(self._dispatch, bind, 0, max_connections=max(16, connection_cap() // 4))
        await self._xmlrpc.start()
        self.uri = "http://%s:%d/" % (self.host, self._xmlrpc.port)
        if self._in_process is not None:
            self._in_process[self.uri] = self._dispatch

    async def _master(self, method: str, *params: Any, timeout: float = 10.0) -> Any:
        code, status, value = await call(self.master_uri, method, self.name, *params,
                                         timeout=timeout)
        if code != 1:
            raise RuntimeError("master refused %s%r: %s" % (method, params, status))
        return value

    async def advertise(self, topic: str, mtype: TopicType, *, latch: bool = False,
                        queue_size: int | None = None) -> Publication:
        """Publish `topic` and register it with the master; `queue_size`: see Publication."""
        pub = Publication(topic, mtype, self.name, latch=latch, queue_size=queue_size)
        self.publications[topic] = pub
        await self._master("registerPublisher", topic, mtype.name, self.uri)
        return pub

    async def subscribe(self, topic: str, mtype: TopicType,
                        callback: Callable[[bytes, PublisherLink], None]) -> Subscription:
        """Subscribe to `topic`: register with the master and connect to its publishers."""
        sub = Subscription(self, topic, mtype, callback)
        self.subscriptions[topic] = sub
        publishers = await self._master("registerSubscriber", topic, mtype.name, self.uri)
        sub.update(list(publishers), additive=True)
        return sub

    async def advertise_service(self, srv: ServiceServer) -> None:
        self.tcpros.services[srv.name] = srv
        await self._master("registerService", srv.name,
                           "rosrpc://%s:%d" % (self.host, self.tcpros.port), self.uri)

    async def subscribe_param(self, key: str, callback: Callable[[Any], None]) -> Any:
        """Current value of `key` ({} when unset); `callback(value)` on every later change."""
        self.param_callbacks[key.rstrip("/") or "/"] = callback
        return await self._master("subscribeParam", self.uri, key)

    async def stop(self) -> None:
        """Read what publishers already sent, unregister everything, close every connection."""
        for sub in self.subscriptions.values():
            await sub.drain()
        calls = []
        # Shutdown must not hang on a master that stopped answering: a short timeout.
        quick = {"timeout": 3.0}
        for topic, sub in self.subscriptions.items():
            calls.append(self._master("unregisterSubscriber", topic, self.uri, **quick))
        for topic in self.publications:
            calls.append(self._master("unregisterPublisher", topic, self.uri, **quick))
        for name in self.tcpros.services:
            calls.append(self._master("unregisterService", name,
                                      "rosrpc://%s:%d" % (self.host, self.tcpros.port), **quick))
        for key in self.param_callbacks:
            calls.append(self._master("unsubscribeParam", self.uri, key, **quick))
        # A master that is already gone must not stop us from closing our own sockets.
        for result in await asyncio.gather(*calls, return_exceptions=True):
            if isinstance(result, BaseException):
                log.debug("unregistering %s: %s", self.name, result)
        for sub in self.subscriptions.values():
            sub.close()
        await self.tcpros.stop()
        if self._xmlrpc is not None:
            if self._in_process is not None:
                self._in_process.pop(self.uri, None)
            await self._xmlrpc.stop()
            self._xmlrpc = None

    # ------------------------------------------------------------------ slave API
    def _dispatch(self, method: str, params: list[Any]) -> Any:
        handler = self._API.get(method)
        if handler is None:
            raise ValueError("method [%s] is not supported by %s" % (method, self.name))
        try:
            return handler(self, *params)
        except TypeError as exc:
            return [-1, "bad arguments to %s: %s" % (method, exc), 0]

    def getBusStats(self, caller_id: str) -> list:
        subs = [[s.topic, [[l.id, l.bytes_received, l.messages_received, 0, 0]
                           for l in s.links.values()]] for s in self.subscriptions.values()]
        return [1, "", [self.tcpros.stats(), subs, [0, 0, 0]]]

    def getBusInfo(self, caller_id: str) -> list:
        info: list[list[Any]] = []
        for pub in self.publications.values():
            for link in pub.links:
                info.append([link.id, link.callerid, "o", "TCPROS", pub.topic, True, link.info])
        for sub in self.subscriptions.values():
            for link in sub.links.values():
                info.append([link.id, link.publisher_uri, "i", "TCPROS", sub.topic, True, link.info])
        return [1, "bus info", info]

    def getMasterUri(self, caller_id: str) -> list:
        return [1, "", self.master_uri]

    def shutdown(self, caller_id: str, msg: str = "") -> list:
        log.info("%s asked %s to shut down: %s", caller_id, self.name, msg)
        self.shutdown_reason = msg
        self.shutdown_requested.set()
        return [1, "shutdown", 0]

    def getPid(self, caller_id: str) -> list:
        return [1, "", os.getpid()]

    def getSubscriptions(self, caller_id: str) -> list:
        return [1, "subscriptions", [[s.topic, s.mtype.name] for s in self.subscriptions.values()]]

    def getPublications(self, caller_id: str) -> list:
        return [1, "publications", [[p.topic, p.mtype.name] for p in self.publications.values()]]

    def paramUpdate(self, caller_id: str, key: str, value: Any) -> list:
        callback = self.param_callbacks.get(key.rstrip("/") or "/")
        if callback is not None:
            try:
                callback(value)
            except Exception:
                log.exception("applying parameter %s", key)
        return [1, "", 0]

    def publisherUpdate(self, caller_id: str, topic: str, publishers: list[str]) -> list:
        sub = self.subscriptions.get(topic)
        if sub is not None:
            sub.update([str(uri) for uri in publishers])
        return [1, "", 0]

    def requestTopic(self, caller_id: str, topic: str, protocols: list) -> list:
        if topic not in self.publications:
            return [-1, "Not a publisher of [%s]" % topic, []]
        for proto in protocols:
            if proto and proto[0] == "TCPROS":
                return [1, "ready on %s:%d" % (self.host, self.tcpros.port),
                        ["TCPROS", self.host, self.tcpros.port]]
        return [0, "no supported protocol implementations", []]

    _API: dict[str, Callable[..., Any]] = {}


SlaveNode._API = {name: getattr(SlaveNode, name) for name in (
    "getBusStats", "getBusInfo", "getMasterUri", "shutdown", "getPid", "getSubscriptions",
    "getPublications", "paramUpdate", "publisherUpdate", "requestTopic")}
