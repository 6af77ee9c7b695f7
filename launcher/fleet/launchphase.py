"""The launch's own phase as a transition table: `step(launch, event) -> (launch, actions)`.

A node's life is `fleet.lifecycle`'s; this is the launch's, in roslaunch's terms: it
starts its nodes, runs once every node has been started (roslaunch's "registrations
complete"), is to end when a node ends it (a required node died or could not start,
on_fatal="shutdown": "Initiating shutdown!"), when a node's process cannot be started
while it starts its nodes (roslaunch's FatalProcessLaunch: a bad launch-prefix), when
every node of this machine has died with a master that is not its own ("all processes
on machine have died, roslaunch will exit"), when it has no process at all with such a
master (a launch of parameters only: "No processes to monitor") or when a stop signal
comes, then stops its nodes, and has ended once they are down. A stop signal while the
nodes are being stopped (the second Ctrl-C) kills those still stopping.

It does no I/O and reads no clock. The fleet (`fleet.state.Fleet`) keeps the launch's
record beside the nodes', steps it and carries out END and SAY; the runner of the
launch (`services.nodeservice.NodeService`, or a supervisor on its own: a remote child,
a test) carries out STOP_ALL and KILL_ALL. Every reader of "is the launch stopping?"
(the supervisor's guards, the remote parent's, the health probes) asks the record, through
`starts_allowed` and `stopping`. Every pair (phase, event) is in TABLE, IGNORED or
REFUSED (a runner's bug, raised as `InvalidTransition`), as the node table's.

    starting  its nodes are being started
    running   every node has been started (or failed to)
    ending    the launch is to end (a node ended it, a start failed, all died, no processes, a
              stop signal): its services are being stopped, its nodes last; no node starts
              again
    stopping  its nodes are being stopped
    ended     its nodes are down
"""

from __future__ import annotations

from launcher.model.record import record

STARTING, RUNNING, ENDING, STOPPING, ENDED = "starting", "running", "ending", "stopping", "ended"
STATES = (STARTING, RUNNING, ENDING, STOPPING, ENDED)

# ---- events: what happened to the launch (told by the fleet, the stop signals, the launch's runner)
ALL_STARTED = "all started"  # every node of the launch has been started, or failed to (registrations complete)
NODE_ENDED_IT = "node ended it"  # a node's table said END_LAUNCH (`status`), or a required one could not be made
ALL_DEAD = "all dead"  # no node of this machine can run again, and one ended by itself (`all_dead` below)
START_FAILED = "start failed"  # a node's process of this machine could not be started (its exec failed)
NO_PROCESSES = "no processes"  # every node has been started, and none has a process, here or elsewhere: the launch
#                                has no node, or none could be made
STOP_SIGNAL = "stop signal"  # SIGINT, SIGTERM or SIGHUP
STOP = "stop"  # the launch's runner stops its nodes now (its services' teardown reached them)
ALL_STOPPED = "all stopped"  # the runner's stop of the nodes is over
EVENTS = (ALL_STARTED, NODE_ENDED_IT, START_FAILED, ALL_DEAD, NO_PROCESSES, STOP_SIGNAL, STOP, ALL_STOPPED)

# ---- actions: what the fleet (END, SAY) and the launch's runner (STOP_ALL, KILL_ALL) carry out
END = "end"  # the launch ends, with exit `status` (the fleet's `done`: the run's body returns)
SAY = "say"  # words for the console (`text`)
STOP_ALL = "stop all"  # stop every node: bound and waited-for ones in order, SIGINTs paced, each escalating
KILL_ALL = "kill all"  # SIGKILL every node still stopping, and those waiting for their turn
NOTE = "note"  # nothing to do (what the mutation check puts in place of an action)

ALL_DEAD_TEXT = "all processes on machine have died, roslaunch will exit"
NO_PROCESSES_TEXT = "No processes to monitor"  # (roslaunch's #556: a launch that only sets parameters exits)


