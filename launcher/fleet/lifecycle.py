"""One node's lifecycle as a transition table: `step(record, event, now) -> (record, actions)`.

Everything that decides what happens to a node lives here, for every node
wherever it runs: the first start (spawn_delay, wait_for), a run that ends
(the restart policy of `launcher.fleet.restart`, required nodes, FATAL),
operator stop and start, hang and limit flags, the launch's stop, and the
states of a node sent to another machine. It does no I/O and reads no clock:
the runners (`process.supervisor` for this machine, `remote.parent` for the
others) feed it what happened and carry out the actions it returns; the
fleet (`fleet.state.Fleet`) keeps the records and tells every view of each
change. Every pair (state, event) is in one of three: TABLE (what it does),
IGNORED (a report that comes after the state it reports on moved on: nothing)
or REFUSED (no runner sends it: a bug in a runner, raised as `InvalidTransition`).

Internal states, and the state the outside (README, events file, status,
`api.Launch`) sees:

    new         made, not started yet                           waiting
    delayed     spawn_delay runs                                 waiting
    held        wait_for conditions awaited (health/readiness)   waiting
    starting    a spawn is under way (this machine)              waiting
    pending     queued for its machine's child (remote)          waiting
    launching   in a `launch` call to its machine's child        waiting
    running     its process runs                                 running
    hung        no answer to getPid: being killed                hung
    stalled     a watched topic went silent or slow              stalled
    stopping    the stop escalation (or the child's stop) runs   running
    detached    the node it is bound to is down: starts again    stopped
                after that one's next start (bind_to, nodelets)
    respawning  ended; starts again at `next_start`              respawning
    lost        its machine dropped; launched again on return    exited
    exited      ended, not started again                         exited
    fatal       failed too many starts in a row                  fatal
    stopped     stopped by the launch or an operator             stopped
"""

from __future__ import annotations


from launcher.model.config import NodePolicy
from launcher.fleet import restart
from launcher.model.record import record

NEW, DELAYED, HELD, STARTING = "new", "delayed", "held", "starting"
PENDING, LAUNCHING, LOST = "pending", "launching", "lost"
RUNNING, HUNG, STOPPING, STALLED = "running", "hung", "stopping", "stalled"
RESPAWNING, EXITED, FATAL, STOPPED = "respawning", "exited", "fatal", "stopped"
DETACHED = "detached"
STATES = (NEW, DELAYED, HELD, STARTING, PENDING, LAUNCHING, RUNNING, HUNG, STALLED, STOPPING, RESPAWNING, LOST,
          EXITED, FATAL, STOPPED, DETACHED)
PUBLIC = {NEW: "waiting", DELAYED: "waiting", HELD: "waiting", STARTING: "waiting", PENDING: "waiting",
          LAUNCHING: "waiting", RUNNING: "running", HUNG: "hung", STALLED: "stalled", STOPPING: "running", RESPAWNING: "respawning",
          LOST: "exited", EXITED: "exited", FATAL: "fatal", STOPPED: "stopped", DETACHED: "stopped"}
# a node in one of these may still run (or run again without an operator): the launch is not "all dead"
ALIVE = frozenset((NEW, DELAYED, HELD, STARTING, PENDING, LAUNCHING, RUNNING, HUNG, STALLED, STOPPING, RESPAWNING,
                   LOST))
# on the way to running: what comes next (running, or why not) is what a reader outside is told
ON_THE_WAY = frozenset((STARTING, PENDING, LAUNCHING))
# ... and in one of these it ended by itself (what "all processes on machine have died" counts)
ENDED = frozenset((EXITED, FATAL))

