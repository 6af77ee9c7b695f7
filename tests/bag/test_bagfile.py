"""BagFile: a message as large as a chunk is written as a chunk of its own, straight to the disk; the bag reads
back the same as one rosbags' writer makes (messages, order, stamps, chunks, index)."""

from __future__ import annotations

from rosbags.rosbag1 import Reader

from launcher.bag.record import BagFile

HEADER = {"type": "std_msgs/String", "md5sum": "992ce8a1687cec8c8bd883ec73ca41d1",
          "message_definition": "string data\n", "callerid": "/talker", "latching": "0"}
CHUNK = 64 * 1024


def string(size: int, n: int) -> bytearray:
    data = ("m %d " % n).encode().ljust(size, b"x")
    return bytearray(len(data).to_bytes(4, "little") + data)  # (a received large message is a bytearray)


def mixed_bag(path: str, compression: str = "none") -> list[tuple[str, int, bytes]]:
    """Small and chunk-sized messages on two topics, interleaved; what was written, in order."""
    bag = BagFile(path, path + ".active", compression, CHUNK)
    written = []
    for n in range(40):
        topic = "/big" if n % 3 else "/small"
        payload = string(3 * CHUNK if n % 3 == 1 else CHUNK if n % 3 == 2 else 10, n)
        stamp = 10**18 + n * 10**6
        bag.write(bag.connection(topic, dict(HEADER, topic=topic)), stamp, payload)
        written.append((topic, stamp, bytes(payload)))
    bag.close()
    return written


def read(path: str) -> list[tuple[str, int, bytes]]:
    with Reader(path) as reader:
        return [(c.topic, t, bytes(d)) for c, t, d in reader.messages()]


def test_chunk_sized_messages_read_back(tmp_path):
    path = str(tmp_path / "mixed.bag")
    written = mixed_bag(path)
    assert read(path) == written
    with Reader(path) as reader:
        assert reader.topics["/big"].msgcount == 26 and reader.topics["/small"].msgcount == 14
        # each large message a chunk of its own; the small ones gathered between them
        assert len(reader.chunk_infos) >= 26


def test_compressed_bags_keep_rosbags_chunks(tmp_path):
    path = str(tmp_path / "lz4.bag")
    written = mixed_bag(path, "lz4")
    assert read(path) == written