@record
class Launch:
    """The launch, as the fleet keeps it."""

    state: str = STARTING
    # its exit status: the first non-zero status a node ended it with (a required node's own exit code, or
    # 128 + the signal that killed it, as ROS-O's roslaunch, ros/ros_comm#2082; 1 for a start that failed)
    exit_status: int = 0
    # roslaunch ends a launch whose nodes all died, or that has no process, only when the master is not its own
    # (its own master is a process it monitors; a rule for the whole run)
    exit_when_all_dead: bool = False
    # roslaunch's own launch ends (status 1) when a node's process cannot be started while it starts its nodes (its
    # FatalProcessLaunch); its remote child, and a runner on its own, go on (the node's table decides what follows)
    start_failure_ends_it: bool = False
    # why it ends, where its nodes ended it by all dying or by having no process (roslaunch's words, for the
    # events file); "" otherwise
    reason: str = ""


@record
class Event:
    kind: str
    status: int = 0  # NODE_ENDED_IT: the exit status that node asks for


@record
class Action:
    kind: str
    status: int = 0
    text: str = ""
    bold: bool = False  # SAY: as roslaunch's printlog_bold


class InvalidTransition(Exception):
    """A runner told the launch something its phase cannot take: a bug, not bad input."""


def step(launch: Launch, event: Event) -> tuple[Launch, list[Action]]:
    """The launch after `event`, and what is to be done. Raises InvalidTransition for a refused pair."""
    handler = TABLE.get((launch.state, event.kind))
    if handler is not None:
        return handler(launch, event)
    if (launch.state, event.kind) in IGNORED:
        return launch, []
    raise InvalidTransition("launch: event [%s] in phase [%s]" % (event.kind, launch.state))  # (REFUSED)


def starts_allowed(launch: Launch) -> bool:
    """May a node start (again) by itself: a timer's due start, a hold let go? Not once the launch is to end."""
    return launch.state in (STARTING, RUNNING)


def stopping(launch: Launch) -> bool:
    """Are the launch's nodes being stopped (or stopped)? Then nothing but the stop touches them."""
    return launch.state in (STOPPING, ENDED)


def all_dead(records, alive, ended, unstarted: int = 0) -> bool:
    """roslaunch's "all processes on machine have died": no node (of this machine's `records`) is in a state of
    `alive`, and one is in `ended` (ended by itself) or could not even be made (`unstarted`)."""
    any_ended = unstarted > 0
    for r in records:
        if r.state in alive:
            return False
        any_ended = any_ended or r.state in ended
    return any_ended


# ---- the transitions ---------------------------------------------------------------------------------------

def _all_started(n: Launch, e: Event) -> tuple[Launch, list[Action]]:
    return n._replace(state=RUNNING), []


def _node_ended_it(n: Launch, e: Event) -> tuple[Launch, list[Action]]:
    """A node ends the launch; the first that fails decides its exit status (a later failure does not
    change it, one after a status 0 does)."""
    status = n.exit_status or e.status
    return n._replace(state=ENDING if n.state in (STARTING, RUNNING) else n.state, exit_status=status), \
        [Action(END, status=status)]


def _all_dead(n: Launch, e: Event) -> tuple[Launch, list[Action]]:
    if not n.exit_when_all_dead:  # (our own master: the launch runs on, as roslaunch's with its roscore)
        return n, []
    return n._replace(state=ENDING, reason=ALL_DEAD_TEXT), \
        [Action(SAY, text=ALL_DEAD_TEXT), Action(END, status=n.exit_status)]


def _start_failed(n: Launch, e: Event) -> tuple[Launch, list[Action]]:
    if not n.start_failure_ends_it:
        return n, []
    status = n.exit_status or 1
    return n._replace(state=ENDING, exit_status=status), [Action(END, status=status)]


