"""The embedded Master over real loopback sockets: hostile input, asynchronous callbacks, in-process params."""

from __future__ import annotations

import asyncio
import socket
import socketserver
import threading
import time
import xmlrpc.client
from xmlrpc.server import SimpleXMLRPCRequestHandler, SimpleXMLRPCServer

import pytest

from launcher.master.server import Master

from helpers import post_once


class MasterThread:
    """A Master on its own event loop in a thread, so that blocking clients can talk to it."""

    def __init__(self, **kw):
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()
        self.master = self.run(self._make(kw))
        self.uri = "http://127.0.0.1:%d/" % self.master.port

    async def _make(self, kw):
        m = Master(host="127.0.0.1", port=0, **kw)
        await m.start()
        return m

    def run(self, coro, timeout=10):
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(timeout)

    def call_soon(self, fn, *args):
        async def wrapper():
            return fn(*args)
        return self.run(wrapper())

    def proxy(self):
        return xmlrpc.client.ServerProxy(self.uri)

    def close(self):
        self.run(self.master.stop())
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(5)
        self.loop.close()


@pytest.fixture
def master():
    m = MasterThread(notify_timeout=1.0)
    yield m
    m.close()


class _Handler(SimpleXMLRPCRequestHandler):
    def log_message(self, *args):
        pass


class _Server(socketserver.ThreadingMixIn, SimpleXMLRPCServer):
    daemon_threads = True


class Node:
    """A fake node's slave API that records calls; `answer` decides the reply."""

    def __init__(self, answer=(1, "", 0)):
        self.calls = []
        self.cond = threading.Condition()
        self.answer = answer
        self.server = _Server(("127.0.0.1", 0), requestHandler=_Handler, logRequests=False)
        self.server.register_instance(self)
        self.uri = "http://127.0.0.1:%d/" % self.server.server_address[1]
        threading.Thread(target=self.server.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True).start()

    def _dispatch(self, method, params):
        with self.cond:
            self.calls.append((method, list(params)))
            self.cond.notify_all()
        return list(self.answer)

    def wait(self, pred, timeout=5.0):
        deadline = time.monotonic() + timeout
        with self.cond:
            while True:
                hits = [c for c in self.calls if pred(*c)]
                if hits or time.monotonic() >= deadline:
                    return hits
                self.cond.wait(deadline - time.monotonic())

    def close(self):
        self.server.shutdown()
        self.server.server_close()


class Hanging:
    """Accepts connections and never answers."""

    def __init__(self):
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(16)
        self.uri = "http://127.0.0.1:%d/" % self.sock.getsockname()[1]
        self.accepted = []
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self):
        while True:
            try:
                c, _ = self.sock.accept()
            except OSError:
                return
            self.accepted.append(c)

    def close(self):
        for c in self.accepted:
            c.close()
        self.sock.close()


def _alive(master):
    return master.proxy().getPid("/probe")[0] == 1


# ---------------------------------------------------------------------------
# hostile input
# ---------------------------------------------------------------------------

BILLION_LAUGHS = (b"<?xml version='1.0'?><!DOCTYPE m [<!ENTITY a 'aaaaaaaaaa'>"
                  + b"".join(b"<!ENTITY %s '%s'>" % (chr(98 + i).encode(), (b"&" + chr(97 + i).encode() + b";") * 10)
                             for i in range(8))
                  + b"]><methodCall><methodName>setParam</methodName><params><param><value>/x</value></param>"
                  b"<param><value>/p</value></param><param><value>&i;</value></param></params></methodCall>")
XXE = (b"<?xml version='1.0'?><!DOCTYPE m [<!ENTITY x SYSTEM 'file:///etc/passwd'>]><methodCall>"
       b"<methodName>setParam</methodName><params><param><value>/x</value></param><param><value>/p</value>"
       b"</param><param><value>&x;</value></param></params></methodCall>")


@pytest.mark.parametrize("body", [BILLION_LAUGHS, XXE, b"<methodCall><methodName>getPid",
                                  b"<methodCall><methodName>setParam</methodName><params><param>"
                                  + b"<value><array><data>" * 5000 + b"</params></methodCall>"],
                         ids=["billion-laughs", "xxe", "truncated", "deep-nesting"])
