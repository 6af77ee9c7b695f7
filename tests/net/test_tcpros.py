"""TCPROS headers and framing (sans-I/O: net/tcpros.py), and the asyncio links over real loopback sockets (a
subscriber's publisher_link, topic_watch, publication, service, tcpros_server)."""

from __future__ import annotations

import asyncio
import gc
import struct
import tracemalloc

import psutil
import pytest
from hypothesis import given
from hypothesis import strategies as st

from launcher.net import tcpros
from launcher.net import publication
from launcher.net import topic_watch
from launcher.net.publication import Publication
from launcher.net.publisher_link import PublisherLink, connect_publisher
from launcher.net.service import ServiceServer
from launcher.net.tcpros import (FrameCounter, FrameDecoder, FrameReader, ScratchPool, TcprosError, TopicType,
                                 decode_header, encode_frame, encode_header)
from launcher.net.tcpros_server import InboundConnection, TcprosServer
from launcher.net.topic_watch import WATCH_LOWAT, watch_publisher
from launcher.net.transport import transport_info

from helpers import until_async

LOG = TopicType("rosgraph_msgs/Log", "acffd30cd6b6de30f120938c17c593fb", "byte level\n")

# A header laid out by hand from the TCPROS spec: 4-byte little-endian length before each field.
# (tests/integration/test_rosout_nodes.py also compares with rosgraph's own encoder.)
RECORDED = (b"\x14\x00\x00\x00callerid=/rostopic_1"
            b"\x11\x00\x00\x00topic=/rosout_agg"
            b"\x0a\x00\x00\x00md5sum=abc")


def test_header_matches_a_recorded_wire_header():
    encoded = encode_header({"callerid": "/rostopic_1", "topic": "/rosout_agg", "md5sum": "abc"})
    assert encoded == struct.pack("<I", len(RECORDED)) + RECORDED
    assert decode_header(RECORDED) == {"callerid": "/rostopic_1", "topic": "/rosout_agg",
                                       "md5sum": "abc"}


def test_value_may_contain_equals_and_newlines():
    fields = {"message_definition": "byte DEBUG=1\nbyte INFO=2\n", "x": ""}
    assert decode_header(encode_header(fields)[4:]) == fields


keys = st.text(st.characters(blacklist_characters="=", blacklist_categories=("Cs",)), min_size=1)
values = st.text(st.characters(blacklist_categories=("Cs",)))


@given(st.dictionaries(keys, values))
def test_header_roundtrip(fields):
    encoded = encode_header(fields)
    assert struct.unpack_from("<I", encoded)[0] == len(encoded) - 4
    assert decode_header(encoded[4:]) == fields


@pytest.mark.parametrize("garbage, why", [
    (b"\x01\x00", "stray"),
    (b"\xff\x00\x00\x00a=b", "overruns"),
    (b"\x03\x00\x00\x00abc", "without '='"),
    (b"\x03\x00\x00\x00a=\xff", "UTF-8"),
])
def test_bad_headers_are_refused_with_a_reason(garbage, why):
    with pytest.raises(TcprosError, match=why):
        decode_header(garbage)


@given(st.lists(st.binary(max_size=300), max_size=20), st.data())
def test_frames_survive_any_split_of_the_stream(payloads, data):
    stream = b"".join(encode_frame(p) for p in payloads)
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=10)))
    decoder = FrameDecoder()
    got: list[bytes] = []
    last = 0
    for cut in cuts + [len(stream)]:
        got += decoder.feed(stream[last:cut])
        last = cut
    assert got == payloads
    assert decoder.pending == 0


def test_partial_frame_waits_for_the_rest():
    decoder = FrameDecoder()
    frame = encode_frame(b"hello")
    assert decoder.feed(frame[:6]) == []
    assert decoder.pending == 6
    assert decoder.feed(frame[6:] + frame[:2]) == [b"hello"]
    assert decoder.pending == 2


