"""Resource sampling and limits: CPU and RSS of every running node's whole process group, from /proc.

Once per `--monitor-period` (1 s by default) the `/proc/<pid>/stat` of every
process of every running node's group is read once (`GroupReader`): the same
line holds its CPU ticks and resident pages. A node's figures are the sums over
its group (what a launch-prefix, a shell wrapper or a forked worker use
counts too); CPU includes the children the node has reaped (cutime, cstime),
so a short-lived helper's CPU is not lost. CPU is in cores over the window
since the group's previous sample (its start, for the first one).

Read directly rather than through psutil: psutil builds a Process object and
opens stat and statm per process; one pread of a held file per process is
several times cheaper (benchmarks/monitor.py --readers: 500 idle nodes).

Limits (`memory_limit` bytes, `cpu_limit` cores, per node): with
`on_limit="warn"` each crossing and each return under the limit is handed to
the supervisor, which records it in the node's state (`NodeStatus.over_limit`:
an event, a WARN on /diagnostics, a column of `launcher status`) and says it on
the console; `"restart"` has the supervisor kill the run and start it again.
"""

from __future__ import annotations

import asyncio
import errno
import os
from typing import TYPE_CHECKING

from launcher.model.units import format_size

if TYPE_CHECKING:  # (annotations only)
    from launcher.fleet.runner import Runner, RunningNode

DEFAULT_PERIOD_S = 1.0
CLOCK_TICKS = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
PAGE_SIZE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096


# A node's new processes (a forked worker) are looked for in all of /proc every this many samples.
RESCAN_EVERY = 10


def _parse_stat(line: bytes) -> tuple[int, str, int, int]:
    """(pgrp, state, CPU ticks with reaped children, resident pages) of a /proc/<pid>/stat line."""
    # after "pid (comm) ": state ppid pgrp session tty tpgid flags minflt cminflt majflt cmajflt
    # utime stime cutime cstime priority nice threads itreal starttime vsize rss
    f = line[line.rfind(b")") + 2:].split(b" ", 22)
    return int(f[2]), f[0].decode(), int(f[11]) + int(f[12]) + int(f[13]) + int(f[14]), int(f[21])


def _read_stat(pid: int) -> bytes:
    fd = os.open("/proc/%d/stat" % pid, os.O_RDONLY)
    try:
        return os.read(fd, 1024)
    finally:
        os.close(fd)


class GroupReader:
    """CPU ticks and resident pages of process groups, from /proc/<pid>/stat of each member.

    The members' stat files are kept open and re-read with one pread each:
    opening a /proc file costs more than generating its text (500 nodes: ~13 ms
    per sample opening each, ~6 ms re-reading held ones, on a busy 2-core box).
    A line identical to the previous one (an idle process) is not parsed again.
    """

    def __init__(self) -> None:
        # pgid -> {pid: [held fd or None, last line, ticks, pages]}
        self.members: dict[int, dict[int, list]] = {}
        self._reads = 0

    def read(self, pgids) -> dict[int, tuple[int, int]]:
        """{pgid: (CPU ticks, resident pages)} summed over the live processes of each of `pgids`."""
        for pgid in [g for g in self.members if g not in pgids]:
            self._forget(pgid)
        new = [g for g in pgids if g not in self.members]
        for pgid in new:
            self.members[pgid] = {}
            self._add(pgid, pgid)  # the leader: a node's pgid is its pid
        if self._reads % RESCAN_EVERY == 0:
            self._discover()
        self._reads += 1
        totals = {}
        for pgid, members in self.members.items():
            ticks = pages = 0
            for pid, entry in list(members.items()):
                fd = entry[0]
                try:
                    line = os.pread(fd, 1024, 0) if fd is not None else _read_stat(pid)
                except OSError:  # gone (a held file of a reaped process reads ESRCH)
                    line = b""
                if line != entry[1]:
                    try:
                        group, state, entry[2], entry[3] = _parse_stat(line)
                    except (IndexError, ValueError):
                        group, state = -1, ""
                    if group != pgid or state == "Z":
                        self._drop(members, pid)
                        continue
                    entry[1] = line
                ticks += entry[2]
                pages += entry[3]
            if members:
                totals[pgid] = (ticks, pages)
        return totals

    def close(self) -> None:
        for pgid in list(self.members):
            self._forget(pgid)

    def _add(self, pgid: int, pid: int) -> None:
        try:
            fd = os.open("/proc/%d/stat" % pid, os.O_RDONLY | os.O_CLOEXEC)
        except OSError as e:
            if e.errno not in (errno.EMFILE, errno.ENFILE):
                return  # gone already
            fd = None  # out of files: read it by name each time instead
        self.members[pgid][pid] = [fd, b"", 0, 0]

    def _discover(self) -> None:
        """Add what joined the groups since (a node's children): one pass over all of /proc."""
        known = {pid for members in self.members.values() for pid in members}
        try:
            entries = os.listdir("/proc")
        except OSError:
            return
        for entry in entries:
            if not entry.isdigit() or int(entry) in known:
                continue
            try:
                group, state, _ticks, _pages = _parse_stat(_read_stat(int(entry)))
            except (OSError, IndexError, ValueError):
                continue
            if group in self.members and state != "Z":
                self._add(group, int(entry))

    def _drop(self, members: dict[int, list], pid: int) -> None:
        fd = members.pop(pid)[0]
        if fd is not None:
            os.close(fd)

    def _forget(self, pgid: int) -> None:
        members = self.members.pop(pgid)
        for pid in list(members):
            self._drop(members, pid)


