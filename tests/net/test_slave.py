"""The slave XML-RPC API of an in-process node, called over real loopback HTTP and TCPROS."""

from __future__ import annotations

import asyncio
import gc
import logging
import os
import struct

import pytest

from launcher.net.slave import SlaveNode, Subscription
from launcher.net import linkstate, tcpros
from launcher.net.publication import Publication
from launcher.net.tcpros import TopicType, encode_frame, encode_header
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


def test_the_header_fields_publishers_send_alike_are_kept_once():
    """A hundred nodes publishing /rosout send one definition (roscpp's, with its comments): the subscription
    keeps it once for all of their links; a publisher that sent another text keeps its own."""
    async def main():
        commented = "string data  # roscpp keeps the comments\n"
        pubs, nodes = [], []
        for i, definition in enumerate([commented, commented, commented, "string data # another text\n"]):
            node = await _node("/talker%d" % i)
            pub = Publication("/chat", TopicType(CHAT.name, CHAT.md5sum, definition), node.name)
            node.publications["/chat"] = pub
            pubs.append(pub)
            nodes.append(node)
        sub_node = await _node("/listener")
        sub = Subscription(sub_node, "/chat", CHAT, lambda data, link: None)
        sub_node.subscriptions["/chat"] = sub
        sub.update([node.uri for node in nodes])
        await until_async(lambda: len(sub.links) == len(nodes), 5)
        headers = [sub.links[node.uri].header for node in nodes]
        assert [h["message_definition"] for h in headers] == [commented] * 3 + ["string data # another text\n"]
        assert headers[0]["message_definition"] is headers[1]["message_definition"] is headers[2]["message_definition"]
        assert headers[3]["message_definition"] is not headers[0]["message_definition"]
        assert all(h["md5sum"] is headers[0]["md5sum"] and h["type"] is headers[0]["type"] for h in headers)
        assert [h["callerid"] for h in headers] == [node.name for node in nodes]
        await _close(sub_node)
        for node in nodes:
            await _close(node)
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


