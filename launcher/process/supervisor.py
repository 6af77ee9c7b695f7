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
(bench/BASELINE.md); pacing keeps the CPU busy without thrashing, while a node
that ignores SIGINT only holds its pacing slot for `stop_hold`, so the total
stays bounded by the slowest node rather than by the number of nodes.

The SIGKILL step is not theoretical: a rospy node that gets SIGINT while its main thread is
inside a master call (init_node makes several; so does any rospy.get_param) deadlocks in its
own handler, which unregisters through the same non-reentrant proxy lock; its SIGTERM handler
is the same code. Only SIGKILL ends it, after sigint_timeout + sigterm_timeout, as roslaunch
does (checked side by side); sending SIGINT again would not help.

A node's `NodePolicy` (`spec.policy`; the default one is roslaunch's behaviour) adds to this:
a delayed first start (`spawn_delay`), per-node stop timeouts, and the restart policy
(`launcher.process.restart`, the same decision for the nodes of other machines), applied in
`_run_ended`: `respawn_on="failure"` with `success_exit_codes`; a delay that grows by
`respawn_backoff` with each failed start in a row (a run shorter than `respawn_min_uptime`)
up to `respawn_delay_max`; and after `respawn_max_retries` restarts that failed in a row, the
node is FATAL (kept in the fleet's status, not restarted), which ends the launch with status 1
when `on_fatal="shutdown"`.
"""

from __future__ import annotations

import asyncio
import os
import signal
import subprocess
import time
from collections import deque
from typing import Callable

from launcher.process import console, restart, screen, state
from launcher.process.spawn import ProcessSpec, restore_default_signals_for_children, start_process
from launcher.process.watchdog import group_members

DEFAULT_SIGINT_TIMEOUT = 15.0
DEFAULT_SIGTERM_TIMEOUT = 2.0
# Pacing of SIGINTs at shutdown (see module docstring). bench.py shutdown --n 100 (roscpp nodes, 2 cores),
# paired ratio to roslaunch: 10 slots 0.77, 15: 0.62, 20: 0.51-0.53, 25: 0.52, 40: 0.75; hold 0.3 s 0.55,
# 0.5 s 0.51-0.53, 1.0 s 0.53.
STOP_CONCURRENCY = 20
STOP_HOLD_S = 0.5
# After SIGKILL a process is gone at once unless stuck in the kernel; don't wait forever.
KILL_WAIT_S = 2.0
MIN_RESPAWN_INTERVAL_S = restart.MIN_RESPAWN_INTERVAL_S  # (the restart policy paces crash loops)
# Leftover members of a group whose leader exited are looked for at this period.
GROUP_POLL_S = 0.02


class NodeProcess:
    """One supervised node: its spec and the state of its current OS process."""

    # (a plain class: `dataclasses` would be imported while the nodes just spawned need the CPU)
    __slots__ = ("spec", "popen", "pid", "pgid", "pidfd", "exit_code", "spawn_count", "started_at", "alive",
                 "group_alive", "stopping", "sigkilled", "respawn_handle", "respawn_at", "timers", "stopped",
                 "group_poll", "pacing_slot", "failures", "restarts", "restart_warned", "held", "restart_reason",
                 "screen")

    def __init__(self, spec: ProcessSpec, pid: int | None = None, pgid: int | None = None,
                 group_alive: bool = False):
        self.spec = spec
        self.popen: subprocess.Popen | None = None
        self.pid = pid
        self.pgid = pgid
        self.pidfd: int | None = None
        self.exit_code: int | None = None
        self.spawn_count = 0
        self.started_at = 0.0  # loop time of the latest start
        self.alive = False  # the group leader runs
        self.group_alive = group_alive  # the leader or anything left in its process group
        self.stopping = False
        self.sigkilled = False
        self.respawn_handle: asyncio.TimerHandle | None = None
        self.respawn_at = 0.0  # loop time of the next start, when respawning
        self.timers: list[asyncio.TimerHandle] = []
        self.stopped: asyncio.Future | None = None  # set when the group is empty during shutdown
        self.group_poll: asyncio.TimerHandle | None = None
        self.pacing_slot = False  # holds one of the shutdown pacing slots
        self.failures = 0  # failed starts in a row (runs shorter than respawn_min_uptime)
        self.restarts = 0  # starts after the first (restart_warn_threshold counts them)
        self.restart_warned = False
        self.held = False  # not started yet: its wait_for conditions are not met (process/readiness.py)
        self.restart_reason = ""  # set when the supervisor kills the run in order to start it again
        self.screen: screen.ScreenOutput | None = None  # the current run's relayed output (process/screen.py)

    @property
    def name(self) -> str:
        return self.spec.name

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


def _exit_status(returncode: int | None) -> int:
    """A shell's exit status for a process's Popen returncode: the code, or 128 + the killing signal."""
    if returncode is None:
        return 1
    return 128 - returncode if returncode < 0 else returncode


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

    `done` is set when the launch should end on its own: a required node died
    or could not start, or (with `exit_when_all_dead`, i.e. an external master,
    as roslaunch) every node has exited and none will respawn.
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
        self.exit_when_all_dead = exit_when_all_dead
        self.watchdog = watchdog
        self.stop_concurrency = max(1, stop_concurrency)
        self.stop_hold = stop_hold
        self.on_spawn = on_spawn
        self.fleet = fleet if fleet is not None else state.Fleet()  # every node's state: the supervisor writes it
        self.procs: list[NodeProcess] = []
        # terminal-bound node output goes through the launcher (process/screen.py); False: nodes inherit the
        # terminal, as under roslaunch
        self.relay_output = relay_output
        self.screens: list[screen.ScreenOutput] = []  # relays still open (a run's leftovers may hold one)
        self.done = asyncio.Event()
        # a required node exited non-zero / by signal or could not start, or a FATAL node has on_fatal="shutdown"
        # the launch's exit status when a node ended it: a required node's own exit code (128 + the
        # signal when one killed it, as ROS-O's roslaunch, ros/ros_comm#2082), 1 for a start that failed
        self.exit_status = 0
        self.shutdown_errors: list[str] = []
        self.shutting_down = False
        self._registrations_complete = False
        self._any_died = False
        self._pacing_active = 0
        self._pacing_queue: deque[NodeProcess] = deque()
        # health hooks (see "health" below): what holds a node's start, and what watches each run
        self.readiness = None  # process/readiness.Readiness: holds nodes that have wait_for conditions
        self.watchers: list = []  # objects with started(proc) and exiting(proc): hang detection, core dumps

    @property
    def required_failed(self) -> bool:
        """A node ended the launch with a failure (a required node's non-zero exit, or a failed start)."""
        return self.exit_status != 0

    # ---- starting ---------------------------------------------------------------------------------

    def start(self, spec: ProcessSpec) -> NodeProcess | None:
        """Spawn a node now. A failure is reported by name and the rest carry on (unless required).

        None if it could not start and will not be tried again (a respawning node will be).
        """
        proc = NodeProcess(spec)
        self.procs.append(proc)
        self.fleet.add(spec.node_name, process=spec.name)
        delay = spec.policy.spawn_delay
        if delay > 0:
            # held like a pending respawn: shutdown cancels it, and the launch is not "all dead" meanwhile
            console.printlog("[%s] waiting %g s before starting (spawn_delay)" % (spec.name, delay))
            proc.respawn_at = self.loop.time() + delay
            proc.respawn_handle = self.loop.call_later(delay, self._delayed_start, proc)
            self.fleet.change(spec.node_name, state.WAITING, reason="spawn_delay %g s" % delay)
            return proc
        if self._hold_until_ready(proc):
            return proc
        self._start(proc)
        return proc if proc.alive or proc.respawn_handle is not None else None

    def _delayed_start(self, proc: NodeProcess) -> None:
        proc.respawn_handle = None
        if self.shutting_down or self.done.is_set():
            return
        if not self._hold_until_ready(proc):
            self._start(proc)

    def _hold_until_ready(self, proc: NodeProcess) -> bool:
        """Hand a first start with wait_for conditions to the readiness watch (True), which starts it later."""
        if self.readiness is None or not proc.spec.policy.wait_for:
            return False
        proc.held = True
        self.readiness.hold(proc)
        return True

    def not_started(self, name: str, required: bool = False) -> None:
        """A node that was never started (already reported by name): what that means for the launch."""
        if required:
            self._required_gone(name, "could not be started")
        else:
            self._any_died = True  # counts as ended, like a failed exec (external master: all ended -> exit)
            self._check_all_dead()

    def registrations_complete(self) -> None:
        """Every node of the launch has been started (or failed to)."""
        self._registrations_complete = True
        self._check_all_dead()

    def _start(self, proc: NodeProcess, append: bool = False) -> None:
        """Start the node's process; a start that fails is a run that ended at once (`_run_ended`)."""
        channels = self._open_channels(proc.spec)
        popen = start_process(proc.spec, self.watchdog, append=append, channels=channels)
        if channels is not None:
            if popen is None:
                channels.close()
            else:
                self._relay(proc, channels, append)
        if popen is None:
            proc.started_at = self.loop.time()  # (paces the retries of a respawning node)
            self._run_ended(proc, started=False)
            return
        self._watch(proc, popen, self.loop.time())

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
        proc.screen = screen.ScreenOutput(self.loop, spec.name, channels.sources, spec.stdout_path, truncate)
        self.screens = [s for s in self.screens if not s.closed]
        self.screens.append(proc.screen)

    def _watch(self, proc: NodeProcess, popen: subprocess.Popen, started_at: float) -> None:
        if proc.group_alive and proc.pgid is not None and not proc.alive:
            # the previous run left processes in its group: keep them on the list to stop at shutdown
            self.procs.append(NodeProcess(proc.spec, pid=proc.pid, pgid=proc.pgid, group_alive=True))
        proc.spawn_count += 1
        proc.popen = popen
        proc.pid = proc.pgid = popen.pid
        proc.exit_code = None
        proc.started_at = started_at
        proc.alive = proc.group_alive = True
        self.fleet.change(proc.spec.node_name, state.RUNNING, pid=popen.pid)
        try:
            proc.pidfd = os.pidfd_open(popen.pid)
            self.loop.add_reader(proc.pidfd, self._on_exit, proc)
        except OSError:
            # pidfd unavailable (very old kernel): fall back to a waiter thread
            proc.pidfd = None
            self.loop.run_in_executor(None, popen.wait).add_done_callback(
                lambda _f, p=proc, po=popen: self.loop.call_soon(self._on_exit, p, po))
        if self.on_spawn is not None:
            self.on_spawn(proc)
        for watcher in self.watchers:
            watcher.started(proc)

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
        if proc.stopping or self.shutting_down:
            self._stopping_progress(proc)
            return
        if proc.restart_reason:
            self._restarted(proc)
            return
        self._run_ended(proc)

    def _run_ended(self, proc: NodeProcess, started: bool = True) -> None:
        """The one place where a node's run ends (it exited, or `started` is False: it failed to start)
        and what comes next is decided: the launch ends (required), the node starts again (respawn),
        or it stays down."""
        self._any_died = True
        if proc.spec.required:
            if not started:
                self._required_gone(proc.name, "could not be started")
                return
            console.printerrlog("=" * 80 + "REQUIRED process [%s] has died!\n%s\nInitiating shutdown!\n"
                                % (proc.name, proc.exit_description()) + "=" * 80)
            self.exit_status = _exit_status(proc.exit_code)
            self.done.set()
            return
        if started:
            desc = proc.exit_description()
            if proc.exit_code:
                console.printerrlog("[%s] %s" % (proc.name, desc))
            else:
                console.printlog_bold("[%s] %s" % (proc.name, desc))
        exit_code, exit_signal = _exit_code_and_signal(proc.exit_code) if started else (None, None)
        spec = proc.spec
        decision = restart.after_run(spec.respawn, spec.respawn_delay, spec.policy, exit_code, started,
                                     self.loop.time() - proc.started_at, proc.failures)
        proc.failures = decision.failures
        if decision.action == restart.FATAL:
            self._fatal(proc, exit_code, exit_signal, decision)
            return
        if decision.note:
            console.printlog("[%s] %s" % (proc.name, decision.note))
        if decision.action == restart.STAY_DOWN:
            self._stays_down(proc, state.EXITED, exit_code, exit_signal, decision.reason)
            return
        # recorded before the start is scheduled: a start without delay happens right away, and its
        # `running` must come after this
        self.fleet.change(spec.node_name, state.RESPAWNING, exit_code=exit_code, exit_signal=exit_signal,
                          next_start=time.time() + decision.delay, reason=decision.reason, failures=proc.failures)
        self._schedule_respawn(proc, decision.delay)

    def _stays_down(self, proc: NodeProcess, new_state: str, exit_code: int | None, exit_signal: int | None,
                    reason: str) -> None:
        self.fleet.change(proc.spec.node_name, new_state, exit_code=exit_code, exit_signal=exit_signal,
                          reason=reason, failures=proc.failures)
        self._check_all_dead()

    def _fatal(self, proc: NodeProcess, exit_code: int | None, exit_signal: int | None,
               decision: restart.Decision) -> None:
        """The node failed more starts in a row than respawn_max_retries allows: it stays down, reported."""
        console.printerrlog("[%s] %s" % (proc.name, decision.note))
        if proc.spec.policy.on_fatal == "shutdown":
            self.fleet.change(proc.spec.node_name, state.FATAL, exit_code=exit_code, exit_signal=exit_signal,
                              reason=decision.reason, failures=proc.failures)
            self.fatal_shutdown(proc.name)
            return
        self._stays_down(proc, state.FATAL, exit_code, exit_signal, decision.reason)

    def fatal_shutdown(self, name: str) -> None:
        """A FATAL node with on_fatal="shutdown" (here or on another machine) ends the launch with status 1."""
        console.printerrlog("=" * 80 + "FATAL process [%s] has failed (on_fatal=\"shutdown\")!\n"
                            "Initiating shutdown!\n" % name + "=" * 80)
        self.exit_status = 1
        self.done.set()

    def _check_group(self, proc: NodeProcess) -> bool:
        """Is anything left in the node's process group? Forget it in the guard when not."""
        if proc.pgid is not None and proc.group_alive and not _group_exists(proc.pgid):
            proc.group_alive = False
            if self.watchdog is not None:
                self.watchdog.forget(proc.pgid)
        return proc.group_alive

    def _schedule_respawn(self, proc: NodeProcess, delay: float) -> None:
        proc.respawn_at = self.loop.time() + delay
        if delay == 0.0:
            # on the next turn of the loop, not now: the caller records the node as respawning first,
            # which would otherwise overwrite the new run's "running"
            proc.respawn_handle = self.loop.call_soon(self._respawn, proc)  # type: ignore[assignment]
        else:
            proc.respawn_handle = self.loop.call_later(delay, self._respawn, proc)

    def _respawn(self, proc: NodeProcess) -> None:
        proc.respawn_handle = None
        if self.shutting_down or self.done.is_set():
            return
        console.printlog("[%s] restarting process" % proc.name)
        proc.restarts += 1
        threshold = proc.spec.policy.restart_warn_threshold
        if threshold is not None and proc.restarts > threshold and not proc.restart_warned:
            proc.restart_warned = True  # once: the status keeps counting
            console.printerrlog("[%s] WARNING: restarted %d times, more than its restart_warn_threshold (%d)"
                                % (proc.name, proc.restarts, threshold))
        self._start(proc, append=True)

    def _check_all_dead(self) -> None:
        if not (self.exit_when_all_dead and self._registrations_complete and self._any_died):
            return
        if any(p.alive or p.respawn_handle is not None or p.held for p in self.procs):
            return
        if not self.done.is_set():
            console.printlog("all processes on machine have died, roslaunch will exit")
            self.done.set()

    def end(self, failed: bool) -> None:
        """End the launch for a reason found outside this machine (a required node elsewhere ended);
        `failed`: the launch exits with status 1."""
        if failed and not self.exit_status:
            self.exit_status = 1
        self.done.set()

    def _required_gone(self, name: str, why: str) -> None:
        console.printerrlog("=" * 80 + "REQUIRED process [%s] %s!\nInitiating shutdown!\n" % (name, why) + "=" * 80)
        self.exit_status = 1
        self.done.set()

    # ---- health: held starts, restarts asked for by a watcher ---------------------------------------

    def release(self, proc: NodeProcess) -> None:
        """A held node's wait_for conditions are met: start it now."""
        proc.held = False
        if not (self.shutting_down or self.done.is_set()):
            self._start(proc)

    def give_up_waiting(self, proc: NodeProcess, why: str) -> None:
        """A held node's conditions were not met in time: it failed to start (a required one ends the launch)."""
        proc.held = False
        self.fleet.change(proc.spec.node_name, state.EXITED, reason=why)
        if proc.spec.required:
            self._required_gone(proc.name, "failed to start: " + why)
        else:
            console.printerrlog("[%s] failed to start: %s" % (proc.name, why))
            self.not_started(proc.name)

    def restart(self, proc: NodeProcess, reason: str) -> None:
        """Kill the node's current run and start it again, respawn or not (`on_limit="restart"`)."""
        if not proc.alive or proc.stopping or proc.restart_reason or self.shutting_down:
            return
        console.printerrlog("[%s] restarting: %s" % (proc.name, reason))
        proc.restart_reason = reason
        # at once rather than by the stop escalation: a node past its memory limit may be taking the
        # machine down with it
        _signal_group(proc.pgid, signal.SIGKILL)

    def limit_crossed(self, proc: NodeProcess, limit: str, maximum: float | None, what: str) -> None:
        """The node's run went over `limit` ("memory_limit", "cpu_limit"; `maximum` its value) or, with
        `maximum` None, back under it (on_limit="warn"): said on the console and recorded in its state."""
        status = self.fleet.nodes.get(proc.spec.node_name)
        if status is None or status.state != state.RUNNING or not proc.alive:
            return  # (hung, or being stopped: that state says more)
        over = dict(status.over_limit)
        if maximum is not None:
            over[limit] = maximum
            console.printerrlog("[%s] WARNING: %s" % (proc.name, what))
            reason = "over %s: %s" % (limit, what)
        else:
            over.pop(limit, None)
            console.printlog("[%s] back under its %s: %s" % (proc.name, limit, what))
            reason = "back under %s: %s" % (limit, what)
        self.fleet.change(proc.spec.node_name, state.RUNNING, pid=proc.pid, over_limit=over, reason=reason)

    def _restarted(self, proc: NodeProcess) -> None:
        code, sig = _exit_code_and_signal(proc.exit_code)
        self.fleet.change(proc.spec.node_name, state.RESPAWNING, exit_code=code, exit_signal=sig,
                          next_start=time.time(), reason=proc.restart_reason)
        proc.restart_reason = ""
        if not self.done.is_set():
            self._start(proc, append=True)

    # ---- stopping ---------------------------------------------------------------------------------

    async def shutdown(self) -> list[str]:
        """Stop every node (reverse start order, paced SIGINTs, per-node escalation); return the errors."""
        self.shutting_down = True
        for p in self.procs:
            if p.respawn_handle is not None:
                p.respawn_handle.cancel()
                p.respawn_handle = None
                if not p.alive:
                    self.fleet.change(p.spec.node_name, state.STOPPED, reason="stopped before its next start")
            if p.held:
                p.held = False
                self.fleet.change(p.spec.node_name, state.STOPPED, reason="stopped while waiting to start")
        to_stop = []
        for p in reversed(self.procs):
            if p.alive or (p.group_alive and self._check_group(p)):
                if p.stopped is None or p.stopped.done():  # (an operator's stop in progress goes on)
                    p.stopped = self.loop.create_future()
                to_stop.append(p)
        for p in to_stop:
            console.printlog("[%s] killing on exit" % p.name)
            self._pacing_queue.append(p)
        self._pace()
        if to_stop:
            await asyncio.gather(*(p.stopped for p in to_stop))
        if self.shutdown_errors:
            console.printerrlog("Shutdown errors:\n" + "\n".join(" * %s" % e for e in self.shutdown_errors))
        return self.shutdown_errors

    def _pace(self) -> None:
        while self._pacing_queue and self._pacing_active < self.stop_concurrency:
            p = self._pacing_queue.popleft()
            if p.stopped is None or p.stopped.done():
                continue
            self._pacing_active += 1
            hold = self.loop.call_later(self.stop_hold, self._release_slot, p)
            p.timers.append(hold)
            p.stopping = True
            p.pacing_slot = True
            _signal_group(p.pgid, signal.SIGINT)
            sigint_timeout = p.spec.policy.sigint_timeout or self.sigint_timeout  # (the node's, or the CLI's)
            p.timers.append(self.loop.call_later(sigint_timeout, self._escalate_term, p))
            if not p.alive:
                self._stopping_progress(p)  # only leftovers of the group: watch them

    def _release_slot(self, p: NodeProcess) -> None:
        if p.pacing_slot:
            p.pacing_slot = False
            self._pacing_active -= 1
            self._pace()

    def _escalate_term(self, p: NodeProcess) -> None:
        if p.stopped is None or p.stopped.done():
            return
        console.printerrlog("[%s] escalating to SIGTERM" % p.name)
        _signal_group(p.pgid, signal.SIGTERM)
        sigterm_timeout = p.spec.policy.sigterm_timeout or self.sigterm_timeout
        p.timers.append(self.loop.call_later(sigterm_timeout, self._escalate_kill, p))

    def _escalate_kill(self, p: NodeProcess, quiet: bool = False) -> None:
        if p.stopped is None or p.stopped.done() or p.sigkilled:
            return
        if not quiet:
            console.printerrlog("[%s] escalating to SIGKILL" % p.name)
        self.shutdown_errors.append("process[%s, pid %s]: required SIGKILL. May still be running." % (p.name, p.pid))
        p.sigkilled = True
        _signal_group(p.pgid, signal.SIGKILL)
        p.timers.append(self.loop.call_later(KILL_WAIT_S, self._give_up, p))

    def _give_up(self, p: NodeProcess) -> None:
        self._finish_stop(p)

    def _stopping_progress(self, p: NodeProcess) -> None:
        """The leader exited while stopping: done once its group is empty too."""
        if p.stopped is None or p.stopped.done():
            return
        if p.alive:
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
        if p.stopped is not None and not p.stopped.done():
            p.stopped.set_result(None)
            code, sig = _exit_code_and_signal(p.exit_code)
            self.fleet.change(p.spec.node_name, state.STOPPED, exit_code=code, exit_signal=sig,
                              reason="killed with SIGKILL" if p.sigkilled
                              else "" if self.shutting_down else "stopped by operator")

    def kill_now(self) -> list[str]:
        """A second Ctrl-C: SIGKILL to every node still stopping; their process names."""
        killed = []
        for p in self.procs:
            if p.stopped is not None and not p.stopped.done():
                killed.append(p.name)
                self._escalate_kill(p, quiet=True)
        return killed

    # ---- operator control: start, stop, restart one node by name (launcher start|stop|restart) --------

    def add(self, spec: ProcessSpec) -> NodeProcess:
        """A node that is not started now (`--no-start`): stopped until an operator starts it."""
        proc = NodeProcess(spec)
        self.procs.append(proc)
        self.fleet.add(spec.node_name, process=spec.name)
        self.fleet.change(spec.node_name, state.STOPPED, reason="not started (--no-start)")
        return proc

    def node(self, node_name: str) -> NodeProcess | None:
        """The node's record: the first one made for it (leftover groups of earlier runs come later)."""
        for p in self.procs:
            if p.spec.node_name == node_name:
                return p
        return None

    def start_node(self, node_name: str) -> bool:
        """Start a node that is not running (a pending respawn happens now); False if it already runs."""
        proc = self.node(node_name)
        if proc is None or self.shutting_down:
            return False
        if proc.alive or (proc.stopped is not None and not proc.stopped.done()):
            return False
        if proc.respawn_handle is not None:
            proc.respawn_handle.cancel()
            proc.respawn_handle = None
        proc.stopping = proc.sigkilled = False
        proc.stopped = None
        console.printlog("[%s] starting process (operator)" % proc.name)
        self._start(proc, append=proc.spawn_count > 0)
        return True

    def stop_node(self, node_name: str) -> asyncio.Future | None:
        """Stop a node with the shutdown escalation (SIGINT, SIGTERM, SIGKILL) and keep it stopped: a
        respawning node is not restarted. A future done once it is down; None if it was not running."""
        proc = self.node(node_name)
        return None if proc is None else self.stop_process(proc)

    def stop_process(self, proc: NodeProcess) -> asyncio.Future | None:
        """`stop_node` of one record (a remote child, given nodes again by later `launch` calls, holds
        several records of one node and stops the one its parent names)."""
        if proc.respawn_handle is not None:  # between two runs: just don't start it again
            proc.respawn_handle.cancel()
            proc.respawn_handle = None
            self.fleet.change(proc.spec.node_name, state.STOPPED, reason="stopped by operator")
            return None
        if proc.stopped is not None and not proc.stopped.done():
            return proc.stopped  # already being stopped
        if not proc.alive:
            return None
        console.printlog("[%s] stopping process (operator)" % proc.name)
        proc.stopped = self.loop.create_future()
        proc.stopping = True
        _signal_group(proc.pgid, signal.SIGINT)
        proc.timers.append(self.loop.call_later(self.sigint_timeout, self._escalate_term, proc))
        return proc.stopped

    async def restart_node(self, node_name: str) -> bool:
        stopping = self.stop_node(node_name)
        if stopping is not None:
            await stopping
        return self.start_node(node_name)

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
