"""The slave XML-RPC API of an in-process node, called over real loopback HTTP and TCPROS."""

from __future__ import annotations

import asyncio
import os

import pytest

from launcher.net.slave import SlaveNode, Subscription, bind_address
from launcher.net.tcpros import Publication, TopicType
from launcher.net.xmlrpc import Fault, call

from helpers import until_async

CHAT = TopicType("std_msgs/String", "992ce8a1687cec8c8bd883ec73ca41d1", "string data\n")
# Nothing listens here: these tests never reach a master.
NO_MASTER = "http://127.0.0.1:9/"


async def _node(name: str) -> SlaveNode:
    node = SlaveNode(name, NO_MASTER, host="127.0.0.1")
    await node.start()
    return node


async def _close(node: SlaveNode) -> None:
    # stop() tries to unregister from the (absent) master; that failure must not matter.
    await node.stop()


def test_identity_calls():
    async def main():
        node = await _node("/a")
        assert node.uri.startswith("http://127.0.0.1:")
        assert await call(node.uri, "getPid", "/x") == [1, "", os.getpid()]
        assert await call(node.uri, "getMasterUri", "/x") == [1, "", NO_MASTER]
        assert await call(node.uri, "getPublications", "/x") == [1, "publications", []]
        assert await call(node.uri, "getSubscriptions", "/x") == [1, "subscriptions", []]
        assert await call(node.uri, "getBusInfo", "/x") == [1, "bus info", []]
        code, _, stats = await call(node.uri, "getBusStats", "/x")
        assert code == 1 and stats == [[], [], [0, 0, 0]]
        await _close(node)
    asyncio.run(main())


def test_unknown_method_is_a_fault_and_bad_arguments_an_error_code():
    async def main():
        node = await _node("/a")
        with pytest.raises(Fault):
            await call(node.uri, "deleteEverything", "/x")
        code, msg, _ = await call(node.uri, "getPid")
        assert code == -1 and "getPid" in msg
        # The server is still fine afterwards.
        assert (await call(node.uri, "getPid", "/x"))[0] == 1
        await _close(node)
    asyncio.run(main())


def test_request_topic():
    async def main():
        node = await _node("/a")
        node.publications["/chat"] = Publication("/chat", CHAT, "/a")
        code, _, proto = await call(node.uri, "requestTopic", "/x", "/chat", [["TCPROS"]])
        assert (code, proto) == (1, ["TCPROS", "127.0.0.1", node.tcpros.port])
        code, _, proto = await call(node.uri, "requestTopic", "/x", "/chat", [["UDPROS", 1]])
        assert (code, proto) == (0, [])
        code, msg, _ = await call(node.uri, "requestTopic", "/x", "/other", [["TCPROS"]])
        assert code == -1 and "/other" in msg
        await _close(node)
    asyncio.run(main())


def test_publisher_update_connects_and_disconnects():
    async def main():
        pub_node = await _node("/talker")
        pub = Publication("/chat", CHAT, "/talker")
        pub_node.publications["/chat"] = pub
        sub_node = await _node("/listener")
        received: list[bytes] = []
        sub = Subscription(sub_node, "/chat", CHAT, lambda data, link: received.append(data))
        sub_node.subscriptions["/chat"] = sub

        assert await call(sub_node.uri, "publisherUpdate", "/master", "/chat",
                          [pub_node.uri]) == [1, "", 0]
        await until_async(lambda: len(pub.links) == 1, 5)
        pub.publish(b"\x05\x00\x00\x00hello")
        await until_async(lambda: received == [b"\x05\x00\x00\x00hello"], 5)

        _, _, info = await call(sub_node.uri, "getBusInfo", "/x")
        assert [i[1:6] for i in info] == [[pub_node.uri, "i", "TCPROS", "/chat", True]]
        _, _, info = await call(pub_node.uri, "getBusInfo", "/x")
        assert [i[1:6] for i in info] == [["/listener", "o", "TCPROS", "/chat", True]]
        assert info[0][6].startswith("TCPROS connection on port %d to [127.0.0.1:"
                                     % pub_node.tcpros.port)
        _, _, stats = await call(sub_node.uri, "getBusStats", "/x")
        assert stats[1][0][0] == "/chat" and stats[1][0][1][0][2] == 1  # one message received
        assert await call(sub_node.uri, "getSubscriptions", "/x") == [
            1, "subscriptions", [["/chat", "std_msgs/String"]]]

        # registerSubscriber's reply may predate a publisherUpdate: it only ever adds.
        sub.update([], additive=True)
        assert list(sub.links) == [pub_node.uri]

        # The publisher left the graph: the link goes, on both sides.
        await call(sub_node.uri, "publisherUpdate", "/master", "/chat", [])
        await until_async(lambda: not pub.links and not sub.links, 5)
        await _close(sub_node)
        await _close(pub_node)
    asyncio.run(main())


def test_unreachable_publisher_does_not_block_the_others():
    async def main():
        pub_node = await _node("/talker")
        pub = Publication("/chat", CHAT, "/talker")
        pub_node.publications["/chat"] = pub
        sub_node = await _node("/listener")
        received: list[bytes] = []
        sub = Subscription(sub_node, "/chat", CHAT, lambda data, link: received.append(data))
        sub_node.subscriptions["/chat"] = sub
        await call(sub_node.uri, "publisherUpdate", "/master", "/chat",
                   ["http://127.0.0.1:9/", pub_node.uri])
        await until_async(lambda: len(pub.links) == 1, 5)
        pub.publish(b"x")
        await until_async(lambda: received == [b"x"], 5)
        await until_async(lambda: not sub.connecting, 5)
        assert list(sub.links) == [pub_node.uri]
        await _close(sub_node)
        await _close(pub_node)
    asyncio.run(main())


def test_param_update_and_shutdown():
    async def main():
        node = await _node("/a")
        seen = []
        node.param_callbacks["/rosout/omit_topics"] = seen.append
        # rosmaster sends subscribed keys with a trailing slash.
        assert await call(node.uri, "paramUpdate", "/master", "/rosout/omit_topics/", True) == [
            1, "", 0]
        assert seen == [True]
        await call(node.uri, "paramUpdate", "/master", "/unrelated/", 1)
        assert seen == [True]
        assert not node.shutdown_requested.is_set()
        assert (await call(node.uri, "shutdown", "/rosnode", "kill"))[0] == 1
        assert node.shutdown_requested.is_set() and node.shutdown_reason == "kill"
        await _close(node)
    asyncio.run(main())


def test_bind_address_stays_on_loopback_for_loopback_names():
    assert bind_address("127.0.0.1") == "127.0.0.1"
    assert bind_address("localhost") == "127.0.0.1"
    assert bind_address("robot.example") == "0.0.0.0"
