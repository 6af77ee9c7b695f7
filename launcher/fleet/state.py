"""Every node's state, in one home: the records the node state machine (`fleet.lifecycle`) steps, and the
stream of their changes that every view listens to.

A runner (the supervisor for this machine's nodes, `remote.parent` for the
others) tells the fleet what happened to a node (`apply(name, event)`); the
fleet steps the node's record, keeps the new one, and hands the change to
each listener in order: the console's words (`output.narrate`), the launch
log, the server's status cache, a remote child's reports to its parent. It
appends it to the run's `launcher-events.jsonl` (one JSON object a line:
time, node, host, state, pid, exit code or signal, restarts, failures, limits
over, reason, and the machine's own `phase`), so a reader can follow a launch
from outside; `changes_since` serves the same stream to a reader that asks
(the long poll of the launch's server). It returns the actions for the runner
to carry out. The launch's own phase is the fleet's too (`launch`, stepped by
`fleet.launchphase`'s table): `done` is set by its END action, when a node ends
the launch (required, on_fatal="shutdown") or, with `exit_when_all_dead`, when
every node has ended; its runner carries out the rest (`launch_step`).

The outside sees eight states (README), each internal state mapping onto one
(`lifecycle.PUBLIC`):

    waiting     its start is held (spawn_delay, wait_for, or on its way to its machine)
    running     its process runs (also while it is being stopped)
    respawning  its process ended; it starts again at `next_start`
    exited      its process ended and will not be started again (or its machine dropped)
    fatal       it failed `respawn_max_retries` runs in a row: not restarted, kept here
    hung        it stopped answering its own XML-RPC API (then killed; respawning or exited follows)
    stalled     a watched topic of its own went silent or too slow (killed, unless on_stall="warn")
    stopped     the launch (or an operator) stopped it

A running node may also be over one of its limits (`memory_limit`, `cpu_limit`
with on_limit="warn"): `over_limit` names them.
"""

from __future__ import annotations

import asyncio
import collections
import collections.abc
import json
import time
from typing import Callable, Iterable

from launcher import compat
from launcher.fleet import launchphase, lifecycle
from launcher.fleet.lastexit import run_ended
from launcher.fleet.lifecycle import LOCAL_HOST, Event, Record, Rules
from launcher.fleet.relations import follow_ups, stop_first
from launcher.fleet.samples import Samples
from launcher.model.record import record
from launcher.model.units import format_size
from launcher.plan.relations import Relations

WAITING = "waiting"
RUNNING = "running"
RESPAWNING = "respawning"
EXITED = "exited"
FATAL = "fatal"
HUNG = "hung"
STALLED = "stalled"
STOPPED = "stopped"
STATES = (WAITING, RUNNING, RESPAWNING, EXITED, FATAL, HUNG, STALLED, STOPPED)

EVENTS_FILE = "launcher-events.jsonl"  # in the run's log directory (a remote child's: launcher-events-NAME.jsonl)
LAUNCH_ENDED = "launch_ended"  # the `event` of the events file's last line, written when the launch ends
RELOAD = "reload"  # the `event` of a reload's line: what it set, deleted, restarted, started, stopped
HISTORY = 60  # resource samples kept per node (a minute at the default period)
# The change stream a long-polling reader can ask for again: each change kept as the one line of JSON it is
# served as (a few hundred bytes; the objects it was made of took 1.3 kB), for a minute at least and at most
# CHANGES_KEPT of them. A view polls every second; one that falls further behind reads the status again
# (`complete` false). In a crash loop of 4 kills a second that is 1,000 lines, a quarter of the maximum.
CHANGES_KEPT = 10000
CHANGES_KEPT_S = 60.0


