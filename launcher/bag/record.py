"""`bag record`: subscribe to topics of any type and write what arrives into ROS 1 bags (rosbag record's rules).

The type, md5sum and full definition of each topic come from its publishers'
TCPROS connection headers (we subscribe with md5sum `*`, as rosbag's
ShapeShifter does), so no message package is needed. A bag is written under
rosbag's `NAME.bag.active` and renamed to `NAME.bag` once closed and indexed.

As in rosbag, messages are taken from the sockets on one side (the asyncio
loop) and written on the other (a writer thread, which owns the open bag while
it runs), through a buffer of `-b` MB whose oldest messages are dropped when it
is full: a slow disk costs the oldest messages (of the topic holding the most of
the buffer: bag/buffer.py), not the reading of the sockets nor a connection.
"""

from __future__ import annotations

import asyncio
import datetime
import errno
import logging
import os
import re
import signal
import threading
import time
from collections import defaultdict
from collections.abc import Callable
from io import BytesIO
from typing import Any, NamedTuple

from rosbags.rosbag1 import Writer
from rosbags.rosbag1.reader import RecordType
from rosbags.rosbag1.writer import Header, WriteChunk, serialize_time, serialize_uint32

from launcher import compat
from launcher.compat import to_thread
from launcher.model import names
from launcher.bag import rosargs
from launcher.bag.buffer import Buffer, Queued
from launcher.bag.msgtypes import rosbags_type
from launcher.net.slave import SlaveNode, default_host
from launcher.net.publisher_link import PublisherLink
from launcher.net.tcpros import ANY_MD5, TopicType
from launcher.net.xmlrpc import call

log = logging.getLogger("launcher.bag")

ANY_TYPE = TopicType("*", ANY_MD5, "")
# rosbag record looks for new topics (-a, -e, --node) once a second.
MASTER_POLL_S = 1.0
# Writes of this size or more go to the disk at once rather than through DiskFile's buffer.
DIRECT_WRITE = 256 * 1024
# rosbag's default chunk size (--chunksize 768 KB).
CHUNK_SIZE = 768 * 1024


class RecordOptions(NamedTuple):
    topics: list[str]
    all: bool = False
    regex: list[str] = []
    exclude: str | None = None
    output_name: str | None = None      # -O
    output_prefix: str | None = None    # -o
    split: bool = False
    size: int = 0                       # bytes (--size, in MB on the command line)
    duration: float = 0.0               # seconds
    max_splits: int = 0
    compression: str = "none"           # none, lz4, bz2
    limit: int = 0
    node: str | None = None
    buffer_size: int = 256 << 20
    chunk_size: int = CHUNK_SIZE
    quiet: bool = False


def bag_names(opts: RecordOptions, split_index: int | None, now: float) -> tuple[str, str]:
    """(final name, name while writing) of one bag, as rosbag's Recorder::updateFilenames makes them."""
    prefix = opts.output_name if opts.output_name is not None else (opts.output_prefix or "")
    if prefix.endswith(".bag"):
        prefix = prefix[:-4]
    parts = [prefix] if prefix else []
    if opts.output_name is None:
        parts.append(datetime.datetime.fromtimestamp(now).strftime("%Y-%m-%d-%H-%M-%S"))
    if split_index is not None:
        parts.append(str(split_index))
    target = "_".join(parts) + ".bag"
    return target, target + ".active"


class DiskFile:
    """The bag's file under rosbags' writer: writes gathered in memory and put to the disk a chunk at a time,
    so that after a failed write (a full disk) `synced` is the end of the last chunk wholly on the disk."""

    def __init__(self, fd: int, pos: int):
        self.fd = fd
        self.buf = bytearray()
        self.pos = pos
        self.synced = pos

    def write(self, data: bytes | memoryview) -> int:
        if len(self.buf) + len(data) >= DIRECT_WRITE:
            # a chunk's body: straight to the disk, not copied into the buffer first (`synced` waits
            # for the chunk's end, so a failure still cuts back to the last whole chunk)
            self._put(self.buf)
            self.buf.clear()
            self._put(data)
        else:
            self.buf += data
        self.pos += len(data)
        return len(data)

    def _put(self, data: bytes | bytearray | memoryview) -> None:
        view = memoryview(data)
        try:
            pos = 0
            while pos < len(view):
                done = os.write(self.fd, view[pos:])
                if not done:
                    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
                pos += done
        finally:
            view.release()  # (the buffer is cleared next: no view of it may be left)

    def tell(self) -> int:
        return self.pos

    def flush(self) -> None:
        self._put(self.buf)
        self.buf.clear()
        self.synced = self.pos

    def seek(self, pos: int, whence: int = os.SEEK_SET) -> int:
        self.flush()
        self.pos = self.synced = os.lseek(self.fd, pos, whence)
        return self.pos

    def cut(self) -> None:
        """Drop what did not reach the disk, and any part of it that did: back to `synced`."""
        self.buf.clear()
        os.ftruncate(self.fd, self.synced)
        self.pos = os.lseek(self.fd, self.synced, os.SEEK_SET)

    def close(self) -> None:
        try:
            self.flush()
        finally:
            os.close(self.fd)


