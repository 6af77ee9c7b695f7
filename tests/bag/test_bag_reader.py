"""launcher.bag.reader: a valid bag reads as rosbags reads it; what a damaged one costs in memory is bounded by what
the file really holds, whatever its lengths say."""

from __future__ import annotations

import random
import tracemalloc

import pytest
from rosbags.rosbag1 import Reader

import bagmutants
from test_bag_fuzz import rosbags_bag

from launcher.bag import info, reader
from launcher.bag.reader import Bag, BagError


@pytest.fixture(scope="module", params=["none", "bz2", "lz4"])
def bag(request, tmp_path_factory) -> str:
    path = str(tmp_path_factory.mktemp("reader") / ("%s.bag" % request.param))
    rosbags_bag(path, request.param)
    return path


def test_reads_as_rosbags_does(bag):
    with Reader(bag) as theirs:
        # (rosbags 0.9's msgdef is a str, 0.10's on a MessageDefinition)
        want = [(c.topic, c.msgtype.replace("/msg/", "/"), c.digest, getattr(c.msgdef, "data", c.msgdef),
                 c.ext.callerid, c.ext.latching, t, bytes(d)) for c, t, d in theirs.messages()]
        start, end, chunks = theirs.start_time, theirs.end_time - 1, len(theirs.chunk_infos)
    with Bag(bag) as ours:
        got = [(c.topic, c.type, c.md5sum, c.msgdef, c.callerid, c.latching, t, bytes(d))
               for t, c, d in ours.messages()]
        assert (ours.start_time, ours.end_time, len(ours.chunks), ours.warnings()) == (start, end, chunks, [])
    assert got == want and len(got) > 200


def test_start_and_stop_and_connections(bag):
    with Bag(bag) as ours:
        every = list(ours.messages())
        count = next(c.id for c in ours.connections if c.topic == "/count")
        middle = every[len(every) // 2][0]
        some = list(ours.messages({count}, start=middle, stop=every[-10][0]))
    assert some and all(c.id == count and middle <= t < every[-10][0] for t, c, _ in some)
    assert some == [m for m in every if m[1].id == count and middle <= m[0] < every[-10][0]]


def test_memory_is_bounded_by_what_the_file_holds(bag):
    """Each 4-byte field of the bag (a seeded sample) set to 0x7fffffff or 0xffffffff: reading it (info's facts and
    every message) never holds much more than the file's own size, though a length may claim 4 GiB."""
    with open(bag, "rb") as f:
        data = f.read()
    rnd = random.Random(37)
    positions = bagmutants.field4_positions(data)
    broken = bag + ".broken"
    worst = 0
    for pos in rnd.sample(positions, 40):
        out = bytearray(data)
        bagmutants.put32(out, pos, rnd.choice([0x7FFFFFFF, 0xFFFFFFFF]))
        with open(broken, "wb") as f:
            f.write(out)
        tracemalloc.start()
        try:
            with Bag(broken) as b:
                info.bag_info(broken, b, freq=True)
                sum(1 for _ in b.messages())
        except BagError:
            pass
        worst = max(worst, tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
    assert worst < 3 * len(data) + reader.STEP + (1 << 20), worst


def test_a_lying_uncompressed_size_costs_no_more_than_the_data(bag):
    """A chunk whose header says it decompresses to 2 GiB: decompressed a step at a time, and found short."""
    with open(bag, "rb") as f:
        data = bytearray(f.read())
    chunk = next(r for r in bagmutants.records(bytes(data), len(bagmutants.MAGIC), len(data)) if r.op == 5)
    bagmutants.put32(data, chunk.fields["size"][0], 0x7FFFFFFF)
    with open(bag + ".lying", "wb") as f:
        f.write(data)
    warnings = []
    tracemalloc.start()
    with Bag(bag + ".lying") as b:
        warnings += b.warnings()  # (found when the bag is opened)
        count = sum(1 for _ in b.messages(warn=warnings.append))  # (found when the chunk is read)
        peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < len(data) + reader.STEP + (1 << 20), peak
    assert count > 0 and len(warnings) == 1 and "chunk 1 of" in warnings[0]
    if bag.endswith("none.bag"):  # (the offsets of its index are checked against the size: info sees it)
        assert "uncompressed, but" in warnings[0]
    else:
        assert "decompresses to" in warnings[0] and "where its header says 2147483647" in warnings[0], warnings


def test_not_a_bag_and_missing(tmp_path):
    junk = tmp_path / "junk.bag"
    junk.write_bytes(b"#ROSBAG V1.2\n" + b"\x00" * 100)
    with pytest.raises(BagError, match="junk.bag: not a ROS bag") as exc:
        Bag(str(junk))
    assert not exc.value.reindexable
    with pytest.raises(BagError, match="nothing.bag: no such file"):
        Bag(str(tmp_path / "nothing.bag"))
    junk.write_bytes(b"#ROSBAG")
    with pytest.raises(BagError, match="truncated at byte 7, inside the '#ROSBAG V2.0' line"):
        Bag(str(junk))


def test_a_message_unlike_its_index_entry_leaves_its_chunk_out(tmp_path):
    """A message record whose time (or connection) is not what the index says: found when its chunk is read."""
    path = str(tmp_path / "plain.bag")
    rosbags_bag(path, "none")
    with open(path, "rb") as f:
        data = bytearray(f.read())
    chunk = [r for r in bagmutants.records(bytes(data), len(bagmutants.MAGIC), len(data)) if r.op == 5][2]
    message = next(r for r in bagmutants.records(bytes(data), chunk.datapos, chunk.end) if r.op == 2)
    pos, value = message.fields["time"]
    bagmutants.put32(data, pos, int.from_bytes(value[:4], "little") + 1)
    with open(path, "wb") as f:
        f.write(data)
    warnings = []
    with Bag(path) as b:
        assert not b.warnings()  # (the index is whole: nothing to see until the chunk is read)
        count = sum(1 for _ in b.messages(warn=warnings.append))
        lost = sum(b.chunks[2].counts.values())
        total = sum(sum(c.counts.values()) for c in b.chunks)
    offset = message.pos - chunk.datapos
    assert len(warnings) == 1 and count == total - lost, warnings
    assert ("chunk 3 of %d at byte %d: the message at offset %d: connection " % (len(b.chunks), chunk.pos, offset)
            in warnings[0] and "where the index says connection" in warnings[0]), warnings