# ---- events: what happened (told by a runner, the readiness poll, the hang probe, the resource monitor)
START = "start"  # the launch starts the node (its first start)
KEEP_STOPPED = "keep stopped"  # `--no-start`: made, left for an operator
DUE = "due"  # the timer of a spawn_delay or a respawn delay ran out
READY = "ready"  # its wait_for conditions are met
NOT_READY = "not ready"  # its wait_timeout passed first (reason: what was missing)
SPAWNED = "spawned"  # its process runs (pid); for a remote node, the child said so
SPAWN_FAILED = "spawn failed"  # its process could not be started
PROCESS_EXITED = "process exited"  # its process ended (exit_code or exit_signal)
HANG = "hang"  # no answer to getPid for hang_timeout (reason)
STALL = "stall"  # a watched topic of its own went silent or too slow (reason)
UNSTALL = "unstall"  # it publishes as it should again (on_stall="warn": the process ran on)
RESTART = "restart"  # a limit with on_limit="restart" was crossed: kill this run, start again (reason)
LIMIT = "limit"  # the run's set of limits crossed changed (over_limit)
STOP = "stop"  # an operator's stop
SHUTDOWN = "shutdown"  # the launch stops
DOWN = "down"  # a stop is complete: nothing of the run is left (killed: it needed SIGKILL)
STOP_REFUSED = "stop refused"  # the remote child could not stop it (reason): it runs on
OPERATOR_START = "operator start"  # `launcher start`
LAUNCH_SENT = "launch sent"  # a `launch` call holding it went to its machine's child
LAUNCHED = "launched"  # the child took it (process: the child's process name)
LAUNCH_REFUSED = "launch refused"  # the call failed as a whole: it waits for the machine's next session
LINK_LOST = "link lost"  # its machine's session ended (reason)
MACHINE_FAILED = "machine failed"  # its machine could never be reached (reason)
# the node it is bound to (bind_to, or the manager of a nodelet loader), on this machine:
BOUND_ENDED = "bound ended"  # ... is down: a run of it ended, or it is being stopped (reason)
BOUND_STARTED = "bound started"  # ... runs again
# a reload (run/reload.py) of the launch's files: a node that changed or was removed is stopped (reason),
# a changed one is then made anew with its new rules (and a clean slate: an operator's stop, failures, FATAL
# are the old node's), and a node whose supervision settings alone changed gets them where it stands
RELOAD_STOP = "reload stop"
RENEW = "renew"
RULES = "rules"
# the master's word (health/registration.py): the current run registered with it at `uri` (by the node's name,
# or as a process of its group), or that registration went. A registration is no state of its own: a node
# registered or not is running all the same; the record says which (`registered`, `uri`), and nothing follows
# from it here (readiness, hang and stall probes, systemd's READY=1 listen to the fleet's changes)
REGISTERED = "registered"
UNREGISTERED = "unregistered"
EVENTS = (START, KEEP_STOPPED, DUE, READY, NOT_READY, SPAWNED, SPAWN_FAILED, PROCESS_EXITED, HANG, STALL, UNSTALL,
          RESTART, LIMIT, STOP, SHUTDOWN, DOWN, STOP_REFUSED, OPERATOR_START, LAUNCH_SENT, LAUNCHED, LAUNCH_REFUSED, LINK_LOST,
          MACHINE_FAILED, BOUND_ENDED, BOUND_STARTED, RELOAD_STOP, RENEW, RULES, REGISTERED, UNREGISTERED)

# ---- actions: what the runner carries out
SPAWN = "spawn"  # start the process (this machine)
LAUNCH = "launch"  # hand it to its machine's child at the next opportunity (remote)
SCHEDULE = "schedule"  # call back with DUE after `delay` seconds
CANCEL = "cancel"  # call off the timer or the readiness hold
HOLD = "hold"  # have the readiness poll watch its wait_for conditions
BEGIN_STOP = "begin stop"  # SIGINT, then the escalation (this machine); the child's stop (remote)
KILL = "kill"  # SIGKILL the run now (hung, or a restart for a limit)
END_LAUNCH = "end launch"  # the launch ends, with exit `status`
NOTE = "note"  # nothing to do: words for the console about what the restart policy decided (`text`)


@record
class Rules:
    """What the lifecycle table reads of a node: fixed for its life in the launch."""

    required: bool = False
    respawn: bool = False
    respawn_delay: float = 0.0
    policy: NodePolicy = NodePolicy()
    remote: bool = False  # it runs on another machine, through that machine's child
    machine: str = ""  # that machine's name (for the words about it)
    # its restarts are the runner's (the restart policy): always here; for a remote node, when it has a
    # NodePolicy (else its child respawns it itself, as roslaunch's does)
    owned: bool = True


# the host of the nodes this machine runs (a remote node's is its machine's address)
LOCAL_HOST = "localhost"