def test_hostile_xml_gets_a_fault_and_nothing_is_set(master, body):
    t0 = time.monotonic()
    out = post_once(master.master.port, body)
    assert time.monotonic() - t0 < 2
    assert out.startswith(b"HTTP/1.1 200")
    with pytest.raises(xmlrpc.client.Fault):
        xmlrpc.client.loads(out.split(b"\r\n\r\n", 1)[1])
    assert master.proxy().hasParam("/x", "/p") == [1, "/p", False]
    assert _alive(master)


def test_oversized_request_is_refused_without_reading_it(master):
    out = post_once(master.master.port, b"", headers=b"Content-Length: 900000000\r\n")
    assert out.split(b" ", 2)[1] in (b"400", b"413")
    assert _alive(master)


def test_unknown_methods_and_bad_arguments(master):
    p = master.proxy()
    with pytest.raises(xmlrpc.client.Fault):
        p.noSuchMethod("/c")
    with pytest.raises(xmlrpc.client.Fault):
        p._dispatch("/c")
    assert p.getParam() == [-1, "missing required caller_id parameter", 0]
    assert p.getParam("/c", "/a", "extra") == [-1, "Error: bad call arity", 0]
    assert p.registerPublisher(5, "/t", "std_msgs/String", "http://h:1/") == [-1, "caller_id must be a string", []]
    assert p.registerPublisher("/c", "/t", "bad type", "http://h:1/")[0] == -1
    assert p.system.multicall([{"methodName": "getPid", "params": ["/c"]}, "junk"])[0][0][0] == 1
    assert _alive(master)


def test_slow_client_does_not_wedge_the_master(master):
    with socket.create_connection(("127.0.0.1", master.master.port), timeout=10) as slow:
        slow.sendall(b"POST / HTTP/1.1\r\nContent-Length: 500\r\n\r\n<methodCall>")
        t0 = time.monotonic()
        for _ in range(20):
            assert _alive(master)
        assert time.monotonic() - t0 < 2


def test_many_idle_connections_do_not_block_service(master):
    socks = [socket.create_connection(("127.0.0.1", master.master.port)) for _ in range(200)]
    try:
        assert _alive(master)
    finally:
        for s in socks:
            s.close()


# ---------------------------------------------------------------------------
# callbacks
# ---------------------------------------------------------------------------

def test_hanging_and_vanished_subscribers_delay_nobody(master):
    hang = Hanging()
    good = Node()
    gone = socket.socket()
    gone.bind(("127.0.0.1", 0))
    gone_uri = "http://127.0.0.1:%d/" % gone.getsockname()[1]
    gone.close()  # nothing listens there any more
    p = master.proxy()
    try:
        p.registerSubscriber("/hang", "/t", "std_msgs/String", hang.uri)
        p.registerSubscriber("/gone", "/t", "std_msgs/String", gone_uri)
        p.registerSubscriber("/good", "/t", "std_msgs/String", good.uri)
        t0 = time.monotonic()
        for i in range(5):
            assert p.registerPublisher("/pub%d" % i, "/t", "std_msgs/String", "http://127.0.0.1:%d/" % (9000 + i))[0] == 1
        # a reply that waited for the hanging node would take its 1 s time-out, each time
        assert time.monotonic() - t0 < 2.5
        want = ["http://127.0.0.1:%d/" % (9000 + i) for i in range(5)]
        assert good.wait(lambda m, a: m == "publisherUpdate" and a[2] == want)
        # the hanging node times out (1 s) and the vanished one is refused: both reported, with their names
        deadline = time.monotonic() + 5
        while len(master.call_soon(master.master.unresponsive_nodes)) < 2:
            assert time.monotonic() < deadline, master.call_soon(master.master.unresponsive_nodes)
            time.sleep(0.05)
        report = {u.api: u for u in master.call_soon(master.master.unresponsive_nodes)}
        assert report[hang.uri].names == ["/hang"] and report[gone_uri].names == ["/gone"]
        assert "connect" in report[gone_uri].last_error.lower()  # "Connect call failed": refused
        assert report[hang.uri].queued >= 1  # the latest publisher list, kept for when it answers
        assert good.uri not in report
        p.unregisterSubscriber("/gone", "/t", gone_uri)  # no longer registered: no longer owed anything
        assert gone_uri not in {u.api for u in master.call_soon(master.master.unresponsive_nodes)}
    finally:
        hang.close()
        good.close()


