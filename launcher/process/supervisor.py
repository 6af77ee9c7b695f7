"""The supervisor: spawns node processes, notices each exit as it happens, respawns, and stops them all.

Everything runs on the caller's asyncio loop. A child's exit is seen through a
pidfd registered with the loop (no polling: roslaunch polls every 0.1 s), so
a respawn follows a death within a few milliseconds. Each node runs in its own
session/process group; every signal goes to the whole group, as roslaunch does.

Stopping follows roslaunch's escalation per node, each on its own clock:
SIGINT, then SIGTERM after `sigint_timeout`, then SIGKILL after
`sigterm_timeout`. Unlike roslaunch (10 worker threads), all nodes are being
stopped at once, except that SIGINTs are paced: at most `stop_concurrency`
nodes may be in their first `stop_hold` seconds of stopping. Signalling 100
roscpp nodes at the same instant on a small machine makes them all thrash
(measured with ../shared/bench); pacing keeps the CPU busy without thrashing, while a node
that ignores SIGINT only holds its pacing slot for `stop_hold`, so the total
stays bounded by the slowest node rather than by the number of nodes.

The SIGKILL step is not theoretical: a rospy node that gets SIGINT while its main thread is
inside a master call (init_node makes several; so does any rospy.get_param) deadlocks in its
own handler, which unregisters through the same non-reentrant proxy lock; its SIGTERM handler
is the same code. Only SIGKILL ends it, after sigint_timeout + sigterm_timeout, as roslaunch
does (checked side by side); sending SIGINT again would not help.

What happens to a node (its first start, what follows a run, operator stops and
starts, the launch's end) is decided by its state machine (`launcher.fleet.lifecycle`,
stepped by the fleet, `launcher.fleet.state`), and whether the launch is stopping by
the launch's phase (`launcher.fleet.launchphase`); the supervisor tells the fleet what
happened to each process and carries out the actions it gets back: spawn, a timer,
a readiness hold, the stop escalation, SIGKILL. It decides nothing of its own but
the mechanics: pidfds, process groups, pacing, escalation.
"""

from __future__ import annotations

import asyncio
import os
import signal
import subprocess

from collections import deque
from typing import Callable

from launcher.compat import pidfd_open
from launcher.output import console, narrate, screen
from launcher.fleet import launchphase, lifecycle, restart, state
from launcher.fleet.relations import ready_to_stop
from launcher.fleet.actions import carry_out
from launcher.fleet.lifecycle import Event
from launcher.plan.specs import ProcessSpec
from launcher.process.spawn import restore_default_signals_for_children, start_process
from launcher.process.watchdog import group_members

DEFAULT_SIGINT_TIMEOUT = 15.0
DEFAULT_SIGTERM_TIMEOUT = 2.0
# Pacing of SIGINTs at shutdown (see module docstring). ../shared/bench's shutdown --n 100 (roscpp nodes, 2 cores),
# paired ratio to roslaunch: 10 slots 0.77, 15: 0.62, 20: 0.51-0.53, 25: 0.52, 40: 0.75; hold 0.3 s 0.55,
# 0.5 s 0.51-0.53, 1.0 s 0.53.
STOP_CONCURRENCY = 20
STOP_HOLD_S = 0.5
# After SIGKILL a process is gone at once unless stuck in the kernel; don't wait forever.
KILL_WAIT_S = 2.0
MIN_RESPAWN_INTERVAL_S = restart.MIN_RESPAWN_INTERVAL_S  # (the restart policy paces crash loops)
# Leftover members of a group whose leader exited are looked for at this period.
GROUP_POLL_S = 0.02
# The open relays' list is rid of its closed ones when it holds twice what it kept the last time, and this many more.
SCREENS_PRUNED_AT = 16