def _no_processes(n: Launch, e: Event) -> tuple[Launch, list[Action]]:
    if not n.exit_when_all_dead:  # (our own master is the process roslaunch's would monitor: its roscore)
        return n, []
    return n._replace(state=ENDING, reason=NO_PROCESSES_TEXT), \
        [Action(SAY, text=NO_PROCESSES_TEXT, bold=True), Action(END, status=n.exit_status)]


def _to_end(n: Launch, e: Event) -> tuple[Launch, list[Action]]:
    """A stop signal: the run's body returns (it waits for the signal itself); no node starts again."""
    return n._replace(state=ENDING), []


def _stop(n: Launch, e: Event) -> tuple[Launch, list[Action]]:
    return n._replace(state=STOPPING), [Action(STOP_ALL)]


def _kill(n: Launch, e: Event) -> tuple[Launch, list[Action]]:
    """A stop signal while the nodes are being stopped (the second Ctrl-C): now."""
    return n, [Action(KILL_ALL)]


def _all_stopped(n: Launch, e: Event) -> tuple[Launch, list[Action]]:
    return n._replace(state=ENDED), []


TABLE = {
    (STARTING, ALL_STARTED): _all_started,
    **{(s, NODE_ENDED_IT): _node_ended_it for s in (STARTING, RUNNING, ENDING, STOPPING)},
    (RUNNING, ALL_DEAD): _all_dead,
    (STARTING, START_FAILED): _start_failed,
    (RUNNING, NO_PROCESSES): _no_processes,
    (STARTING, STOP_SIGNAL): _to_end,
    (RUNNING, STOP_SIGNAL): _to_end,
    (STOPPING, STOP_SIGNAL): _kill,
    **{(s, STOP): _stop for s in (STARTING, RUNNING, ENDING)},
    (STOPPING, ALL_STOPPED): _all_stopped,
}

# Pairs that change nothing, on purpose.
IGNORED = frozenset(
    # a remote child's parent gives it nodes again (each `launch` call's nodes are all started); or the start
    # of the nodes was cut short by the launch's end (a stop signal meanwhile)
    [(s, ALL_STARTED) for s in (RUNNING, ENDING, STOPPING)]
    # roslaunch counts the dead once every node has been started, and only until the launch is to end
    + [(s, ALL_DEAD) for s in (STARTING, ENDING, STOPPING, ENDED)]
    # a node's start that failed once every node has been started (a respawn, an operator's start: the node's own
    # table decides what follows), or while the launch ends anyway
    + [(s, START_FAILED) for s in (RUNNING, ENDING, STOPPING)]
    # told right after ALL_STARTED: a launch already to end (a stop signal, a required node) goes on ending
    + [(s, NO_PROCESSES) for s in (ENDING, STOPPING)]
    # the launch ends already (a second signal before its nodes' stop has begun changes nothing), or has ended
    + [(ENDING, STOP_SIGNAL), (ENDED, STOP_SIGNAL)]
    # its nodes are being stopped, or are down: a second stop (another runner's shutdown) adds nothing
    + [(STOPPING, STOP), (ENDED, STOP)]
    # a node's word after the launch's end
    + [(ENDED, NODE_ENDED_IT)]
)
assert not IGNORED & TABLE.keys()

# Pairs no runner sends: with TABLE and IGNORED they are every pair, each in one (tests/fleet/test_launchphase.py).
REFUSED = frozenset(
    # no node is started once the launch has ended
    [(ENDED, ALL_STARTED), (ENDED, START_FAILED)]
    # it follows ALL_STARTED, which leaves STARTING and is refused once the launch has ended
    + [(STARTING, NO_PROCESSES), (ENDED, NO_PROCESSES)]
    # only a stop that began can be over
    + [(s, ALL_STOPPED) for s in (STARTING, RUNNING, ENDING, ENDED)]
)
assert not REFUSED & (TABLE.keys() | IGNORED)
