"""`bag play`: publish a bag's messages at their recorded pace (rosbag play's options), each topic with its recorded type.

The type, md5sum, definition and latching of each topic come from the bag's
connection records, so no message package is needed. With `--clock`,
`/clock` (rosgraph_msgs/Clock) carries the bag's time for `use_sim_time` nodes.
"""

from __future__ import annotations

import argparse
import asyncio
import heapq
import os
import signal
import struct
import sys
import termios
import time
import tty
from collections.abc import Iterator
from typing import Any

from launcher import compat
from launcher.model import names
from launcher.bag import rosargs
from launcher.bag.info import open_bag, warn
from launcher.bag.reader import Bag, BagError
from launcher.net.slave import SlaveNode, default_host
from launcher.net.publication import Publication
from launcher.net.tcpros import TopicType

CLOCK_TOPIC = "/clock"
CLOCK_TYPE = TopicType("rosgraph_msgs/Clock", "a9c97c1d230cfc112e270351a944ee47", "time clock\n")
_TIME = struct.Struct("<II")
# How long the last messages may take to leave our sockets once playback is done.
FLUSH_S = 5.0
# Waits are slept in slices of this, so that SIGINT ends a long gap at once...
SLICE_S = 0.1
# ...and their last part slept in the kernel (asyncio's timers wake up to 1 ms late).
FINE_S = 0.0015
# Progress lines per second at most (rosbag rewrites its line on every message).
PROGRESS_HZ = 10.0


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="launcher bag play", description="Play back the contents of bags (rosbag play).")
    p.add_argument("bags", nargs="*", metavar="BAG")
    p.add_argument("--bags", dest="more_bags", nargs="+", default=[], metavar="BAG", help="bags to play")
    p.add_argument("-q", "--quiet", action="store_true", help="suppress console output")
    p.add_argument("-i", "--immediate", action="store_true", help="play back all messages without waiting")
    p.add_argument("--pause", action="store_true", help="start in paused mode (space toggles, s steps)")
    p.add_argument("--queue", type=int, default=100, metavar="SIZE", help="messages waiting for each subscriber's "
                   "socket, per topic, the oldest dropped past it (0: unbounded; default 100)")
    p.add_argument("--hz", type=float, default=None, help="publish /clock at this frequency (default 100)")
    p.add_argument("-d", "--delay", type=float, default=0.2, metavar="SEC", help="sleep SEC after advertising the topics")
    p.add_argument("-r", "--rate", type=float, default=1.0, metavar="FACTOR", help="multiply the publish rate")
    p.add_argument("-s", "--start", type=float, default=0.0, metavar="SEC", help="start SEC seconds into the bags")
    p.add_argument("-u", "--duration", type=float, default=None, metavar="SEC", help="play only SEC seconds")
    p.add_argument("-l", "--loop", action="store_true", help="loop playback")
    p.add_argument("-k", "--keep-alive", action="store_true", help="keep alive past the end of the bag")
    p.add_argument("--topics", nargs="+", default=[], metavar="TOPIC", help="topics to play")
    p.add_argument("--wait-for-subscribers", action="store_true",
                   help="wait for at least one subscriber on each topic before publishing")
    p.add_argument("--clock", action="store_true", help="publish the clock time")
    return p


def say(text: str, end: str = "\n") -> None:
    """A line of rosbag play's on stdout, at once (a launch's log shows it as it comes)."""
    sys.stdout.write(text + end)
    sys.stdout.flush()