@record
class Record:
    """One node, as the fleet keeps it. Times are the runner's clock (`now` of each step)."""

    name: str  # the ROS node name, /robot/driver
    process: str  # roslaunch's process name, robot/driver-2
    host: str  # LOCAL_HOST, or its machine's address
    rules: Rules
    state: str = NEW
    pid: int | None = None
    spawn_count: int = 0  # runs started (roslaunch's spawn_count)
    restarts: int = 0  # runs after the first, an operator's included
    respawns: int = 0  # starts the restart policy made (restart_warn_threshold counts these)
    restart_warned: bool = False
    failures: int = 0  # failed starts in a row (the restart policy's count)
    started: float | None = None  # the current (or last) run's start
    exit_code: int | None = None
    exit_signal: int | None = None
    next_start: float | None = None  # when respawning or waiting for spawn_delay
    reason: str = ""  # why the last change happened, in words
    over_limit: tuple[tuple[str, float], ...] = ()  # the limits the current run is over, (limit, maximum)
    operator_stopped: bool = False  # an operator's stop holds: nothing but an operator's start starts it
    restart_reason: str = ""  # this run is being killed in order to start again
    rebind: bool = False  # being stopped because the node it is bound to is down: detached once down
    stop_reason: str = ""  # why the launch is stopping it (a reload), said once it is down
    registered: bool = False  # its current run is registered with the master ...
    uri: str = ""  # ... and this is that run's XML-RPC URI


@record
class Event:
    kind: str
    pid: int | None = None
    exit_code: int | None = None
    exit_signal: int | None = None
    reason: str = ""
    process: str = ""
    over_limit: tuple[tuple[str, float], ...] = ()
    killed: bool = False
    detail: str = ""  # the runner's own words about it, for the console (roslaunch's exit description)
    rules: Rules | None = None  # RENEW, RULES: the node's new rules (None: as they are)
    uri: str = ""  # REGISTERED, UNREGISTERED: the registration's URI


@record
class Action:
    kind: str
    delay: float = 0.0
    status: int = 0
    text: str = ""


class InvalidTransition(Exception):
    """A runner told a node something its state cannot take: a bug, not bad input."""


def step(record: Record, event: Event, now: float) -> tuple[Record, list[Action]]:
    """The node after `event`, and what the runner is to do. Raises InvalidTransition for a pair the
    table does not know."""
    handler = TABLE.get((record.state, event.kind))
    if handler is not None:
        return handler(record, event, now)
    if (record.state, event.kind) in IGNORED:
        return record, []
    raise InvalidTransition("node [%s]: event [%s] in state [%s]" % (record.name, event.kind, record.state))  # (REFUSED)


def exit_status(exit_code: int | None, exit_signal: int | None) -> int:
    """A shell's exit status for how a run ended: the code, or 128 + the signal that killed it."""
    if exit_signal is not None:
        return 128 + exit_signal
    return 1 if exit_code is None else exit_code


# ---- starting ------------------------------------------------------------------------------------------

def _go(r: Record, reason: str = "", **changes) -> tuple[Record, list[Action]]:
    """Start now: spawn here, or queue for its machine's child."""
    if r.rules.remote:
        return r._replace(state=PENDING, reason=reason, next_start=None, **changes), [Action(LAUNCH)]
    return r._replace(state=STARTING, reason=reason, next_start=None, **changes), [Action(SPAWN)]


def _ready_or_hold(r: Record) -> tuple[Record, list[Action]]:
    policy = r.rules.policy
    if policy.wait_for and r.rules.owned:
        return r._replace(state=HELD, next_start=None, reason="waiting for " + describe(policy.wait_for)), \
            [Action(HOLD)]
    return _go(r)


def _start(r: Record, e: Event, now: float) -> tuple[Record, list[Action]]:
    delay = r.rules.policy.spawn_delay if r.rules.owned else 0.0
    if delay > 0:
        return r._replace(state=DELAYED, next_start=now + delay, reason="spawn_delay %g s" % delay), \
            [Action(SCHEDULE, delay)]
    return _ready_or_hold(r)


def _keep_stopped(r: Record, e: Event, now: float) -> tuple[Record, list[Action]]:
    return r._replace(state=STOPPED, reason="not started (--no-start)"), []


def _spawn_delay_over(r: Record, e: Event, now: float) -> tuple[Record, list[Action]]:
    return _ready_or_hold(r)


def _ready(r: Record, e: Event, now: float) -> tuple[Record, list[Action]]:
    return _go(r)


def _not_ready(r: Record, e: Event, now: float) -> tuple[Record, list[Action]]:
    new = r._replace(state=EXITED, reason=e.reason)
    return new, [Action(END_LAUNCH, status=1)] if r.rules.required else []


def _respawn_due(r: Record, e: Event, now: float) -> tuple[Record, list[Action]]:
    respawns = r.respawns + 1
    threshold = r.rules.policy.restart_warn_threshold
    warned = r.restart_warned or (threshold is not None and respawns > threshold)
    return _go(r, respawns=respawns, restart_warned=warned)


