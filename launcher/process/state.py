"""Every node's state, kept in one place: what the events file, status, diagnostics and the live view all read.

A node is in one state at a time:

    waiting     its start is held (spawn_delay, or wait_for conditions not met yet)
    running     its process runs
    respawning  its process ended; it starts again at `next_start`
    exited      its process ended and will not be started again
    fatal       it failed `respawn_max_retries` runs in a row: not restarted, kept here
    hung        it stopped answering its own XML-RPC API (then killed; respawning or exited follows)
    stopped     the launch (or an operator) stopped it

A running node may also be over one of its limits (`memory_limit`,
`cpu_limit` with on_limit="warn"): `over_limit` names them, set when the
resource monitor sees the run cross a limit and cleared when it is back under,
and with any new run or other state.

The supervisor is the only writer: it calls `Fleet.change` at every transition
and at every crossing of a limit. Each change is appended as one JSON object
to the run's `launcher-events.jsonl` (time, node, host, state, pid, exit code
or signal, restarts, limits over, reason), so a reader can follow a launch
from outside; the in-memory `NodeStatus` is what a reader inside the launcher
looks at.
"""

from __future__ import annotations

import collections
import json
import time
from typing import Callable, Iterable

WAITING = "waiting"
RUNNING = "running"
RESPAWNING = "respawning"
EXITED = "exited"
FATAL = "fatal"
HUNG = "hung"
STOPPED = "stopped"
STATES = (WAITING, RUNNING, RESPAWNING, EXITED, FATAL, HUNG, STOPPED)

LOCAL_HOST = "localhost"  # the host of the nodes this machine runs (a remote node's is its machine's address)
HISTORY = 60  # resource samples kept per node (a minute at the default period)


class NodeStatus:
    """One node as a reader sees it. Times are wall-clock seconds (time.time())."""

    __slots__ = ("name", "process", "host", "state", "pid", "started_at", "restarts", "exit_code", "exit_signal",
                 "next_start", "reason", "failures", "cpu", "rss", "history", "over_limit")

    def __init__(self, name: str, process: str = "", host: str = LOCAL_HOST):
        self.name = name  # the ROS node name, e.g. /robot/driver
        self.process = process or name  # roslaunch's process name, e.g. robot/driver-2
        self.host = host
        self.state = WAITING
        self.pid: int | None = None
        self.started_at: float | None = None  # the current (or last) run's start
        self.restarts = 0  # starts after the first
        self.exit_code: int | None = None  # the last run's exit code, if it exited
        self.exit_signal: int | None = None  # the signal that ended the last run, if one did
        self.next_start: float | None = None  # when respawning
        self.reason = ""  # why the last change happened, in words
        self.failures = 0  # failed starts in a row (runs shorter than respawn_min_uptime), for backoff and FATAL
        self.cpu: float | None = None  # cores used over the last sample period
        self.rss: int | None = None  # bytes, the node's whole process group
        self.history: collections.deque[tuple[float, float, int]] = collections.deque(maxlen=HISTORY)
        # the limits the current run is over: "memory_limit" (bytes) or "cpu_limit" (cores) -> the limit
        self.over_limit: dict[str, float] = {}

    def uptime(self, now: float | None = None) -> float | None:
        if self.state != RUNNING or self.started_at is None:
            return None
        return (time.time() if now is None else now) - self.started_at

    def as_dict(self) -> dict:
        return {"name": self.name, "process": self.process, "host": self.host, "state": self.state, "pid": self.pid,
                "started_at": self.started_at, "uptime": self.uptime(), "restarts": self.restarts,
                "exit_code": self.exit_code, "exit_signal": self.exit_signal, "next_start": self.next_start,
                "reason": self.reason, "failures": self.failures, "cpu": self.cpu, "rss": self.rss,
                "over_limit": dict(self.over_limit)}


def size_text(n: float) -> str:
    """Bytes in words: 612.0 MB."""
    for unit, scale in (("GB", 1 << 30), ("MB", 1 << 20), ("kB", 1 << 10)):
        if n >= scale:
            return "%.1f %s" % (n / scale, unit)
    return "%d B" % n