class NodeStatus:
    """One node as a reader sees it: a view of its record, written only by the fleet. Times are
    wall-clock seconds (time.time())."""

    __slots__ = ("name", "process", "host", "state", "phase", "pid", "started_at", "restarts", "spawn_count",
                 "exit_code", "exit_signal", "next_start", "reason", "failures", "cpu", "rss", "history",
                 "over_limit", "last_exit_code", "last_exit_signal", "last_exit_at", "registered", "uri",
                 "cpu_seconds")

    def __init__(self, name: str, process: str = "", host: str = LOCAL_HOST):
        self.name = name  # the ROS node name, e.g. /robot/driver
        self.process = process or name  # roslaunch's process name, e.g. robot/driver-2
        self.host = host
        self.state = WAITING
        self.phase = lifecycle.NEW  # the state machine's own state (lifecycle.STATES)
        self.pid: int | None = None
        self.started_at: float | None = None  # the current (or last) run's start
        self.restarts = 0  # starts after the first
        self.spawn_count = 0  # runs started
        self.exit_code: int | None = None  # the last run's exit code, if it exited
        self.exit_signal: int | None = None  # the signal that ended the last run, if one did
        # how the last run that ended did end, and when (wall clock): kept while the node runs again, when
        # exit_code and exit_signal (the current run's) are None again (why does it keep restarting?)
        self.last_exit_code: int | None = None
        self.last_exit_signal: int | None = None
        self.last_exit_at: float | None = None
        self.next_start: float | None = None  # when respawning
        self.reason = ""  # why the last change happened, in words
        self.failures = 0  # failed starts in a row (runs shorter than respawn_min_uptime), for backoff and FATAL
        self.cpu: float | None = None  # cores used over the last sample period
        self.rss: int | None = None  # bytes, the node's whole process group
        # CPU seconds used by all its runs so far, as sampled (a counter: it never goes down across respawns)
        self.cpu_seconds = 0.0
        self.history = Samples(HISTORY)  # (time, cpu, rss) of its last samples, in arrays: 24 bytes each
        # the limits the current run is over: "memory_limit" (bytes) or "cpu_limit" (cores) -> the limit
        self.over_limit: dict[str, float] = {}
        # its current run is registered with the master, at this XML-RPC URI ("running" says that a process
        # runs; a ROS node is up once it is registered too)
        self.registered = False
        self.uri = ""

    def uptime(self, now: float | None = None) -> float | None:
        if self.state != RUNNING or self.started_at is None:
            return None
        return (time.time() if now is None else now) - self.started_at

    def as_dict(self) -> dict:
        return {"name": self.name, "process": self.process, "host": self.host, "state": self.state,
                "phase": self.phase, "pid": self.pid, "started_at": self.started_at, "uptime": self.uptime(),
                "restarts": self.restarts, "exit_code": self.exit_code, "exit_signal": self.exit_signal,
                "next_start": self.next_start, "reason": self.reason, "failures": self.failures, "cpu": self.cpu,
                "rss": self.rss, "over_limit": dict(self.over_limit), "last_exit_code": self.last_exit_code,
                "last_exit_signal": self.last_exit_signal, "last_exit_at": self.last_exit_at,
                "registered": self.registered, "uri": self.uri,
                "cpu_seconds": round(self.cpu_seconds, 3)}


@record
class Change:
    """One step of one node: what every view listens to."""

    seq: int  # 1, 2, ... in the order of the changes of this run
    time: float  # wall clock
    old: Record
    new: Record
    event: Event
    actions: list  # the machine's actions (a NOTE among them is for the console)
    status: NodeStatus  # the node's view now (it changes with later changes)
    line: dict  # the change as the events file writes it


def over_limit_text(over_limit: dict[str, float], cpu: float | None, rss: int | None) -> str:
    """The limits a node is over, each with the value it has now: "memory_limit 500MB (uses 612.3MB)" (sizes as
    the README's units rule writes them: the limit as given, the measured use in decimal units)."""
    parts = []
    for limit, maximum in sorted(over_limit.items()):
        if limit == "memory_limit":
            parts.append("memory_limit %s (uses %s)" % (format_size(maximum),
                                                        "?" if rss is None else format_size(rss, measured=True)))
        else:
            parts.append("%s %g cores (uses %s)" % (limit, maximum, "?" if cpu is None else "%.2f" % cpu))
    return ", ".join(parts)