class NodeProcess:
    """One node's process as the supervisor handles it: the OS side only (its state is the fleet's record).

    A run that ended leaving processes in its group gets a record of its own, a `leftover`, so that
    shutdown stops those too; a leftover has no state in the fleet."""

    # (a plain class: `dataclasses` would be imported while the nodes just spawned need the CPU)
    __slots__ = ("spec", "status", "popen", "pid", "pgid", "pidfd", "exit_code", "alive", "group_alive",
                 "sigkilled", "respawn_handle", "timers", "stopped", "group_poll", "pacing_slot", "screen",
                 "leftover")

    def __init__(self, spec: ProcessSpec, status: state.NodeStatus | None = None, pid: int | None = None,
                 pgid: int | None = None, group_alive: bool = False):
        self.spec = spec
        self.status = status  # the node's view in the fleet (None: a leftover)
        self.leftover = status is None
        self.popen: subprocess.Popen | None = None
        self.pid = pid
        self.pgid = pgid
        self.pidfd: int | None = None
        self.exit_code: int | None = None  # Popen's returncode of the last run (negative: killed by that signal)
        self.alive = False  # the group leader runs
        self.group_alive = group_alive  # the leader or anything left in its process group
        self.sigkilled = False
        self.respawn_handle: asyncio.Handle | None = None  # the timer of a DUE (spawn_delay, respawn delay)
        self.timers: list[asyncio.TimerHandle] = []  # the stop escalation's
        self.stopped: asyncio.Future | None = None  # set when a stop is complete (its group is empty)
        self.group_poll: asyncio.TimerHandle | None = None
        self.pacing_slot = False  # holds one of the shutdown pacing slots
        self.screen: screen.ScreenOutput | None = None  # the current run's relayed output (output/screen.py)

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def spawn_count(self) -> int:
        return self.status.spawn_count if self.status is not None else 0

    @property
    def stopping(self) -> bool:
        return self.stopped is not None and not self.stopped.done()

    def exit_description(self) -> str:
        """roslaunch's words for how the process ended (LocalProcess.get_exit_description)."""
        if self.exit_code is None:
            text = "process has died without exit code [pid %s, cmd %s]." % (self.pid, " ".join(self.spec.argv))
        elif self.exit_code != 0:
            text = "process has died [pid %s, exit code %s, cmd %s]." % (self.pid, self.exit_code,
                                                                         " ".join(self.spec.argv))
        else:
            text = "process has finished cleanly"
        if self.spec.log_dir:
            text += "\nlog file: %s*.log" % os.path.join(self.spec.log_dir, self.spec.log_name)
        return text


def rules_of(spec: ProcessSpec) -> lifecycle.Rules:
    """What the state machine reads of a node of this machine."""
    return lifecycle.Rules(required=spec.required, respawn=spec.respawn, respawn_delay=spec.respawn_delay,
                         policy=spec.policy)


def _exit_code_and_signal(returncode: int | None) -> tuple[int | None, int | None]:
    """Popen's returncode (negative: killed by that signal) as (exit code, signal)."""
    if returncode is not None and returncode < 0:
        return None, -returncode
    return returncode, None


def _group_exists(pgid: int) -> bool:
    """Does the process group still have a live member? (Zombies don't count.)

    An orphaned member that has exited stays a zombie until init reaps it,
    which some inits do only now and then; waiting for that would stall a
    shutdown for nothing. `killpg(pgid, 0)` answers the common case (no member
    at all) with one syscall; only if it succeeds are the members looked up.
    """
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    if not os.path.isdir("/proc"):
        return True
    return bool(group_members({pgid}, sessions=False))


def _signal_group(pgid: int | None, sig: int) -> None:
    if pgid is None:
        return
    try:
        os.killpg(pgid, sig)
    except (ProcessLookupError, PermissionError):
        pass