def _spawned(r: Record, e: Event, now: float) -> tuple[Record, list[Action]]:
    """A run began (the child may say so after its `launch` answer: the run is then known already)."""
    if r.state == RUNNING and (r.pid is None or r.pid == e.pid):
        return r._replace(pid=e.pid, process=e.process or r.process), []
    first = r.spawn_count == 0
    # a remote run may register before its child says it started (its registration is this run's)
    kept = r.state == LAUNCHING and r.registered
    return r._replace(state=RUNNING, pid=e.pid, process=e.process or r.process, spawn_count=r.spawn_count + 1,
                      restarts=r.restarts + (0 if first else 1), started=now, exit_code=None, exit_signal=None,
                      next_start=None, reason="", over_limit=(), restart_reason="", rebind=False,
                      registered=kept, uri=r.uri if kept else ""), []


def _launch_sent(r: Record, e: Event, now: float) -> tuple[Record, list[Action]]:
    return r._replace(state=LAUNCHING, started=now), []


def _launched(r: Record, e: Event, now: float) -> tuple[Record, list[Action]]:
    """The child took it, under a process name; it runs once the child says with which pid (before or
    after this answer)."""
    return r._replace(process=e.process or r.process), []


def _launch_refused(r: Record, e: Event, now: float) -> tuple[Record, list[Action]]:
    return r._replace(state=PENDING, reason=e.reason), []


# ---- a run ends ------------------------------------------------------------------------------------------

def _run_ended(r: Record, e: Event, now: float, started: bool = True) -> tuple[Record, list[Action]]:
    """The one place where what follows a run is decided: the launch ends (required), the node starts
    again (the restart policy, or its child does it), or it stays down (exited, fatal)."""
    rules = r.rules
    code, sig = (e.exit_code, e.exit_signal) if started else (None, None)
    ended = r._replace(exit_code=code, exit_signal=sig, over_limit=(), restart_reason="", next_start=None,
                       registered=False, uri="")
    if started and r.restart_reason:  # killed in order to start again (on_limit="restart")
        return ended._replace(state=RESPAWNING, next_start=now, reason=r.restart_reason), [Action(SCHEDULE, 0.0)]
    if rules.required:
        if not started:
            status = 1
        elif rules.remote:
            status = 0 if code == 0 else 1
        else:
            status = exit_status(code, sig)
        why = "required: the launch ends" if started else (e.reason or "could not be started")
        return ended._replace(state=EXITED, reason=why), [Action(END_LAUNCH, status=status)]
    if not rules.owned:  # its child respawns it, as roslaunch's does
        return ended._replace(state=RESPAWNING if rules.respawn else EXITED, reason=""), []
    uptime = now - r.started if started and r.started is not None else 0.0
    d = restart.after_run(rules.respawn, rules.respawn_delay, rules.policy, code, started, uptime, r.failures)
    ended = ended._replace(failures=d.failures, reason=d.reason)
    notes = [Action(NOTE, text=d.note)] if d.note else []
    if d.action == restart.FATAL:
        shutdown = rules.policy.on_fatal == "shutdown"
        return ended._replace(state=FATAL), notes + ([Action(END_LAUNCH, status=1)] if shutdown else [])
    if d.action == restart.STAY_DOWN:
        return ended._replace(state=EXITED), notes
    return ended._replace(state=RESPAWNING, next_start=now + d.delay), notes + [Action(SCHEDULE, d.delay)]


def _exited(r: Record, e: Event, now: float) -> tuple[Record, list[Action]]:
    return _run_ended(r, e, now)


def _spawn_failed(r: Record, e: Event, now: float) -> tuple[Record, list[Action]]:
    return _run_ended(r._replace(started=now, pid=None), e, now, started=False)


def _exit_while_stopping(r: Record, e: Event, now: float) -> tuple[Record, list[Action]]:
    return r._replace(exit_code=e.exit_code, exit_signal=e.exit_signal), []


# ---- health: hung, limits ------------------------------------------------------------------------------

def _hang(r: Record, e: Event, now: float) -> tuple[Record, list[Action]]:
    return r._replace(state=HUNG, reason=e.reason, over_limit=()), [Action(KILL)]


def _stall(r: Record, e: Event, now: float) -> tuple[Record, list[Action]]:
    """Stalled: reported; killed unless on_stall="warn" (its end then goes the way of any run's end)."""
    warn_only = r.rules.policy.on_stall == "warn"
    return r._replace(state=STALLED, reason=e.reason), [] if warn_only else [Action(KILL)]


def _unstall(r: Record, e: Event, now: float) -> tuple[Record, list[Action]]:
    return r._replace(state=RUNNING, reason=e.reason), []


def _restart(r: Record, e: Event, now: float) -> tuple[Record, list[Action]]:
    if r.restart_reason:
        return r, []  # (already being killed for that)
    return r._replace(restart_reason=e.reason), [Action(KILL)]


