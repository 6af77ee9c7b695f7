"""The relations among a machine's nodes, as data, and what they make follow a node's change: pure.

Two relations come from the launch file (the nodes' policies, as the plan made them):
a node bound to another (`bind_to`, or a nodelet loader to its manager:
`plan.order.bind_nodelets`) is stopped while that one is down and started again
after its next start; a node that waits for another (`wait_for="node:..."`, which a
`bind_to` adds) is stopped before it at the launch's end. `of` makes both once from
the nodes' names and policies; the fleet keeps them (made again only when its nodes
or their rules change) and steps the nodes the first relation names (`follow_ups`)
as it steps a node, so a runner carries out their actions as any other; an
operator's stop of a node stops the nodes bound to it first (`stop_first`), and the
launch's stop follows the second (`ready_to_stop`). Both ends of a relation are nodes
of one machine: its supervisor runs them both. (Made in the fleet, from the policies
the plan gave each node, rather than in `plan/`: the fleet is below the plan, and a
machine's nodes come one `launch` call at a time to a remote child, or change in a
reload.)
"""

from __future__ import annotations

from typing import Container, Iterable, Mapping, NamedTuple

from launcher.fleet import lifecycle
from launcher.fleet.lifecycle import Event
from launcher.model.config import NodePolicy

# A node in one of these runs for the nodes bound to it; in one of DOWN it is down for them (they stop and wait
# for its next start), in the words told to them.
UP = frozenset((lifecycle.RUNNING, lifecycle.STALLED))
DOWN = {lifecycle.RESPAWNING: "is respawning", lifecycle.HUNG: "is hung", lifecycle.STOPPING: "is being stopped",
        lifecycle.EXITED: "exited", lifecycle.FATAL: "is fatal", lifecycle.STOPPED: "is stopped",
        lifecycle.DETACHED: "is stopped"}


class Relations(NamedTuple):
    """Each node's relations to the other nodes of its machine, by node name, in the order the nodes were given."""

    bound: Mapping[str, tuple[str, ...]] = {}  # a node -> the nodes bound to it (bind_to)
    partner: Mapping[str, str] = {}  # a bound node -> the node it is bound to
    stop_before: Mapping[str, tuple[str, ...]] = {}  # a node -> the nodes that wait for it: stopped before it


def of(nodes: Iterable[tuple[str, NodePolicy]]) -> Relations:
    """The relations `nodes` (name, policy) ask for, in their order. A relation to a node not among a machine's
    nodes (another machine's, or no node of the launch) names it all the same: it is none, as every reader
    asks about the nodes it has."""
    relations = Relations()
    for name, policy in nodes:
        relations = joined(relations, name, policy)
    return relations


def joined(relations: Relations, name: str, policy: NodePolicy) -> Relations:
    """`relations` with those of one more node (as the fleet is given its nodes: one at a time); the same object
    when it asks for none (most nodes: nothing is copied)."""
    waits = [t for kind, t in policy.wait_for if kind == "node" and t != name]
    binds = policy.bind_to and policy.bind_to != name
    if not waits and not binds:
        return relations
    bound, partner, before = dict(relations.bound), dict(relations.partner), dict(relations.stop_before)
    if binds:
        partner[name] = policy.bind_to
        bound[policy.bind_to] = bound.get(policy.bind_to, ()) + (name,)
    for target in waits:
        if name not in before.get(target, ()):
            before[target] = before.get(target, ()) + (name,)
    return Relations(bound, partner, before)


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