class Supervisor:
    """Runs and watches a set of nodes on the running asyncio loop.

    `done` (the fleet's) is set when the launch should end on its own: a required node died
    or could not start, a FATAL node has on_fatal="shutdown", or (with `exit_when_all_dead`,
    i.e. an external master, as roslaunch) every node has exited and none will respawn.
    """

    def __init__(self, *, sigint_timeout: float = DEFAULT_SIGINT_TIMEOUT,
                 sigterm_timeout: float = DEFAULT_SIGTERM_TIMEOUT, exit_when_all_dead: bool = True,
                 watchdog=None, stop_concurrency: int = STOP_CONCURRENCY, stop_hold: float = STOP_HOLD_S,
                 on_spawn: Callable[[NodeProcess], None] | None = None, fleet: state.Fleet | None = None,
                 relay_output: bool = True):
        self.loop = asyncio.get_running_loop()
        restore_default_signals_for_children()
        self.sigint_timeout = sigint_timeout
        self.sigterm_timeout = sigterm_timeout
        self.watchdog = watchdog
        self.stop_concurrency = max(1, stop_concurrency)
        self.stop_hold = stop_hold
        self.on_spawn = on_spawn
        # every node's state (the supervisor tells it what happened; it tells the console)
        self.fleet = narrate.attach(fleet if fleet is not None else state.Fleet(warn=console.printerrlog))
        self.fleet.clock = self.loop.time
        self.fleet.exit_when_all_dead = exit_when_all_dead
        self.procs: list[NodeProcess] = []
        self._by_name: dict[str, NodeProcess] = {}
        # terminal-bound node output goes through the launcher (output/screen.py); False: nodes inherit the
        # terminal, as under roslaunch
        self.relay_output = relay_output
        self.screens: list[screen.ScreenOutput] = []  # relays still open (a run's leftovers may hold one)
        self._screens_pruned_at = SCREENS_PRUNED_AT  # (the closed ones are dropped when the list reaches this)
        self.shutdown_errors: list[str] = []
        self._pacing_active = 0
        self._pacing_queue: deque[NodeProcess] = deque()
        # health hooks (see "health" below): what holds a node's start, and what watches each run
        self.readiness = None  # health/readiness.Readiness: holds nodes that have wait_for conditions
        self.watchers: list = []  # objects with started(proc) and exiting(proc): hang detection, core dumps
        self._deferred: list[NodeProcess] = []  # at shutdown, nodes waiting for their dependents to be down

    @property
    def done(self) -> asyncio.Event:
        return self.fleet.done

    @property
    def shutting_down(self) -> bool:
        """The launch's nodes are being stopped: its phase says (fleet.launchphase), for every runner and watcher."""
        return self.fleet.stopping

    @property
    def exit_status(self) -> int:
        return self.fleet.exit_status

    @property
    def required_failed(self) -> bool:
        """A node ended the launch with a failure (a required node's non-zero exit, or a failed start)."""
        return self.fleet.exit_status != 0

    # ---- telling the fleet, and doing what it says ----------------------------------------------------

    def _tell(self, proc: NodeProcess, event: Event) -> list[lifecycle.Action]:
        """Tell the fleet; carry out what it says, for this node and for the nodes its change concerns (bound to
        it: the fleet's relations decide)."""
        if proc.leftover:
            return []  # (a late timer or watcher of a node a reload removed: no longer the fleet's)
        return self.fleet.step(proc.spec.node_name, event, self._carry_out)

    def _carry_out(self, name: str, actions: list[lifecycle.Action]) -> None:
        proc = self._by_name.get(name)
        if proc is not None:
            carry_out(self, proc, actions)

    def _related(self, names) -> list[NodeProcess]:
        """The processes of the named nodes (the fleet's relations name them)."""
        procs = (self._by_name.get(n) for n in names)
        return [p for p in procs if p is not None and not p.leftover]

    def _state(self, proc: NodeProcess) -> str:
        return self.fleet.records[proc.spec.node_name].state

    # ---- the node table's actions (fleet.actions.ActionRunner) ------------------------------------------

    def launch(self, proc: NodeProcess) -> None:
        """(LAUNCH is for a node of another machine: none runs here.)"""

    def hold(self, proc: NodeProcess) -> None:
        if self.readiness is None:
            self._tell(proc, Event(lifecycle.READY))
        else:
            self.readiness.hold(proc)

    def kill(self, proc: NodeProcess) -> None:
        _signal_group(proc.pgid, signal.SIGKILL)

    def schedule(self, proc: NodeProcess, delay: float) -> None:
        if delay == 0.0:
            # on the next turn of the loop, not now: the change that asked for it is still being told
            proc.respawn_handle = self.loop.call_soon(self._due, proc)
        else:
            proc.respawn_handle = self.loop.call_later(delay, self._due, proc)

    def _due(self, proc: NodeProcess) -> None:
        proc.respawn_handle = None
        if self.fleet.starts_allowed:
            self._tell(proc, Event(lifecycle.DUE))

    def cancel(self, proc: NodeProcess) -> None:
        if proc.respawn_handle is not None:
            proc.respawn_handle.cancel()
            proc.respawn_handle = None
        if self.readiness is not None:
            self.readiness.drop(proc)

    # ---- starting ---------------------------------------------------------------------------------

    def _record(self, spec: ProcessSpec) -> NodeProcess:
        self.fleet.add(spec.node_name, process=spec.name, rules=rules_of(spec))
        proc = NodeProcess(spec, self.fleet.nodes[spec.node_name])
        earlier = self._by_name.get(spec.node_name)
        if earlier is not None:
            # a node given again (a remote child's parent starts it anew, as talker-3): the new record
            # speaks for the node; the earlier one only has its process group to stop at shutdown
            earlier.leftover, earlier.status = True, None
        self.procs.append(proc)
        self._by_name[spec.node_name] = proc
        return proc

    def start(self, spec: ProcessSpec) -> NodeProcess | None:
        """Start a node (now, or after its spawn_delay or wait_for). A failure is reported by name and
        the rest carry on (unless required). None if it could not start and will not be tried again."""
        proc = self._record(spec)
        self._tell(proc, Event(lifecycle.START))
        return None if self._state(proc) in (lifecycle.EXITED, lifecycle.FATAL) else proc

    def add(self, spec: ProcessSpec) -> NodeProcess:
        """A node that is not started now (`--no-start`): stopped until an operator starts it."""
        proc = self._record(spec)
        self._tell(proc, Event(lifecycle.KEEP_STOPPED))
        return proc

    def not_started(self, name: str, required: bool = False) -> None:
        """A node whose command could not be made (already reported by name): what that means for the launch."""
        if required:
            console.printerrlog(narrate.BAR + "REQUIRED process [%s] could not be started!\nInitiating shutdown!\n"
                                % name + narrate.BAR)
        self.fleet.not_started(required)

    def registrations_complete(self) -> None:
        """Every node of the launch has been started (or failed to)."""
        self.fleet.registrations_complete()

    def spawn(self, proc: NodeProcess) -> None:
        """Start the node's process; a start that fails is a run that ended at once."""
        append = proc.spawn_count > 0
        channels = self._open_channels(proc.spec)
        popen = start_process(proc.spec, self.watchdog, append=append, channels=channels)
        if channels is not None:
            if popen is None:
                channels.close()
            else:
                self._relay(proc, channels, append)
        if popen is None:
            self._tell(proc, Event(lifecycle.SPAWN_FAILED))
            return
        self._watch(proc, popen)
        self._tell(proc, Event(lifecycle.SPAWNED, pid=popen.pid, process=proc.spec.name))
        if self.on_spawn is not None:
            self.on_spawn(proc)
        for watcher in self.watchers:
            watcher.started(proc)

    def _open_channels(self, spec: ProcessSpec) -> screen.Channels | None:
        if not self.relay_output:
            return None
        try:
            return screen.open_channels(spec.output)
        except OSError as e:  # (out of descriptors) the node still runs, writing to the terminal itself
            console.printerrlog("[%s] cannot relay its output (%s): it writes to the terminal directly, and "
                                "no file keeps that output" % (spec.name, e.strerror))
            return None

    def _relay(self, proc: NodeProcess, channels: screen.Channels, append: bool) -> None:
        spec = proc.spec
        # a screen node's copy starts afresh as a log node's file does (roslaunch: kept across respawns);
        # a log node's stderr joins the file its stdout is written to
        truncate = spec.output == "screen" and not (append or spec.respawn)
        proc.screen = screen.ScreenOutput(self.loop, spec.name, channels.sources, spec.stdout_path, truncate,
                                              spec.node_name)
        self.screens.append(proc.screen)
        if len(self.screens) >= self._screens_pruned_at:
            # (once the list has doubled since the last time: a scan at every spawn made a start of n nodes
            # O(n^2), 5,000 checks for 100 nodes, half a million for 1,000)
            self.screens = [s for s in self.screens if not s.closed]
            self._screens_pruned_at = 2 * len(self.screens) + SCREENS_PRUNED_AT

    def _watch(self, proc: NodeProcess, popen: subprocess.Popen) -> None:
        if proc.group_alive and proc.pgid is not None and not proc.alive:
            # the previous run left processes in its group: keep them on the list to stop at shutdown
            self.procs.append(NodeProcess(proc.spec, pid=proc.pid, pgid=proc.pgid, group_alive=True))
        proc.popen = popen
        proc.pid = proc.pgid = popen.pid
        proc.exit_code = None
        proc.alive = proc.group_alive = True
        proc.sigkilled = False
        try:
            proc.pidfd = pidfd_open(popen.pid)
            self.loop.add_reader(proc.pidfd, self._on_exit, proc)
        except OSError:
            # pidfd unavailable (very old kernel): fall back to a waiter thread
            proc.pidfd = None
            self.loop.run_in_executor(None, popen.wait).add_done_callback(
                lambda _f, p=proc, po=popen: self.loop.call_soon(self._on_exit, p, po))

    # ---- watching ---------------------------------------------------------------------------------

    def _on_exit(self, proc: NodeProcess, popen: subprocess.Popen | None = None) -> None:
        if popen is not None and popen is not proc.popen:
            return  # a stale notification from an earlier run of this node
        for watcher in self.watchers:
            watcher.exiting(proc)  # (before the process is reaped: a watcher may still look at it)
        if proc.pidfd is not None:
            self.loop.remove_reader(proc.pidfd)
            os.close(proc.pidfd)
            proc.pidfd = None
        if proc.screen is not None:
            proc.screen.drain()  # what the node wrote comes before the launcher's words about its exit
            proc.screen = None
        rc = proc.popen.poll() if proc.popen is not None else None
        if rc is None and proc.popen is not None:
            rc = proc.popen.wait()
        proc.exit_code = rc
        proc.alive = False
        self._check_group(proc)
        if not proc.leftover:  # (a record given over to a newer one speaks for the node no more)
            code, sig = _exit_code_and_signal(rc)
            self._tell(proc, Event(lifecycle.PROCESS_EXITED, exit_code=code, exit_signal=sig,
                                   detail=proc.exit_description()))
        if proc.stopping:
            self._stopping_progress(proc)

    def _check_group(self, proc: NodeProcess) -> bool:
        """Is anything left in the node's process group? Forget it in the guard when not."""
        if proc.pgid is not None and proc.group_alive and not _group_exists(proc.pgid):
            proc.group_alive = False
            if self.watchdog is not None:
                self.watchdog.forget(proc.pgid)
        return proc.group_alive

    # ---- health: held starts, restarts and flags asked for by a watcher -------------------------------

    def release(self, proc: NodeProcess) -> None:
        """A held node's wait_for conditions are met: start it now."""
        if self.fleet.starts_allowed:
            self._tell(proc, Event(lifecycle.READY))

    def output_path(self, node_name: str) -> str | None:
        """The file that holds a node's output (readiness' `output:` conditions), None for no node here."""
        proc = self.node(node_name)
        return proc.spec.stdout_path if proc is not None else None

    def give_up_waiting(self, proc: NodeProcess, why: str) -> None:
        """A held node's conditions were not met in time: it failed to start (a required one ends the launch)."""
        self._tell(proc, Event(lifecycle.NOT_READY, reason=why))

    def hung(self, proc: NodeProcess, reason: str) -> None:
        """The hang probe's verdict on the current run: reported, and the run killed."""
        if proc.alive and not self.shutting_down:
            self._tell(proc, Event(lifecycle.HANG, reason=reason))

    def stalled(self, proc: NodeProcess, reason: str) -> None:
        """The stall watch's verdict on the current run (health/stall.py): reported, and killed unless
        its on_stall is "warn"."""
        if proc.alive and not self.shutting_down:
            self._tell(proc, Event(lifecycle.STALL, reason=reason))

    def unstalled(self, proc: NodeProcess, reason: str) -> None:
        if proc.alive and not self.shutting_down:
            self._tell(proc, Event(lifecycle.UNSTALL, reason=reason))

    def restart(self, proc: NodeProcess, reason: str) -> None:
        """Kill the node's current run and start it again, respawn or not (`on_limit="restart"`): at once
        rather than by the stop escalation, as a node past its memory limit may be taking the machine down."""
        if proc.alive and not self.shutting_down:
            self._tell(proc, Event(lifecycle.RESTART, reason=reason))

    def limit_crossed(self, proc: NodeProcess, limit: str, maximum: float | None, what: str) -> None:
        """The node's run went over `limit` ("memory_limit", "cpu_limit"; `maximum` its value) or, with
        `maximum` None, back under it (on_limit="warn"): said on the console and recorded in its state."""
        if not proc.alive:
            return
        over = dict(self.fleet.records[proc.spec.node_name].over_limit)
        if maximum is not None:
            over[limit] = maximum
            reason, detail = "over %s: %s" % (limit, what), "WARNING: " + what
        else:
            over.pop(limit, None)
            reason, detail = "back under %s: %s" % (limit, what), "back under its %s: %s" % (limit, what)
        self._tell(proc, Event(lifecycle.LIMIT, over_limit=tuple(over.items()), reason=reason, detail=detail))

    # ---- stopping ---------------------------------------------------------------------------------

    def begin_stop(self, proc: NodeProcess) -> None:
        """The stop escalation of one node, on its own clock: at shutdown through the pacing queue."""
        if proc.stopped is None or proc.stopped.done():
            proc.stopped = self.loop.create_future()
        if self.shutting_down:
            self._pacing_queue.append(proc)
        else:
            self._signal_stop(proc)

    def _signal_stop(self, proc: NodeProcess) -> None:
        _signal_group(proc.pgid, signal.SIGINT)
        # the node's own sigint_timeout (its NodePolicy), else the command line's
        sigint_timeout = proc.spec.policy.sigint_timeout or self.sigint_timeout
        proc.timers.append(self.loop.call_later(sigint_timeout, self._escalate_term, proc))
        if not proc.alive:
            self._stopping_progress(proc)  # only leftovers of the group: watch them

    async def shutdown(self) -> list[str]:
        """Stop every node (reverse start order, paced SIGINTs, per-node escalation); return the errors.

        A node that another running node waited for (`wait_for="node:..."`, `bind_to`) is stopped once
        that one is down: a controller spawner stops before its controller manager, a nodelet loader before
        its manager. Nodes with no such relation stop together, as before.

        The launch's runner has stepped its phase to stopping (STOP_ALL is this call); a supervisor that is its
        own launch's runner (a remote child, a test) steps it here."""
        own = not self.fleet.stopping
        if own:
            self.fleet.launch_step(launchphase.STOP)
        relations = self.fleet.relations  # (the order: a node after the nodes that wait for it)
        self._deferred = []
        alive = {p.spec.node_name for p in self.procs if p.alive and not p.leftover}
        ready = set(ready_to_stop(relations, (p.spec.node_name for p in self.procs if not p.leftover), alive))
        for p in reversed(self.procs):
            if p.leftover or p.spec.node_name in ready:
                self._shut(p)
            else:
                self._deferred.append(p)
        self._pace()
        while True:
            stopping = [p.stopped for p in self.procs if p.stopping]
            if not stopping and not self._deferred:
                break
            if stopping:  # (woken at each end only while a deferred node may become ready: n waits on n ends else)
                await asyncio.wait(stopping, return_when=asyncio.FIRST_COMPLETED if self._deferred
                                   else asyncio.ALL_COMPLETED)
            busy = {p.spec.node_name for p in self.procs if (p.alive or p.stopping) and not p.leftover}
            names = set(ready_to_stop(relations, (p.spec.node_name for p in self._deferred), busy))
            ready = [p for p in self._deferred if p.spec.node_name in names]
            if not ready and not any(p.stopping for p in self.procs):
                ready = list(self._deferred)  # (nothing left to wait for)
            for p in ready:
                self._deferred.remove(p)
                self._shut(p)
            self._pace()
        if self.shutdown_errors:
            console.printerrlog("Shutdown errors:\n" + "\n".join(" * %s" % e for e in self.shutdown_errors))
        if own:
            self.fleet.launch_step(launchphase.ALL_STOPPED)
        return self.shutdown_errors

    def _shut(self, p: NodeProcess) -> None:
        if not p.leftover:
            self._tell(p, Event(lifecycle.SHUTDOWN))
        if not p.stopping and (p.alive or (p.group_alive and self._check_group(p))):
            # a leftover group (or what an ended run left in its group): stopped as a node is
            console.printlog("[%s] killing on exit" % p.name)
            p.stopped = self.loop.create_future()
            self._pacing_queue.append(p)

    def _pace(self) -> None:
        while self._pacing_queue and self._pacing_active < self.stop_concurrency:
            p = self._pacing_queue.popleft()
            if not p.stopping or p.timers:  # (done already, or its escalation runs: an operator's stop)
                continue
            self._pacing_active += 1
            p.pacing_slot = True
            p.timers.append(self.loop.call_later(self.stop_hold, self._release_slot, p))
            self._signal_stop(p)

    def _release_slot(self, p: NodeProcess) -> None:
        if p.pacing_slot:
            p.pacing_slot = False
            self._pacing_active -= 1
            self._pace()

    def _escalate_term(self, p: NodeProcess) -> None:
        if not p.stopping:
            return
        console.printerrlog("[%s] escalating to SIGTERM" % p.name)
        _signal_group(p.pgid, signal.SIGTERM)
        sigterm_timeout = p.spec.policy.sigterm_timeout or self.sigterm_timeout
        p.timers.append(self.loop.call_later(sigterm_timeout, self._escalate_kill, p))

    def _escalate_kill(self, p: NodeProcess, quiet: bool = False) -> None:
        if not p.stopping or p.sigkilled:
            return
        if not quiet:
            console.printerrlog("[%s] escalating to SIGKILL" % p.name)
        self.shutdown_errors.append("process[%s, pid %s]: required SIGKILL. May still be running." % (p.name, p.pid))
        p.sigkilled = True
        _signal_group(p.pgid, signal.SIGKILL)
        p.timers.append(self.loop.call_later(KILL_WAIT_S, self._finish_stop, p))

    def _stopping_progress(self, p: NodeProcess) -> None:
        """The leader exited while stopping: done once its group is empty too."""
        if not p.stopping or p.alive:
            return
        if self._check_group(p):
            if p.group_poll is None:
                p.group_poll = self.loop.call_later(GROUP_POLL_S, self._poll_group, p)
            return
        self._finish_stop(p)

    def _poll_group(self, p: NodeProcess) -> None:
        p.group_poll = None
        self._stopping_progress(p)

    def _finish_stop(self, p: NodeProcess) -> None:
        for t in p.timers:
            t.cancel()
        p.timers.clear()
        if p.group_poll is not None:
            p.group_poll.cancel()
            p.group_poll = None
        self._release_slot(p)
        if p.stopping:
            p.stopped.set_result(None)
            if not p.leftover and self._state(p) == lifecycle.STOPPING:
                code, sig = _exit_code_and_signal(p.exit_code)
                self._tell(p, Event(lifecycle.DOWN, exit_code=code, exit_signal=sig, killed=p.sigkilled))

    def kill_now(self) -> list[str]:
        """A second Ctrl-C: SIGKILL to every node still stopping (and to those waiting for their turn); their
        process names."""
        for p in self._deferred:
            self._shut(p)
        self._deferred = []
        killed = []
        for p in self.procs:
            if p.stopping:
                killed.append(p.name)
                self._escalate_kill(p, quiet=True)
        return killed

    # ---- operator control: start, stop, restart one node by name (launcher start|stop|restart) --------

    def node(self, node_name: str) -> NodeProcess | None:
        """The node's process record (not one of the leftover groups of earlier runs)."""
        return self._by_name.get(node_name)

    def start_node(self, node_name: str) -> bool:
        """Start a node that is not running (a pending start happens now, a FATAL one gets a clean slate);
        False if it runs or is being stopped."""
        proc = self.node(node_name)
        if proc is None or self.shutting_down:
            return False
        return bool(self._tell(proc, Event(lifecycle.OPERATOR_START)))

    def stop_node(self, node_name: str) -> asyncio.Future | None:
        """Stop a node with the shutdown escalation (SIGINT, SIGTERM, SIGKILL) and keep it stopped: a
        respawning node is not restarted. A future done once it is down; None if it was not running."""
        proc = self.node(node_name)
        return None if proc is None else self.stop_process(proc)

    def stop_process(self, proc: NodeProcess) -> asyncio.Future | None:
        """`stop_node` of one record (a remote child, given nodes again by later `launch` calls, holds
        several records of one node and stops the one its parent names)."""
        if proc.stopping:
            return proc.stopped  # already being stopped
        bound = self.fleet.unbind(proc.spec.node_name, self._carry_out)  # (the nodes bound to it: stopped first)
        if bound:
            return asyncio.ensure_future(self._stop_bound_first(proc, self._related(bound)))
        self._tell(proc, Event(lifecycle.STOP))
        return proc.stopped if proc.stopping else None

    async def _stop_bound_first(self, proc: NodeProcess, bound: list[NodeProcess]) -> None:
        """An operator's stop of a node others are bound to: they are being stopped first (the fleet's
        `unbind`: a nodelet's loader unloads it from its manager), then it; they start again after its next
        start."""
        try:
            stopping = [b.stopped for b in bound if b.stopping]
            if stopping:
                await asyncio.wait(stopping)
        finally:
            self.fleet.bound_stopped(proc.spec.node_name)
        if not proc.stopping:
            self._tell(proc, Event(lifecycle.STOP))
        if proc.stopping:
            await proc.stopped

    async def restart_node(self, node_name: str) -> bool:
        stopping = self.stop_node(node_name)
        if stopping is not None:
            await stopping
        return self.start_node(node_name)

    # ---- a reload: nodes changed, added and removed (services/nodeservice.py applies plan/diff) ------------

    def reload_stop(self, node_name: str, reason: str) -> asyncio.Future | None:
        """Stop a node a reload changed or removed, as an operator's stop does but for `reason` (its record
        is the launch's again afterwards: renewed or removed). A future done once it is down; None if it was
        not running."""
        proc = self.node(node_name)
        if proc is None or proc.stopping:
            return None if proc is None else proc.stopped
        self._tell(proc, Event(lifecycle.RELOAD_STOP, reason=reason))
        return proc.stopped if proc.stopping else None

    def renew(self, spec: ProcessSpec, reason: str) -> None:
        """A node a reload changed, stopped already: its new spec, made anew and started as a new node is."""
        proc = self.node(spec.node_name)
        if proc is None or self.shutting_down:
            return
        proc.spec = spec
        self._tell(proc, Event(lifecycle.RENEW, rules=rules_of(spec), reason=reason))
        self._tell(proc, Event(lifecycle.START))

    def new_rules(self, spec: ProcessSpec, reason: str) -> None:
        """A node whose supervision settings alone a reload changed: they hold from its next decision on (its
        process runs on, with the command line it has)."""
        proc = self.node(spec.node_name)
        if proc is None:
            return
        proc.spec.respawn, proc.spec.respawn_delay = spec.respawn, spec.respawn_delay
        proc.spec.required, proc.spec.policy = spec.required, spec.policy
        self._tell(proc, Event(lifecycle.RULES, rules=rules_of(spec), reason=reason))

    def remove(self, node_name: str) -> None:
        """A node a reload took out of the launch, stopped already: its process record only has its process
        group left to stop at shutdown (if anything of it lingers)."""
        proc = self._by_name.pop(node_name, None)
        if proc is not None:
            proc.leftover, proc.status = True, None
            self.fleet.remove(node_name)

    def close(self) -> None:
        """Drop loop registrations (after shutdown)."""
        for relay in self.screens:
            relay.close()
        self.screens.clear()
        for p in self.procs:
            if p.pidfd is not None:
                try:
                    self.loop.remove_reader(p.pidfd)
                    os.close(p.pidfd)
                except (OSError, ValueError):
                    pass
                p.pidfd = None