def _limit(r: Record, e: Event, now: float) -> tuple[Record, list[Action]]:
    return r._replace(over_limit=tuple(sorted(e.over_limit)), reason=e.reason), []


# ---- stopping and operators ----------------------------------------------------------------------------

def _stop_run(r: Record, e: Event, now: float) -> tuple[Record, list[Action]]:
    operator = e.kind == STOP
    why = e.reason if e.kind == RELOAD_STOP else ""
    return r._replace(state=STOPPING, operator_stopped=r.operator_stopped or operator, stop_reason=why), \
        [Action(BEGIN_STOP)]


def _stop_before_start(r: Record, e: Event, now: float) -> tuple[Record, list[Action]]:
    if e.kind == STOP:
        why, operator = "stopped by operator", True
    elif e.kind == RELOAD_STOP:
        why, operator = e.reason, r.operator_stopped
    elif r.state in (HELD, NEW, DELAYED) and r.spawn_count == 0:
        why, operator = "stopped while waiting to start", r.operator_stopped
    else:
        why, operator = "stopped before its next start", r.operator_stopped
    return r._replace(state=STOPPED, next_start=None, reason=why, operator_stopped=operator), [Action(CANCEL)]


def _down(r: Record, e: Event, now: float) -> tuple[Record, list[Action]]:
    code, sig = (e.exit_code, e.exit_signal) if e.exit_code is not None or e.exit_signal is not None \
        else (r.exit_code, r.exit_signal)
    if r.rebind and not r.operator_stopped:  # (stopped with the node it is bound to: it waits for that one)
        return r._replace(state=DETACHED, exit_code=code, exit_signal=sig, over_limit=(), restart_reason="",
                          rebind=False, stop_reason="", registered=False, uri=""), []
    why = "killed with SIGKILL" if e.killed else "stopped by operator" if r.operator_stopped \
        else e.reason or r.stop_reason
    return r._replace(state=STOPPED, pid=r.pid, exit_code=code, exit_signal=sig, reason=why, over_limit=(),
                      restart_reason="", rebind=False, stop_reason="", registered=False, uri=""), []


def _stop_refused(r: Record, e: Event, now: float) -> tuple[Record, list[Action]]:
    return r._replace(state=RUNNING, operator_stopped=False, reason=e.reason), []


def _operator_start(r: Record, e: Event, now: float) -> tuple[Record, list[Action]]:
    """An operator's start: now, whatever held it, and with a clean slate of failures (as supervisorctl's
    start of a FATAL program)."""
    new, actions = _go(r, reason="started by operator", failures=0, operator_stopped=False)
    return new, [Action(CANCEL)] + actions


# ---- bound to another node (bind_to, a nodelet loader's manager) ----------------------------------------
# A bound node is of no use without its partner (a nodelet's loader without its manager): it is stopped
# while that one is down, and started again (once, whatever its own respawn says) after that one's next
# start, its hold waiting for it to register. The fleet tells it of its partner's ends and starts (fleet.relations).

def _bound_ended_running(r: Record, e: Event, now: float) -> tuple[Record, list[Action]]:
    return r._replace(state=STOPPING, rebind=True, reason=e.reason), [Action(BEGIN_STOP)]


def _bound_ended_down(r: Record, e: Event, now: float) -> tuple[Record, list[Action]]:
    """Not running (held for its conditions, its own respawn pending, or ended): it waits for its partner's
    next start instead."""
    return r._replace(state=DETACHED, next_start=None, reason=e.reason), [Action(CANCEL)]


def _bound_started(r: Record, e: Event, now: float) -> tuple[Record, list[Action]]:
    return _ready_or_hold(r._replace(failures=0))


# ---- a reload ------------------------------------------------------------------------------------------

def _renew(r: Record, e: Event, now: float) -> tuple[Record, list[Action]]:
    """Made anew by a reload (it changed): its new rules, and nothing of the old node's fate holds it
    (an operator's stop, failures in a row, FATAL); a START follows. Its counts of runs go on."""
    return r._replace(state=NEW, rules=e.rules or r.rules, failures=0, operator_stopped=False, respawns=0,
                      restart_warned=False, next_start=None, reason=e.reason), []


def _new_rules(r: Record, e: Event, now: float) -> tuple[Record, list[Action]]:
    """Its supervision settings changed (respawn, restart policy, limits): from its next decision on."""
    return r._replace(rules=e.rules or r.rules), []


# ---- other machines ------------------------------------------------------------------------------------

