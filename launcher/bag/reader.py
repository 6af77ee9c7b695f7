"""What a valid ROS bag (format 2.0) looks like: a bag opened with every length, offset, count and field checked
before it is used, for `info` and `play`.

A bag is a file header, chunks (each followed by its index records) and, at
the end, the index: connection records and a chunk info per chunk. Damage
is told in words that name the file and where: `truncated at byte N`,
`chunk 3 of 7 at byte 1234: unknown compression 'xz'`, `index record of 12
bytes where 47 were expected`. Damage to the file header or the index ends
the reading (a `BagError`; `launcher bag reindex` walks such a bag instead);
damage to one chunk (its record, its index records, its compressed data, a
message in it) loses that chunk only: the chunk is left out with a warning
and the rest plays.

No length in the file is trusted for memory: a record's extent is checked
against the file (or the chunk holding it) before it is read, and a chunk is
decompressed in steps up to the size its header states, so what is held is at
most the largest record the file really has. rosbags' reader is not used: it
asserts on damage (an AssertionError out of `read_index_data`) and reads
lengths as they come.
"""

from __future__ import annotations

import bisect
import bz2
import os
import re
import struct
from collections.abc import Callable, Iterator
from typing import BinaryIO, NamedTuple, Optional

from launcher.model import names

MAGIC = b"#ROSBAG V2.0\n"
OP_MSG_DATA, OP_BAG_HEADER, OP_INDEX_DATA, OP_CHUNK, OP_CHUNK_INFO, OP_CONNECTION = 2, 3, 4, 5, 6, 7
OP_NAMES = {OP_MSG_DATA: "message data record", OP_BAG_HEADER: "bag header", OP_INDEX_DATA: "index record",
            OP_CHUNK: "chunk", OP_CHUNK_INFO: "chunk info", OP_CONNECTION: "connection record"}
COMPRESSIONS = ("none", "bz2", "lz4")
# No record header of a sane bag comes near this (the largest, a connection record's, holds a topic name).
MAX_HEADER = 1 << 16
# An index record's header is always these 47 bytes: op, ver, conn and count, each a fixed size.
INDEX_HEADER = 47
# Chunks are decompressed this much at a time: a size stated in the file is never allocated at once.
STEP = 1 << 20
# A time's nanoseconds are below this in any bag a ROS writer made.
NSEC = 1_000_000_000
NEVER = 2 ** 63 - 1

_U32 = struct.Struct("<I")
_TIME = struct.Struct("<II")
_ENTRY = struct.Struct("<III")    # an index record's entry: secs, nsecs, offset in the chunk
_COUNT = struct.Struct("<II")     # a chunk info's entry: connection id, messages
# A message data record's header as every writer makes it: op, conn and time, each once, in any order.
_MESSAGE_HEADER = re.compile(
    rb"(?:(\x04\x00\x00\x00op=\x02)|\x09\x00\x00\x00conn=(.{4})|\x0d\x00\x00\x00time=(.{8})){3}", re.DOTALL)


class BagError(Exception):
    """A bag that cannot be read: its file name and what is wrong where. `reindexable`: a walk of its records
    (`launcher bag reindex`) may still recover its messages."""

    def __init__(self, text: str, reindexable: bool = False):
        super().__init__(text)
        self.reindexable = reindexable


class Damage(Exception):
    """What is wrong where, in words (the file's name is added by the caller)."""


class Truncated(Damage):
    """The file ends before a record it holds does."""


class Connection(NamedTuple):
    id: int
    topic: str
    type: str                 # the ROS 1 name: std_msgs/String
    md5sum: str
    msgdef: str
    callerid: Optional[str]
    latching: Optional[int]