def visible(change: Change) -> bool:
    """Is this a change a reader of the events file sees? (Internal steps, e.g. running -> stopping, or
    pending -> launching, are not written: the outside's states and their fields are the file's.)"""
    old, new = change.old, change.new
    if new.state in lifecycle.ON_THE_WAY or new.state == lifecycle.STOPPING:
        return False  # (what follows says more: running, stopped, or why not)
    return (lifecycle.PUBLIC[old.state] != lifecycle.PUBLIC[new.state] or old.pid != new.pid
            or old.spawn_count != new.spawn_count or old.exit_code != new.exit_code
            or old.exit_signal != new.exit_signal or old.over_limit != new.over_limit
            or old.failures != new.failures or (old.reason != new.reason and new.reason != "")
            or old.registered != new.registered or old.uri != new.uri)


class _LocalStates(collections.abc.Mapping):
    """The state of each node of this machine, read from the records as asked (a node's step asks about a few)."""

    __slots__ = ("records",)

    def __init__(self, records: dict[str, Record]):
        self.records = records

    def __getitem__(self, name: str) -> str:
        r = self.records[name]
        if r.host != LOCAL_HOST:
            raise KeyError(name)
        return r.state

    def __iter__(self):
        return (n for n, r in self.records.items() if r.host == LOCAL_HOST)

    def __len__(self) -> int:
        return sum(1 for _ in self)