def over_limit_text(over_limit: dict[str, float], cpu: float | None, rss: int | None) -> str:
    """The limits a node is over, each with the value it has now: "memory_limit 500.0 MB (uses 612.0 MB)"."""
    parts = []
    for limit, maximum in sorted(over_limit.items()):
        if limit == "memory_limit":
            parts.append("memory_limit %s (uses %s)" % (size_text(maximum), "?" if rss is None else size_text(rss)))
        else:
            parts.append("%s %g cores (uses %s)" % (limit, maximum, "?" if cpu is None else "%.2f" % cpu))
    return ", ".join(parts)


class Fleet:
    """The states of all nodes of a run, and the events file they are written to."""

    def __init__(self, events_path: str | None = None, warn: Callable[[str], None] | None = None):
        self.nodes: dict[str, NodeStatus] = {}
        self._events = None
        self._warn = warn
        self.listeners: list[Callable[[NodeStatus], None]] = []  # called after every change
        if events_path:
            try:
                # line-buffered: a reader (`launcher events -f`) sees each event as it happens
                self._events = open(events_path, "a", buffering=1, encoding="utf-8")
            except OSError as e:
                self._say("cannot write the events file [%s]: %s" % (events_path, e.strerror))

    def add(self, name: str, process: str = "", host: str = LOCAL_HOST) -> NodeStatus:
        status = self.nodes.get(name)
        if status is None:
            status = self.nodes[name] = NodeStatus(name, process, host)
        return status

    def change(self, name: str, state: str, *, pid: int | None = None, exit_code: int | None = None,
               exit_signal: int | None = None, next_start: float | None = None, reason: str = "",
               failures: int | None = None, over_limit: dict[str, float] | None = None) -> NodeStatus:
        """Record that `name` is now in `state` (a transition; the same state again is an event too).

        `failures` (failed starts in a row) is kept as it was when not given. `over_limit`, given, is the
        set of limits the running node is now over; not given, it is kept while the same run goes on and
        cleared otherwise (a node that ended or started again is over nothing)."""
        assert state in STATES, state
        status = self.add(name)
        now = time.time()
        # (running again with the same pid is the same run: a limit crossed, not a restart)
        new_run = state == RUNNING and (status.state != RUNNING or pid != status.pid)
        if new_run:
            if status.started_at is not None:
                status.restarts += 1
            status.started_at = now
            status.pid = pid
            status.exit_code = status.exit_signal = None
        elif exit_code is not None or exit_signal is not None:
            status.exit_code, status.exit_signal = exit_code, exit_signal
        status.state = state
        status.next_start = next_start if state == RESPAWNING else None
        status.reason = reason
        if failures is not None:
            status.failures = failures
        if state != RUNNING:
            status.cpu = None
        if over_limit is not None:
            status.over_limit = dict(over_limit)
        elif new_run or state != RUNNING:
            status.over_limit = {}
        self._write({"time": round(now, 6), "node": name, "host": status.host, "state": state, "pid": status.pid,
                     "exit_code": status.exit_code, "exit_signal": status.exit_signal,
                     "restarts": status.restarts, "failures": status.failures, "next_start": status.next_start,
                     "over_limit": status.over_limit, "reason": reason})
        for listener in self.listeners:
            listener(status)
        return status

    def sample(self, name: str, cpu: float, rss: int) -> None:
        status = self.nodes.get(name)
        if status is not None:
            status.cpu, status.rss = cpu, rss
            status.history.append((time.time(), cpu, rss))

    def __iter__(self) -> Iterable[NodeStatus]:
        return iter(self.nodes.values())

    def _write(self, event: dict) -> None:
        if self._events is None:
            return
        try:
            self._events.write(json.dumps(event, separators=(",", ":")) + "\n")
        except OSError as e:  # a full disk: say so once, keep supervising
            self._say("cannot write the events file: %s" % e.strerror)
            self._close()

    def _say(self, msg: str) -> None:
        if self._warn is not None:
            self._warn("WARNING: %s" % msg)

    def _close(self) -> None:
        if self._events is not None:
            try:
                self._events.close()
            except OSError:
                pass
            self._events = None

    def close(self) -> None:
        self._close()