def _new_chunk() -> WriteChunk:
    """An empty chunk as rosbags' writer starts one: its start time above any stamp, lowered by the first
    message (rosbags' own constant for it is 2**64 in 0.9, MAXSIZE in 0.11; any value past every stamp will do)."""
    return WriteChunk(BytesIO(), -1, 2**63 - 1, 0, defaultdict(list))


class BagFile:
    """One bag being written: its connections (one per topic and publisher header) and its size."""

    def __init__(self, path: str, active: str, compression: str, chunk_size: int):
        self.path = path
        self.active = active
        self.writer = Writer(active)
        self.compressed = compression != "none"
        if compression != "none":
            self.writer.set_compression(Writer.CompressionFormat[compression.upper()])
        self.writer.chunk_threshold = chunk_size
        self.writer.open()
        bio = self.writer.bio
        bio.flush()
        self.disk = DiskFile(os.dup(bio.fileno()), bio.tell())
        bio.close()
        self.writer.bio = self.disk
        self.connections: dict[tuple, Any] = {}
        self.started = time.monotonic()
        self.messages = 0

    def connection(self, topic: str, header: dict[str, str]) -> Any:
        latching = header.get("latching")
        key = (topic, header.get("type", ""), header.get("md5sum", ""), header.get("message_definition", ""),
               header.get("callerid"), latching)
        conn = self.connections.get(key)
        if conn is None:
            conn = self.writer.add_connection(
                topic, rosbags_type(key[1]), msgdef=key[3], md5sum=key[2], callerid=key[4],
                latching=int(latching) if latching and latching.isdigit() else None)
            self.connections[key] = conn
        return conn

    def write(self, conn: Any, stamp_ns: int, payload: bytes | bytearray) -> None:
        writer = self.writer
        chunks = len(writer.chunks)
        if not self.compressed and len(payload) >= writer.chunk_threshold and not writer.chunks[-1].data.tell():
            self._write_chunk_of_one(conn, stamp_ns, payload)
        else:
            writer.write(conn, stamp_ns, payload)
        self.messages += 1
        if len(writer.chunks) != chunks:  # a chunk was completed: to the disk with it
            self.disk.flush()

    def _write_chunk_of_one(self, conn: Any, stamp_ns: int, payload: bytes | bytearray) -> None:
        """A message as large as a chunk, as a chunk of its own: the records rosbags' writer writes for it
        (chunk, message, index), but the message goes straight to the disk, not copied into the chunk's
        buffer and out again (for megabyte messages those copies and their fresh pages were most of the cost)."""
        writer, disk = self.writer, self.disk
        record = BytesIO()
        header = Header()
        header.set_uint32("conn", conn.id)
        header.set_time("time", stamp_ns)
        header.write(record, RecordType.MSGDATA)
        record.write(serialize_uint32(len(payload)))
        head = record.getvalue()
        chunk = writer.chunks[-1]
        chunk.pos = disk.tell()
        header = Header()
        header.set_string("compression", "none")
        header.set_uint32("size", len(head) + len(payload))
        header.write(disk, RecordType.CHUNK)
        disk.write(serialize_uint32(len(head) + len(payload)) + head)
        disk.write(payload)
        index = Header()
        index.set_uint32("ver", 1)
        index.set_uint32("conn", conn.id)
        index.set_uint32("count", 1)
        index.write(disk, RecordType.IDXDATA)
        disk.write(serialize_uint32(12) + serialize_time(stamp_ns) + serialize_uint32(0))
        chunk.start = chunk.end = stamp_ns
        chunk.connections[conn.id].append((stamp_ns, 0))
        chunk.data.close()
        writer.chunks.append(_new_chunk())

    @property
    def size(self) -> int:
        bio = self.writer.bio
        return (bio.tell() if bio else 0) + self.writer.chunks[-1].data.tell()

    def close(self) -> None:
        """Write the last chunk and the index, then give the bag its final name."""
        self.writer.close()
        os.rename(self.active, self.path)

    def salvage(self) -> bool:
        """After a failed write: cut the bag back to its last whole chunk and index that (the index is small, and
        the cut frees at least the chunk that did not fit). True if the bag was closed, readable."""
        writer = self.writer
        try:
            self.disk.cut()
            writer.chunks = [c for c in writer.chunks if c.pos != -1 and c.pos < self.disk.synced]
            writer.chunks.append(_new_chunk())
            writer.close()
            os.rename(self.active, self.path)
            return True
        except OSError:
            self.abort()
            return False

    def abort(self) -> None:
        """Keep what reached the disk under the .active name (reindex reads it)."""
        try:
            self.disk.close()
        except OSError:
            pass
        self.writer.bio = None