def test_absurd_length_is_refused_before_allocating():
    decoder = FrameDecoder(limit=1000)
    with pytest.raises(TcprosError, match="exceeds"):
        decoder.feed(struct.pack("<I", 0xFFFFFFF0) + b"xx")


@given(st.lists(st.integers(0, 3000), max_size=20), st.lists(st.integers(1, 5000), min_size=1, max_size=30))
def test_the_frame_counter_counts_what_the_decoder_splits_however_the_stream_is_cut(sizes, cuts):
    stream = b"".join(encode_frame(b"x" * n) for n in sizes)
    counter, decoder, counted, frames, pos, i = FrameCounter(), FrameDecoder(), 0, 0, 0, 0
    while pos < len(stream):
        chunk = memoryview(stream)[pos:pos + cuts[i % len(cuts)]]
        counted += counter.feed(chunk)
        frames += len(decoder.feed(bytes(chunk)))
        pos, i = pos + len(chunk), i + 1
    assert counted == frames == len(sizes)


def test_the_frame_counter_refuses_an_absurd_length():
    with pytest.raises(TcprosError, match="exceeds"):
        FrameCounter(limit=100).feed(struct.pack("<I", 101))


def read_in_place(reader: FrameReader, stream: bytes, cuts: list[int]) -> list:
    """As asyncio's BufferedProtocol: each piece copied into get_buffer() (as recv_into would), then received()."""
    got: list = []
    last = 0
    for cut in cuts + [len(stream)]:
        while last < cut:
            buf = reader.get_buffer()
            assert len(buf) > 0
            n = min(len(buf), cut - last)
            buf[:n] = stream[last:last + n]
            last += n
            got += reader.received(n)
    return got


@given(st.lists(st.sampled_from([0, 1, 3, 100, FrameReader.SCRATCH - 4, FrameReader.SCRATCH - 3, 200_000]),
                max_size=8), st.data())
def test_frames_read_in_place_survive_any_split(sizes, data):
    payloads = [bytes([i % 251]) * size for i, size in enumerate(sizes)]
    stream = b"".join(encode_frame(p) for p in payloads)
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=10)))
    reader = FrameReader()
    got = read_in_place(reader, stream, cuts)
    assert [bytes(g) for g in got] == payloads and reader.pending == 0
    # a frame larger than the scratch buffer is handed on as the buffer it was read into
    assert all(isinstance(g, bytearray) == (len(g) > FrameReader.SCRATCH - 4) for g in got)


def test_frame_read_in_place_waits_for_the_rest_and_refuses_absurd_lengths():
    reader = FrameReader()
    frame = encode_frame(b"y" * 100_000)
    assert read_in_place(reader, frame[:70_000], []) == [] and reader.pending == 70_000
    assert read_in_place(reader, frame[70_000:] + frame[:2], []) == [b"y" * 100_000] and reader.pending == 2
    with pytest.raises(TcprosError, match="exceeds"):
        read_in_place(FrameReader(limit=1000), struct.pack("<I", 0xFFFFFFF0) + b"xx", [])