class Fleet:
    """The records of all nodes of a run, their views, the change stream and the launch's outcome."""

    def __init__(self, events_path: str | None = None, warn: Callable[[str], None] | None = None,
                 clock: Callable[[], float] = time.monotonic, exit_when_all_dead: bool = False,
                 say: Callable[[str, bool], None] | None = None):
        self.records: dict[str, Record] = {}
        self.nodes: dict[str, NodeStatus] = {}
        self.clock = clock  # the runners' clock (the loop's): timers, uptimes
        self._events = None
        self._warn = warn
        self.say = say  # the outcome's words ("all processes on machine have died ..."): say(text, bold)
        self.listeners: list[Callable[[Change], None]] = []  # called after every change, in order
        self.seq = 0
        # the change stream's backlog: (seq, when kept (self.clock), the change's JSON line as it is served)
        self.changes: collections.deque[tuple[int, float, str]] = collections.deque(maxlen=CHANGES_KEPT)
        self._changed: asyncio.Event | None = None  # set at a change while a long poll waits
        # the launch's phase (launchphase), and its outcome: `done`, set by the phase's END
        self.launch = launchphase.Launch(exit_when_all_dead=exit_when_all_dead)
        self.done = compat.Event()
        self._unstarted = 0  # nodes that never got a record (their command could not be made)
        # the relations among this machine's nodes (bound, stopped before): the plan's, given (`relate`)
        self.relations = Relations()
        # nodes whose bound nodes an operator's stop stops ahead of them: those are not started again meanwhile
        self.unbinding: set[str] = set()
        if events_path:
            try:
                # line-buffered: a reader (`launcher events -f`) sees each event as it happens
                self._events = open(events_path, "a", buffering=1, encoding="utf-8")
            except OSError as e:
                self._warning("cannot write the events file [%s]: %s" % (events_path, e.strerror))

    # ---- records -------------------------------------------------------------------------------------

    def add(self, name: str, process: str = "", host: str = LOCAL_HOST, rules: Rules = Rules()) -> Record:
        """The node's record, made on first sight (a second add of the same name keeps the first)."""
        record = self.records.get(name)
        if record is None:
            record = self.records[name] = Record(name, process or name, host, rules)
            self.nodes[name] = NodeStatus(name, record.process, host)
        return record

    def remove(self, name: str) -> None:
        """A node a reload took out of the launch, once it is down (it was stopped first): no longer the
        launch's. (The events file's reload line says so.)"""
        record = self.records.get(name)
        if record is None:
            return
        if record.state in lifecycle.ALIVE and record.state != lifecycle.NEW:
            raise ValueError("node [%s] is %s: it is stopped before it is removed" % (name, record.state))
        del self.records[name], self.nodes[name]

    def apply(self, name: str, event: Event) -> list[lifecycle.Action]:
        """Step the node with `event`; tell every listener; return what the runner is to do."""
        old = self.records[name]
        now = self.clock()
        try:
            new, actions = lifecycle.step(old, event, now)
        except lifecycle.InvalidTransition as e:  # a runner's bug: said, and the node is left as it was
            self._warning("internal error: %s" % e)
            return []
        if new is old:
            return actions
        self.records[name] = new
        status = self._mirror(new, now)
        self.seq += 1
        when = time.time()
        change = Change(self.seq, when, old, new, event, actions, status, self._line(self.seq, when, new, status))
        if visible(change):
            self._write(self._keep(change.line))
        else:  # (a step the events file leaves out: served marked internal)
            self._keep(dict(change.line, internal=True))
        for listener in self.listeners:
            try:
                listener(change)
            except Exception as e:  # noqa: BLE001 - a view's bug must not stop the supervision of the nodes
                self._warning("internal error in %r: %s: %s" % (listener, type(e).__name__, e))
        if self._changed is not None:
            self._changed.set()
        for action in actions:
            if action.kind == lifecycle.END_LAUNCH:
                self.end(action.status)
        if event.kind == lifecycle.SPAWN_FAILED and new.host == LOCAL_HOST:
            self.launch_step(launchphase.START_FAILED)  # (the launch's phase decides whether that ends it)
        if new.state in lifecycle.ENDED and old.state not in lifecycle.ENDED:
            self._check_all_dead()
        return actions

    def step(self, name: str, event: Event, carry: Callable[[str, list], None]) -> list[lifecycle.Action]:
        """`apply`, `carry(name, actions)` (the runner carries them out), then the same for each event the relations
        make follow the change (`relations.follow_ups`: the nodes bound to it told it went down or runs again), in
        order, each with its own follow-ups. Returns the node's own actions."""
        old = self.records[name].state
        actions = self.apply(name, event)
        new = self.records[name].state  # (before the actions are carried out: they tell their own events)
        carry(name, actions)
        related = self.relations
        if old != new and (name in related.bound or name in related.partner):
            states = self._local_states()
            for other, follow in follow_ups(related, states, name, old, new, frozenset(self.unbinding), self.stopping):
                if other in self.records:
                    self.step(other, follow, carry)
        return actions

    def unbind(self, name: str, carry: Callable[[str, list], None]) -> list[str]:
        """An operator's stop of `name`: the nodes bound to it that run are stopped first (`relations.stop_first`),
        stepped here with `carry` as `step` does, and not started again until `bound_stopped`; their names (none:
        `name` is stopped at once)."""
        told = stop_first(self.relations, self._local_states(), name)
        if told:
            self.unbinding.add(name)
            for other, event in told:
                self.step(other, event, carry)
        return [other for other, _ in told]

    def bound_stopped(self, name: str) -> None:
        """The nodes bound to `name` that its operator's stop stopped first are down (or that stop was called off)."""
        self.unbinding.discard(name)

    def _local_states(self) -> collections.abc.Mapping[str, str]:
        return _LocalStates(self.records)

    def relate(self, relations: Relations) -> None:
        """The relations among this machine's nodes, as the plan made them (`Plan.relations`), for the nodes it is
        given and those a reload or a remote child's next `launch` call gives it."""
        self.relations = relations

    def registration(self, name: str, uri: str, present: bool) -> None:
        """The master's word about a node's current run (health/registration.py): registered at `uri`, or that
        registration gone. No runner is needed: the lifecycle table answers these with no action."""
        if name in self.records:
            self.apply(name, Event(lifecycle.REGISTERED if present else lifecycle.UNREGISTERED, uri=uri))

    def _mirror(self, r: Record, now: float) -> NodeStatus:
        status = self.nodes[r.name]
        wall = time.time() - now  # this clock's zero on the wall clock
        status.process = r.process
        status.state = lifecycle.PUBLIC[r.state]
        status.phase = r.state
        status.pid = r.pid
        status.started_at = None if r.started is None or r.spawn_count == 0 else wall + r.started
        status.restarts = r.restarts
        status.spawn_count = r.spawn_count
        if run_ended((status.exit_code, status.exit_signal), (r.exit_code, r.exit_signal)):
            status.last_exit_code, status.last_exit_signal, status.last_exit_at = r.exit_code, r.exit_signal, wall + now
        status.exit_code, status.exit_signal = r.exit_code, r.exit_signal
        status.next_start = None if r.next_start is None else wall + r.next_start
        status.reason = r.reason
        status.failures = r.failures
        status.over_limit = dict(r.over_limit)
        status.registered, status.uri = r.registered, r.uri
        if status.state != RUNNING:
            status.cpu = status.rss = None  # (a stopped node uses nothing: no stale sample)
        return status

    def sample(self, name: str, cpu: float, rss: int, cpu_time: float = 0.0) -> None:
        """A running node's CPU (cores over the last period), RSS (bytes), and the CPU seconds it used since its
        previous sample (`cpu_time`, added to its counter)."""
        status = self.nodes.get(name)
        if status is not None and status.state == RUNNING:
            status.cpu, status.rss = cpu, rss
            status.cpu_seconds += cpu_time
            status.history.append((time.time(), cpu, rss))

    def __iter__(self) -> Iterable[NodeStatus]:
        return iter(self.nodes.values())

    # ---- the change stream, for readers outside -----------------------------------------------------------

    def changes_json(self, seq: int) -> tuple[str, bool]:
        """The changes after `seq` as a JSON array, each as the events file has it (a step it leaves out, such
        as running -> stopping, marked `"internal": true`: a view that shows the file's lines skips it; the
        run's own lines, a reload's, the master's restart, the launch's end, as the file has them too), and
        whether they are all there (False: older ones were dropped; a reader should read the status again)."""
        lines = []
        for kept_seq, _, text in reversed(self.changes):  # (a reader is near the end: read from there)
            if kept_seq <= seq:
                break
            lines.append(text)
        complete = not self.changes or self.changes[0][0] <= seq + 1 or seq >= self.seq
        return "[" + ",".join(reversed(lines)) + "]", complete

    def changes_since(self, seq: int) -> tuple[list[dict], bool]:
        """`changes_json`'s changes as dicts."""
        text, complete = self.changes_json(seq)
        return json.loads(text), complete

    def _keep(self, line: dict) -> str:
        """A change (or a run's line) in the backlog, as the JSON line it is served and written as; those past
        the backlog's bounds dropped."""
        text = json.dumps(line, separators=(",", ":"), default=str)
        now = self.clock()
        changes = self.changes
        changes.append((self.seq, now, text))
        while changes[0][1] < now - CHANGES_KEPT_S:
            changes.popleft()
        return text

    async def wait_change(self, seq: int, timeout: float) -> None:
        """Return when there is a change after `seq`, or after `timeout` seconds."""
        if self.seq > seq:
            return
        if self._changed is None:
            self._changed = compat.Event()
        self._changed.clear()
        try:
            await compat.wait_for(self._changed.wait(), timeout)
        except asyncio.TimeoutError:
            pass

    # ---- the launch's phase and outcome ---------------------------------------------------------------

    @property
    def exit_status(self) -> int:
        """The launch's exit status: the first non-zero status a node ended it with (launchphase), else 0."""
        return self.launch.exit_status

    @property
    def exit_when_all_dead(self) -> bool:
        return self.launch.exit_when_all_dead

    @exit_when_all_dead.setter
    def exit_when_all_dead(self, value: bool) -> None:
        self.launch = self.launch._replace(exit_when_all_dead=value)

    def start_failure_ends_the_launch(self) -> None:
        """This is roslaunch's own launch (not a remote child, nor a runner on its own): a node's process that
        cannot be started while it starts its nodes ends it (launchphase)."""
        self.launch = self.launch._replace(start_failure_ends_it=True)

    @property
    def stopping(self) -> bool:
        """The launch's nodes are being stopped (or are down): nothing but that stop touches them."""
        return launchphase.stopping(self.launch)

    @property
    def starts_allowed(self) -> bool:
        """No node starts again by itself (a timer's start, a hold let go) once the launch is to end."""
        return launchphase.starts_allowed(self.launch)

    def launch_step(self, kind: str, status: int = 0) -> list[launchphase.Action]:
        """Step the launch's phase; carry out END (`done`) and SAY; return the actions for the launch's runner
        (STOP_ALL, KILL_ALL)."""
        try:
            self.launch, actions = launchphase.step(self.launch, launchphase.Event(kind, status))
        except launchphase.InvalidTransition as e:  # a runner's bug: said, and the launch is left as it was
            self._warning("internal error: %s" % e)
            return []
        for action in actions:
            if action.kind == launchphase.END:
                self.done.set()
            elif action.kind == launchphase.SAY and self.say is not None:
                self.say(action.text, action.bold)
        return actions

    def end(self, status: int) -> None:
        """A node (here or elsewhere) ends the launch with `status` (the first one that fails decides)."""
        self.launch_step(launchphase.NODE_ENDED_IT, status)

    def not_started(self, required: bool) -> None:
        """A node whose command could not even be made (already reported by name): it has no record."""
        if required:
            self.end(1)
        else:
            self._unstarted += 1
            self._check_all_dead()

    def registrations_complete(self) -> None:
        """Every node of the launch has been started (or failed to)."""
        self.launch_step(launchphase.ALL_STARTED)
        if not self.records:  # (a node of another machine has a record too: its machine's roslaunch is a process)
            self.launch_step(launchphase.NO_PROCESSES)
        self._check_all_dead()

    def _check_all_dead(self) -> None:
        local = [r for r in self.records.values() if r.host == LOCAL_HOST]
        if launchphase.all_dead(local, lifecycle.ALIVE, lifecycle.ENDED, self._unstarted):
            self.launch_step(launchphase.ALL_DEAD)  # (the phase decides whether that ends the launch)

    # ---- the events file -----------------------------------------------------------------------------------

    def launch_ended(self, reason: str, exit_status: int) -> None:
        """The launch's last line in the events file: a reader after it knows it ended, when and why (one
        that was killed has none)."""
        self.run_event(LAUNCH_ENDED, reason=reason, exit_status=exit_status)

    def run_event(self, event: str, **fields: object) -> None:
        """A line in the events file about the run, not one node (`event`: its name, `reason`: its words)."""
        self._write(self._stream({"event": event, "time": round(time.time(), 6), **fields}))

    def reloaded(self, reason: str, **what: list) -> None:
        """A reload's line in the events file: what it changed, in words (`reason`) and by name."""
        self._write(self._stream({"event": RELOAD, "time": round(time.time(), 6), "reason": reason, **what}))

    def _stream(self, line: dict) -> str:
        """A run's line numbered in the change stream (`seq`), for the long poll's readers too: its JSON."""
        self.seq += 1
        text = self._keep({"seq": self.seq, **line})
        if self._changed is not None:
            self._changed.set()
        return text

    @staticmethod
    def _line(seq: int, when: float, r: Record, status: NodeStatus) -> dict:
        """A change as the events file and the long poll give it."""
        return {"seq": seq, "time": round(when, 6), "node": r.name, "host": r.host, "state": status.state,
                "phase": r.state, "pid": r.pid, "exit_code": r.exit_code, "exit_signal": r.exit_signal,
                "restarts": r.restarts, "failures": r.failures, "next_start": status.next_start,
                "over_limit": dict(r.over_limit), "reason": r.reason, "registered": r.registered, "uri": r.uri}

    def _write(self, text: str) -> None:
        """A line of the events file: the change stream's JSON of a change or a run's line."""
        if self._events is None:
            return
        try:
            self._events.write(text + "\n")
        except OSError as e:  # a full disk: say so once, keep supervising
            self._warning("cannot write the events file: %s" % e.strerror)
            self._close()

    def _warning(self, msg: str) -> None:
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