async def _liar(behaviour, accepts: list[float]) -> tuple[SlaveNode, asyncio.AbstractServer]:
    """A node whose requestTopic sends subscribers to a TCPROS port that lies as `behaviour(reader, writer)` does."""
    loop = asyncio.get_running_loop()

    async def handle(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        accepts.append(loop.time())
        try:
            (size,) = struct.unpack("<I", await reader.readexactly(4))
            await reader.readexactly(size)
            await behaviour(reader, writer)
        except (OSError, asyncio.IncompleteReadError):
            pass
        finally:
            writer.close()

    server = await asyncio.start_server(handle, "127.0.0.1", 0)
    node = await _node("/liar%d" % id(accepts))
    node.publications["/chat"] = Publication("/chat", CHAT, node.name)
    node.tcpros.port = server.sockets[0].getsockname()[1]  # (its requestTopic answers with this port)
    return node, server


def _valid_header() -> bytes:
    return encode_header({"callerid": "/liar", "topic": "/chat", "type": CHAT.name, "md5sum": CHAT.md5sum,
                          "message_definition": CHAT.definition})


async def _refuse(reader, writer):
    writer.write(encode_header({"error": "go away"}))


async def _huge(reader, writer):
    writer.write(_valid_header() + struct.pack("<I", 0x7FFFFFFF))
    await reader.read()


async def _slow(reader, writer):
    writer.write(_valid_header()[:3])
    await reader.read()


async def _cut(reader, writer):
    writer.write(_valid_header() + encode_frame(b"m") + struct.pack("<I", 500_000_000) + b"x" * 1000)


def test_lying_publishers_are_dropped_and_tried_again_as_each_deserves(monkeypatch, caplog):
    """Each lie is one warning naming the publisher and the topic, and no future is left with an exception nobody
    retrieves; a refusal waits for the publisher's next listing, a broken link is tried again after doubling
    delays (here shortened), the handshake has a deadline, a good publisher beside them is read on."""
    monkeypatch.setattr(linkstate, "RETRY_FIRST_S", 0.1)
    monkeypatch.setattr(linkstate, "HANDSHAKE_TIMEOUT_S", 0.3)
    caplog.set_level(logging.WARNING, logger="launcher.slave")

    async def main():
        loop = asyncio.get_running_loop()
        unhandled: list[dict] = []
        loop.set_exception_handler(lambda _loop, context: unhandled.append(context))
        accepts: dict[str, list[float]] = {k: [] for k in ("refuse", "huge", "slow", "cut")}
        liars = {k: await _liar(b, accepts[k]) for k, b in
                 (("refuse", _refuse), ("huge", _huge), ("slow", _slow), ("cut", _cut))}
        good_node = await _node("/talker")
        good = Publication("/chat", CHAT, "/talker")
        good_node.publications["/chat"] = good
        sub_node = await _node("/listener")
        received: list[tuple[str, bytes]] = []
        sub = Subscription(sub_node, "/chat", TopicType("*", tcpros.ANY_MD5, ""),
                           lambda data, link: received.append((link.publisher_uri, bytes(data))))
        sub_node.subscriptions["/chat"] = sub
        uris = [good_node.uri] + [node.uri for node, _ in liars.values()]
        sub.update(uris)
        await until_async(lambda: len(good.links) == 1, 5)
        for n in range(20):
            good.publish(b"good %d" % n)
            await asyncio.sleep(0.05)
        await until_async(lambda: len(accepts["huge"]) >= 4 and len(accepts["slow"]) >= 2, 10)
        assert [d for u, d in received if u == good_node.uri] == [b"good %d" % n for n in range(20)]
        assert list(sub.links) == [good_node.uri]
        # doubling delays: 0.1, 0.2, 0.4 s (each measured from the failure, which follows the accept at once). Never
        # sooner than its delay; a loaded machine can only make a try later, so the upper bound is loose
        gaps = [b - a for a, b in zip(accepts["huge"], accepts["huge"][1:])]
        assert all(d - 0.01 <= g <= d + 1.0 for d, g in zip((0.1, 0.2, 0.4), gaps[:3])), gaps
        assert len(accepts["refuse"]) == 1
        sub.update(uris)  # the master lists it again (it advertised again): tried once more, at once
        await until_async(lambda: len(accepts["refuse"]) == 2, 5)
        assert [d for u, d in received if u == liars["cut"][0].uri][:2] == [b"m", b"m"]
        await sub_node.stop()
        for node, server in liars.values():
            server.close()
            await node.stop()
        await good_node.stop()
        gc.collect()
        await asyncio.sleep(0.05)
        return unhandled, {k: node.uri for k, (node, _) in liars.items()}

    unhandled, uris = asyncio.run(main())
    assert unhandled == []
    lines = [r.getMessage() for r in caplog.records]
    assert all("\n" not in line for line in lines)

    def said(kind: str) -> list[str]:
        return [line for line in lines if line.startswith("publisher %s" % uris[kind])]
    assert said("refuse") == ["publisher %s on /chat: refused the connection: go away; dropping the connection until "
                              "it advertises again" % uris["refuse"]] * 2
    assert said("huge")[:2] == ["publisher %s (/liar) on /chat: frame of 2147483647 bytes exceeds the 1000000000 "
                                "byte limit; dropping the connection, trying again in %s s" % (uris["huge"], d)
                                for d in ("0.1", "0.2")]
    assert said("slow")[0] == ("publisher %s on /chat: sent no whole connection header in 0.3 s (3 bytes came); "
                               "dropping the connection, trying again in 0.1 s" % uris["slow"])
    assert said("cut")[0] == ("publisher %s (/liar) on /chat: closed the connection in the middle of a frame (1000 of "
                              "its 500000000 bytes); dropping the connection, trying again in 0.1 s" % uris["cut"])