def _link_lost(r: Record, e: Event, now: float) -> tuple[Record, list[Action]]:
    """Its machine's session ended while it ran, or was being handed over: it is launched again when
    the table answers (a required one ends the launch)."""
    lost = r._replace(state=LOST, reason=e.reason, over_limit=(), registered=False, uri="")
    return lost, [Action(END_LAUNCH, status=1)] if r.rules.required else []


def _stopped_with_link(r: Record, e: Event, now: float) -> tuple[Record, list[Action]]:
    """Being stopped when the link went: what runs on that machine is stopped by its end anyway."""
    return _down(r, e._replace(reason=e.reason), now)


def _machine_failed(r: Record, e: Event, now: float) -> tuple[Record, list[Action]]:
    new = r._replace(state=EXITED, reason=e.reason, next_start=None, registered=False, uri="")
    return new, [Action(CANCEL)] + ([Action(END_LAUNCH, status=1)] if r.rules.required else [])


# ---- the master's word -----------------------------------------------------------------------------------

def _registered(r: Record, e: Event, now: float) -> tuple[Record, list[Action]]:
    if r.registered and r.uri == e.uri:
        return r, []
    return r._replace(registered=True, uri=e.uri), []


def _unregistered(r: Record, e: Event, now: float) -> tuple[Record, list[Action]]:
    """Its registration went (a registration at another URI, the run's newer one, stays)."""
    if not r.registered or (e.uri and e.uri != r.uri):
        return r, []
    return r._replace(registered=False, uri=""), []


def describe(conditions) -> str:
    """`topic:/scan, node:/amcl`: the words of the launch file."""
    return ", ".join("%s:%s" % c for c in conditions)


# ---- the table -------------------------------------------------------------------------------------------

_WAITING_TO_START = (NEW, DELAYED, HELD, RESPAWNING, PENDING, LOST, DETACHED)
_DOWN_FOR_GOOD = (EXITED, FATAL, STOPPED)
# a process of the node may be registered (a remote one may register before its child says it runs)
_MAY_BE_REGISTERED = (LAUNCHING, RUNNING, HUNG, STALLED, STOPPING)

TABLE = {
    (NEW, START): _start,
    (NEW, KEEP_STOPPED): _keep_stopped,
    (DELAYED, DUE): _spawn_delay_over,
    (HELD, READY): _ready,
    (HELD, NOT_READY): _not_ready,
    (RESPAWNING, DUE): _respawn_due,
    (STARTING, SPAWNED): _spawned,
    (STARTING, SPAWN_FAILED): _spawn_failed,
    (PENDING, LAUNCH_SENT): _launch_sent,
    (LOST, LAUNCH_SENT): _launch_sent,
    (LAUNCHING, LAUNCHED): _launched,
    (LAUNCHING, SPAWNED): _spawned,
    (LAUNCHING, SPAWN_FAILED): _spawn_failed,
    (LAUNCHING, LAUNCH_REFUSED): _launch_refused,
    (RUNNING, LAUNCHED): _launched,
    (RUNNING, SPAWNED): _spawned,  # the pid after the `launch` answer, or a run its child respawned
    (RESPAWNING, SPAWNED): _spawned,  # (a remote node its child respawns)
    (RUNNING, PROCESS_EXITED): _exited,
    (HUNG, PROCESS_EXITED): _exited,
    (LAUNCHING, PROCESS_EXITED): _exited,  # (its child told of its death before it answered the call)
    (STOPPING, PROCESS_EXITED): _exit_while_stopping,
    (RUNNING, HANG): _hang,
    (STALLED, HANG): _hang,  # (hung says more)
    (RUNNING, STALL): _stall,
    (STALLED, UNSTALL): _unstall,
    (STALLED, PROCESS_EXITED): _exited,
    (STALLED, STOP): _stop_run,
    (STALLED, SHUTDOWN): _stop_run,
    (RUNNING, RESTART): _restart,
    (RUNNING, LIMIT): _limit,
    (RUNNING, STOP): _stop_run,
    (LAUNCHING, STOP): _stop_run,  # (taken by the child, its pid not told yet)
    (HUNG, STOP): _stop_run,
    (RUNNING, SHUTDOWN): _stop_run,
    (HUNG, SHUTDOWN): _stop_run,
    (STOPPING, DOWN): _down,
    (STOPPING, STOP_REFUSED): _stop_refused,
    (RUNNING, LINK_LOST): _link_lost,
    (LAUNCHING, LINK_LOST): _link_lost,
    (STOPPING, LINK_LOST): _stopped_with_link,
    # a node given again (a remote child's parent starts it anew after its end)
    **{(s, START): _start for s in _DOWN_FOR_GOOD},
    **{(s, STOP): _stop_before_start for s in _WAITING_TO_START},
    **{(s, SHUTDOWN): _stop_before_start for s in _WAITING_TO_START + (LAUNCHING,)},
    **{(s, OPERATOR_START): _operator_start for s in (NEW, DELAYED, HELD, RESPAWNING, DETACHED) + _DOWN_FOR_GOOD},
    **{(s, BOUND_ENDED): _bound_ended_running for s in (RUNNING, STALLED, HUNG)},
    **{(s, BOUND_ENDED): _bound_ended_down for s in (HELD, RESPAWNING, EXITED, FATAL)},
    (DETACHED, BOUND_STARTED): _bound_started,
    **{(s, RELOAD_STOP): _stop_run for s in (RUNNING, HUNG, STALLED)},
    **{(s, RELOAD_STOP): _stop_before_start for s in _WAITING_TO_START + (LAUNCHING,)},
    **{(s, RENEW): _renew for s in (NEW, DETACHED) + _DOWN_FOR_GOOD},  # (detached: held again for its partner)
    **{(s, RULES): _new_rules for s in STATES},
    **{(s, MACHINE_FAILED): _machine_failed for s in (NEW, DELAYED, HELD, PENDING, LAUNCHING, RUNNING, LOST,
                                                      RESPAWNING)},
    **{(s, REGISTERED): _registered for s in _MAY_BE_REGISTERED},
    **{(s, UNREGISTERED): _unregistered for s in _MAY_BE_REGISTERED},
}