class ResourceMonitor:
    """Samples a supervisor's running nodes into its Fleet and applies their limits."""

    def __init__(self, supervisor: Runner, period: float = DEFAULT_PERIOD_S):
        self.supervisor = supervisor
        self.period = period
        self.loop = asyncio.get_running_loop()
        self._last: dict[int, tuple[float, int]] = {}  # pgid -> (loop time, CPU ticks) of its previous sample
        self.reader = GroupReader()

    async def run(self) -> None:
        try:
            await asyncio.sleep(self.period)  # (not while the launch is spawning its nodes)
            while True:
                started = self.loop.time()
                self.sample()
                await asyncio.sleep(max(0.0, started + self.period - self.loop.time()))
        finally:
            self.reader.close()

    def sample(self) -> None:
        running = {p.pgid: p for p in self.supervisor.procs if p.alive and p.pgid is not None}
        if not running:
            self._last.clear()
            return
        totals = self.reader.read(running)
        now = self.loop.time()
        last = {}
        for pgid, (ticks, pages) in totals.items():
            proc = running[pgid]
            since, before = self._last.get(pgid, (self.supervisor.fleet.records[proc.spec.node_name].started, 0))
            used = max(0, ticks - before) / CLOCK_TICKS  # (a member reaped by another process: its ticks leave)
            cpu = used / max(now - since, 1e-3)
            rss = pages * PAGE_SIZE
            last[pgid] = (now, ticks)
            self.supervisor.fleet.sample(proc.spec.node_name, cpu, rss, used)
            self._check_limits(proc, cpu, rss)
        self._last = last

    def _check_limits(self, proc: RunningNode, cpu: float, rss: int) -> None:
        policy = proc.spec.policy
        if policy.memory_limit is not None:
            over = rss > policy.memory_limit
            self._limit(proc, "memory_limit", policy.memory_limit, over, "uses %s of memory, %s its limit of %s"
                        % (format_size(rss, measured=True), "over" if over else "under", format_size(policy.memory_limit)))
        if policy.cpu_limit is not None:
            over = cpu > policy.cpu_limit
            self._limit(proc, "cpu_limit", policy.cpu_limit, over, "uses %.2f CPU cores, %s its limit of %g"
                        % (cpu, "over" if over else "under", policy.cpu_limit))

    def _limit(self, proc: RunningNode, limit: str, maximum: float, over: bool, what: str) -> None:
        if over and proc.spec.policy.on_limit == "restart":
            self.supervisor.restart(proc, what)
            return
        # whether the run is already known to be over it: the node's state says (a new run starts under)
        status = self.supervisor.fleet.nodes.get(proc.spec.node_name)
        if status is not None and over != (limit in status.over_limit):
            self.supervisor.limit_crossed(proc, limit, maximum if over else None, what)
