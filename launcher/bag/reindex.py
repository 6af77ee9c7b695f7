"""`bag reindex`: a bag without its index (an `.active` bag, a truncated or damaged one) read record by record and written anew.

The records are walked from the start (`reader`'s checked reads): chunks
(decompressed), the connection and message records inside them; the walk
stops at the first record that is cut short or makes no sense, and everything
before it is kept. A chunk whose record is whole but whose data is damaged is
left out with a warning and the walk goes on past it.
"""

from __future__ import annotations

import os
import struct
import sys
from collections.abc import Iterator
from typing import Optional

from launcher.bag.msgtypes import rosbags_type
from launcher.bag.reader import (MAGIC, OP_BAG_HEADER, OP_CHUNK, OP_CONNECTION, OP_MSG_DATA, Connection, Damage, File,
                                 Record, _record_in, connection, decompress, uint)

_TIME = struct.Struct("<II")
# Where the first chunk starts in a bag of rosbags' (its bag header record padded to 4096 bytes) and of rosbag's (the
# header and data of its bag header record padded to 4096): a damaged bag header is stepped over to these.
FIRST_CHUNK = (len(MAGIC) + 4096, len(MAGIC) + 4104)


class ReindexError(Exception):
    """A file that is no bag at all."""


class Walk:
    """The records of a bag, one at a time from its start: (kind, connection id, Connection or time, data). Nothing is
    held but the record at hand (a chunk: its records, decompressed). `stop` says what ended the walk; `skipped`,
    the chunks left out on the way (their record whole, their data damaged)."""

    def __init__(self, path: str):
        self.path = path
        self.stop = "the end of the file"
        self.skipped: list[str] = []

    def __iter__(self) -> Iterator[tuple[int, int, object, bytes]]:
        with open(self.path, "rb") as f:
            file = File(f, os.fstat(f.fileno()).st_size)
            if file.size < len(MAGIC) or file.read(0, len(MAGIC)) != MAGIC:
                raise ReindexError("%s: not a ROS bag (no '#ROSBAG V2.0' line)" % self.path)
            pos = len(MAGIC)
            retries = list(FIRST_CHUNK)
            while pos < file.size:
                try:
                    rec = file.record(pos, file.size, "the record")
                except Damage as exc:
                    if pos in (len(MAGIC), *FIRST_CHUNK) and retries:
                        pos = retries.pop(0)  # a damaged bag header: the chunks after it may still be whole
                        continue
                    self.stop = "byte %d of %d (%s)" % (pos, file.size, exc)
                    return
                retries = []
                if rec.op == OP_CHUNK:
                    yield from self._chunk(file, rec)
                elif rec.op == OP_CONNECTION:
                    item = _connection(rec.header, file.read(rec.datapos, rec.datasize))
                    if item:
                        yield item
                elif rec.op == OP_BAG_HEADER and pos != len(MAGIC):
                    self.stop = "byte %d of %d (a second bag header)" % (pos, file.size)
                    return
                pos = rec.end

    def _chunk(self, file: File, rec) -> Iterator[tuple[int, int, object, bytes]]:
        what = "the chunk at byte %d" % rec.pos
        try:
            kind = rec.header.get("compression", b"").decode("ascii", "replace")
            size = uint(rec.header, "size", 4, what)
            if kind == "none":
                if rec.datasize != size:  # (a length lied about is not read: the other says how long it is)
                    raise Damage("uncompressed, but %d bytes where its header says %d" % (rec.datasize, size))
                data = file.read(rec.datapos, rec.datasize)
            elif kind in ("bz2", "lz4"):
                data = decompress(kind, file, rec.datapos, rec.datasize, size)
            else:
                raise Damage("unknown compression %r" % kind)
        except Damage as exc:
            self.skipped.append("%s: %s" % (what, exc))
            return
        pos = 0
        while pos < len(data):  # its records up to the first one cut short or damaged
            try:
                inner = _record_in(data, pos, "the record at offset %d" % pos)
            except Damage as exc:
                self.skipped.append("%s: the rest from %s" % (what, exc))
                return
            body = data[inner.datapos:inner.end]
            if inner.op == OP_CONNECTION:
                item = _connection(inner.header, body)
            elif inner.op == OP_MSG_DATA and len(inner.header.get("time", b"")) == 8 \
                    and len(inner.header.get("conn", b"")) == 4:
                sec, nsec = _TIME.unpack(inner.header["time"])
                item = (OP_MSG_DATA, int.from_bytes(inner.header["conn"], "little"), sec * 1_000_000_000 + nsec, body)
            else:
                item = None
            if item:
                yield item
            pos = inner.end