class Chunk(NamedTuple):
    """A chunk, from its chunk info in the index and its own record; `damage` says why it cannot be read."""
    number: int               # 1-based, in the index's order
    pos: int                  # 0, and start NEVER, end -1, counts {}: its chunk info was damaged
    start: int                # ns, the first and last message's times (the chunk info's)
    end: int
    counts: dict              # connection id -> messages (the chunk info's)
    compression: str          # "" where its record could not be read
    size: int                 # uncompressed bytes (the chunk header's)
    datapos: int
    datasize: int             # compressed bytes on the disk
    entries: list             # [(time ns, connection id, offset)] from its index records
    damage: Optional[str]


def fields(data: bytes, what: str) -> dict:
    """A record header's (or a connection header's) `name=value` fields; values are bytes."""
    out = {}
    pos = 0
    while pos < len(data):
        if pos + 4 > len(data):
            raise Damage("%s: %d stray bytes at its end" % (what, len(data) - pos))
        (size,) = _U32.unpack_from(data, pos)
        pos += 4
        if size > len(data) - pos:
            raise Damage("%s: a field of %d bytes where %d are left" % (what, size, len(data) - pos))
        name, eq, value = data[pos:pos + size].partition(b"=")
        if not eq:
            raise Damage("%s: a field without '='" % what)
        try:
            out[name.decode("ascii")] = value
        except UnicodeDecodeError:
            raise Damage("%s: a field name that is not ASCII" % what) from None
        pos += size
    return out


def uint(header: dict, name: str, size: int, what: str) -> int:
    value = header.get(name)
    if value is None:
        raise Damage("%s: no '%s' field" % (what, name))
    if len(value) != size:
        raise Damage("%s: its '%s' field has %d bytes where %d were expected" % (what, name, len(value), size))
    return int.from_bytes(value, "little")


def _time(value: bytes) -> int:
    secs, nsecs = _TIME.unpack(value)
    return secs * NSEC + nsecs if nsecs < NSEC else -1


def stamp(header: dict, name: str, what: str) -> int:
    value = header.get(name)
    if value is None or len(value) != 8:
        raise Damage("%s: no 8-byte '%s' field" % (what, name))
    secs, nsecs = _TIME.unpack(value)
    if nsecs >= NSEC:
        raise Damage("%s: its '%s' has %d nanoseconds" % (what, name, nsecs))
    return secs * NSEC + nsecs


def text(header: dict, name: str, what: str, required: bool = True) -> Optional[str]:
    value = header.get(name)
    if value is None:
        if required:
            raise Damage("%s: no '%s' field" % (what, name))
        return None
    try:
        return value.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise Damage("%s: its '%s' is not UTF-8 text (byte %d)" % (what, name, exc.start)) from None


def op_of(header: dict, what: str) -> int:
    return uint(header, "op", 1, what)


class Record(NamedTuple):
    pos: int
    header: dict
    op: int
    datapos: int
    datasize: int

    @property
    def end(self) -> int:
        return self.datapos + self.datasize


class File:
    """A bag's file read at checked places: nothing past `size` (or the caller's limit) is asked for."""

    def __init__(self, f: BinaryIO, size: int):
        self.f = f
        self.size = size

    def read(self, pos: int, n: int) -> bytes:
        self.f.seek(pos)
        data = self.f.read(n)
        if len(data) != n:  # (the file shrank under us)
            raise Truncated("truncated at byte %d" % (pos + len(data)))
        return data

    def record(self, pos: int, limit: int, what: str, limit_what: str = "") -> Record:
        """The record at `pos`, which must end by `limit` (the end of the file, or of what holds it: `limit_what`)."""
        def past(end: int) -> Damage:
            if limit_what:
                return Damage("%s at byte %d runs to byte %d, past %s at byte %d" % (what, pos, end, limit_what, limit))
            return Truncated("truncated at byte %d: %s at byte %d runs to byte %d" % (limit, what, pos, end))
        if pos + 4 > limit:
            raise past(pos + 4)
        (hlen,) = _U32.unpack(self.read(pos, 4))
        if hlen > MAX_HEADER:
            raise Damage("%s at byte %d: a header of %d bytes (a record header has at most %d)"
                         % (what, pos, hlen, MAX_HEADER))
        if pos + 8 + hlen > limit:
            raise past(pos + 8 + hlen)
        raw = self.read(pos + 4, hlen + 4)
        header = fields(raw[:hlen], "%s at byte %d" % (what, pos))
        (dlen,) = _U32.unpack_from(raw, hlen)
        datapos = pos + 8 + hlen
        if datapos + dlen > limit:
            raise past(datapos + dlen)
        return Record(pos, header, op_of(header, "%s at byte %d" % (what, pos)), datapos, dlen)


