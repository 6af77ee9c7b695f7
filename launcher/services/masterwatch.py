"""Watching a master found running: its restart noticed, the launch's parameters set again and the nodes that were registered with it restarted.

A master that restarts forgets everything: the parameters the launch set and
every registration. rospy nodes never register again by themselves
(clearpathrobotics/robot_upstart#35), so they run on, unreachable. A master
has no way to tell anyone it started, so the launch asks it: once every
WATCH_PERIOD_S, one system.multicall with getParam('/run_id') and, for each
running node not yet seen registered in its current run, lookupNode: each
round for its first UNSEEN_ASKS rounds, then at gaps that double up to
RESTING_GAP (a program that never registers, not a ROS node, costs the master
and the launch next to nothing; a node that registers late is still seen
within RESTING_GAP rounds), never for a node whose `registers="false"` says it
is none. A
restart is a /run_id that changed or went (roscore sets a new one; a bare
rosmaster has none), seen whether or not the master stopped answering in
between (a restart may fall between two asks). A master that stops answering
and comes back with the same /run_id has kept its state: it is only said.

The same ask is the launch's one look at such a master's registrations (our
own master tells them as they happen): the URIs lookupNode gives go to the run's
graph (`model.graph`, which tells the fleet's records, readiness, hang and stall
probes and systemd's READY=1), with a lookupNode of each node a held node waits
for and, while one waits for a topic or a service, getSystemState. Nothing else
asks a master about registrations.

`MasterState` is the decision (pure: answers in, verdicts out); `MasterWatch`
is the timer around it. Our own master needs none of this: it lives and dies
with the launch.
"""

from __future__ import annotations

import asyncio
from typing import TYPE_CHECKING, Any

from launcher.fleet import lifecycle
from launcher.fleet.state import LOCAL_HOST
from launcher.model.graph import NODE, SERVICE, TOPIC
from launcher.model.names import CALLER_ID
from launcher.model.record import record
from launcher.net.xmlrpc import call
from launcher.output import console

if TYPE_CHECKING:  # (annotations only)
    from launcher.services.service import MasterLink, RunNodes

# One call a second: a restart is noticed within about a second, and a master serving hundreds of nodes
# does not notice one more client (a node's own traffic with it is far more).
WATCH_PERIOD_S = 1.0
WATCH_TIMEOUT_S = 3.0  # an answer slower than this counts as none
# A run not seen registered by this many asks is taken for a process that does not register (not a ROS node):
# it is not restarted with the master, and asked about less and less often: the gaps double up to RESTING_GAP
# rounds. Asked every second, a hundred such processes held 0.8% of a core in the launch (and the master's
# answers); a node that registers late (a slow init_node) still reaches the run's graph within RESTING_GAP.
UNSEEN_ASKS = 5
RESTING_GAP = 16

_UP = (lifecycle.RUNNING, lifecycle.STALLED)  # a run that may have registered, and can be restarted

# the verdicts of MasterState.seen
SAME = ""  # nothing new
DOWN = "down"  # it stopped answering
BACK = "back"  # it answers again, with its state (the same /run_id)
RESTARTED = "restarted"  # a new master: its /run_id changed or went


@record
class Answer:
    """One ask of the master: did it answer, its /run_id (None: not set), the nodes asked about and those
    of them it knows."""

    answered: bool
    run_id: str | None = None
    asked: tuple[str, ...] = ()
    registered: tuple[str, ...] = ()
    uris: tuple[tuple[str, str], ...] = ()  # (name, URI) of the registered ones
    state: tuple[tuple[str, ...], tuple[str, ...]] | None = None  # (topics published, services), when asked


@record
class Run:
    """What the asks told of one node's current run."""

    pid: int
    registered: bool  # seen registered
    misses: int  # asks that found it not (yet) registered
    due: int  # the round from which it is asked about again


def gap(misses: int) -> int:
    """Rounds from an ask that found a run not registered, the `misses`-th such ask, to its next ask."""
    if misses < UNSEEN_ASKS:
        return 1
    return min(RESTING_GAP, 2 ** (misses - UNSEEN_ASKS + 1))


