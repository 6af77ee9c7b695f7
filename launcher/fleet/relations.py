"""What the relations among a machine's nodes make follow a node's change: pure.

The relations themselves are the plan's (`plan.relations`: who is bound to
whom, who waits for whom), made once from the nodes' policies and given to the
fleet (`Fleet.relate`). Here is what they decide as the nodes change: the
events the nodes bound to a node are told when it goes down or runs again
(`follow_ups`; the fleet steps them as it steps the node, so a runner carries
out their actions as any other); an operator's stop of a node stops the nodes
bound to it first (`stop_first`); the launch's stop follows the waits
(`ready_to_stop`). Both ends of a relation are nodes of one machine: its
supervisor runs them both.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Container, Iterable, Mapping

from launcher.fleet import lifecycle
from launcher.fleet.lifecycle import Event

if TYPE_CHECKING:
    from launcher.plan.relations import Relations

# A node in one of these runs for the nodes bound to it; in one of DOWN it is down for them (they stop and wait
# for its next start), in the words told to them.
UP = frozenset((lifecycle.RUNNING, lifecycle.STALLED))
DOWN = {lifecycle.RESPAWNING: "is respawning", lifecycle.HUNG: "is hung", lifecycle.STOPPING: "is being stopped",
        lifecycle.EXITED: "exited", lifecycle.FATAL: "is fatal", lifecycle.STOPPED: "is stopped",
        lifecycle.DETACHED: "is stopped"}


def why_ended(name: str, state: str) -> str:
    """The reason a node bound to `name` is told it ended: it went into `state` (one of DOWN)."""
    return "bound to [%s], which %s" % (name, DOWN[state])


def follow_ups(relations: Relations, states: Mapping[str, str], name: str, old: str, new: str,
               unbinding: frozenset[str] = frozenset(), stopping: bool = False) -> list[tuple[str, Event]]:
    """The events the nodes related to `name` are told after it went from state `old` to `new`, in order:
    each node bound to it BOUND_ENDED when it goes down, BOUND_STARTED when it runs again; and `name` itself
    BOUND_STARTED when it has come down (detached) while its partner already runs again (it was being stopped
    when that one ran), unless the partner's bound nodes are being stopped ahead of it (`unbinding`: an
    operator's stop of the partner). Nothing while the launch's nodes are being stopped (`stopping`: they are
    stopped in their order anyway), nor for a step that changed no state. `states`: every node's state."""
    if old == new or stopping:
        return []
    out = []
    bound = [b for b in relations.bound.get(name, ()) if b in states]
    if new in DOWN:
        out += [(b, Event(lifecycle.BOUND_ENDED, reason=why_ended(name, new))) for b in bound]
    elif new == lifecycle.RUNNING and old not in UP:
        out += [(b, Event(lifecycle.BOUND_STARTED)) for b in bound]
    if new == lifecycle.DETACHED:
        partner = relations.partner.get(name)
        if partner is not None and states.get(partner) in UP and partner not in unbinding:
            out.append((name, Event(lifecycle.BOUND_STARTED)))
    return out


def ready_to_stop(relations: Relations, waiting: Iterable[str], busy: Container[str]) -> list[str]:
    """The launch's stop order: of the nodes `waiting` for their turn to stop, those (in their order) that no node
    `busy` (running, or being stopped) waits for: a controller spawner stops before its controller manager, a
    nodelet loader before its manager; nodes with no such relation stop together."""
    return [n for n in waiting if not any(w in busy for w in relations.stop_before.get(n, ()))]


def stop_first(relations: Relations, states: Mapping[str, str], name: str) -> list[tuple[str, Event]]:
    """An operator's stop of `name` while it runs: the nodes bound to it that run (or are being stopped) are told
    BOUND_ENDED first (a nodelet's loader unloads it from its manager); it is stopped once they are down. None:
    it is stopped at once."""
    if states.get(name) not in UP:
        return []
    why = why_ended(name, lifecycle.STOPPING)
    return [(b, Event(lifecycle.BOUND_ENDED, reason=why)) for b in relations.bound.get(name, ())
            if states.get(b) in UP or states.get(b) == lifecycle.STOPPING]