class Recorder:
    """rosbag record as an in-process node on one asyncio loop."""

    def __init__(self, opts: RecordOptions, node: SlaveNode, say: Callable[[str], None] = print):
        self.opts = opts
        self.node = node
        self.say = say
        self.exclude = re.compile(opts.exclude) if opts.exclude else None
        self.regex = [re.compile(r) for r in opts.regex]
        self.bag: BagFile | None = None
        self.split_index = 0 if opts.split else None
        self.written: list[str] = []       # closed bags of this recording, oldest first (--max-splits)
        self.counts: dict[str, int] = {}   # per topic, for -l
        self.full: set[str] = set()        # topics that reached -l
        self.failed: str | None = None
        self.done = compat.Event()
        self.loop = asyncio.get_running_loop()
        self.buffer = Buffer(opts.buffer_size)
        self.writer: threading.Thread | None = None

    # ------------------------------------------------------------------ bags
    def _open(self) -> None:
        path, active = bag_names(self.opts, self.split_index, time.time())
        os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
        self.bag = BagFile(path, active, self.opts.compression, self.opts.chunk_size)
        if not self.opts.quiet:
            self.say("[ INFO] [%.9f]: Recording to '%s'." % (time.time(), path))

    def _close(self) -> None:
        bag, self.bag = self.bag, None
        if bag is None:
            return
        try:
            bag.close()
        except OSError as exc:
            self._failed_write(bag, exc)
            return
        self.written.append(bag.path)
        if not self.opts.quiet:
            self.say("[ INFO] [%.9f]: Closing '%s'." % (time.time(), bag.path))

    def _split(self) -> None:
        self._close()
        if self.failed:
            return
        assert self.split_index is not None
        self.split_index += 1
        if self.opts.max_splits and len(self.written) >= self.opts.max_splits:
            oldest = self.written.pop(0)
            try:
                os.remove(oldest)
            except OSError as exc:
                log.warning("cannot remove %s (--max-splits): %s", oldest, exc)
        self._open()

    def _failed_write(self, bag: BagFile, exc: OSError) -> None:
        """A write failed (a full disk): the recording ends, the bag keeps what is whole on the disk."""
        if bag.salvage():
            self._fail("writing %s: %s; recording stopped, %s holds what was written before the last chunk"
                       % (bag.active, exc, bag.path))
        else:
            self._fail("writing %s: %s; recording stopped (launcher bag reindex %s recovers what it holds)"
                       % (bag.active, exc, bag.active))

    def _fail(self, why: str) -> None:
        if self.failed is None:
            self.failed = why
            self.say("[ERROR] [%.9f]: %s" % (time.time(), why))
        self.loop.call_soon_threadsafe(self.done.set)  # (called by the writer thread too)

    # ------------------------------------------------------------------ messages
    def on_message(self, payload: bytes | bytearray, link: PublisherLink) -> None:
        if self.failed:
            return
        topic = link.topic
        if self.opts.limit:
            count = self.counts.get(topic, 0)
            if count >= self.opts.limit:
                return
            self.counts[topic] = count + 1
        # stamped when received, as rosbag does
        dropped = self.buffer.put(Queued(topic, link.header or {}, time.time_ns(), payload), time.monotonic())
        if dropped:
            self.say("[ WARN] [%.9f]: rosbag record buffer exceeded.  Dropping oldest queued message. (%d dropped: "
                     "the disk is slower than the topics; -b sets the buffer, %d MB)"
                     % (time.time(), dropped, self.opts.buffer_size >> 20))
        if self.opts.limit and self.counts[topic] >= self.opts.limit:
            self._topic_full(topic)

    def _write_loop(self) -> None:
        """The writer thread: buffered messages into the bag until the buffer is closed and empty, or a failure."""
        try:
            while not self.failed and (batch := self.buffer.take()):
                for item in batch:
                    if self.failed:
                        return
                    self._write(item)
        except Exception as exc:  # never a silent end of the writing while the loop goes on receiving
            log.exception("writing the bag")
            self._fail("writing the bag: %s" % exc)

    def _write(self, item: Queued) -> None:
        bag = self.bag
        if bag is None:
            return
        # As rosbag: the message that finds the bag full or old enough opens the next one, or, without --split,
        # ends the recording (`--duration 30` alone records 30 s).
        if (self.opts.size and bag.size >= self.opts.size) or (
                self.opts.duration and time.monotonic() - bag.started >= self.opts.duration):
            if not self.opts.split:
                self.loop.call_soon_threadsafe(self.done.set)
                return
            try:
                self._split()
            except OSError as exc:
                self._fail("opening the next bag: %s" % exc)
                return
            bag = self.bag
            if bag is None:
                return
        try:
            bag.write(bag.connection(item.topic, item.header), item.stamp_ns, item.payload)
        except OSError as exc:
            self.bag = None
            self._failed_write(bag, exc)

    def _topic_full(self, topic: str) -> None:
        self.full.add(topic)
        sub = self.node.subscriptions.get(topic)
        if sub is not None:
            sub.close()
        # rosbag record ends when every topic it subscribed has reached its limit.
        if all(t in self.full for t in self.node.subscriptions):
            self.done.set()

    # ------------------------------------------------------------------ topics
    def _wanted(self, topic: str) -> bool:
        if self.exclude is not None and self.exclude.search(topic):
            return False
        return self.opts.all or any(r.fullmatch(topic) for r in self.regex)

    async def _subscribe(self, topic: str) -> None:
        if topic in self.node.subscriptions:
            return
        await self.node.subscribe(topic, ANY_TYPE, self.on_message)
        if not self.opts.quiet:
            self.say("[ INFO] [%.9f]: Subscribing to %s" % (time.time(), topic))

    async def _node_topics(self) -> list[str]:
        """The topics `--node` subscribes to, from that node's own slave API."""
        code, _, uri = await call(self.node.master_uri, "lookupNode", self.node.name, self.opts.node, timeout=5.0)
        if code != 1:
            return []
        code, _, subs = await call(uri, "getSubscriptions", self.node.name, timeout=5.0)
        return [t for t, _ in subs] if code == 1 else []

    async def _poll_master(self) -> None:
        while not self.done.is_set():
            try:
                if self.opts.all or self.regex:
                    _, _, topics = await call(self.node.master_uri, "getPublishedTopics", self.node.name, "",
                                              timeout=5.0)
                    for topic, _type in topics:
                        if self._wanted(topic) and topic not in self.full:
                            await self._subscribe(topic)
                if self.opts.node:
                    for topic in await self._node_topics():
                        if topic not in self.full and not (self.exclude and self.exclude.search(topic)):
                            await self._subscribe(topic)
            except (OSError, asyncio.TimeoutError, ValueError) as exc:
                log.debug("asking the master for topics: %s", exc)
            try:
                await compat.wait_for(self.done.wait(), MASTER_POLL_S)
            except asyncio.TimeoutError:
                pass

    async def run(self) -> int:
        try:
            self._open()
        except (OSError, ValueError) as exc:
            self.say("[ERROR] [%.9f]: cannot open the bag: %s" % (time.time(), exc))
            return 1
        self.writer = threading.Thread(target=self._write_loop, name="bag writer", daemon=True)
        self.writer.start()
        for topic in self.opts.topics:
            await self._subscribe(topic)
        poller = None
        if self.opts.all or self.regex or self.opts.node:
            poller = asyncio.get_running_loop().create_task(self._poll_master())
        shutdown = asyncio.get_running_loop().create_task(self.node.shutdown_requested.wait())
        shutdown.add_done_callback(lambda _: self.done.set())
        await self.done.wait()
        shutdown.cancel()
        if poller is not None:
            poller.cancel()
        # What the kernel already holds for us belongs in the bag: read it, then close (a publisher faster than
        # the disk would otherwise keep the writer from ever finding the buffer empty).
        for sub in list(self.node.subscriptions.values()):
            await sub.drain()
        for sub in list(self.node.subscriptions.values()):
            sub.close()
        # ...and what the buffer holds (rosbag's writer too empties its queue before it closes the bag)
        self.buffer.close()
        await to_thread(self.writer.join)
        if self.buffer.total_dropped:
            self.say("[ WARN] [%.9f]: %d messages were dropped: the buffer (-b %d MB) was full"
                     % (time.time(), self.buffer.total_dropped, self.opts.buffer_size >> 20))
        self._close()
        return 1 if self.failed else 0


async def record(opts: RecordOptions, name: str, master_uri: str, host: str | None = None) -> int:
    """Run a recording until SIGINT/SIGTERM, a shutdown call, -l, or a write error."""
    await rosargs.wait_for_master(master_uri, name)
    node = SlaveNode(name, master_uri, host=host or default_host())
    await node.start()
    recorder = Recorder(opts, node)
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, recorder.done.set)
    try:
        return await recorder.run()
    finally:
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.remove_signal_handler(sig)
        await node.stop()


def resolve_topics(topics: list[str], node_name: str) -> list[str]:
    return [names.resolve_name(t, node_name) for t in topics]

