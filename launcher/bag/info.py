"""`bag info`: rosbag info's summary of a bag (path, span, size, counts, compression, types, topics)."""

from __future__ import annotations

import os
import sys
import time
from typing import Any

from rosbags.rosbag1 import Reader, ReaderError
from rosbags.rosbag1.reader import decompressors

from launcher.bag import reindex
from launcher.bag.msgtypes import ros1_type


class BagError(Exception):
    """A bag that cannot be read: its file name and why."""


def open_bag(path: str) -> Reader:
    """An open Reader, or BagError naming the file (an .active or truncated bag: what reindex does for it)."""
    try:
        reader = Reader(path)
        reader.open()
    except FileNotFoundError:
        raise BagError("%s: no such file" % path) from None
    except (ReaderError, OSError, ValueError, KeyError) as exc:
        why = str(exc) or type(exc).__name__
        raise BagError("%s: not a readable bag: %s%s" % (path, why, _recoverable(path))) from None
    return reader


def _recoverable(path: str) -> str:
    """What reindex could still read of a damaged bag, in words ("" for a file that is no bag)."""
    try:
        conns, msgs, stop = reindex.scan(path)
    except (reindex.ReindexError, OSError):
        return ""
    known = sum(1 for m in msgs if m[2] in conns)
    return (" (%d messages on %d connections can still be read, up to %s: 'launcher bag reindex %s' "
            "writes them into an indexed bag)" % (known, len(conns), stop, path))


def human_size(size: float) -> str:
    for suffix in ("B", "KB", "MB", "GB", "TB"):
        if size < 1024.0 or suffix == "TB":
            return "%.1f %s" % (size, suffix) if suffix != "B" else "%d B" % size
        size /= 1024.0
    return "%.1f TB" % size


def _stamp(ns: int) -> str:
    secs = ns / 1e9
    return "%s.%s (%.2f)" % (time.strftime("%b %d %Y %H:%M:%S", time.localtime(secs)), ("%.2f" % secs)[-2:], secs)


def _duration(ns: int) -> str:
    duration = ns / 1e9
    secs = duration % 60
    mins = int(duration / 60)
    hrs = int(mins / 60)
    if hrs > 0:
        return "%dhr %d:%02ds (%ds)" % (hrs, mins % 60, secs, duration)
    if mins > 0:
        return "%d:%02ds (%ds)" % (mins, secs, duration)
    return "%.1fs" % duration


def summary(path: str, reader: Any) -> str:
    """rosbag info's text for one open bag."""
    lines = ["path:        %s" % path, "version:     2.0"]
    topics = reader.topics
    count = sum(t.msgcount for t in topics.values())
    if count:
        lines += ["duration:    %s" % _duration(reader.end_time - reader.start_time),
                  "start:       %s" % _stamp(reader.start_time),
                  "end:         %s" % _stamp(reader.end_time)]
    lines.append("size:        %s" % human_size(os.path.getsize(path)))
    lines.append("messages:    %d" % count)
    names = {fn: name for name, fn in decompressors.items()}
    kinds = [names.get(c.decompressor, "?") for c in reader.chunks.values()]
    compressed = [k for k in kinds if k != "none"]
    kind = compressed[0] if compressed else "none"
    lines.append("compression: %s [%d/%d chunks]" % (kind, len(compressed) if compressed else len(kinds), len(kinds)))
    types = sorted({(ros1_type(c.msgtype), c.digest) for c in reader.connections})
    width = max((len(t) for t, _ in types), default=0)
    for i, (mtype, md5) in enumerate(types):
        lines.append("%s%-*s [%s]" % ("types:       " if i == 0 else " " * 13, width, mtype, md5))
    twidth = max((len(t) for t in topics), default=0)
    cwidth = max((len(str(t.msgcount)) for t in topics.values()), default=0)
    dwidth = max((len(ros1_type(t.msgtype or "")) for t in topics.values()), default=0)
    for i, (topic, t) in enumerate(sorted(topics.items())):
        line = "%s%-*s   %*d %s    : %-*s" % ("topics:      " if i == 0 else " " * 13, twidth, topic, cwidth, t.msgcount,
                                            "msgs" if t.msgcount > 1 else "msg ", dwidth, ros1_type(t.msgtype or "*"))
        if len(t.connections) > 1:
            line += " (%d connections)" % len(t.connections)
        lines.append(line)
    return "\n".join(lines)


def main(paths: list[str]) -> int:
    status = 0
    for i, path in enumerate(paths):
        try:
            reader = open_bag(path)
        except BagError as exc:
            print("ERROR %s" % exc, file=sys.stderr)
            status = 1
            continue
        try:
            if i:
                print("---")
            print(summary(path, reader))
        finally:
            reader.close()
    return status