class MasterState:
    """What the launch knows of the master: the /run_id it last had, whether it answers, and for the run of
    each node (by pid) whether it was seen registered or how many asks found it not (yet) registered."""

    def __init__(self, run_id: str | None):
        self.run_id = run_id
        self.down = False
        self.round = 0  # the asks so far: one a round
        self.runs: dict[str, Run] = {}  # node name -> its current run, once asked about

    def to_ask(self, running: dict[str, int]) -> list[str]:
        """A new round: the running nodes (name -> pid) to ask about in it: each whose current run was not seen
        registered yet and is due (a new run is at once)."""
        self.round += 1
        return [name for name, pid in running.items() if self._due(name, pid)]

    def resting(self, running: dict[str, int]) -> list[str]:
        """The running nodes not asked about in this round though not seen registered: runs past UNSEEN_ASKS
        misses, between two asks."""
        runs = self.runs
        return [name for name, pid in running.items()
                if not self._due(name, pid) and not runs[name].registered]

    def _due(self, name: str, pid: int) -> bool:
        run = self.runs.get(name)
        return run is None or run.pid != pid or (not run.registered and run.due <= self.round)

    def seen(self, answer: Answer, running: dict[str, int]) -> str:
        """The verdict on one answer; `running` (name -> pid) is what was running when it was asked."""
        if not answer.answered:
            if self.down:
                return SAME
            self.down = True
            return DOWN
        was_down, self.down = self.down, False
        if answer.run_id != self.run_id:
            return RESTARTED
        registered = set(answer.registered)
        for name in answer.asked:
            pid = running.get(name)
            if pid is None:
                continue
            run = self.runs.get(name)
            misses = run.misses if run is not None and run.pid == pid else 0
            if name in registered:
                self.runs[name] = Run(pid, True, misses, self.round)
            else:
                self.runs[name] = Run(pid, False, misses + 1, self.round + gap(misses + 1))
        return BACK if was_down else SAME

    def restarted(self, run_id: str | None, running: dict[str, int]) -> list[str]:
        """The master is a new one with `run_id`: the nodes of `running` whose run was registered with the
        old one, as far as the launch can tell: seen registered, or not yet asked UNSEEN_ASKS times (a node
        starts and registers between two asks; a process that never registers, not a ROS node, is left
        alone). Each is restarted, and asked about again once it runs."""
        self.run_id = run_id
        names = []
        for name, pid in sorted(running.items()):
            run = self.runs.get(name)
            if run is None or run.pid != pid or run.registered or run.misses < UNSEEN_ASKS:
                names.append(name)
        self.runs.clear()
        return names