def _expect(rec: Record, op: int, what: str) -> None:
    if rec.op != op:
        raise Damage("%s at byte %d: a %s (op %d) where a %s was expected"
                     % (what, rec.pos, OP_NAMES.get(rec.op, "record of unknown kind"), rec.op, OP_NAMES[op]))


def connection(rec: Record, data: bytes, what: str) -> Connection:
    """A connection record: the ids and topic of its header, the type, md5sum and definition of its data."""
    cid = uint(rec.header, "conn", 4, what)
    topic = text(rec.header, "topic", what)
    if not topic or not names.is_legal_name(names.canonicalize_name(topic)):  # ('/a//b' is '/a/b', as rosbags says)
        raise Damage("%s: topic %r is not a legal ROS name" % (what, topic))
    conn = fields(data, "%s's connection header" % what)
    mtype = text(conn, "type", what)
    if not re.fullmatch(r"[\w.-]+/\w+", mtype):
        raise Damage("%s: message type %r is not pkg/Name" % (what, mtype))
    md5sum = text(conn, "md5sum", what)
    if md5sum != "*" and (len(md5sum) != 32 or any(c not in "0123456789abcdef" for c in md5sum)):
        raise Damage("%s: md5sum %r is not 32 hex digits" % (what, md5sum))
    latching = text(conn, "latching", what, required=False)
    return Connection(cid, names.canonicalize_name(topic), mtype, md5sum, text(conn, "message_definition", what),
                      text(conn, "callerid", what, required=False),
                      int(latching) if latching and re.fullmatch("[0-9]{1,9}", latching) else None)


