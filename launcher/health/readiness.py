"""Readiness: holding a node's start until its `wait_for` conditions exist on the master.

A condition is `(kind, name)`:

    topic    some node publishes it
    service  some node provides it
    node     the node is registered (a node of the launch: its current run, as the fleet's record says; any
             other: by its name)
    param    the parameter is set (hasParam)
    output   a line of that node's output matches a pattern (`NODE:PATTERN`; `health/outputwatch.py`
             follows its output file while the condition waits)

The first three are what is registered with the master: the run's graph (`model.graph`) and the fleet tell
of their changes, and the held nodes are looked at again at each (our master tells the graph as it happens;
a master found running is asked by its watcher, `services.masterwatch`, about what is waited for). A
parameter or an output line is looked for at most `POLL_S` apart, and only while a node waits for one: one
call per distinct parameter, so a launch with a hundred waiting nodes asks no more than one with a single one.
The conditions are checked at the first start only: a respawn does not wait
again (what it needed was there once; holding a crashed node back until its
peers are all up again is the restart policy's business, not readiness'). The
one exception is a bound node (`bind_to`, a nodelet loader) started again after
its partner's restart: it is held again until that partner's new run has registered.

While held, the node's state is `held` (`waiting` to the outside); when its
`wait_timeout` passes with a condition still missing, its runner reports it
as failed to start, naming what was missing (`give_up_waiting`). The runner
(the supervisor, or the remote parent) is told `release(key)` or
`give_up_waiting(key, why)`; `drop(key)` lets go of a node (stopped, shutdown).
"""

from __future__ import annotations

import asyncio
from typing import TYPE_CHECKING, Any

from launcher import compat
from launcher.net import xmlrpc
from launcher.fleet.lifecycle import describe
from launcher.fleet.state import Change, Fleet
from launcher.health.outputwatch import OutputFollower
from launcher.model.graph import NODE, Graph
from launcher.model.names import CALLER_ID

if TYPE_CHECKING:  # (annotations only)
    from launcher.fleet.runner import HeldNode, ReadinessRunner

# While a parameter or an output line is waited for, it is looked for at most this often.
POLL_S = 0.2
# One master call may take this long before the poll counts its conditions as not met yet.
CALL_TIMEOUT_S = 2.0
_POLLED = ("param", "output")


class Readiness:
    """The nodes of one runner whose start is held, and what releases them: the graph's and the fleet's
    changes, and the poll of parameters and output lines while one is waited for."""

    def __init__(self, master_uri: str, runner: ReadinessRunner, graph: Graph, fleet: Fleet,
                 period: float = POLL_S):
        self.master_uri = master_uri
        self.runner = runner
        self.graph = graph
        self.fleet = fleet
        self.period = period
        self.loop = asyncio.get_running_loop()
        self.waiting: dict[HeldNode, float] = {}  # NodeProcess -> loop time of its wait_timeout
        self._task: asyncio.Task | None = None
        self._wake = compat.Event()  # set by a change that may meet a condition
        graph.listeners.append(self._changed)
        fleet.listeners.append(self._changed)
        # node name -> its output file followed, while an output condition waits (runner.output_path(name))
        self.outputs: dict[str, OutputFollower] = {}

    def hold(self, proc: HeldNode) -> None:
        """Hold `proc` (anything with a `spec.policy`) until its conditions are met; the poll starts with
        the first one."""
        self.waiting[proc] = self.loop.time() + proc.spec.policy.wait_timeout
        if self._task is None or self._task.done():
            self._task = self.loop.create_task(self._poll())

    def drop(self, proc: HeldNode) -> None:
        self.waiting.pop(proc, None)

    def close(self) -> None:
        for listeners in (self.graph.listeners, self.fleet.listeners):
            if self._changed in listeners:
                listeners.remove(self._changed)
        if self._task is not None:
            self._task.cancel()
            self._task = None
        self.graph.want(self, set())
        self.waiting.clear()
        self.outputs.clear()

    def _changed(self, _change: Change) -> None:
        if self.waiting:
            self._wake.set()

    async def _poll(self) -> None:
        try:
            await self._until_released()
        finally:
            self.graph.want(self, set())

    async def _until_released(self) -> None:
        while self.waiting:
            self._wake.clear()  # (before looking: a change while the master is asked wakes the next look)
            wanted = {c for proc in self.waiting for c in proc.spec.policy.wait_for}
            self.graph.want(self, wanted)
            present = await self.present(wanted)
            now = self.loop.time()
            for proc, deadline in list(self.waiting.items()):
                if proc not in self.waiting:  # let go of (dropped) while the master was asked
                    continue
                missing = [c for c in proc.spec.policy.wait_for if c not in present]
                if not missing:
                    del self.waiting[proc]
                    self.runner.release(proc)
                elif now >= deadline:
                    del self.waiting[proc]
                    self.runner.give_up_waiting(
                        proc, "still waiting after %g s for %s" % (proc.spec.policy.wait_timeout, describe(missing)))
            if self.waiting:
                timeout = min(self.waiting.values()) - self.loop.time()
                if any(kind in _POLLED for kind, _ in wanted):
                    timeout = min(timeout, self.period)
                try:
                    await compat.wait_for(self._wake.wait(), max(0.0, timeout))
                except asyncio.TimeoutError:
                    pass
        self.outputs.clear()  # (a later wait reads the files from their start again)

    async def present(self, wanted: set[tuple[str, str]]) -> set[tuple[str, str]]:
        """Which of the `wanted` conditions hold now (a master that does not answer: no parameter is set)."""
        found: set[tuple[str, str]] = set()
        for kind, name in wanted:
            if kind == "output":
                if self._output_matched(name):
                    found.add((kind, name))
            elif kind == "param":
                if await self._ask("hasParam", name):
                    found.add((kind, name))
            elif kind == NODE:
                record = self.fleet.records.get(name)
                if record.registered if record is not None else self.graph.has(kind, name):
                    found.add((kind, name))
            elif self.graph.has(kind, name):
                found.add((kind, name))
        return found

    def _output_matched(self, condition: str) -> bool:
        node, _, pattern = condition.partition(":")  # (a node name holds no colon)
        follower = self.outputs.get(node)
        if follower is None:
            path = self.runner.output_path(node)
            if path is None:
                return False
            follower = self.outputs[node] = OutputFollower(path)
        follower.matcher.want(pattern)
        if pattern not in follower.matcher.matched:
            follower.read()
        return pattern in follower.matcher.matched

    async def _ask(self, method: str, *args: Any) -> Any:
        """The value of a master call that succeeded (code 1), else None."""
        try:
            code, _msg, value = await xmlrpc.call(self.master_uri, method, CALLER_ID, *args, timeout=CALL_TIMEOUT_S)
        except (OSError, asyncio.TimeoutError, xmlrpc.Fault, xmlrpc.XmlRpcError, ValueError, TypeError):
            return None
        return value if code == 1 else None
