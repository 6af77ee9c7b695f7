"""Both ends of a TCPROS handshake as pure state: fed bytes and a fake clock, no socket."""

from __future__ import annotations

from types import SimpleNamespace

from launcher.net import tcpros
from launcher.net.tcpros import (ANY_MD5, FAILED, HEADER, MESSAGES, InboundState, PublisherLinkState, TopicType,
                                 encode_frame, encode_header)

STRING = TopicType("std_msgs/String", "992ce8a1687cec8c8bd883ec73ca41d1", "string data\n")


def link(mtype: TopicType = STRING, now: float = 100.0) -> PublisherLinkState:
    return PublisherLinkState("/chatter", mtype, "/me", "http://pub:1/", now)


def their_header(**fields: str) -> bytes:
    return encode_header(dict({"callerid": "/talker", "topic": "/chatter", "type": "std_msgs/String",
                               "md5sum": STRING.md5sum, "message_definition": "string data\n", "latching": "0"},
                              **fields))


def test_our_request_names_the_topic_type_and_md5sum():
    fields = tcpros.decode_header(link().request()[4:])
    assert fields == {"callerid": "/me", "topic": "/chatter", "type": "std_msgs/String", "md5sum": STRING.md5sum,
                      "message_definition": "string data\n", "tcp_nodelay": "1"}


def test_header_then_messages_split_anywhere_with_counts_and_the_time_of_the_last_one():
    state = link()
    wire = their_header() + encode_frame(b"\x02\x00\x00\x00hi") + encode_frame(b"\x00\x00\x00\x00")
    events = []
    for i in range(len(wire)):  # one byte at a time: frames across feeds
        events += state.receive(wire[i:i + 1], 100.0 + i / 1000)
    assert [kind for kind, _ in events] == ["header", "message", "message"]
    assert events[0][1]["callerid"] == "/talker" and events[1][1] == b"\x02\x00\x00\x00hi"
    assert (state.phase, state.messages_received, state.bytes_received) == (MESSAGES, 2, len(wire))
    assert state.last_message_at == 100.0 + (len(wire) - 1) / 1000
    assert abs(state.silence(110.0) - (110.0 - state.last_message_at)) < 1e-9


def test_silence_counts_from_the_connection_until_a_first_message():
    state = link(now=50.0)
    state.receive(their_header(), 51.0)
    assert state.silence(60.0) == 10.0 and state.last_message_at is None


def test_an_error_header_is_a_refusal_and_nothing_after_it_is_read():
    state = link()
    events = state.receive(encode_header({"error": "no such topic"}) + encode_frame(b"x"), 1.0)
    assert events == [("failed", "publisher http://pub:1/ refused /chatter: no such topic")]
    assert state.phase == FAILED and state.receive(encode_frame(b"y"), 2.0) == []


def test_a_type_mismatch_fails_unless_either_side_takes_any_type():
    events = link().receive(their_header(md5sum="0" * 32, type="std_msgs/Int32"), 1.0)
    assert events[0][0] == "failed" and "sends std_msgs/Int32" in events[0][1]
    assert link().receive(their_header(md5sum=ANY_MD5), 1.0)[0][0] == "header"
    anything = TopicType("*", ANY_MD5, "")
    assert link(anything).receive(their_header(md5sum="0" * 32), 1.0)[0][0] == "header"


def test_an_absurd_length_fails_without_allocating_it():
    state = link()
    assert state.phase == HEADER
    events = state.receive(b"\xff\xff\xff\x7f", 1.0)  # a 2 GB header
    assert events[0][0] == "failed" and state.phase == FAILED


PUB = SimpleNamespace(topic="/chatter", mtype=STRING, callerid="/me", latch=True)
SRV = SimpleNamespace(md5sum="abc", callerid="/me", request_type="a/B", response_type="a/C", type_name="a/D")


def test_an_inbound_subscriber_gets_our_header_or_a_refusal_in_roscpps_words():
    inbound = InboundState("/me", {"/chatter": PUB}, {"/srv": SRV})
    kind, pub, reply = inbound.offer({"topic": "/chatter", "md5sum": STRING.md5sum, "callerid": "/echo"})
    assert (kind, pub, reply["latching"], reply["type"]) == ("subscriber", PUB, "1", "std_msgs/String")
    assert inbound.offer({"topic": "/chatter", "callerid": "/echo"}) == ("refuse", "Missing required 'md5sum' field")
    assert inbound.offer({"topic": "/other", "md5sum": "*", "callerid": "/e"})[1].startswith(
        "[/me] is not a publisher of [/other]")
    assert inbound.offer({"topic": "/chatter", "md5sum": "0" * 32, "type": "std_msgs/Int32", "callerid": "/e"}) == (
        "refuse", "topic types do not match: [std_msgs/Int32] vs. [std_msgs/String]")


def test_an_inbound_service_client_and_rosservices_probe():
    inbound = InboundState("/me", {}, {"/srv": SRV})
    kind, srv, reply, probe = inbound.offer({"service": "/srv", "md5sum": "*", "callerid": "/c", "probe": "1"})
    assert (kind, srv, reply["type"], probe) == ("service", SRV, "a/D", True)
    assert inbound.offer({"service": "/srv", "md5sum": "zzz", "callerid": "/c"})[0] == "refuse"
    assert inbound.offer({"service": "/nope", "callerid": "/c"})[0] == "refuse"
