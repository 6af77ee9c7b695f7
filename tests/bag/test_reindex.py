"""A damaged bag: info and play name the file and what can still be read; reindex writes that into an indexed bag."""

from __future__ import annotations

import os
import subprocess
import sys

from rosbags.rosbag1 import Reader, Writer

from helpers import ROOT

from launcher.bag import reindex
from launcher.bag.record import BagFile

COUNT = 300


def string(text: str) -> bytes:
    data = text.encode()
    return len(data).to_bytes(4, "little") + data


def make_bag(path: str) -> None:
    writer = Writer(path)
    writer.chunk_threshold = 2048  # many chunks, so that a cut keeps most of them
    writer.open()
    conn = writer.add_connection("/chatter", "std_msgs/msg/String", msgdef="string data\n",
                                 md5sum="992ce8a1687cec8c8bd883ec73ca41d1", callerid="/talker", latching=0)
    for n in range(COUNT):
        writer.write(conn, 10**18 + n * 10**7, string("m %d" % n))
    writer.close()


def bag(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "launcher.bag", *args], capture_output=True, text=True, timeout=60,
                          env=dict(os.environ, PYTHONPATH=ROOT, ROS_MASTER_URI="http://127.0.0.1:9/"))


def test_truncated_bag_is_named_and_recovered(tmp_path):
    path = str(tmp_path / "cut.bag")
    make_bag(path)
    size = os.path.getsize(path)
    with open(path, "r+b") as f:
        f.truncate(size * 2 // 3)  # the index and the last chunks are gone
    for cmd in ("info", "play"):
        out = bag(cmd, path)
        assert out.returncode == 1 and "Traceback" not in out.stderr, out.stderr
        assert path in out.stderr and "can still read" in out.stderr and "launcher bag reindex" in out.stderr
    fixed = bag("reindex", path)
    assert fixed.returncode == 0, fixed.stderr
    assert os.path.exists(str(tmp_path / "cut.orig.bag"))  # as rosbag reindex: the original is kept
    with Reader(path) as reader:
        data = [bytes(d[4:]).decode() for _, _, d in reader.messages()]
        assert reader.connections[0].ext.callerid == "/talker"
    assert 100 < len(data) < COUNT and data == ["m %d" % n for n in range(len(data))]


def test_active_bag_reindexed_beside_it(tmp_path):
    # a recording that ended without its index (a killed recorder): what its chunks hold comes back
    active = str(tmp_path / "run.bag.active")
    recording = BagFile(str(tmp_path / "run.bag"), active, "none", 1024)
    conn = recording.connection("/chatter", {"type": "std_msgs/String", "md5sum": "992ce8a1687cec8c8bd883ec73ca41d1",
                                             "message_definition": "string data\n", "callerid": "/t"})
    for n in range(COUNT):
        recording.write(conn, 10**18 + n * 10**7, string("m %d" % n))
    recording.abort()
    assert not os.path.exists(str(tmp_path / "run.bag"))
    target, count, stop, skipped = reindex.reindex(active)
    assert target == str(tmp_path / "run.bag") and 0 < count <= COUNT
    with Reader(target) as reader:
        assert [bytes(d[4:]).decode() for _, _, d in reader.messages()] == ["m %d" % n for n in range(count)]


def test_not_a_bag(tmp_path):
    junk = tmp_path / "junk.bag"
    junk.write_bytes(b"\x00" * 5000)
    for cmd in ("info", "play", "reindex"):
        out = bag(cmd, str(junk))
        assert out.returncode == 1 and str(junk) in out.stderr and "Traceback" not in out.stderr, (cmd, out.stderr)


def test_a_damaged_copy_of_a_connection_record_is_passed_over(tmp_path):
    """A connection record whose md5sum is damaged in its chunk: the index's copy is taken; damaged in both, its
    messages are left out and said so."""
    import bagmutants

    path = str(tmp_path / "conn.bag")
    make_bag(path)
    with open(path, "rb") as f:
        data = bytearray(f.read())
    first_chunk = next(r for r in bagmutants.records(bytes(data), len(bagmutants.MAGIC), len(data)) if r.op == 5)
    # the md5sum of the connection record in the first chunk, and of the index's copy at the end of the file
    copies = [data.index(b"md5sum=", first_chunk.datapos) + 7, data.rindex(b"md5sum=") + 7]
    assert copies[0] < copies[1]
    data[copies[0]] = ord("Z")
    for name, broken in [("one", data), ("both", bytearray(data))]:
        if name == "both":
            broken[copies[1]] = ord("Z")
        with open(str(tmp_path / (name + ".bag")), "wb") as f:
            f.write(broken)
        (tmp_path / name).mkdir()
        target, count, stop, skipped = reindex.reindex(str(tmp_path / (name + ".bag")), str(tmp_path / name))
        if name == "one":
            assert count == COUNT and not skipped
            with Reader(target) as reader:
                assert reader.connections[0].digest == "992ce8a1687cec8c8bd883ec73ca41d1"
        else:
            assert count == 0 and skipped == ["%d messages of connection 0, whose connection record is lost or "
                                              "damaged" % COUNT]
