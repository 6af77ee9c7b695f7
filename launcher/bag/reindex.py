"""`bag reindex`: a bag without its index (an `.active` bag, a truncated or damaged one) read record by record and written anew.

rosbags reads only indexed bags, so the records are walked here: chunks
(decompressed), the connection and message records inside them; the walk stops
at the first record that is cut short or makes no sense, and everything before
it is kept.
"""

from __future__ import annotations

import bz2
import os
import struct
import sys
from collections.abc import Iterator

from rosbags.rosbag1 import Writer

from launcher.bag.msgtypes import rosbags_type

MAGIC = b"#ROSBAG V2.0\n"
OP_MSG_DATA, OP_BAG_HEADER, OP_INDEX_DATA, OP_CHUNK, OP_CHUNK_INFO, OP_CONNECTION = 2, 3, 4, 5, 6, 7
_U32 = struct.Struct("<I")
# No record of a sane bag has a header this large; a larger length is damage, not data.
MAX_HEADER = 1 << 20


class ReindexError(Exception):
    """A file that is no bag at all."""


def fields(data: bytes) -> dict[str, bytes]:
    """A record header's (or connection header's) `name=value` fields; values are bytes."""
    out: dict[str, bytes] = {}
    pos = 0
    while pos + 4 <= len(data):
        (size,) = _U32.unpack_from(data, pos)
        pos += 4
        if size > len(data) - pos:
            raise ValueError("field overruns its header")
        key, eq, value = data[pos:pos + size].partition(b"=")
        if not eq:
            raise ValueError("field without '='")
        out[key.decode("ascii", "replace")] = value
        pos += size
    return out


def records(buf: bytes | memoryview, pos: int) -> Iterator[tuple[dict[str, bytes], memoryview, int]]:
    """(header, data, end) of each whole record from `pos`; stops at the first one cut short or malformed."""
    view = memoryview(buf)
    end = len(view)
    while pos + 4 <= end:
        (hlen,) = _U32.unpack_from(view, pos)
        if hlen > MAX_HEADER or pos + 4 + hlen + 4 > end:
            return
        try:
            header = fields(bytes(view[pos + 4:pos + 4 + hlen]))
        except ValueError:
            return
        (dlen,) = _U32.unpack_from(view, pos + 4 + hlen)
        start = pos + 8 + hlen
        if start + dlen > end or "op" not in header:
            return
        yield header, view[start:start + dlen], start + dlen
        pos = start + dlen


def _decompress(kind: bytes, data: memoryview, size: int) -> bytes:
    if kind == b"none":
        return bytes(data)
    if kind == b"bz2":
        return bz2.decompress(data)
    if kind == b"lz4":
        import lz4.frame  # (rosbags' own dependency; only lz4 bags need it)
        return lz4.frame.decompress(data)
    raise ValueError("unknown compression %r" % kind)


def scan(path: str) -> tuple[dict[int, dict[str, bytes]], list[tuple[int, int, int, bytes]], str]:
    """(connections by id, messages as (time ns, order, connection id, data), what stopped the walk)."""
    with open(path, "rb") as f:
        buf = f.read()
    if not buf.startswith(MAGIC):
        raise ReindexError("%s: not a ROS bag (no '#ROSBAG V2.0' line)" % path)
    conns: dict[int, dict[str, bytes]] = {}
    msgs: list[tuple[int, int, int, bytes]] = []
    stop = "the end of the file"
    pos = len(MAGIC)
    last = pos
    for header, data, end in records(buf, pos):
        last = end
        op = header["op"][:1]
        if op == bytes([OP_CHUNK]):
            try:
                inner = _decompress(header.get("compression", b"none"), data, 0)
            except Exception as exc:  # a damaged chunk ends what can be trusted
                stop = "a damaged chunk at byte %d (%s)" % (end - len(data), exc)
                break
            for h, d, _ in records(inner, 0):
                _take(h, d, conns, msgs)
        elif op == bytes([OP_CONNECTION]):
            _take(header, data, conns, msgs)
    if last < len(buf):
        stop = "byte %d of %d (a record cut short or damaged)" % (last, len(buf))
    return conns, msgs, stop


def _take(header: dict[str, bytes], data: memoryview, conns: dict, msgs: list) -> None:
    op = header["op"][:1]
    if op == bytes([OP_CONNECTION]) and "conn" in header:
        (cid,) = _U32.unpack(header["conn"][:4])
        try:
            conns.setdefault(cid, dict(fields(bytes(data)), topic=header.get("topic", b"")))
        except ValueError:
            pass
    elif op == bytes([OP_MSG_DATA]) and "conn" in header and len(header.get("time", b"")) == 8:
        (cid,) = _U32.unpack(header["conn"][:4])
        sec, nsec = struct.unpack("<II", header["time"])
        msgs.append((sec * 1_000_000_000 + nsec, len(msgs), cid, bytes(data)))


def output_path(path: str, output_dir: str | None) -> str:
    name = path[:-len(".active")] if path.endswith(".active") else path
    return os.path.join(output_dir, os.path.basename(name)) if output_dir else name


def reindex(path: str, output_dir: str | None = None) -> tuple[str, int, str]:
    """Write the messages that can be read from `path` into a new indexed bag: (its path, messages, where the
    walk stopped). A bag reindexed in place keeps its original as NAME.orig.bag, as rosbag's does."""
    conns, msgs, stop = scan(path)
    target = output_path(path, output_dir)
    if os.path.abspath(target) == os.path.abspath(path):
        backup = target[:-4] + ".orig.bag" if target.endswith(".bag") else target + ".orig"
        os.replace(path, backup)
    elif os.path.exists(target):
        raise ReindexError("%s exists already: not overwriting it (give --output-dir)" % target)
    msgs.sort()
    writer = Writer(target)
    writer.open()
    made = {}
    written = 0
    for stamp, _, cid, data in msgs:
        header = conns.get(cid)
        if header is None:
            continue  # a message whose connection record was lost with the damage
        conn = made.get(cid)
        if conn is None:
            latching = header.get("latching", b"").decode("ascii", "replace")
            text = {k: header.get(k, b"").decode("utf-8", "replace") for k in
                    ("topic", "type", "md5sum", "message_definition", "callerid")}
            conn = made[cid] = writer.add_connection(
                text["topic"], rosbags_type(text["type"]), msgdef=text["message_definition"], md5sum=text["md5sum"],
                callerid=text["callerid"] if "callerid" in header else None,
                latching=int(latching) if latching.isdigit() else None)
        writer.write(conn, stamp, data)
        written += 1
    writer.close()
    return target, written, stop


def main(paths: list[str], output_dir: str | None = None) -> int:
    status = 0
    for path in paths:
        try:
            target, count, stop = reindex(path, output_dir)
        except (ReindexError, OSError) as exc:
            print("ERROR %s" % exc, file=sys.stderr)
            status = 1
            continue
        print("%s: %d messages into %s (read up to %s)" % (path, count, target, stop))
    return status
