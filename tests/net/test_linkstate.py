"""Both ends of a TCPROS handshake as pure state: fed bytes and a fake clock, no socket."""

from __future__ import annotations

import struct
from types import SimpleNamespace

import pytest

from launcher.net import linkstate, tcpros
from launcher.net.linkstate import (BROKEN, CLOSED, ENDED, FAILED, HEADER, MESSAGES, REFUSED, InboundState,
                                    PublisherLinkState, PublisherRetry)
from launcher.net.tcpros import ANY_MD5, TopicType, encode_frame, encode_header

STRING = TopicType("std_msgs/String", "992ce8a1687cec8c8bd883ec73ca41d1", "string data\n")


def link(mtype: TopicType = STRING, now: float = 100.0) -> PublisherLinkState:
    return PublisherLinkState("/chatter", mtype, "/me", "http://pub:1/", now)


def their_header(**fields: str) -> bytes:
    return encode_header(dict({"callerid": "/talker", "topic": "/chatter", "type": "std_msgs/String",
                               "md5sum": STRING.md5sum, "message_definition": "string data\n", "latching": "0"},
                              **fields))


HEADER_BYTES = their_header()


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
    assert state.ending is None and state.why == ""


def test_an_error_header_is_a_refusal_and_nothing_after_it_is_read():
    state = link()
    events = state.receive(encode_header({"error": "no such topic"}) + encode_frame(b"x"), 1.0)
    assert events == [("failed", "publisher http://pub:1/ on /chatter: refused the connection: no such topic")]
    assert state.phase == FAILED and state.ending == REFUSED and state.receive(encode_frame(b"y"), 2.0) == []


def test_a_type_mismatch_fails_unless_either_side_takes_any_type():
    state = link()
    events = state.receive(their_header(md5sum="0" * 32, type="std_msgs/Int32"), 1.0)
    assert events[0][0] == "failed" and "sends std_msgs/Int32" in events[0][1] and state.ending == REFUSED
    assert link().receive(their_header(md5sum=ANY_MD5), 1.0)[0][0] == "header"
    anything = TopicType("*", ANY_MD5, "")
    assert link(anything).receive(their_header(md5sum="0" * 32), 1.0)[0][0] == "header"


@pytest.mark.parametrize("fields, words", [
    ({"type": "no type here"}, "sent type 'no type here', md5sum '992ce8a1687cec8c8bd883ec73ca41d1': not a message "
                                  "type and its md5sum"),
    ({"md5sum": "nonsense"}, "sent type 'std_msgs/String', md5sum 'nonsense': not a message type and its md5sum"),
    ({"md5sum": None}, "sent a connection header without 'md5sum'"),
    ({"type": None}, "sent a connection header without 'type'"),
])
def test_a_header_of_no_message_type_is_refused_even_by_a_subscriber_of_any_type(fields, words):
    header = {"callerid": "/liar", "topic": "/chatter", "type": "std_msgs/String", "md5sum": STRING.md5sum}
    header.update(fields)
    state = link(TopicType("*", ANY_MD5, ""))
    events = state.receive(encode_header({k: v for k, v in header.items() if v is not None}), 1.0)
    assert events == [("failed", "publisher http://pub:1/ (/liar) on /chatter: " + words)]
    assert state.ending == REFUSED


def test_an_absurd_length_fails_without_allocating_it():
    state = link()
    assert state.phase == HEADER
    events = state.receive(b"\xff\xff\xff\x7f", 1.0)  # a 2 GB header
    assert events == [("failed", "publisher http://pub:1/ on /chatter: frame of 2147483647 bytes exceeds the "
                                 "1000000000 byte limit")]
    assert state.phase == FAILED and state.ending == BROKEN


def test_an_absurd_length_right_after_the_header_names_the_caller_id_the_header_gave():
    state = link()
    events = state.receive(HEADER_BYTES + b"\xff\xff\xff\x7f", 1.0)
    assert [kind for kind, _ in events] == ["header", "failed"]
    assert events[1][1] == ("publisher http://pub:1/ (/talker) on /chatter: frame of 2147483647 bytes exceeds the "
                            "1000000000 byte limit")


def test_one_limit_for_headers_and_messages():
    for before in (b"", their_header()):
        state = link()
        state.receive(before, 1.0)
        assert state.receive(struct.pack("<I", tcpros.MAX_FRAME_SIZE), 1.0) == []  # (not allocated: see test_tcpros)
        state = link()
        state.receive(before, 1.0)
        assert state.receive(struct.pack("<I", tcpros.MAX_FRAME_SIZE + 1), 1.0)[-1][0] == "failed"