class Bag:
    """An open bag: its connections and chunks, checked; `messages` reads them, leaving damaged chunks out."""

    def __init__(self, path: str):
        self.path = path
        self.connections: list[Connection] = []
        self.chunks: list[Chunk] = []
        self.trailing = 0         # bytes after the index (no writer leaves any)
        try:
            self.f = open(path, "rb")
        except FileNotFoundError:
            raise BagError("%s: no such file" % path) from None
        except OSError as exc:
            raise BagError("%s: %s" % (path, exc.strerror or exc)) from None
        try:
            self.file = File(self.f, os.fstat(self.f.fileno()).st_size)
            self._read_index()
        except Damage as exc:
            self.f.close()
            raise BagError("%s: %s" % (path, exc), reindexable=not isinstance(exc, NotABag)) from None
        except OSError as exc:
            self.f.close()
            raise BagError("%s: %s" % (path, exc.strerror or exc)) from None
        self._current: tuple = (None, None)      # (chunk number, its records), one chunk at a time
        self._bad: set = set()                   # chunks found damaged when read (said once, not at every loop)

    def close(self) -> None:
        self.f.close()

    def __enter__(self) -> Bag:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def size(self) -> int:
        return self.file.size

    @property
    def start_time(self) -> int:
        """The first chunk's first message (ns), as rosbag says a bag's start; NEVER for a bag without chunks."""
        return min((c.start for c in self.chunks), default=NEVER)

    @property
    def end_time(self) -> int:
        """The last message's time (ns); -1 for a bag without chunks."""
        return max((c.end for c in self.chunks), default=-1)

    def damaged(self) -> list[Chunk]:
        return [c for c in self.chunks if c.damage]

    def warnings(self) -> list[str]:
        """What is wrong with a bag that can still be read, a line each."""
        out = ["%s: %s: %s left out" % (self.path, c.damage, _its_messages(c))
               for c in self.damaged()]
        if self.trailing:
            out.append("%s: %d bytes after the index at its end are no part of the bag"
                       % (self.path, self.trailing))
        return out

    # -- the file header and the index

    def _read_index(self) -> None:
        file = self.file
        if file.size < len(MAGIC) or file.read(0, len(MAGIC)) != MAGIC:
            head = file.read(0, min(file.size, len(MAGIC)))
            if head and MAGIC.startswith(head):
                raise Truncated("truncated at byte %d, inside the '#ROSBAG V2.0' line" % file.size)
            raise NotABag("not a ROS bag (it does not start with '#ROSBAG V2.0')")
        rec = file.record(len(MAGIC), file.size, "the bag header")
        _expect(rec, OP_BAG_HEADER, "the bag header")
        what = "the bag header"
        index_pos = uint(rec.header, "index_pos", 8, what)
        conn_count = uint(rec.header, "conn_count", 4, what)
        chunk_count = uint(rec.header, "chunk_count", 4, what)
        encryptor = text(rec.header, "encryptor", what, required=False)
        if encryptor:
            raise NotABag("encrypted (%r): not supported" % encryptor)
        self.header_end = rec.end
        if index_pos == 0:
            raise Damage("not indexed (a recording that did not end: the bag header has no index_pos)")
        if index_pos > file.size:
            raise Truncated("truncated at byte %d: the bag header puts the index at byte %d" % (file.size, index_pos))
        if index_pos < rec.end:
            raise Damage("the bag header's index_pos %d points inside the bag header (bytes %d to %d)"
                         % (index_pos, rec.pos, rec.end))
        self.index_pos = index_pos
        # The index: conn_count connection records, then chunk_count chunk infos, up to the end of the file.
        pos = index_pos
        infos: list[tuple[Record, bytes]] = []
        ids: set = set()
        want = "the bag header says %d connections and %d chunks" % (conn_count, chunk_count)
        while pos < file.size and len(self.connections) + len(infos) < conn_count + chunk_count:
            n = len(self.connections) + len(infos)
            what = ("connection record %d of %d in the index" % (n + 1, conn_count) if n < conn_count else
                    "chunk info %d of %d in the index" % (n - conn_count + 1, chunk_count))
            rec = file.record(pos, file.size, what)
            wanted = OP_CONNECTION if n < conn_count else OP_CHUNK_INFO
            if rec.op != wanted:
                if pos == index_pos and rec.op not in (OP_CONNECTION, OP_CHUNK_INFO):
                    raise Damage("the bag header's index_pos %d points at a %s (op %d), not at the index"
                                 % (index_pos, OP_NAMES.get(rec.op, "record of unknown kind"), rec.op))
                raise Damage("%s, but its index holds a %s (op %d) at byte %d where %s was expected"
                             % (want, OP_NAMES.get(rec.op, "record of unknown kind"), rec.op, pos, what))
            data = file.read(rec.datapos, rec.datasize)
            if wanted == OP_CONNECTION:
                conn = connection(rec, data, "%s at byte %d" % (what, pos))
                if conn.id in ids:
                    raise Damage("%s at byte %d: connection %d a second time" % (what, pos, conn.id))
                ids.add(conn.id)
                self.connections.append(conn)
            else:
                infos.append((rec, data))
            pos = rec.end
        if len(self.connections) + len(infos) < conn_count + chunk_count:
            raise Damage("%s, but its index (bytes %d to %d) holds %d connection records and %d chunk infos"
                         % (want, index_pos, file.size, len(self.connections), len(infos)))
        if pos < file.size:
            try:
                more = file.record(pos, file.size, "")
            except Damage:
                more = None
            if more is not None and more.op in (OP_CONNECTION, OP_CHUNK_INFO):
                raise Damage("%s, but its index holds more: a %s at byte %d" % (want, OP_NAMES[more.op], pos))
        self.trailing = file.size - pos
        self.chunks = self._chunks(infos, ids)

    def _chunks(self, infos: list, ids: set) -> list[Chunk]:
        """Each chunk info's chunk. A chunk info that makes no sense loses its chunk only (its messages unknown):
        the others still say where theirs are."""
        parsed = []
        for n, (rec, data) in enumerate(infos, 1):
            what = "chunk info %d of %d (byte %d)" % (n, len(infos), rec.pos)
            try:
                parsed.append((n, *self._chunk_info(rec, data, ids, what), None))
            except Damage as exc:
                parsed.append((n, 0, NEVER, -1, {}, str(exc)))
        # a chunk is read up to the next chunk's start (or the index's): none may run into another
        starts = sorted({p[1] for p in parsed if not p[5]} | {self.index_pos})
        chunks = []
        for n, pos, start, end, counts, damage in parsed:
            if damage:
                chunks.append(Chunk(n, pos, start, end, counts, "", 0, 0, 0, [], damage))
                continue
            limit = starts[bisect.bisect_right(starts, pos)]
            chunks.append(self._chunk(n, len(parsed), pos, limit, start, end, counts))
        return chunks

    def _chunk_info(self, rec: Record, data: bytes, ids: set, what: str) -> tuple:
        """(chunk position, start, end, {connection id: messages}) of a chunk info record."""
        if uint(rec.header, "ver", 4, what) != 1:
            raise Damage("%s: version %d (only 1 is known)" % (what, uint(rec.header, "ver", 4, what)))
        pos = uint(rec.header, "chunk_pos", 8, what)
        start, end = stamp(rec.header, "start_time", what), stamp(rec.header, "end_time", what)
        count = uint(rec.header, "count", 4, what)
        if count == 0:
            raise Damage("%s: a chunk of no connections" % what)
        if len(data) != count * _COUNT.size:
            raise Damage("%s: %d bytes of counts for %d connections (%d expected)"
                         % (what, len(data), count, count * _COUNT.size))
        counts = {}
        for cid, messages in _COUNT.iter_unpack(data):
            if cid not in ids:
                raise Damage("%s: connection %d, which the index does not have" % (what, cid))
            counts[cid] = messages
        if start > end:
            raise Damage("%s: it starts (%d ns) after it ends (%d ns)" % (what, start, end))
        if not self.header_end <= pos < self.index_pos:
            raise Damage("%s: its chunk at byte %d is outside the chunks (bytes %d to %d)"
                         % (what, pos, self.header_end, self.index_pos))
        return pos, start, end, counts

    def _chunk(self, n: int, total: int, pos: int, limit: int, start: int, end: int, counts: dict) -> Chunk:
        """A chunk's record and its index records, checked against its chunk info; a damaged chunk says why."""
        name = "chunk %d of %d at byte %d" % (n, total, pos)
        limit_what = "the next chunk" if limit < self.index_pos else "the index"
        compression, size, datapos, datasize, entries = "", 0, 0, 0, []
        try:
            rec = self.file.record(pos, limit, "its record", limit_what)
            _expect(rec, OP_CHUNK, "its record")
            kind = text(rec.header, "compression", "its record")
            size = uint(rec.header, "size", 4, "its record")
            # (known together or not at all: info counts the sizes of a chunk whose record was read)
            compression, datapos, datasize = kind, rec.datapos, rec.datasize
            if compression not in COMPRESSIONS:
                raise Damage("unknown compression %r" % compression)
            if compression == "none" and datasize != size:
                raise Damage("uncompressed, but %d bytes where its header says %d" % (datasize, size))
            at = rec.end
            seen = set()
            for i in range(len(counts)):
                what = "index record %d of %d" % (i + 1, len(counts))
                (hlen,) = _U32.unpack(self.file.read(at, 4)) if at + 4 <= limit else (INDEX_HEADER,)
                if hlen != INDEX_HEADER:
                    raise Damage("%s at byte %d: an index record of %d bytes where %d were expected"
                                 % (what, at, hlen, INDEX_HEADER))
                irec = self.file.record(at, limit, what, limit_what)
                _expect(irec, OP_INDEX_DATA, what)
                what = "%s at byte %d" % (what, at)
                if uint(irec.header, "ver", 4, what) != 1:
                    raise Damage("%s: version %d (only 1 is known)" % (what, uint(irec.header, "ver", 4, what)))
                cid = uint(irec.header, "conn", 4, what)
                count = uint(irec.header, "count", 4, what)
                if cid not in counts or cid in seen:
                    raise Damage("%s: connection %d, which the chunk info does not list (or lists once)"
                                 % (what, cid))
                seen.add(cid)
                if count != counts[cid]:
                    raise Damage("%s: %d messages of connection %d where the chunk info says %d"
                                 % (what, count, cid, counts[cid]))
                if irec.datasize != count * _ENTRY.size:
                    raise Damage("%s: %d bytes for %d entries (%d expected)"
                                 % (what, irec.datasize, count, count * _ENTRY.size))
                for secs, nsecs, offset in _ENTRY.iter_unpack(self.file.read(irec.datapos, irec.datasize)):
                    t = secs * NSEC + nsecs
                    if nsecs >= NSEC or not start <= t <= end or offset >= size:
                        raise Damage("%s: an entry at %d.%09d s, offset %d, outside the chunk (%d bytes, %d.%09d "
                                     "to %d.%09d s)" % (what, secs, nsecs, offset, size, *divmod(start, NSEC),
                                                        *divmod(end, NSEC)))
                    entries.append((t, cid, offset))
                at = irec.end
            damage = None
        except Damage as exc:
            damage = "%s: %s" % (name, exc)
            entries = []
        return Chunk(n, pos, start, end, counts, compression, size, datapos, datasize, entries, damage)

    # -- messages

    def index(self, connections: Optional[set] = None, start: int = 0, stop: Optional[int] = None) -> list:
        """(time, chunk number, offset, connection id) of each message to read, in time (then file) order."""
        out = []
        for chunk in self.chunks:
            if chunk.damage:
                continue
            out.extend((t, chunk.number, offset, cid) for t, cid, offset in chunk.entries
                       if (connections is None or cid in connections) and t >= start
                       and (stop is None or t < stop))
        out.sort()
        return out

    def messages(self, connections: Optional[set] = None, start: int = 0, stop: Optional[int] = None,
                 warn: Callable[[str], None] = lambda line: None) -> Iterator[tuple[int, Connection, bytes]]:
        """(time ns, connection, data) of each message in time order; a chunk found damaged when it is read is
        left out (`warn` says so) and the rest read on."""
        by_id = {c.id: c for c in self.connections}
        bad = self._bad
        for t, number, offset, cid in self.index(connections, start, stop):
            if number in bad:
                continue
            chunk = self.chunks[number - 1]
            if self._current[0] != number:
                self._current = (None, None)
                try:
                    self._current = (number, self._load(chunk))
                except Damage as exc:
                    bad.add(number)
                    warn("%s: chunk %d of %d at byte %d: %s: %s left out"
                         % (self.path, number, len(self.chunks), chunk.pos, exc, _its_messages(chunk)))
                    continue
            view, where = self._current[1]
            dpos, dlen = where[offset]
            yield t, by_id[cid], view[dpos:dpos + dlen]

    def _load(self, chunk: Chunk) -> tuple:
        """A chunk's records, decompressed and checked: every message its index records point at is there, whole,
        with the connection and time they say. (its data, {offset: (the message's data position, size)})"""
        data = (self.file.read(chunk.datapos, chunk.datasize) if chunk.compression == "none" else
                decompress(chunk.compression, self.file, chunk.datapos, chunk.datasize, chunk.size))
        where = {}
        size = len(data)
        for t, cid, offset in chunk.entries:
            # the usual message record (op, conn and time, once each, in any order) checked at once; any other
            # shape, or a connection or time other than the index's, is looked at field by field below
            hlen = _U32.unpack_from(data, offset)[0] if offset + 4 <= size else size
            end = offset + 8 + hlen
            usual = _MESSAGE_HEADER.fullmatch(data, offset + 4, end - 4) if end <= size else None
            if usual and usual.group(1) and usual.group(2) and usual.group(3):
                dlen = _U32.unpack_from(data, end - 4)[0]
                if (end + dlen <= size and int.from_bytes(usual.group(2), "little") == cid
                        and _time(usual.group(3)) == t):
                    where[offset] = (end, dlen)
                    continue
            what = "the message at offset %d" % offset
            pos = offset
            while True:  # (a writer may point at the connection record before a message: skipped, as rosbags does)
                rec = _record_in(data, pos, what)
                if rec.op != OP_CONNECTION:
                    break
                pos = rec.end
            _expect(rec, OP_MSG_DATA, what)
            conn, time = uint(rec.header, "conn", 4, what), stamp(rec.header, "time", what)
            if conn != cid or time != t:
                raise Damage("%s: connection %d at %d ns, where the index says connection %d at %d ns"
                             % (what, conn, time, cid, t))
            where[offset] = (rec.datapos, rec.datasize)
        return data, where