def _connection(header: dict, data: bytes) -> Optional[tuple]:
    """A connection record, checked as the reader checks the index's: a damaged copy is passed over (another copy,
    in a later chunk or in the index, may be whole)."""
    try:
        conn = connection(Record(0, header, OP_CONNECTION, 0, len(data)), data, "a connection record")
    except Damage:
        return None
    return OP_CONNECTION, conn.id, conn, b""


def count(path: str) -> tuple[int, int, str]:
    """(connections, messages on them, what stopped the walk) of what reindex can read of `path`."""
    conns: set = set()
    messages: dict[int, int] = {}  # by connection: its record may come after them (in the index at the end)
    walk = Walk(path)
    for kind, cid, _, _ in walk:
        if kind == OP_CONNECTION:
            conns.add(cid)
        else:
            messages[cid] = messages.get(cid, 0) + 1
    return len(conns), sum(n for cid, n in messages.items() if cid in conns), walk.stop


def output_path(path: str, output_dir: str | None) -> str:
    name = path[:-len(".active")] if path.endswith(".active") else path
    return os.path.join(output_dir, os.path.basename(name)) if output_dir else name


def reindex(path: str, output_dir: str | None = None) -> tuple[str, int, str, list[str]]:
    """Write the messages that can be read from `path` into a new indexed bag, in the order they come: (its path,
    messages, where the walk stopped, the chunks left out). Two walks: the connections first (the index at the end
    holds them all, even those whose chunk is lost), then the messages. A bag reindexed in place keeps its original
    as NAME.orig.bag, as rosbag's does."""
    conns: dict[int, Connection] = {}
    for kind, cid, conn, _ in Walk(path):
        if kind == OP_CONNECTION:
            conns.setdefault(cid, conn)
    target = output_path(path, output_dir)
    source = path
    if os.path.abspath(target) == os.path.abspath(path):
        backup = target[:-4] + ".orig.bag" if target.endswith(".bag") else target + ".orig"
        os.replace(path, backup)
        source = backup
    elif os.path.exists(target):
        raise ReindexError("%s exists already: not overwriting it (give --output-dir)" % target)
    # (imported here: info and play import this module for the walk, and rosbags' import costs them ~90 ms)
    from rosbags.rosbag1 import Writer

    writer = Writer(target)
    writer.open()
    made = {}
    same: dict[Connection, object] = {}
    lost: dict[int, int] = {}
    written = 0
    walk = Walk(source)
    for kind, cid, stamp, data in walk:
        if kind != OP_MSG_DATA:
            continue
        conn = conns.get(cid)
        if conn is None:  # its connection record lost with the damage (or every copy of it damaged)
            lost[cid] = lost.get(cid, 0) + 1
            continue
        out = made.get(cid)
        if out is None:
            # (two ids of the same connection, one of them damaged, are one connection: rosbags' writer takes a
            # connection once)
            key = conn._replace(id=0)
            out = made[cid] = same.get(key) or writer.add_connection(
                conn.topic, rosbags_type(conn.type), msgdef=conn.msgdef, md5sum=conn.md5sum,
                callerid=conn.callerid, latching=conn.latching)
            same[key] = out
        writer.write(out, stamp, data)
        written += 1
    writer.close()
    skipped = walk.skipped + ["%d message%s of connection %d, whose connection record is lost or damaged"
                              % (n, "" if n == 1 else "s", cid) for cid, n in sorted(lost.items())]
    return target, written, walk.stop, skipped


def main(paths: list[str], output_dir: str | None = None) -> int:
    status = 0
    for path in paths:
        try:
            target, count, stop, skipped = reindex(path, output_dir)
        except (ReindexError, OSError) as exc:
            print("ERROR %s" % exc, file=sys.stderr)
            status = 1
            continue
        for line in skipped:
            print("[ WARN] %s: %s: left out" % (path, line), file=sys.stderr)
        print("%s: %d messages into %s (read up to %s)" % (path, count, target, stop))
    return status