def test_the_header_is_due_by_the_handshake_deadline():
    state = link(now=100.0)
    assert state.deadline == 100.0 + linkstate.HANDSHAKE_TIMEOUT_S
    state.receive(their_header()[:10], 101.0)
    assert state.expire(state.deadline - 0.001) == [] and state.phase == HEADER
    assert state.expire(state.deadline) == [("failed", "publisher http://pub:1/ on /chatter: sent no whole connection "
                                                       "header in 10 s (10 bytes came)")]
    assert state.ending == BROKEN
    done = link(now=100.0)
    done.receive(their_header(), 101.0)
    assert done.expire(200.0) == [] and done.phase == MESSAGES  # (the deadline is the header's only)


@pytest.mark.parametrize("sent, ending, words", [
    (b"", BROKEN, "closed the connection before sending a connection header"),
    (b"\x10\x00", BROKEN, "closed the connection in the middle of a frame (its connection header: 2 of the 4 bytes "
                           "of its length)"),
    (HEADER_BYTES[:30], BROKEN, "closed the connection in the middle of a frame (its connection header: 26 of its "
                                "%d bytes)" % (len(HEADER_BYTES) - 4)),
    (HEADER_BYTES + encode_frame(b"abc"), ENDED, "closed the connection"),
    (HEADER_BYTES + encode_frame(b"abc")[:5], BROKEN, "closed the connection in the middle of a frame (1 of its 3 "
                                                      "bytes)"),
    (HEADER_BYTES + struct.pack("<I", 900_000_000) + b"x" * 70_000, BROKEN,
     "closed the connection in the middle of a frame (70000 of its 900000000 bytes)"),
])
def test_a_close_says_what_it_cut(sent, ending, words):
    state = link()
    state.receive(sent, 1.0)
    assert state.lost(2.0) == ending and state.ending == ending
    who = "publisher http://pub:1/ (/talker)" if len(sent) > len(HEADER_BYTES) else "publisher http://pub:1/"
    assert state.why == "%s on /chatter: %s" % (who, words)
    assert state.receive(encode_frame(b"late"), 3.0) == []


def test_our_own_close_is_closed_and_a_failure_is_not_overwritten_by_the_close_that_follows():
    state = link()
    state.close()
    assert (state.ending, state.phase) == (CLOSED, FAILED)
    refused = link()
    refused.receive(encode_header({"error": "no"}), 1.0)
    assert refused.lost(2.0) == REFUSED and "refused the connection: no" in refused.why


# PublisherRetry, every cell: (delay before, refused before) x ending -> (next attempt after `now`, delay after,
# refused after); a connection opened at 99.0 and ended at 100.0 (a short one).
RETRY_CELLS = [
    ((0.0, False), BROKEN, (1.0, 1.0, False)),
    ((0.0, False), ENDED, (1.0, 1.0, False)),
    ((0.0, False), REFUSED, (None, 0.0, True)),
    ((0.0, False), CLOSED, (None, 0.0, False)),
    ((4.0, False), BROKEN, (8.0, 8.0, False)),
    ((4.0, False), ENDED, (1.0, 1.0, False)),
    ((4.0, False), REFUSED, (None, 4.0, True)),
    ((4.0, False), CLOSED, (None, 4.0, False)),
    ((16.0, False), BROKEN, (30.0, 30.0, False)),
    ((30.0, False), BROKEN, (30.0, 30.0, False)),
    ((30.0, False), ENDED, (1.0, 1.0, False)),
    ((30.0, False), REFUSED, (None, 30.0, True)),
    ((30.0, False), CLOSED, (None, 30.0, False)),
    ((4.0, True), BROKEN, (8.0, 8.0, True)),
    ((4.0, True), ENDED, (1.0, 1.0, True)),
    ((4.0, True), REFUSED, (None, 4.0, True)),
    ((4.0, True), CLOSED, (None, 4.0, True)),
]


@pytest.mark.parametrize("before, ending, after", RETRY_CELLS)
def test_publisher_retry_every_cell(before, ending, after):
    retry = PublisherRetry()
    retry.delay, retry.refused = before
    at = retry.ended(ending, 99.0, 100.0)
    assert (None if at is None else at - 100.0, retry.delay, retry.refused) == after


def test_publisher_retry_doubles_to_thirty_seconds_starts_over_after_a_long_life_and_waits_for_a_listing():
    retry = PublisherRetry()
    assert [retry.ended(BROKEN, 0.0, 0.0) for _ in range(7)] == [1.0, 2.0, 4.0, 8.0, 16.0, 30.0, 30.0]
    assert retry.ended(BROKEN, 0.0, linkstate.RETRY_MAX_S) == linkstate.RETRY_MAX_S + 1.0  # healthy 30 s: over again
    assert retry.listed() is False  # listed, not refused: nothing to do (its timer stands)
    assert retry.ended(REFUSED, 0.0, 50.0) is None
    assert retry.listed() is True and retry.listed() is False


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