def _its_messages(chunk: Chunk) -> str:
    count = sum(chunk.counts.values())
    if not chunk.counts:  # (its chunk info was what was damaged)
        return "its messages are"
    return "its message is" if count == 1 else "its %d messages are" % count


def _record_in(view: bytes, pos: int, what: str) -> Record:
    """A record inside a decompressed chunk."""
    size = len(view)
    if pos + 4 > size:
        raise Damage("%s runs past the chunk's end (%d bytes)" % (what, size))
    (hlen,) = _U32.unpack_from(view, pos)
    if hlen > MAX_HEADER or pos + 8 + hlen > size:
        raise Damage("%s: a header of %d bytes runs past the chunk's end (%d bytes)" % (what, hlen, size))
    header = fields(view[pos + 4:pos + 4 + hlen], what)
    (dlen,) = _U32.unpack_from(view, pos + 4 + hlen)
    if pos + 8 + hlen + dlen > size:
        raise Damage("%s: %d bytes of data run past the chunk's end (%d bytes)" % (what, dlen, size))
    return Record(pos, header, op_of(header, what), pos + 8 + hlen, dlen)


def decompress(kind: str, file: File, pos: int, n: int, size: int) -> bytes:
    """A chunk's compressed data (`n` bytes at `pos`), which must come to exactly `size` bytes: read and
    decompressed STEP bytes at a time, so that a length lied about costs no more memory than the data really
    holds (a compressed stream ends where it ends)."""
    if kind == "bz2":
        decompressor = bz2.BZ2Decompressor()
    else:
        import lz4.frame  # (rosbags' dependency; only lz4 chunks need it)
        decompressor = lz4.frame.LZ4FrameDecompressor()
    out = bytearray()
    done = 0
    try:
        while not decompressor.eof:
            if decompressor.needs_input:
                if done == n:
                    raise Damage("its %s data ends early (%d of %d bytes decompressed)" % (kind, len(out), size))
                piece = file.read(pos + done, min(STEP, n - done))
                done += len(piece)
            else:
                piece = b""
            # (one byte past the stated size is asked for: more data than stated is damage)
            out += decompressor.decompress(piece, max_length=min(STEP, size + 1 - len(out)))
            if len(out) > size:
                raise Damage("it decompresses to more than the %d bytes its header says" % size)
    except (OSError, ValueError, EOFError, RuntimeError) as exc:
        # the decompressors' own word for data they cannot decode: nothing before decompressing can check it
        raise Damage("its %s data is damaged (%s)" % (kind, exc)) from None
    if decompressor.unused_data or done < n:
        raise Damage("%d bytes after its %s data" % (len(decompressor.unused_data or b"") + n - done, kind))
    if len(out) != size:
        raise Damage("it decompresses to %d bytes where its header says %d" % (len(out), size))
    return bytes(out)


class NotABag(Damage):
    """A file that is no bag at all (reindex cannot help)."""
