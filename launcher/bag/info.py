"""`bag info`: rosbag info's summary of a bag, as text, as YAML (`-y`), one key of that YAML (`-k`), with each
topic's median frequency (`--freq`)."""

from __future__ import annotations

import os
import re
import sys
import time
from typing import Any, NamedTuple

import yaml

from launcher.bag import reindex
from launcher.bag.reader import Bag, BagError

# The largest damaged bag whose recoverable messages an error counts (a walk of the whole file).
COUNT_LIMIT = 256 << 20


def open_bag(path: str) -> Bag:
    """An open bag, checked, or BagError naming the file and what is wrong where (and, for a bag whose index is lost
    or damaged, what reindex can still read of it)."""
    try:
        return Bag(path)
    except BagError as exc:
        raise BagError(str(exc) + (_recoverable(path) if exc.reindexable else "")) from None


def warn(line: str) -> None:
    """A damaged part of a bag that is left out, said on stderr at once."""
    print("[ WARN] %s" % line, file=sys.stderr, flush=True)


def _recoverable(path: str) -> str:
    """What reindex could still read of a damaged bag, in words ("" for a file that is no bag, or nothing). A bag
    larger than COUNT_LIMIT is not walked for the count (minutes, for an error message)."""
    try:
        if os.path.getsize(path) > COUNT_LIMIT:
            return " ('launcher bag reindex %s' can still read what its whole chunks hold into an indexed bag)" % path
        conns, known, _ = reindex.count(path)
    except (reindex.ReindexError, OSError):
        return ""
    if not known:
        return ""
    return (" ('launcher bag reindex %s' can still read %d messages on %d connection%s of it into an indexed bag)"
            % (path, known, conns, "" if conns == 1 else "s"))


class Compression(NamedTuple):
    kind: str                     # none, lz4, bz2
    chunks: int
    compressed: int               # bytes on the disk
    uncompressed: int             # bytes of records


class TopicInfo(NamedTuple):
    topic: str
    datatype: str                 # that of the topic's first connection, as rosbag says it
    messages: int
    connections: int
    frequency: float | None       # Hz: 1 / the median period (--freq only)


class BagInfo(NamedTuple):
    """What rosbag info says of a bag: the same numbers, computed the same way (seconds as floats from
    secs + nsecs / 1e9, so that the %.6f of the YAML agrees to the last digit)."""
    path: str
    size: int
    indexed: bool                 # False: no chunks (rosbag prints only path, version and size then)
    start: float
    end: float
    messages: int
    chunks: int
    compressions: list[Compression]   # most chunks first
    types: list[tuple[str, str]]      # (type, md5sum), sorted
    topics: list[TopicInfo]           # sorted by topic


