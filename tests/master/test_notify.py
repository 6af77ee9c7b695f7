"""The Notifier: per-node ordering, superseded publisherUpdates, time-outs, cancellation."""

from __future__ import annotations

import asyncio
import os
import subprocess
import sys

from launcher.net import xmlrpc_server
from launcher.master.api import MasterApi
from launcher.master.notify import Notifier, is_this_host, process_started, replaced_process, since_boot

from helpers import until, until_async


class SlowNode:
    """A node's slave API on loopback that records calls; `delay` seconds before each answer."""

    def __init__(self, delay=0.0, answer=(1, "", 0)):
        self.delay = delay
        self.answer = answer
        self.calls = []
        self.server = xmlrpc_server.XmlRpcServer(self.dispatch, "127.0.0.1", 0)

    def dispatch(self, method, params):
        self.calls.append((method, params))

        async def reply():
            await asyncio.sleep(self.delay)
            return list(self.answer)
        return reply()

    async def __aenter__(self):
        await self.server.start()
        self.uri = "http://127.0.0.1:%d/" % self.server.port
        return self

    async def __aexit__(self, *exc):
        await self.server.stop()


def test_calls_to_one_node_keep_their_order_and_queued_publisher_updates_coalesce():
    async def scenario():
        n = Notifier(timeout=5)
        async with SlowNode(delay=0.2) as node:
            n.publisher_update(node.uri, "/t", ["a"])          # sent at once
            await until_async(lambda: len(node.calls) == 1, 5)
            n.param_update(node.uri, "/p/", 1)                  # queued behind it
            n.publisher_update(node.uri, "/t", ["a", "b"])     # queued
            n.publisher_update(node.uri, "/t", ["a", "b", "c"])  # supersedes the queued one
            n.publisher_update(node.uri, "/u", ["x"])          # another topic: kept
            await until_async(lambda: n.pending() == 0, 5)
            assert node.calls == [
                ("publisherUpdate", ["/master", "/t", ["a"]]),
                ("paramUpdate", ["/master", "/p/", 1]),
                ("publisherUpdate", ["/master", "/t", ["a", "b", "c"]]),
                ("publisherUpdate", ["/master", "/u", ["x"]]),
            ]
        await n.close()
    asyncio.run(scenario())


def test_a_hanging_node_only_delays_itself():
    async def scenario():
        n = Notifier(timeout=2.0)
        async with SlowNode(delay=30) as hung, SlowNode() as fine:
            n.shutdown_node(hung.uri, "/x", "why", 0.0)
            n.param_update(hung.uri, "/p/", 2)
            n.param_update(fine.uri, "/p/", 3)
            await until_async(lambda: len(hung.calls) == 1, 5)
            t0 = asyncio.get_running_loop().time()
            await until_async(lambda: len(fine.calls) == 1, timeout=1.5)  # not behind the hung node's 2 s
            await until_async(lambda: len(hung.calls) == 2, timeout=5)      # time-out, then the next call
            assert asyncio.get_running_loop().time() - t0 >= 1.5
            assert hung.calls[0] == ("getPid", ["/master"])  # (unanswered: no shutdown follows)
        await n.close()
        assert n.pending() == 0
    asyncio.run(scenario())


def test_results_reach_the_callback_and_close_cancels_everything():
    async def scenario():
        n = Notifier(timeout=5)
        results = []
        async with SlowNode(answer=(-1, "not subscribed", 0)) as node:
            n.param_update(node.uri, "/p/", 1, results.append)
            await until_async(lambda: results, 5)
            assert results == [[-1, "not subscribed", 0]]
            node.delay = 30
            for i in range(5):
                n.param_update(node.uri, "/p/", i)
            await until_async(lambda: len(node.calls) == 2, 5)
            await n.close()
            assert n.pending() == 0
            n.param_update(node.uri, "/p/", 9)  # after close: dropped
            assert n.pending() == 0
    asyncio.run(scenario())


def test_non_http_apis_are_skipped_and_unreachable_ones_reported_until_forgotten():
    async def scenario():
        n = Notifier(timeout=1)
        n.publisher_update("rosrpc://127.0.0.1:1", "/t", [])
        assert n.pending() == 0
        api = "http://127.0.0.1:1/"
        n.publisher_update(api, "/t", ["a"])  # nothing listens: refused at once, and dropped (as rosmaster)
        await until_async(lambda: n.unreachable(), 5)
        (u,) = n.unreachable()
        assert (u.api, u.failures, u.queued) == (api, 1, 0)
        n.forget(api)  # no longer registered: no longer reported
        assert n.pending() == 0 and n.unreachable() == []
        await n.close()
    asyncio.run(scenario())


def test_an_api_served_in_this_process_is_called_in_order_with_copies_and_no_request():
    # nothing listens at this port: a request there would be refused, and the API reported unreachable
    api = "http://127.0.0.1:1/"
    calls = []

    def dispatch(method, params):
        calls.append((method, params))
        if params[1] == "/fails":
            raise OSError("the handler's own error")  # a request's handler raising: a fault, not an unreachable node
        return [1, "", [params[1]]]

    async def scenario():
        n = Notifier(timeout=5, in_process={api: dispatch})
        uris = ["http://a:1/"]
        results = []
        n.publisher_update(api, "/t", uris)
        n.param_update(api, "/fails", 1)
        value = {"k": [1, (2, 3)]}
        n.param_update(api, "/p", value, results.append)
        await until_async(lambda: n.pending() == 0 and results, 5)
        uris.append("http://b:2/")  # the master's list changes after: the node's copy is its own, as a request's
        assert calls == [("publisherUpdate", ["/master", "/t", ["http://a:1/"]]),
                         ("paramUpdate", ["/master", "/fails", 1]),
                         ("paramUpdate", ["/master", "/p", {"k": [1, [2, 3]]}])]  # (a tuple arrives as an array)
        assert calls[0][1][2] is not uris and calls[2][1][2]["k"] is not value["k"]
        assert results == [[1, "", ["/p"]]]
        assert n.unreachable() == []
        await n.close()
    asyncio.run(scenario())