def test_reregistration_sends_shutdown_to_the_old_api(master):
    old, new = Node(), Node()
    p = master.proxy()
    try:
        p.registerPublisher("/dup", "/t1", "std_msgs/String", old.uri)
        p.registerPublisher("/dup", "/t2", "std_msgs/String", new.uri)
        hits = old.wait(lambda m, a: m == "shutdown")
        assert hits and hits[0][1] == ["/master", "[/dup] Reason: new node registered with same name"]
        assert p.lookupNode("/c", "/dup")[2] == new.uri
        assert "/t1" not in [t for t, _ in p.getSystemState("/c")[2][0]]
    finally:
        old.close()
        new.close()


def test_param_subscriber_answering_minus_one_is_dropped(master):
    refuser = Node(answer=(-1, "not subscribed", 0))
    watcher = Node()
    p = master.proxy()
    try:
        p.subscribeParam("/refuser", refuser.uri, "/p")
        p.subscribeParam("/watcher", watcher.uri, "/p")
        p.setParam("/c", "/p", 1)
        assert refuser.wait(lambda m, a: m == "paramUpdate")
        assert watcher.wait(lambda m, a: m == "paramUpdate" and a[2] == 1)
        deadline = time.monotonic() + 5
        while p.lookupNode("/c", "/refuser")[0] == 1 and time.monotonic() < deadline:
            time.sleep(0.02)
        assert p.lookupNode("/c", "/refuser")[0] == -1  # its only registration is gone
        p.setParam("/c", "/p", 2)
        assert watcher.wait(lambda m, a: m == "paramUpdate" and a[2] == 2)
        assert len([c for c in refuser.calls if c[0] == "paramUpdate"]) == 1
    finally:
        refuser.close()
        watcher.close()


def test_in_process_set_and_delete_notify_subscribers(master):
    node = Node()
    p = master.proxy()
    try:
        p.subscribeParam("/n", node.uri, "/cfg")
        src = {"a": 1, "b": {"c": 2}}
        master.call_soon(master.master.set_param, "/cfg", src)
        assert node.wait(lambda m, a: m == "paramUpdate" and a[1:] == ["/cfg/", {"a": 1, "b": {"c": 2}}])
        src["a"] = 99  # the master keeps its own copy
        assert p.getParam("/c", "/cfg/a")[2] == 1
        master.call_soon(master.master.delete_param, "/cfg")
        assert node.wait(lambda m, a: m == "paramUpdate" and a[1:] == ["/cfg/", {}])
        assert p.hasParam("/c", "/cfg")[2] is False
    finally:
        node.close()


def test_shutdown_call_sets_the_event_after_replying(master):
    p = master.proxy()
    assert p.shutdown("/c") [0] == -1  # needs (caller_id, msg)
    assert not master.master.shutdown_requested.is_set()
    assert p.shutdown("/c", "bye") == [1, "shutdown", 0]
    assert master.master.shutdown_requested.is_set()
    assert "bye" in master.master.shutdown_reason


def test_port_taken_raises_oserror():
    async def scenario():
        a = Master(host="127.0.0.1", port=0)
        await a.start()
        try:
            b = Master(host="127.0.0.1", port=a.port)
            with pytest.raises(OSError):
                await b.start()
        finally:
            await a.stop()
    asyncio.run(scenario())


def test_uri_honours_ros_hostname_and_ros_ip():
    async def scenario(env):
        m = Master(port=0, environ=env)
        await m.start()
        try:
            return m.uri, m.host
        finally:
            await m.stop()
    uri, host = asyncio.run(scenario({"ROS_HOSTNAME": "localhost"}))
    assert uri.startswith("http://localhost:") and host == "127.0.0.1"
    uri, host = asyncio.run(scenario({"ROS_IP": "127.0.0.1"}))
    assert uri.startswith("http://127.0.0.1:") and host == "127.0.0.1"
    uri, host = asyncio.run(scenario({}))
    assert uri.startswith("http://%s:" % socket.gethostname()) and host == "0.0.0.0"


def test_ros_ipv6_binds_one_dual_stack_socket():
    if not socket.has_ipv6:
        pytest.skip("no IPv6 here")

    async def scenario():
        m = Master(port=0, environ={"ROS_IPV6": "on"})
        try:
            await m.start()
        except OSError as e:
            pytest.skip("cannot bind IPv6: %s" % e)
        loop = asyncio.get_running_loop()
        try:
            answers = []
            for host in ("127.0.0.1", "[::1]"):
                px = xmlrpc.client.ServerProxy("http://%s:%d/" % (host, m.port))
                answers.append((await loop.run_in_executor(None, px.getPid, "/x"))[0])
            return answers
        finally:
            await m.stop()
    assert asyncio.run(scenario()) == [1, 1]
