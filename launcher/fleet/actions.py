"""What carries out the node table's actions, and the one place that reads them: `ActionRunner` and `carry_out`.

The node state machine (`fleet.lifecycle`) decides; a runner does. Two runners
implement `ActionRunner`: the supervisor (`process.supervisor`, this machine's nodes:
processes, pidfds, signals) and the remote parent (`remote.parent`, the other
machines' nodes: `launch` calls to their children). Each tells the fleet what
happened to a node and hands the actions it gets back to `carry_out`, so an action
means the same to both. END_LAUNCH is the fleet's own (the launch's phase,
`fleet.launchphase`) and NOTE is words for the console (`output.narrate`): no
runner's. Pure: no I/O here, only calls of the runner's methods in the actions'
order. (`fleet.runner` holds the other seams of a runner: what the health watchers
and the services call on it.)
"""

from __future__ import annotations

from typing import Any, Iterable, Protocol

from launcher.fleet import lifecycle


class ActionRunner(Protocol):
    """A node's runner; `node` is its own handle of the node (the supervisor's NodeProcess, the parent's
    RemoteNode)."""

    def spawn(self, node: Any) -> None:
        """SPAWN: start its process on this machine."""

    def launch(self, node: Any) -> None:
        """LAUNCH: hand it to its machine's child at the next opportunity."""

    def schedule(self, node: Any, delay: float) -> None:
        """SCHEDULE: tell the fleet DUE after `delay` seconds."""

    def cancel(self, node: Any) -> None:
        """CANCEL: call off its timer and its readiness hold."""

    def hold(self, node: Any) -> None:
        """HOLD: have readiness watch its wait_for conditions (READY or NOT_READY follows)."""

    def begin_stop(self, node: Any) -> None:
        """BEGIN_STOP: the stop escalation (this machine), or the child's stop (asked by the caller)."""

    def kill(self, node: Any) -> None:
        """KILL: SIGKILL its run now."""


# each action kind a runner carries out, and its method (END_LAUNCH, NOTE: not a runner's)
METHODS = {lifecycle.SPAWN: "spawn", lifecycle.LAUNCH: "launch", lifecycle.SCHEDULE: "schedule",
           lifecycle.CANCEL: "cancel", lifecycle.HOLD: "hold", lifecycle.BEGIN_STOP: "begin_stop",
           lifecycle.KILL: "kill"}
NOT_A_RUNNERS = frozenset((lifecycle.END_LAUNCH, lifecycle.NOTE))


def carry_out(runner: ActionRunner, node: Any, actions: Iterable[lifecycle.Action]) -> None:
    """Do what the node's step said, in its order."""
    for action in actions:
        kind = action.kind
        if kind == lifecycle.SCHEDULE:
            runner.schedule(node, action.delay)
        elif kind in METHODS:
            getattr(runner, METHODS[kind])(node)
        elif kind not in NOT_A_RUNNERS:
            raise ValueError("no runner carries out [%s]" % kind)  # (a kind added to the table, not here)