class MasterWatch:
    """The launch's service that watches a master found running (see the module's text)."""

    def __init__(self, session: MasterLink, nodes: RunNodes, period: float = WATCH_PERIOD_S):
        self.session = session  # the URI, the parameters, the run id
        self.nodes = nodes  # the fleet and the supervisor
        self.period = period
        self.state = MasterState(session.run_id)
        self._task: asyncio.Task | None = None

    async def start(self) -> None:
        self._task = asyncio.get_running_loop().create_task(self._watch())

    async def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
            try:
                await self._task
            except BaseException:  # noqa: BLE001 - cancelled, or a bug already reported
                pass
            self._task = None

    def _running(self) -> dict[str, int]:
        """This machine's running nodes that register (`registers="false"`: a program that never will): name ->
        pid."""
        fleet = self.nodes.fleet
        if fleet is None:
            return {}
        return {r.name: r.pid for r in fleet.records.values()
                if r.state in _UP and r.pid and r.host == LOCAL_HOST and r.rules.policy.registers}

    def _graph_names(self, asked: list[str], resting: list[str]) -> list[str]:
        """The other names whose registration someone waits for: a node a held node waits for, a node of the
        launch (here or on another machine) running and not registered yet, unless its asks are resting."""
        fleet = self.nodes.fleet
        names = [name for kind, name in sorted(self.session.graph.wanted) if kind == NODE]
        if fleet is not None:
            skip = set(resting)
            names += [r.name for r in fleet.records.values()
                      if r.state in _UP and not r.registered and r.rules.policy.registers and r.name not in skip]
        seen = set(asked)
        return [n for n in names if not (n in seen or seen.add(n))]

    async def _ask(self, names: list[str], system_state: bool = False) -> Answer:
        calls = [{"methodName": "getParam", "params": [CALLER_ID, "/run_id"]}]
        calls += [{"methodName": "lookupNode", "params": [CALLER_ID, n]} for n in names]
        if system_state:
            calls.append({"methodName": "getSystemState", "params": [CALLER_ID]})
        try:
            results = await call(self.session.uri, "system.multicall", calls, timeout=WATCH_TIMEOUT_S)
        except (OSError, ValueError, asyncio.TimeoutError):
            return Answer(False)
        except Exception:  # noqa: BLE001 - a fault: something answers there, a master that will not say
            return Answer(True, self.state.run_id)
        if not isinstance(results, list) or len(results) != len(calls):
            return Answer(True, self.state.run_id)

        def value(r: Any) -> Any:
            ok = isinstance(r, list) and r and isinstance(r[0], list) and len(r[0]) == 3 and r[0][0] == 1
            return r[0][2] if ok else None
        run_id = value(results[0])
        uris = tuple((n, value(r)) for n, r in zip(names, results[1:]) if isinstance(value(r), str) and value(r))
        state = None
        if system_state:
            got = value(results[-1])
            if isinstance(got, list) and len(got) == 3:
                state = (tuple(t for t, nodes in got[0] if nodes), tuple(s for s, nodes in got[2] if nodes))
        return Answer(True, str(run_id) if run_id else None, tuple(names), tuple(n for n, _ in uris), uris, state)

    async def _watch(self) -> None:
        uri = self.session.uri
        while True:
            await asyncio.sleep(self.period)
            running = self._running()
            names = self.state.to_ask(running)
            graph = self.session.graph
            answer = await self._ask(names + self._graph_names(names, self.state.resting(running)),
                                     any(kind in (TOPIC, SERVICE) for kind, _ in graph.wanted))
            verdict = self.state.seen(answer, running)
            if verdict in (SAME, BACK):
                uris = dict(answer.uris)
                for name in answer.asked:
                    graph.node(name, uris.get(name))
                if answer.state is not None:
                    graph.replace(topics=answer.state[0], services=answer.state[1])
            if verdict == DOWN:
                console.printerrlog("WARNING: the master at %s does not answer" % uri)
                self._event("master_down", "the master at %s does not answer" % uri)
            elif verdict == BACK:
                console.printlog("the master at %s answers again (the same run id: nothing was lost)" % uri)
                self._event("master_back", "the master at %s answers again" % uri)
            elif verdict == RESTARTED:
                await self._restarted(answer.run_id)

    async def _restarted(self, seen_run_id: str | None) -> None:
        session, uri = self.session, self.session.uri
        old = self.state.run_id
        run_id = await session.run_id_after_restart(seen_run_id)
        session.graph.clear()  # (a new master: nothing is registered with it)
        names = self.state.restarted(run_id, self._running())
        what = "the master at %s restarted (run id %s, was %s)" % (uri, run_id, old)
        console.printlog_bold("%s: setting the launch's parameters again and restarting the %d node(s) that "
                              "were registered with it%s" % (what, len(names), ": " + ", ".join(names) if names else ""))
        try:
            await session.restore_parameters()
        except Exception as e:  # noqa: BLE001 - a master gone again: its next restart is noticed in turn
            console.printerrlog("cannot set the launch's parameters again on the master at %s: %s" % (uri, e))
        self._event("master_restarted", what, nodes=names, run_id=run_id)
        supervisor = self.nodes.supervisor
        for name in names:
            proc = supervisor.node(name) if supervisor is not None else None
            if proc is not None:
                supervisor.restart(proc, "the master at %s restarted" % uri)

    def _event(self, event: str, reason: str, **fields: Any) -> None:
        fleet = self.nodes.fleet
        if fleet is not None:
            fleet.run_event(event, reason=reason, **fields)
