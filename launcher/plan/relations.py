"""The relations among a machine's nodes, made from the plan's nodes: pure data.

Two relations come from the launch file (the nodes' policies, as the plan made
them): a node bound to another (`bind_to`, or a nodelet loader to its manager:
`plan.order.bind_nodelets`) is stopped while that one is down and started
again after its next start; a node that waits for another (`wait_for="node:..."`,
which a `bind_to` adds) is stopped before it at the launch's end. `of` makes
both, once per plan (`Plan.relations`: the nodes of this machine), or once per
`launch` call a remote child is given (added to what it has, `without` the
relations of the nodes it is given again). The fleet keeps what it is given
(`Fleet.relate`) and steps the nodes the first relation names as it steps a
node (`fleet.relations`: the events a change makes follow, the operator's
stop, the launch's stop order).
"""

from __future__ import annotations

from typing import Iterable, Mapping

from launcher.model.config import NodePolicy
from launcher.model.record import record


@record
class Relations:
    """Each node's relations to the other nodes of its machine, by node name, in the order the nodes were given."""

    bound: Mapping[str, tuple[str, ...]] = {}  # a node -> the nodes bound to it (bind_to)
    partner: Mapping[str, str] = {}  # a bound node -> the node it is bound to
    stop_before: Mapping[str, tuple[str, ...]] = {}  # a node -> the nodes that wait for it: stopped before it


def of(nodes: Iterable[tuple[str, NodePolicy | None]], relations: Relations = Relations()) -> Relations:
    """The relations `nodes` (name, policy) ask for, in their order, added to `relations`. A relation to a node
    not among a machine's nodes (another machine's, or no node of the launch) names it all the same: it is none,
    as every reader asks about the nodes it has."""
    for name, policy in nodes:
        if policy is not None:
            relations = joined(relations, name, policy)
    return relations


def joined(relations: Relations, name: str, policy: NodePolicy) -> Relations:
    """`relations` with those of one more node; the same object when it asks for none (most nodes: nothing is
    copied)."""
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


def without(relations: Relations, names: Iterable[str]) -> Relations:
    """`relations` with none of the named nodes' own (a node given again, as a remote child's parent renews it
    with other rules): no partner, in no node's bound nodes, waiting for none. The relations to them stay: a
    node bound to one of them is bound to what comes under its name."""
    names = set(names)
    if not names & (set(relations.partner) | {n for waiting in relations.stop_before.values() for n in waiting}):
        return relations

    def kept(by: Mapping[str, tuple[str, ...]]) -> dict[str, tuple[str, ...]]:
        left = {node: tuple(n for n in them if n not in names) for node, them in by.items()}
        return {node: them for node, them in left.items() if them}
    return Relations(kept(relations.bound), {n: p for n, p in relations.partner.items() if n not in names},
                     kept(relations.stop_before))