def _link_lost_respawning(r: Record, e: Event, now: float) -> tuple[Record, list[Action]]:
    """A node its child was respawning is lost with the link like a running one; a node whose restart is
    the parent's (owned) waits for its timer, on no machine."""
    return _link_lost(r, e, now) if not r.rules.owned else (r, [])


TABLE[(RESPAWNING, LINK_LOST)] = _link_lost_respawning

# Pairs that change nothing, on purpose: a report that comes after the state it reports on moved on.
IGNORED = frozenset(
    [(s, STOP) for s in (STOPPING,) + _DOWN_FOR_GOOD]  # already stopped, being stopped, or down for good
    + [(s, SHUTDOWN) for s in (STOPPING,) + _DOWN_FOR_GOOD]  # (an operator's stop in progress goes on)
    + [(s, RELOAD_STOP) for s in (STOPPING,) + _DOWN_FOR_GOOD]
    + [(s, OPERATOR_START) for s in (STARTING, RUNNING, HUNG, STALLED, STOPPING, PENDING, LAUNCHING, LOST)]
    + [(s, PROCESS_EXITED) for s in (STOPPED, EXITED, FATAL, LOST, PENDING)]  # a child's late report
    + [(s, SPAWNED) for s in (STOPPED, STOPPING, LOST)]  # a child's late "started with pid"
    + [(s, LAUNCHED) for s in (STOPPED, STOPPING, LOST, PENDING, EXITED, FATAL)]  # its call answered late
    + [(s, SPAWN_FAILED) for s in (STOPPED, LOST, PENDING)]
    + [(s, LAUNCH_REFUSED) for s in (LOST, PENDING, STOPPED, RUNNING, EXITED, FATAL, RESPAWNING)]
    + [(s, LINK_LOST) for s in (NEW, DELAYED, HELD, PENDING, LOST) + _DOWN_FOR_GOOD]
    + [(s, MACHINE_FAILED) for s in (STOPPING,) + _DOWN_FOR_GOOD]
    + [(s, HANG) for s in (HUNG, STOPPING, STOPPED, EXITED, FATAL, RESPAWNING)]  # a probe's late verdict
    + [(s, STALL) for s in (STALLED, HUNG, STOPPING, STOPPED, EXITED, FATAL, RESPAWNING)]  # a watch's late verdict
    + [(s, UNSTALL) for s in STATES if s != STALLED]
    + [(s, RESTART) for s in (HUNG, STALLED, STOPPING, STOPPED, EXITED, FATAL, RESPAWNING, STARTING)]
    + [(s, LIMIT) for s in STATES if s != RUNNING]  # (hung, or being stopped: that state says more)
    + [(s, DUE) for s in (STOPPED, EXITED, FATAL)]  # a timer that fired as it was cancelled
    + [(s, READY) for s in (STOPPED, EXITED, FATAL)]
    + [(s, NOT_READY) for s in (STOPPED, EXITED, FATAL)]
    # detached: down, as a stopped node, until its partner starts
    + [(DETACHED, k) for k in (DUE, PROCESS_EXITED, HANG, STALL, RESTART, LAUNCHED, LAUNCH_REFUSED, LINK_LOST,
                               MACHINE_FAILED)]
    # not started yet (its hold waits for the partner), being stopped, stopped, or waiting for it already
    + [(s, BOUND_ENDED) for s in (NEW, DELAYED, STARTING, STOPPING, STOPPED, DETACHED)]
    # a partner's start concerns only a detached node
    + [(s, BOUND_STARTED) for s in (NEW, DELAYED, HELD, STARTING, RUNNING, HUNG, STALLED, STOPPING, RESPAWNING,
                                     EXITED, FATAL, STOPPED)]
    # a run that ended (its registration, late, or left on a master found running), or none under way
    + [(s, k) for s in STATES if s not in _MAY_BE_REGISTERED for k in (REGISTERED, UNREGISTERED)]
)
assert not IGNORED & TABLE.keys()