def _sec(ns: int) -> float:
    return float(ns // 1_000_000_000) + float(ns % 1_000_000_000) / 1e9


def _median(values: list[float]) -> float:
    ordered = sorted(values)
    half = len(ordered) // 2
    return ordered[half] if len(ordered) % 2 else float(ordered[half - 1] + ordered[half]) / 2


def bag_info(path: str, bag: Bag, freq: bool = False) -> BagInfo:
    """The facts of one open bag; `freq`: each topic's median frequency from its index (rosbag info --freq).
    A damaged chunk's messages are counted as its chunk info says (as rosbag's); its sizes and compression as its
    record says, if that could be read."""
    size = bag.size
    chunks = bag.chunks
    if not chunks:
        return BagInfo(path, size, False, 0.0, 0.0, 0, 0, [], [], [])
    # as rosbag: the first chunk's start and the last chunk's end (of those whose chunk info could be read)
    timed = [c for c in chunks if c.start <= c.end]
    start, end = (_sec(timed[0].start), _sec(timed[-1].end)) if timed else (0.0, 0.0)
    messages = sum(sum(c.counts.values()) for c in chunks)
    by_kind: dict[str, list[int]] = {}
    for chunk in chunks:
        if not chunk.compression or not chunk.size:
            continue  # a damaged chunk whose record could not be read: nothing to say of its sizes
        total = by_kind.setdefault(chunk.compression, [0, 0, 0])
        total[0] += 1
        total[1] += chunk.datasize
        total[2] += chunk.size
    # rosbag orders them by (count, name), most first
    compressions = [Compression(k, *v) for k, v in sorted(by_kind.items(), key=lambda kv: (kv[1][0], kv[0]),
                                                          reverse=True)]
    datatypes: dict[str, str] = {}
    for conn in bag.connections:
        datatypes.setdefault(conn.type, conn.md5sum)
    stamps_of: dict[int, list[int]] = {}
    if freq:
        for chunk in chunks:
            for t, cid, _ in chunk.entries:
                stamps_of.setdefault(cid, []).append(t)
    topics = []
    for topic in sorted({c.topic for c in bag.connections}):
        conns = [c for c in bag.connections if c.topic == topic]
        count = sum(chunk.counts.get(c.id, 0) for c in conns for chunk in chunks)
        frequency = None
        if freq:
            stamps = [_sec(t) for t in sorted(t for c in conns for t in stamps_of.get(c.id, []))]
            if len(stamps) > 1:
                period = _median([b - a for a, b in zip(stamps, stamps[1:])])
                frequency = 1.0 / period if period > 0.0 else None
        topics.append(TopicInfo(topic, conns[0].type, count, len(conns), frequency))
    return BagInfo(path, size, True, start, end, messages, len(chunks), compressions, sorted(datatypes.items()),
                   topics)


def human_size(size: float) -> str:
    """rosbag's sizes: KB at least."""
    for suffix in ("KB", "MB", "GB", "TB", "PB", "EB", "ZB", "YB"):
        size /= 1024.0
        if size < 1024.0:
            return "%.1f %s" % (size, suffix)
    return "-"


def human_frequency(freq: float) -> str:
    for suffix in ("Hz", "kHz", "MHz", "GHz", "THz", "PHz", "EHz", "ZHz", "YHz"):
        if freq < 1000.0:
            return "%.1f %s" % (freq, suffix)
        freq /= 1000.0
    return "-"


def _stamp(secs: float) -> str:
    return "%s%s (%.2f)" % (time.strftime("%b %d %Y %H:%M:%S", time.localtime(secs)),
                           ("%.2f" % (secs - int(secs)))[1:], secs)


def _duration(duration: float) -> str:
    secs = duration % 60
    mins = int(duration / 60)
    hrs = int(mins / 60)
    if hrs > 0:
        return "%dhr %d:%02ds (%ds)" % (hrs, mins % 60, secs, duration)
    if mins > 0:
        return "%d:%02ds (%ds)" % (mins, secs, duration)
    return "%.1fs" % duration


def text(info: BagInfo) -> str:
    """rosbag info's text."""
    rows = [("path", info.path), ("version", "2.0")]
    if not info.indexed:
        rows.append(("size", human_size(info.size)))
        return _columns(rows)
    duration = info.end - info.start
    rows += [("duration", _duration(duration)), ("start", _stamp(info.start)), ("end", _stamp(info.end)),
             ("size", human_size(info.size)), ("messages", str(info.messages))]
    rows.append(("compression", ", ".join(
        "%s [%d/%d chunks]" % (c.kind, c.chunks, info.chunks) if c.kind == "none" else
        "%s [%d/%d chunks; %.2f%%]" % (c.kind, c.chunks, info.chunks, 100.0 * c.compressed / c.uncompressed)
        for c in info.compressions)))
    if any(c.kind != "none" for c in info.compressions):
        whole = _human_pair(sum(c.uncompressed for c in info.compressions),
                            sum(c.compressed for c in info.compressions), duration)
        rows += [("uncompressed", whole[0]), ("compressed", whole[1])]
    type_width = max(len(t) for t, _ in info.types)
    rows += [("types" if i == 0 else "", "%-*s [%s]" % (type_width, t, md5)) for i, (t, md5) in enumerate(info.types)]
    topic_width = max(len(t.topic) for t in info.topics)
    count_width = max(len("%d" % t.messages) for t in info.topics)
    freq_width = max((len(human_frequency(t.frequency)) for t in info.topics if t.frequency is not None), default=0)
    for i, t in enumerate(info.topics):
        line = "%-*s   %*d %s" % (topic_width, t.topic, count_width, t.messages, "msgs" if t.messages > 1 else "msg ")
        line += (" @ %*s" % (freq_width, human_frequency(t.frequency)) if t.frequency is not None
                 else "   %*s" % (freq_width, ""))
        line += " : %-*s" % (type_width, t.datatype)
        if t.connections > 1:
            line += " (%d connections)" % t.connections
        rows.append(("topics" if i == 0 else "", line))
    return _columns(rows)


def _human_pair(uncompressed: int, compressed: int, duration: float) -> tuple[str, str]:
    """rosbag's 'uncompressed' and 'compressed' rows: sizes (and rates) aligned with each other."""
    sizes = human_size(uncompressed), human_size(compressed)
    width = max(len(s) for s in sizes)
    if duration <= 0:
        return "%*s" % (width, sizes[0]), "%*s" % (width, sizes[1])
    rates = human_size(uncompressed / duration), human_size(compressed / duration)
    rate_width = max(len(r) for r in rates)
    return ("%*s @ %*s/s" % (width, sizes[0], rate_width, rates[0]),
            "%*s @ %*s/s (%.2f%%)" % (width, sizes[1], rate_width, rates[1], 100.0 * compressed / uncompressed))


def _columns(rows: list[tuple[str, str]]) -> str:
    width = max(len(field) for field, _ in rows) + 1
    # (rosbag strips the end of the whole text only: the other lines keep their padding)
    return "\n".join("%-*s %s" % (width, field + ":" if field else "", value) for field, value in rows).rstrip()


def yaml_text(info: BagInfo) -> str:
    """rosbag info -y: the same facts as YAML, in rosbag's words and order."""
    lines = ["path: %s" % info.path, "version: 2.0"]
    if not info.indexed:
        return "\n".join(lines + ["size: %d" % info.size, "indexed: False"]) + "\n"
    lines += ["duration: %.6f" % (info.end - info.start), "start: %.6f" % info.start, "end: %.6f" % info.end,
              "size: %d" % info.size, "messages: %d" % info.messages, "indexed: True",
              "compression: %s" % (info.compressions[0].kind if info.compressions else "unknown")]
    if any(c.kind != "none" for c in info.compressions):
        lines += ["uncompressed: %d" % sum(c.uncompressed for c in info.compressions),
                  "compressed: %d" % sum(c.compressed for c in info.compressions)]
    lines.append("types:")
    for datatype, md5 in info.types:
        lines += ["    - type: %s" % datatype, "      md5: %s" % md5]
    lines.append("topics:")
    for t in info.topics:
        lines += ["    - topic: %s" % t.topic, "      type: %s" % t.datatype, "      messages: %d" % t.messages]
        if t.connections > 1:
            lines.append("      connections: %d" % t.connections)
        if t.frequency is not None:
            lines.append("      frequency: %.4f" % t.frequency)
    return "\n".join(lines) + "\n"


class UnknownKey(Exception):
    """A -k key that names nothing in the YAML."""


_KEY = re.compile(r"[A-Za-z_]\w*(?:\.[A-Za-z_]\w*|\[-?\d+\])*")
_STEP = re.compile(r"([A-Za-z_]\w*)|\[(-?\d+)\]")


def key_text(yaml_doc: str, key: str) -> str:
    """rosbag info -y -k KEY: the value at KEY (`duration`, `topics`, `topics[0].type`: names and indexes, where
    rosbag evaluates any Python expression), printed as rosbag prints it: a scalar as Python writes the value YAML
    read, a list an item per `- `, a map a field per line."""
    if not _KEY.fullmatch(key):
        raise UnknownKey(key)
    value: Any = yaml.safe_load(yaml_doc)
    for step in _STEP.finditer(key):
        try:
            value = value[step.group(1)] if step.group(1) else value[int(step.group(2))]
        except (KeyError, IndexError, TypeError):
            raise UnknownKey(key) from None
    return _key_value(value)


def _key_value(value: Any, indent: int = 0) -> str:
    pad = "  " * indent
    if isinstance(value, list):
        return "".join("%s- %s\n" % (pad, _key_value(item, indent + 1)) for item in value)
    if isinstance(value, dict):
        return ("\n" + pad).join("%s: %s" % (k, v) for k, v in value.items())
    return pad + str(value)


def main(paths: list[str], as_yaml: bool = False, key: str | None = None, freq: bool = False) -> int:
    status = 0
    for i, path in enumerate(paths):
        try:
            bag = open_bag(path)
        except BagError as exc:
            print("ERROR %s" % exc, file=sys.stderr)
            return 1  # as rosbag info: the bags after a bad one are not read
        with bag:
            for line in bag.warnings():
                warn(line)
            info = bag_info(path, bag, freq)
        if not as_yaml:
            print(text(info))
        elif not key:  # (as rosbag: -k '' is the whole YAML)
            print(yaml_text(info))
        else:
            try:
                print(key_text(yaml_text(info), key))
            except UnknownKey:
                print('Error getting key "%s"' % key, file=sys.stderr)
                status = 1
        if i < len(paths) - 1:
            print("---")
    return status
