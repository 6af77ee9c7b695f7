"""Broken bags for the bag fuzz: a bag's structure mapped (independently of launcher.bag.reader), and mutants of it
of each kind the hostile-input round used (issue 37), made from a seeded random generator."""

from __future__ import annotations

import random
import struct
from typing import NamedTuple

MAGIC = b"#ROSBAG V2.0\n"
U32 = struct.Struct("<I")
OPS = {2: "message", 3: "bag header", 4: "index", 5: "chunk", 6: "chunk info", 7: "connection"}
KINDS = ["truncated", "flipped", "field4", "bag_header", "compression", "header_length"]


class Rec(NamedTuple):
    pos: int
    op: int
    hlen: int
    fields: dict            # name -> (value position, value bytes)
    field_sizes: list       # positions of each field's length prefix
    datapos: int
    dlen: int

    @property
    def end(self) -> int:
        return self.datapos + self.dlen


def records(data: bytes, pos: int, end: int) -> list[Rec]:
    """The whole records from `pos` to `end` (a valid bag: no checks)."""
    out = []
    while pos + 4 <= end:
        (hlen,) = U32.unpack_from(data, pos)
        at, fields, sizes = pos + 4, {}, []
        while at < pos + 4 + hlen:
            (size,) = U32.unpack_from(data, at)
            sizes.append(at)
            name, _, value = data[at + 4:at + 4 + size].partition(b"=")
            fields[name.decode()] = (at + 4 + len(name) + 1, value)
            at += 4 + size
        (dlen,) = U32.unpack_from(data, pos + 4 + hlen)
        rec = Rec(pos, fields["op"][1][0], hlen, fields, sizes, pos + 8 + hlen, dlen)
        out.append(rec)
        pos = rec.end
    return out


def field4_positions(data: bytes) -> list[int]:
    """Every 4-byte field of a bag's structure: record and field lengths, 4-byte values (and 8-byte ones' halves),
    index entries and chunk info counts; inside uncompressed chunks too."""
    out = []
    for rec in records(data, len(MAGIC), len(data)):
        out += [rec.pos, rec.datapos - 4] + rec.field_sizes
        for pos, value in rec.fields.values():
            out += [pos + i for i in range(0, len(value) - 3, 4)] if len(value) in (4, 8) else []
        if rec.op == 4:
            out += list(range(rec.datapos, rec.end, 4))
        elif rec.op == 6:
            out += list(range(rec.datapos, rec.end, 4))
        elif rec.op == 5 and rec.fields["compression"][1] == b"none":
            for inner in records(data, rec.datapos, rec.end):
                out += [inner.pos, inner.datapos - 4] + inner.field_sizes
                out += [p for p, v in inner.fields.values() if len(v) in (4, 8)]
    return out


def header_end(data: bytes) -> int:
    return records(data, len(MAGIC), len(MAGIC) + 4096 + 4)[0].end


def put32(data: bytearray, pos: int, value: int) -> None:
    data[pos:pos + 4] = U32.pack(value)


def mutant(data: bytes, kind: str, rnd: random.Random) -> tuple[bytes, str]:
    """One broken copy of a valid bag, and what was done to it."""
    out = bytearray(data)
    recs = records(data, len(MAGIC), len(data))
    if kind == "truncated":
        cut = rnd.randrange(header_end(data), len(data))  # (after its header: reindex must recover it)
        return bytes(out[:cut]), "cut at byte %d" % cut
    if kind == "flipped":
        done = []
        for _ in range(rnd.choice([1, 1, 2, 4])):
            pos = rnd.randrange(len(MAGIC), len(data))
            out[pos] ^= 1 << rnd.randrange(8)
            done.append(pos)
        return bytes(out), "bits flipped at bytes %s" % done
    if kind == "field4":
        pos = rnd.choice(field4_positions(data))
        value = rnd.choice([0, 0x7FFFFFFF, 0xFFFFFFFF])
        put32(out, pos, value)
        return bytes(out), "the 4-byte field at byte %d set to %#x" % (pos, value)
    if kind == "bag_header":
        head = recs[0]
        name = rnd.choice(["index_pos", "conn_count", "chunk_count"])
        pos, value = head.fields[name]
        old = int.from_bytes(value, "little")
        new = rnd.choice([0, old + 1, max(old - 1, 0), 0xFFFFFFFF, 0x7FFFFFFF, len(data) + 1000, 100])
        out[pos:pos + len(value)] = new.to_bytes(len(value), "little")
        return bytes(out), "bag header's %s %d -> %d" % (name, old, new)
    if kind == "compression":
        chunk = rnd.choice([r for r in recs if r.op == 5])
        pos, value = chunk.fields["compression"]
        new = rnd.choice(["xz", "bz2", "lz4", "none", "zst"]).encode()
        if len(new) == len(value):
            out[pos:pos + len(value)] = new
        else:  # a name of another length: its record's header and field lengths made to fit
            field_at = [p for p in chunk.field_sizes if p + 4 + len(b"compression=") == pos][0]
            out[pos:pos + len(value)] = new
            put32(out, field_at, len(b"compression=") + len(new))
            put32(out, chunk.pos, chunk.hlen + len(new) - len(value))
        return bytes(out), "chunk at byte %d: compression %s -> %s" % (chunk.pos, value.decode(), new.decode())
    if kind == "header_length":
        rec = rnd.choice(recs)
        value = rnd.choice([0x7FFFFFFF, 0xFFFFFFFF, 1 << 24, rec.hlen + 1000])
        put32(out, rec.pos, value)
        return bytes(out), "the %s at byte %d: header length %d -> %d" % (OPS[rec.op], rec.pos, rec.hlen, value)
    raise ValueError(kind)