def test_an_in_process_api_that_does_not_answer_in_time_is_a_hung_node():
    api = "http://127.0.0.1:1/"

    def dispatch(method, params):
        return asyncio.sleep(30)  # (an awaitable answer, as a server's handler may give)

    async def scenario():
        n = Notifier(timeout=0.2, in_process={api: dispatch})
        n.publisher_update(api, "/t", ["http://a:1/"])
        await until_async(lambda: n.unreachable(), 5)
        (u,) = n.unreachable()
        assert (u.api, u.failures) == (api, 1)
        await n.close()
    asyncio.run(scenario())


def test_a_replaced_node_is_told_to_shut_down_only_if_the_process_at_its_uri_is_older_than_its_registration():
    """ros/ros_comm#2241: the old URI of a name may be another process's now (its port reused). The master asks
    it for its pid only then (never at registration: rosmaster calls nodes only to update or stop them), and
    a process of this machine that started after the node registered there is not the node."""
    async def scenario():
        n = Notifier(timeout=2.0)
        api = MasterApi(n)
        async with SlowNode(answer=(1, "", os.getpid())) as same, SlowNode(answer=(1, "", 0)) as reused, \
                SlowNode(answer=(1, "", 333)) as fresh:
            api.dispatch("registerPublisher", ["/a", "/t", "std_msgs/String", same.uri])
            api.dispatch("registerPublisher", ["/b", "/t", "std_msgs/String", reused.uri])
            await until_async(lambda: n.pending() == 0, 5)
            assert [m for m, _ in same.calls + reused.calls if m != "publisherUpdate"] == []  # nothing asked yet
            # /b's process died and a newer one took its port (this test's child, started after /b registered)
            registered = api.registry.get_node("/b").registered_at
            until(lambda: since_boot() > registered + 0.02, 5)  # (a start in the same clock tick tells nothing)
            newer = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
            try:
                until(lambda: process_started(newer.pid) is not None, 5)
                reused.answer = (1, "", newer.pid)
                api.dispatch("registerPublisher", ["/a", "/t", "std_msgs/String", fresh.uri])
                api.dispatch("registerPublisher", ["/b", "/t", "std_msgs/String", fresh.uri])
                await until_async(lambda: n.pending() == 0, 5)
            finally:
                newer.kill()
                newer.wait()
            # this process is older than /a's registration: the node; the newer one is not
            assert [m for m, _ in same.calls if m != "publisherUpdate"] == ["getPid", "shutdown"]
            assert [m for m, _ in reused.calls if m != "publisherUpdate"] == ["getPid"]
        await n.close()
    asyncio.run(scenario())


def test_who_is_not_the_replaced_node():
    assert replaced_process(None, None, 10.0) == "nothing there answers getPid with a pid"
    assert replaced_process(42, 9.0, 10.0) is None  # started before it registered: may be the node
    assert replaced_process(42, None, 10.0) is None  # another machine's (or gone): cannot tell, as rosmaster
    assert "started 5.00 s after" in replaced_process(42, 15.0, 10.0)
    assert process_started(os.getpid()) < since_boot()
    assert is_this_host("http://127.0.0.1:1/") and is_this_host("http://localhost:1/")
    assert not is_this_host("http://192.0.2.1:1/")


class _Recorder:
    def __init__(self):
        self.calls = []

    def publisher_update(self, api, topic, pub_uris):
        self.calls.append(("publisherUpdate", api))

    def param_update(self, api, key, value, on_result=None):
        self.calls.append(("paramUpdate", api))

    def shutdown_node(self, api, caller_id, reason, registered_at=None):
        self.calls.append(("shutdown", api))

    def forget(self, api):
        self.calls.append(("forget", api))


def test_the_master_forgets_an_api_when_no_registered_node_has_it():
    rec = _Recorder()
    api = MasterApi(rec)
    x, y = "http://h:1/", "http://h:2/"
    api.dispatch("registerSubscriber", ["/a", "/t", "std_msgs/String", x])
    api.dispatch("subscribeParam", ["/a", x, "/p"])
    api.dispatch("registerSubscriber", ["/b", "/t", "std_msgs/String", x])  # another node, the same API
    api.dispatch("unregisterSubscriber", ["/a", "/t", x])
    api.dispatch("unsubscribeParam", ["/a", x, "/p"])
    api.dispatch("unregisterSubscriber", ["/b", "/t", x])
    assert rec.calls == [("forget", x)]  # once, when the last node with it went
    rec.calls = []
    api.dispatch("registerSubscriber", ["/c", "/t", "std_msgs/String", x])
    api.dispatch("registerSubscriber", ["/c", "/t", "std_msgs/String", y])  # /c again, a new process
    assert rec.calls == [("shutdown", x), ("forget", x)]  # told to go first: a shutdown is kept by forget