def clock_payload(stamp_ns: int) -> bytes:
    return _TIME.pack(stamp_ns // 1_000_000_000, stamp_ns % 1_000_000_000)



class Player:
    """Plays open bag readers through `node`'s publications."""

    def __init__(self, opts: argparse.Namespace, readers: list[Bag], node: SlaveNode, remaps: dict[str, str]):
        self.opts = opts
        self.readers = readers
        self.node = node
        self.remaps = remaps
        self.pubs: dict[tuple[int, int], Publication] = {}  # (reader, connection id) -> publication
        self.clock: Publication | None = None
        self.stop = compat.Event()
        self.paused = opts.pause
        self.step = False
        self.resumed = compat.Event()
        self.published = 0
        self._progress_at = 0.0
        # rosbag's status line, rewritten in place: on a terminal only (in a pipe or a log it is noise)
        self.status_line = not opts.quiet and sys.stdout.isatty()
        self.now = 0              # the bag time played up to (ns)
        self.first = 0            # the bag time of the first message played, and of the last to play
        self.last = 0

    async def advertise(self) -> None:
        wanted = {names.canonicalize_name(t) for t in self.opts.topics}
        by_topic: dict[str, Publication] = {}
        for i, reader in enumerate(self.readers):
            for conn in reader.connections:
                if wanted and conn.topic not in wanted:
                    continue
                topic = self.remaps.get(conn.topic, conn.topic)
                pub = by_topic.get(topic)
                if pub is None:
                    mtype = TopicType(conn.type, conn.md5sum, conn.msgdef)
                    latch = conn.latching == 1
                    pub = await self.node.advertise(topic, mtype, latch=latch, queue_size=self.opts.queue)
                    by_topic[topic] = pub
                self.pubs[(i, conn.id)] = pub
        if self.opts.clock:
            self.clock = await self.node.advertise(CLOCK_TOPIC, CLOCK_TYPE)
        # as rosbag play: one sleep after all the advertising, and its words whether quiet or not
        say("Waiting %g seconds after advertising topics..." % self.opts.delay, end="")
        if self.opts.delay > 0:
            await asyncio.sleep(self.opts.delay)
        say(" done.\n\nHit space to toggle paused, or 's' to step.")

    def _messages(self, start: int, stop: int | None) -> Iterator[tuple[int, int, Any, bytes]]:
        """(time, reader, connection, data) of every message to play, in time order over all bags (a chunk found
        damaged as it is read: left out with a warning, the rest played)."""
        streams = []
        for i, reader in enumerate(self.readers):
            ids = {c.id for c in reader.connections if (i, c.id) in self.pubs}
            if ids:
                streams.append(((t, i, c, d) for t, c, d in reader.messages(ids, start, stop, warn=warn)))
        return heapq.merge(*streams, key=lambda m: (m[0], m[1]))

    async def _sleep_until(self, deadline: float) -> None:
        # A plain sleep (no task per message: at 1 kHz that overhead is the timing error), in slices so
        # that a stop is seen within SLICE_S; the last FINE_S is slept by the kernel's nanosleep, since
        # the loop's timers wake up to a millisecond late (epoll's timeout is in ms). Spinning instead
        # is worse on a busy machine: the scheduler preempts a spinner for a whole time slice.
        while not self.stop.is_set():
            delay = deadline - time.monotonic()
            if delay <= FINE_S:
                break
            await asyncio.sleep(min(delay - FINE_S, SLICE_S))
        delay = deadline - time.monotonic()
        if delay > 0 and not self.stop.is_set():
            time.sleep(delay)

    async def _wait_subscribers(self) -> None:
        say("Waiting for subscribers.")
        pubs = {id(p): p for p in self.pubs.values()}.values()
        while not self.stop.is_set() and any(not p.links for p in pubs):
            await self._sleep_until(time.monotonic() + 0.01)
        say("Finished waiting for subscribers.")

    async def play_once(self, start: int, stop: int | None) -> None:
        rate = self.opts.rate
        wall0 = time.monotonic()
        tick = 1.0 / self.opts.hz if self.opts.hz > 0 else 0.01
        first = True
        for stamp, i, conn, data in self._messages(start, stop):
            if first:
                # playback starts with the first message, not with the bag's start, as rosbag's does
                wall0 = time.monotonic() - (stamp - start) / 1e9 / rate
                first = False
                self.first = self.now = stamp
            if self.stop.is_set():
                return
            if self.paused:
                paused_at = time.monotonic()
                await self._wait_resumed()
                wall0 += time.monotonic() - paused_at
            if not self.opts.immediate:
                target = wall0 + (stamp - start) / 1e9 / rate
                if self.clock is not None:
                    while not self.stop.is_set() and (now := time.monotonic()) < target - tick:
                        self.clock.publish(clock_payload(start + int((now - wall0) * rate * 1e9)))
                        await self._sleep_until(now + tick)
                await self._sleep_until(target)
                if self.stop.is_set():
                    return
            if self.clock is not None:
                self.clock.publish(clock_payload(stamp))
            self.pubs[(i, conn.id)].publish(data)
            self.published += 1
            self.now = stamp
            self._progress()
            if self.step:
                self.step = False
                self.paused = True
            if self.opts.immediate and self.published % 256 == 0:
                await asyncio.sleep(0)  # let the sockets drain and signals in

    async def _wait_resumed(self) -> None:
        while self.paused and not self.stop.is_set():
            self._status("PAUSED ")
            self.resumed.clear()
            stopping = asyncio.ensure_future(self.stop.wait())
            resumed = asyncio.ensure_future(self.resumed.wait())
            await asyncio.wait({stopping, resumed}, return_when=asyncio.FIRST_COMPLETED)
            stopping.cancel()
            resumed.cancel()

    def _status(self, what: str) -> None:
        """rosbag play's status line: the bag time played up to, and how far into the played span."""
        if self.status_line:
            sys.stdout.write("\r [%s]  Bag Time: %13.6f   Duration: %.6f / %.6f               \r" % (
                what, self.now / 1e9, (self.now - self.first) / 1e9, (self.last - self.first) / 1e9))
            sys.stdout.flush()

    def _progress(self) -> None:
        now = time.monotonic()
        if self.status_line and now - self._progress_at >= 1.0 / PROGRESS_HZ:
            self._progress_at = now
            self._status("RUNNING")

    def on_key(self) -> None:
        key = os.read(sys.stdin.fileno(), 1).decode("ascii", "replace")
        if key == " ":
            self.paused = not self.paused
            self.resumed.set()
        elif key == "s" and self.paused:
            self.step = True
            self.paused = False
            self.resumed.set()

    async def flush(self) -> None:
        """Wait (a little) until what was published has left for every subscriber."""
        deadline = time.monotonic() + FLUSH_S
        while time.monotonic() < deadline:
            if not any(l.pending for p in self.node.publications.values() for l in p.links):
                return
            await asyncio.sleep(0.005)

    async def run(self) -> int:
        await self.advertise()
        if self.opts.wait_for_subscribers:
            await self._wait_subscribers()
        bag_start = min(r.start_time for r in self.readers)
        start = bag_start + int(self.opts.start * 1e9)
        stop = start + int(self.opts.duration * 1e9) if self.opts.duration is not None else None
        end = max(r.end_time for r in self.readers)
        self.last = end if stop is None else min(stop, end)
        while not self.stop.is_set():
            await self.play_once(start, stop)
            if not self.opts.loop:
                break
        await self.flush()
        # (rosbag's last line: Done. at the end of the bag, an empty one when stopped)
        say("" if self.stop.is_set() else "\nDone.")
        if self.opts.keep_alive:
            await self.stop.wait()
        return 0


async def play(opts: argparse.Namespace, readers: list[Bag], ros: rosargs.RosArgs) -> int:
    await rosargs.wait_for_master(ros.master_uri, ros.name)
    node = SlaveNode(ros.name, ros.master_uri, host=ros.host or default_host())
    await node.start()
    player = Player(opts, readers, node, ros.remaps)
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, player.stop.set)
    shutdown = loop.create_task(node.shutdown_requested.wait())
    shutdown.add_done_callback(lambda _: player.stop.set())
    if not opts.quiet:
        say("")
    keys = not opts.quiet and sys.stdin is not None and sys.stdin.isatty()
    saved = None
    if keys:
        # as rosbag play: keys act when pressed (no Enter), and the terminal is given back as it was
        saved = termios.tcgetattr(sys.stdin.fileno())
        tty.setcbreak(sys.stdin.fileno())
        loop.add_reader(sys.stdin.fileno(), player.on_key)
    try:
        return await player.run()
    finally:
        if keys:
            loop.remove_reader(sys.stdin.fileno())
            termios.tcsetattr(sys.stdin.fileno(), termios.TCSADRAIN, saved)
        shutdown.cancel()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.remove_signal_handler(sig)
        await node.stop()


def main(argv: list[str]) -> int:
    ros = rosargs.split(argv, "play")
    p = parser()
    opts = p.parse_args(ros.args)
    bags = opts.bags + opts.more_bags
    if not bags:
        p.error("you must specify at least 1 bag file to play back")
    if opts.rate <= 0:
        p.error("--rate must be greater than 0")
    if opts.queue < 0:
        p.error("--queue must be 0 (unbounded) or more")
    if opts.hz is not None and not opts.clock:
        # (rosbag play ignores it silently; a launch file's habit, so a warning, not an error)
        print("[ WARN] --hz %g has no effect without --clock" % opts.hz, file=sys.stderr, flush=True)
    if opts.hz is None:
        opts.hz = 100.0
    readers = []
    try:
        for path in bags:
            say("[ INFO] [%.9f]: Opening %s" % (time.time(), path))
            readers.append(open_bag(path))
            for line in readers[-1].warnings():
                warn(line)
    except BagError as exc:
        print("ERROR %s" % exc, file=sys.stderr)
        for reader in readers:
            reader.close()
        return 1
    try:
        return asyncio.run(play(opts, readers, ros))
    finally:
        for reader in readers:
            reader.close()