def test_a_claimed_length_costs_memory_only_as_its_bytes_come():
    """A publisher may announce a frame up to the limit (roscpp's 10^9 bytes) and send little of it: the frame's
    buffer grows with what came (1 MiB, then 16 times what came), not with what was announced."""
    rss = psutil.Process().memory_info().rss
    readers = [FrameReader() for _ in range(3)]
    for reader in readers:  # 2.7 GB announced in all
        assert read_in_place(reader, struct.pack("<I", 900_000_000) + b"z" * 100_000, []) == []
        assert reader.partial() == "100000 of its 900000000 bytes" and reader.held == tcpros.FIRST_BODY
    assert psutil.Process().memory_info().rss - rss < 50 << 20
    # as more comes, the buffer grows to TRUST_FACTOR times what came, never to what was announced
    reader = readers[0]
    for sent in (1 << 20, 3 << 20, 20 << 20):
        read_in_place(reader, b"z" * (sent - (reader.pending - 4)), [])
        assert reader.pending - 4 == sent and sent <= reader.held <= tcpros.TRUST_FACTOR * sent, (sent, reader.held)
    # and a large frame that does come whole is what was sent
    big = bytes(range(256)) * ((3 << 20) // 256)
    reader = FrameReader()
    (got,) = read_in_place(reader, encode_frame(big), [1000, 2 << 20])
    assert len(got) == len(big) and bytes(got) == big and reader.partial() == ""


def test_what_a_close_would_cut_is_said_by_the_reader_and_the_counter():
    for cut, words in ((0, ""), (2, "2 of the 4 bytes of its length"), (4, "0 of its 100000 bytes"),
                       (70_004, "70000 of its 100000 bytes"), (100_004, "")):
        stream = encode_frame(b"q" * 100_000)[:cut]
        reader, counter = FrameReader(), FrameCounter()
        read_in_place(reader, stream, [])
        counter.feed(stream)
        assert reader.partial() == counter.partial() == words, cut


SIZES = [0, 1, 3, 100, 1000, FrameReader.SCRATCH - 4, FrameReader.SCRATCH - 3, 100_000]


@given(st.lists(st.lists(st.sampled_from(SIZES), max_size=4), min_size=2, max_size=3),
       st.lists(st.sampled_from([1, 2, 5, 100, 5000, 65_000]), max_size=6), st.lists(st.integers(0, 7), min_size=1,
                                                                                     max_size=12))
def test_readers_sharing_a_pool_read_their_own_frames_however_their_reads_interleave(streams, reads, orders):
    """Readers lend and borrow scratch buffers from one pool: whatever order their reads come in (one at a time
    as asyncio's, or several readers' buffers asked for before any is filled), each reads its own frames."""
    pool = ScratchPool(FrameReader.SCRATCH, kept=1)
    readers = [FrameReader(pool=pool) for _ in streams]
    payloads = [[bytes([(7 * r + i) % 251]) * size for i, size in enumerate(sizes)] for r, sizes in enumerate(streams)]
    wire = [b"".join(encode_frame(p) for p in ps) for ps in payloads]
    sent, got, step = [0] * len(readers), [[] for _ in readers], 0
    reads = reads + [70_000]  # (every few reads a large one: a frame of 64 kB in reads of a byte is slow to test)
    while any(sent[r] < len(wire[r]) for r in range(len(readers))):
        busy = [r for r in range(len(readers)) if sent[r] < len(wire[r])]
        # some readers ask for a buffer (as many as `orders` says, from a place it says), then each is filled
        order = orders[step % len(orders)]
        asked = [busy[(order + k) % len(busy)] for k in range(1 + order % len(busy))]
        bufs = [readers[r].get_buffer() for r in asked]
        for r, buf in zip(asked, bufs):
            n = min(len(buf), len(wire[r]) - sent[r], reads[step % len(reads)])
            buf[:n] = wire[r][sent[r]:sent[r] + n]
            sent[r] += n
            got[r] += readers[r].received(n)
            step += 1
    assert [[bytes(g) for g in frames] for frames in got] == payloads
    assert all(reader.pending == 0 for reader in readers)


def test_a_reader_between_frames_holds_no_scratch_buffer():
    """The scratch buffer goes back to the pool as soon as it holds nothing of a frame, and is kept while it
    holds the start of one; a large frame is read into its own buffer, the scratch buffer given back."""
    pool = ScratchPool(FrameReader.SCRATCH, kept=1)
    idle, cut, large = FrameReader(pool=pool), FrameReader(pool=pool), FrameReader(pool=pool)
    assert read_in_place(idle, encode_frame(b"a" * 100) * 3, []) == [b"a" * 100] * 3
    assert pool.free == 1  # (lent, given back)
    assert read_in_place(cut, encode_frame(b"b" * 100)[:50], []) == [] and pool.free == 0
    assert read_in_place(idle, encode_frame(b"c"), []) == [b"c"] and pool.free == 1  # a new one, given back
    assert read_in_place(large, encode_frame(b"d" * 100_000)[:70_000], []) == [] and pool.free == 1
    assert large.held == 100_000
    assert read_in_place(cut, encode_frame(b"b" * 100)[50:], []) == [b"b" * 100]
    assert pool.free == 1  # (the pool keeps one: the second was let go)
    assert cut.take_pending() == b"" and large.take_pending()[:4] == struct.pack("<I", 100_000)


def test_transport_info_has_rosnode_info_shape():
    assert transport_info(None) == "TCPROS connection"


# ------------------------------------------------------------------ asyncio, real loopback sockets

async def _server_with_publication(latch: bool = False) -> tuple[TcprosServer, Publication]:
    server = TcprosServer("/pubnode", "127.0.0.1")
    await server.start()
    pub = Publication("/chat", LOG, "/pubnode", latch=latch)
    server.publications["/chat"] = pub
    return server, pub


def _subscriber(received: list[bytes], mtype: TopicType = LOG, topic: str = "/chat") -> PublisherLink:
    return PublisherLink(topic, mtype, "/subnode", "http://pub:1/",
                         lambda payload, link: received.append(payload), lambda link: None)


def test_publish_and_subscribe_over_loopback():
    async def main():
        server, pub = await _server_with_publication()
        received: list[bytes] = []
        link = await connect_publisher("127.0.0.1", server.port, _subscriber(received))
        assert link.header["callerid"] == "/pubnode"
        assert link.header["md5sum"] == LOG.md5sum
        assert link.header["latching"] == "0"
        await until_async(lambda: len(pub.links) == 1, 5)
        assert pub.links[0].callerid == "/subnode"
        assert "TCPROS connection on port %d to [127.0.0.1:" % server.port in pub.links[0].info
        for i in range(1000):
            pub.publish(b"m%d" % i)
        await until_async(lambda: len(received) == 1000, 5)
        assert received == [b"m%d" % i for i in range(1000)]
        link.close()
        await until_async(lambda: not pub.links, 5)
        await server.stop()
    asyncio.run(main())


def test_a_watch_counts_a_busy_topic_as_it_comes_and_a_quiet_one_when_drained():
    async def main():
        server, pub = await _server_with_publication()
        counts: list[int] = []
        link = await watch_publisher("127.0.0.1", server.port, "/chat", "/watch", "http://pub:1/", counts.append)
        await until_async(lambda: len(pub.links) == 1, 5)
        for i in range(3):
            pub.publish(b"small %d" % i)  # under the socket's low-water mark: the loop is not woken for them
        await until_async(lambda: (link.drain(), sum(counts))[1] == 3, 5)
        big = b"x" * (WATCH_LOWAT * 8)
        for _ in range(5):
            pub.publish(big)
        await until_async(lambda: sum(counts) >= 7, 5)  # read by the loop, in gulps, without a drain
        link.drain()
        assert sum(counts) == 8 and len(counts) < 3 + 5 * 8  # (not a wake-up per message or per 64 kB)
        await server.stop()
        await until_async(lambda: (link.drain(), link.closed)[1], 5)  # the publisher went
    asyncio.run(main())


def test_idle_links_and_watches_cost_little_memory_each():
    """A subscriber's link or a watch at rest holds no read buffer: what it costs, both ends of it in this
    process (the sockets, the protocols, the transports, both connection headers) is a few kB, not its
    share of a 64 kB scratch buffer (a link) or of a 256 kB read buffer (a watch)."""
    links, watches, bound = 40, 10, 24 << 10

    async def main():
        server, pub = await _server_with_publication()
        received: list[bytes] = []
        # one of each first: what the first costs once (the pools' buffers, the loop's lazily made parts)
        await connect_publisher("127.0.0.1", server.port, _subscriber(received))
        counts: list[int] = []
        first = await watch_publisher("127.0.0.1", server.port, "/chat", "/watch", "http://pub:1/", counts.append)
        pub.publish(b"m" * 300)
        await until_async(lambda: len(received) == 1 and (first.drain(), counts)[1] == [1], 5)
        gc.collect()
        tracemalloc.start()
        try:
            before = tracemalloc.get_traced_memory()[0]
            kept = [await connect_publisher("127.0.0.1", server.port, _subscriber(received)) for _ in range(links)]
            await until_async(lambda: len(pub.links) == 1 + links + 1, 5)
            pub.publish(b"m" * 300)  # (each reads a message: its scratch buffer lent and given back)
            await until_async(lambda: len(received) == 2 + links, 5)
            gc.collect()
            per_link = (tracemalloc.get_traced_memory()[0] - before) / links
            before = tracemalloc.get_traced_memory()[0]
            kept += [await watch_publisher("127.0.0.1", server.port, "/chat", "/watch%d" % i, "http://pub:1/",
                                           counts.append) for i in range(watches)]
            await until_async(lambda: len(pub.links) == 1 + links + 1 + watches, 5)
            pub.publish(b"m" * 300)
            watching = [first] + kept[links:]  # (a message under the low-water mark waits for a drain)
            await until_async(lambda: ([w.drain() for w in watching], sum(counts))[1] == 3 + watches, 5)
            gc.collect()
            per_watch = (tracemalloc.get_traced_memory()[0] - before) / watches
        finally:
            tracemalloc.stop()
        assert per_link < bound and per_watch < bound, (per_link, per_watch)
        await server.stop()
    asyncio.run(main())


def test_wrong_md5_is_refused_with_an_error_header():
    async def main():
        server, pub = await _server_with_publication()
        other = TopicType("std_msgs/String", "992ce8a1687cec8c8bd883ec73ca41d1", "string data\n")
        with pytest.raises(TcprosError, match="topic types do not match"):
            await connect_publisher("127.0.0.1", server.port, _subscriber([], other))
        assert pub.links == []
        await server.stop()
    asyncio.run(main())


def test_unknown_topic_is_refused():
    async def main():
        server, _ = await _server_with_publication()
        with pytest.raises(TcprosError, match="is not a publisher of \\[/nope\\]"):
            await connect_publisher("127.0.0.1", server.port, _subscriber([], topic="/nope"))
        await server.stop()
    asyncio.run(main())


def test_garbage_client_does_not_disturb_a_good_subscriber():
    async def main():
        server, pub = await _server_with_publication()
        received: list[bytes] = []
        await connect_publisher("127.0.0.1", server.port, _subscriber(received))
        # A client that sends an absurd header length, one that sends a malformed header,
        # and one that connects and stalls without a word.
        bad1 = await asyncio.open_connection("127.0.0.1", server.port)
        bad1[1].write(b"\xff\xff\xff\x7f" + b"x" * 100)
        bad2 = await asyncio.open_connection("127.0.0.1", server.port)
        bad2[1].write(b"\x05\x00\x00\x00\x01\x00\x00\x00z")
        stall = await asyncio.open_connection("127.0.0.1", server.port)
        assert await asyncio.wait_for(bad1[0].read(), 5) == b""
        assert await asyncio.wait_for(bad2[0].read(), 5) == b""
        for i in range(100):
            pub.publish(b"%d" % i)
        await until_async(lambda: len(received) == 100, 5)
        stall[1].close()
        await server.stop()
    asyncio.run(main())


def test_a_subscriber_that_stops_reading_is_dropped_from_not_waited_for(monkeypatch):
    monkeypatch.setattr(publication, "MAX_WRITE_BACKLOG", 64 * 1024)

    async def main():
        server, pub = await _server_with_publication()
        good: list[bytes] = []
        await connect_publisher("127.0.0.1", server.port, _subscriber(good))
        # A raw subscriber that completes the handshake, then never reads again.
        reader, writer = await asyncio.open_connection("127.0.0.1", server.port)
        writer.write(encode_header({"callerid": "/stuck", "topic": "/chat", "md5sum": "*"}))
        await until_async(lambda: len(pub.links) == 2, 5)
        stuck = [l for l in pub.links if l.callerid == "/stuck"][0]
        payload = b"x" * 10000
        for i in range(0, 2000, 5):
            for _ in range(5):
                pub.publish(payload)
            # Keep pace with the good reader, so that only the stuck one ever falls behind.
            await until_async(lambda: len(good) == i + 5, timeout=20)
        assert stuck.conn.drops > 0
        writer.close()
        await server.stop()
    asyncio.run(main())


def test_latched_publication_sends_the_last_message_on_connect():
    async def main():
        server, pub = await _server_with_publication(latch=True)
        pub.publish(b"first")
        pub.publish(b"last")
        received: list[bytes] = []
        link = await connect_publisher("127.0.0.1", server.port, _subscriber(received))
        assert link.header["latching"] == "1"
        await until_async(lambda: received == [b"last"], 5)
        await server.stop()
    asyncio.run(main())


def test_service_call_and_failure():
    async def main():
        server = TcprosServer("/srvnode", "127.0.0.1")
        await server.start()

        def handler(req: bytes) -> bytes:
            if req == b"boom":
                raise ValueError("no such logger")
            return req.upper()

        server.services["/echo"] = ServiceServer("/echo", "pkg/Echo", "0123", "pkg/EchoRequest",
                                                 "pkg/EchoResponse", "/srvnode", handler)

        async def call(req: bytes) -> tuple[dict, int, bytes]:
            reader, writer = await asyncio.open_connection("127.0.0.1", server.port)
            writer.write(encode_header({"callerid": "/c", "service": "/echo", "md5sum": "0123"}))
            writer.write(encode_frame(req))
            size = struct.unpack("<I", await reader.readexactly(4))[0]
            header = decode_header(await reader.readexactly(size))
            ok = (await reader.readexactly(1))[0]
            size = struct.unpack("<I", await reader.readexactly(4))[0]
            body = await reader.readexactly(size)
            writer.close()
            return header, ok, body

        header, ok, body = await call(b"abc")
        assert (header["type"], header["md5sum"], ok, body) == ("pkg/Echo", "0123", 1, b"ABC")
        header, ok, body = await call(b"boom")
        assert (ok, body) == (0, b"no such logger")
        await server.stop()
    asyncio.run(main())


def test_inbound_connections_are_forgotten_when_closed():
    async def main():
        server, pub = await _server_with_publication()
        reader, writer = await asyncio.open_connection("127.0.0.1", server.port)
        await until_async(lambda: len(server.connections) == 1, 5)
        assert isinstance(next(iter(server.connections)), InboundConnection)
        writer.close()
        await until_async(lambda: not server.connections, 5)
        await server.stop()
    asyncio.run(main())


@pytest.mark.parametrize("cut", [2, 10, 70_000])
def test_what_a_reader_holds_after_the_header_is_counted_by_the_watch(cut):
    """A watch reads the handshake with a FrameReader, then counts frames: what the reader holds of a frame
    (a small one in its scratch buffer, a large one in its own) goes on to the counter whole."""
    stream = encode_frame(b"y" * 100_000) + encode_frame(b"z" * 5)
    reader = FrameReader()
    assert read_in_place(reader, stream[:cut], []) == []
    counter = FrameCounter()
    assert counter.feed(reader.take_pending()) + counter.feed(stream[cut:]) == 2 and reader.pending == 0
