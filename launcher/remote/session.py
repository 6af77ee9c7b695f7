"""A machine's session with its roslaunch child, as a state machine (pure), and the words of the protocol.

One session is an ssh connection running a child: `connecting` (the child is
being started and has not registered), `accepting` (it registered and the
launch's parameters are set: it takes `launch` calls), `ending` (it refused a
call, or its last node ended and it is about to exit: nothing more is sent to
it), `down` (no session). When a session ends, `after_session` decides what
comes next: the machine failed (no session ever registered), a new session
after a delay that doubles with each drop (a drop, or a session that ended
with nodes still to start), or none until a node is to start there again.
`remote.parent` carries it out; the tests drive it with no ssh and no clock.

Which nodes the parent hands a session, and when a child ends with its last
node, are read off the nodes' states (`fleet.lifecycle`): `QUEUED`, `child_ends`.

The protocol's words: the child's "started with pid" line and a process's
name (`talker-3`) that stands for a node (`talker`), what a `log` call is,
a `process_died`'s exit code, a refused `stop_process`.
"""

from __future__ import annotations

import re
from typing import Iterable, NamedTuple

from launcher.fleet import lifecycle

DOWN, CONNECTING, ACCEPTING, ENDING = "down", "connecting", "accepting", "ending"
# A dropped machine is tried again after 1, 2, 4 ... seconds, at most this long apart.
RETRY_FIRST_S = 1.0
RETRY_MAX_S = 30.0

# what comes after a session
GIVE_UP = "give up"  # no session ever registered: the machine failed (say why, once)
RETRY = "retry"  # a new session after `delay`
IDLE = "idle"  # none until a node is to start on the machine again

# the nodes handed to the machine's child at the next opportunity: a record in one of these is queued there
QUEUED = frozenset((lifecycle.PENDING, lifecycle.LOST))
# states in which a node has a process on its child (or is being given one)
ON_CHILD = frozenset((lifecycle.LAUNCHING, lifecycle.RUNNING, lifecycle.STOPPING))

# what a child's `log(NAME, LEVEL, TEXT)` is: an error, a node's start (its process name and pid), or words
LOG_ERROR = 8  # rosgraph_msgs/Log's ERROR: this level and above are errors
ERROR, STARTED, INFO = "error", "started", "info"
NO_STOP_PROCESS = ("its roslaunch child cannot stop one process (only a child that is this launcher, `launch`, "
                   "can: LAUNCHER_REMOTE_PROGRAM=launch); the node runs on")

_STARTED = re.compile(r"process\[(?P<proc>[^\]]+)\]: started with pid \[(?P<pid>\d+)\]")
_NUMBER = re.compile(r"-\d+$")


class Session(NamedTuple):
    phase: str = DOWN
    reached: bool = False  # a session of this machine registered once
    launched: bool = False  # a `launch` call of this session succeeded
    delay: float = RETRY_FIRST_S  # the next retry's


class Next(NamedTuple):
    what: str  # GIVE_UP, RETRY or IDLE
    delay: float = 0.0
    dropped: bool = False  # say the machine dropped (not for a session that ended as planned)


def started(s: Session) -> Session:
    """An ssh session is being opened."""
    return s._replace(phase=CONNECTING, launched=False)


def accepting(s: Session) -> Session:
    """The child registered and the launch's parameters are set."""
    return s._replace(phase=ACCEPTING, reached=True)


def launched(s: Session) -> Session:
    return s._replace(launched=True)


def ending(s: Session) -> Session:
    """The child refused a call, or its last node ended (it exits, as roslaunch's children do)."""
    return s._replace(phase=ENDING if s.phase != DOWN else DOWN)


def after_session(s: Session, *, registered: bool, lost: bool, queued: bool) -> tuple[Session, Next]:
    """The session ended; `registered`: its child registered; `lost`: nodes it ran were lost with it;
    `queued`: nodes wait to be started there."""
    reached = s.reached or registered
    s = s._replace(phase=DOWN, reached=reached)
    if not reached:
        return s, Next(GIVE_UP)
    if lost or not registered or (queued and not s.launched):
        return s._replace(delay=min(RETRY_MAX_S, s.delay * 2)), Next(RETRY, s.delay, dropped=lost or not registered)
    s = s._replace(delay=RETRY_FIRST_S)
    return s, Next(RETRY, 0.0) if queued else Next(IDLE)


def child_ends(s: Session, nodes: Iterable[tuple[str, bool]]) -> bool:
    """Does the child end now that a node of it died? `nodes`: (state, owned by the parent's restart policy) of
    each of its machine's nodes. A child whose last node died exits (roslaunch's and ours): what is to start
    next waits for a new session rather than racing the child's exit with a `launch` call. Not after starts
    that failed (`launched` unset): Debian's child ends only when a node died; ours, which also ends then,
    refuses the next `launch`, which then waits for the next session. A node the child respawns itself
    (not owned) is still its own while it respawns."""
    return s.launched and not any(state in ON_CHILD or (state == lifecycle.RESPAWNING and not owned)
                                  for state, owned in nodes)


def log_kind(level: object, message: str) -> tuple[str, tuple[str, int] | None]:
    """What a child's `log` call says: (ERROR, STARTED or INFO, the (process name, pid) of a start line)."""
    if isinstance(level, int) and level >= LOG_ERROR:
        return ERROR, None
    if "started with pid" in message:
        return STARTED, started_line(message)
    return INFO, None


def stop_refusal(fault: str) -> str:
    """Why a child did not stop one process, from its fault: roslaunch's child has no `stop_process`."""
    return NO_STOP_PROCESS if "not supported" in fault else fault


def started_line(message: str) -> tuple[str, int] | None:
    """(process name, pid) of a child's "process[talker-3]: started with pid [1234]" line."""
    m = _STARTED.search(message)
    return (m.group("proc"), int(m.group("pid"))) if m else None


def node_of_process(process_name: str) -> str:
    """The launch file's name of the node a child's process name (`ns/name-N`) stands for."""
    return _NUMBER.sub("", process_name)


def died(exit_code: object) -> tuple[int | None, int | None]:
    """`process_died`'s exit code as (exit code, signal): a negative code is a signal, as Popen's."""
    code = exit_code if isinstance(exit_code, int) else None
    return (None, -code) if code is not None and code < 0 else (code, None)