# Pairs no runner sends: each is a runner's bug, raised as InvalidTransition (the fleet says "internal error" and
# leaves the node as it was). With TABLE and IGNORED they are every pair, each in one (tests/fleet/test_lifecycle.py).
_LOCAL_ONLY = (STARTING, HUNG, STALLED)  # (states of a node of this machine: the health watchers are local)
REFUSED = frozenset(
    # the launch starts a node once (again only after its end: a remote child's parent gives it anew)
    [(s, START) for s in STATES if s not in (NEW,) + _DOWN_FOR_GOOD]
    # only a node being made is kept stopped (--no-start)
    + [(s, KEEP_STOPPED) for s in STATES if s != NEW]
    # no timer runs: a spawn_delay's or a respawn's only (a cancelled one firing late: ignored)
    + [(s, DUE) for s in (NEW, HELD, STARTING, PENDING, LAUNCHING, RUNNING, HUNG, STALLED, STOPPING, LOST)]
    # only a held node is in the readiness hold (one let go of late: ignored)
    + [(s, k) for k in (READY, NOT_READY) for s in STATES if s not in (HELD,) + _DOWN_FOR_GOOD]
    # a run is told after a spawn or a `launch` call (or its child's respawn), not before
    + [(s, SPAWNED) for s in (NEW, DELAYED, HELD, PENDING, HUNG, STALLED, EXITED, FATAL, DETACHED)]
    # only a spawn or a `launch` call fails to start
    + [(s, SPAWN_FAILED) for s in (NEW, DELAYED, HELD, RUNNING, HUNG, STALLED, STOPPING, RESPAWNING, EXITED, FATAL,
                                   DETACHED)]
    # no process of it runs (a spawn's exit comes after its start; a run's end is told once)
    + [(s, PROCESS_EXITED) for s in (NEW, DELAYED, HELD, STARTING, RESPAWNING)]
    # the probes and the limit watch look at a running process only
    + [(s, k) for k in (HANG, STALL) for s in (NEW, DELAYED, HELD, STARTING, PENDING, LAUNCHING, LOST)]
    + [(s, RESTART) for s in (NEW, DELAYED, HELD, PENDING, LAUNCHING, LOST)]
    # a spawn is done within one call of the runner: no stop comes between
    + [(STARTING, k) for k in (STOP, SHUTDOWN, RELOAD_STOP)]
    # only a stop under way ends, or is refused
    + [(s, k) for k in (DOWN, STOP_REFUSED) for s in STATES if s != STOPPING]
    # only a node queued for its machine is sent
    + [(s, LAUNCH_SENT) for s in STATES if s not in (PENDING, LOST)]
    # only a node in a `launch` call is answered (a late answer: ignored)
    + [(s, k) for k in (LAUNCHED, LAUNCH_REFUSED) for s in (NEW, DELAYED, HELD, STARTING, HUNG, STALLED)]
    + [(s, LAUNCHED) for s in (RESPAWNING,)] + [(s, LAUNCH_REFUSED) for s in (STOPPING,)]
    # a node of this machine has no machine's session to lose
    + [(s, k) for k in (LINK_LOST, MACHINE_FAILED) for s in _LOCAL_ONLY]
    # a bound node and its partner are both of this machine
    + [(s, k) for k in (BOUND_ENDED, BOUND_STARTED) for s in (PENDING, LAUNCHING, LOST)]
    # a reload renews a node once it has stopped it
    + [(s, RENEW) for s in STATES if s not in (NEW, DETACHED) + _DOWN_FOR_GOOD]
)
assert not REFUSED & (TABLE.keys() | IGNORED)

