"""What the relations among a machine's nodes (`plan.relations`) make follow a node's change (`fleet.relations`):
the events told to the nodes bound to it, every (old state, new state) cell written out; the fleet stepping those
events itself (`Fleet.step`); an operator's stop and the launch's stop order."""

from __future__ import annotations

import pytest

from launcher.fleet import lifecycle as m
from launcher.fleet.relations import follow_ups, ready_to_stop, stop_first
from launcher.fleet.state import Fleet
from launcher.model.config import NodePolicy
from launcher.plan.relations import Relations, of


def bound_to(partner: str) -> NodePolicy:
    return NodePolicy(bind_to=partner, wait_for=(("node", partner),))


# What the nodes bound to /manager are told when /manager goes into each state (old != new). Written out, not
# derived: None is nothing; ENDED is BOUND_ENDED with those words; STARTED is BOUND_STARTED when /manager was not
# up before (running or stalled), nothing when it was (a stall that cleared is no new start).
ENDED, STARTED = "ended", "started"
TOLD = {
    m.NEW: None, m.DELAYED: None, m.HELD: None, m.STARTING: None, m.PENDING: None, m.LAUNCHING: None,
    m.RUNNING: (STARTED, None), m.STALLED: None, m.LOST: None,
    m.HUNG: (ENDED, "bound to [/manager], which is hung"),
    m.STOPPING: (ENDED, "bound to [/manager], which is being stopped"),
    m.RESPAWNING: (ENDED, "bound to [/manager], which is respawning"),
    m.EXITED: (ENDED, "bound to [/manager], which exited"),
    m.FATAL: (ENDED, "bound to [/manager], which is fatal"),
    m.STOPPED: (ENDED, "bound to [/manager], which is stopped"),
    m.DETACHED: (ENDED, "bound to [/manager], which is stopped"),
}
REL = of([("/manager", NodePolicy()), ("/a", bound_to("/manager")), ("/b", bound_to("/manager"))])


@pytest.mark.parametrize("old", m.STATES)
@pytest.mark.parametrize("new", m.STATES)
def test_what_the_nodes_bound_to_a_node_are_told_when_it_changes(old, new):
    assert set(TOLD) == set(m.STATES)
    states = {"/manager": new, "/a": m.RUNNING, "/b": m.HELD}
    got = follow_ups(REL, states, "/manager", old, new)
    told = TOLD[new]
    if old == new or told is None or (told[0] == STARTED and old in (m.RUNNING, m.STALLED)):
        assert got == []
    elif told[0] == STARTED:
        assert got == [("/a", m.Event(m.BOUND_STARTED)), ("/b", m.Event(m.BOUND_STARTED))]
    else:
        assert got == [("/a", m.Event(m.BOUND_ENDED, reason=told[1])),
                       ("/b", m.Event(m.BOUND_ENDED, reason=told[1]))]
    # while the launch's nodes are being stopped nothing follows (they are stopped in their order)
    assert follow_ups(REL, states, "/manager", old, new, stopping=True) == []


def test_a_bound_node_no_longer_among_the_nodes_is_told_nothing():
    states = {"/manager": m.RESPAWNING, "/b": m.RUNNING}  # (/a: removed by a reload)
    assert follow_ups(REL, states, "/manager", m.RUNNING, m.RESPAWNING) == [
        ("/b", m.Event(m.BOUND_ENDED, reason="bound to [/manager], which is respawning"))]


# A bound node that has just come down (detached) while its partner is in each state: started again at once only
# when the partner runs (it ran again while this one was being stopped), and not while an operator's stop of the
# partner stops its bound nodes ahead of it.
AGAIN = {s: s in (m.RUNNING, m.STALLED) for s in m.STATES}


@pytest.mark.parametrize("partner", m.STATES)
@pytest.mark.parametrize("old", [m.STOPPING, m.HELD, m.RESPAWNING, m.EXITED, m.FATAL])
def test_a_detached_node_starts_again_at_once_only_while_its_partner_runs(partner, old):
    states = {"/manager": partner, "/a": m.DETACHED, "/b": m.RUNNING}
    again = [("/a", m.Event(m.BOUND_STARTED))] if AGAIN[partner] else []
    assert follow_ups(REL, states, "/a", old, m.DETACHED) == again
    assert follow_ups(REL, states, "/a", old, m.DETACHED, unbinding=frozenset({"/manager"})) == []
    assert follow_ups(REL, states, "/a", old, m.DETACHED, stopping=True) == []
    assert follow_ups(REL, states, "/a", m.DETACHED, m.DETACHED) == []
    # (a node bound to none: nothing)
    assert follow_ups(REL, dict(states, **{"/manager": m.DETACHED}), "/manager", old, m.DETACHED) == [
        ("/a", m.Event(m.BOUND_ENDED, reason="bound to [/manager], which is stopped")),
        ("/b", m.Event(m.BOUND_ENDED, reason="bound to [/manager], which is stopped"))]


def running(fleet: Fleet, name: str, pid: int) -> None:
    fleet.apply(name, m.Event(m.START))
    if fleet.records[name].state == m.HELD:  # (a bound node waits for its partner's registration)
        fleet.apply(name, m.Event(m.READY))
    fleet.apply(name, m.Event(m.SPAWNED, pid=pid))
    assert fleet.records[name].state == m.RUNNING


def test_the_fleet_steps_the_nodes_bound_to_a_node_as_it_steps_it():
    """`Fleet.step` carries out the node's actions, then steps the nodes bound to it and carries out theirs, in
    order; a node of another machine is in no relation (its runner is its machine's child)."""
    fleet = Fleet(clock=lambda: 0.0)
    fleet.relate(of([("/manager", NodePolicy()), ("/loader", bound_to("/manager"))]))  # (this machine's: the plan's)
    fleet.add("/manager", rules=m.Rules(respawn=True))
    fleet.add("/loader", rules=m.Rules(policy=bound_to("/manager")))
    fleet.add("/far", host="far.example", rules=m.Rules(policy=bound_to("/manager"), remote=True))
    running(fleet, "/manager", 10)
    running(fleet, "/loader", 11)
    assert fleet.relations.bound == {"/manager": ("/loader",)}
    carried = []
    own = fleet.step("/manager", m.Event(m.PROCESS_EXITED, exit_code=1),
                     lambda name, actions: carried.append((name, [a.kind for a in actions])))
    assert [a.kind for a in own] == carried[0][1] and carried[0][0] == "/manager"
    assert carried[1:] == [("/loader", [m.BEGIN_STOP])]
    assert fleet.records["/loader"].state == m.STOPPING and fleet.records["/far"].state == m.NEW
    assert fleet.records["/loader"].reason == "bound to [/manager], which is respawning"
    # the loader down: detached; the manager's next start starts it again (held for its registration)
    fleet.step("/loader", m.Event(m.DOWN), lambda name, actions: None)
    assert fleet.records["/loader"].state == m.DETACHED
    carried.clear()
    fleet.step("/manager", m.Event(m.DUE), lambda name, actions: carried.append((name, [a.kind for a in actions])))
    fleet.step("/manager", m.Event(m.SPAWNED, pid=12), lambda name, actions: carried.append(name))
    assert carried[-1] == "/loader" and fleet.records["/loader"].state == m.HELD

    # a node of this machine bound to another machine's (which its child runs, and this fleet's runner does not
    # step): it is told nothing of that one, and comes down for good
    fleet.add("/away", host="far.example", rules=m.Rules(remote=True))
    fleet.add("/near", rules=m.Rules(policy=bound_to("/away")))
    fleet.relate(of([("/near", bound_to("/away"))], fleet.relations))  # (as a remote child's next launch call)
    running(fleet, "/near", 13)
    for kind in (m.START, m.LAUNCH_SENT, m.SPAWNED):
        fleet.apply("/away", m.Event(kind, pid=20))
    assert fleet.records["/away"].state == m.RUNNING and fleet.relations.partner["/near"] == "/away"
    fleet.step("/near", m.Event(m.BOUND_ENDED, reason="by hand"), lambda name, actions: None)
    fleet.step("/near", m.Event(m.DOWN), lambda name, actions: None)
    assert fleet.records["/near"].state == m.DETACHED


def test_the_fleet_keeps_the_relations_it_is_given():
    """The fleet makes no relation of its own: a node's rules (a reload's) change none until the plan's are given
    again (`Fleet.relate`: the reload gives the new plan's before its nodes change)."""
    fleet = Fleet(clock=lambda: 0.0)
    assert fleet.relations == Relations()
    fleet.add("/manager")
    fleet.add("/loader", rules=m.Rules(policy=bound_to("/manager")))
    assert fleet.relations == Relations()
    given = of([("/manager", NodePolicy()), ("/loader", bound_to("/manager"))])
    fleet.relate(given)
    assert fleet.relations is given
    fleet.apply("/loader", m.Event(m.RULES, rules=m.Rules()))
    assert fleet.relations is given
    running(fleet, "/manager", 10)
    carried = []
    fleet.step("/manager", m.Event(m.PROCESS_EXITED, exit_code=1), lambda name, actions: carried.append(name))
    assert carried == ["/manager", "/loader"]  # (told by the relation it was given)


def test_the_stop_order_stops_a_node_once_no_node_that_waits_for_it_is_busy():
    rel = of([("/manager", NodePolicy()), ("/loader", bound_to("/manager")),
              ("/spawner", NodePolicy(wait_for=(("node", "/controllers"),))), ("/controllers", NodePolicy()),
              ("/other", NodePolicy())])
    everyone = ["/manager", "/loader", "/spawner", "/controllers", "/other"]
    assert ready_to_stop(rel, everyone, set(everyone)) == ["/loader", "/spawner", "/other"]
    assert ready_to_stop(rel, ["/manager", "/controllers"], {"/manager", "/controllers", "/spawner"}) == \
        ["/manager"]
    assert ready_to_stop(rel, ["/controllers", "/manager"], set()) == ["/controllers", "/manager"]  # (its order)
    assert ready_to_stop(Relations(), everyone, set(everyone)) == everyone


# An operator's stop of /manager in each state, its bound nodes /a (in each state) and /b (held): those running or
# being stopped are told first; none when /manager does not run (it is stopped, or not, at once).
@pytest.mark.parametrize("manager", m.STATES)
@pytest.mark.parametrize("bound", m.STATES)
def test_an_operators_stop_of_a_node_stops_the_running_nodes_bound_to_it_first(manager, bound):
    states = {"/manager": manager, "/a": bound, "/b": m.HELD}
    first = manager in (m.RUNNING, m.STALLED) and bound in (m.RUNNING, m.STALLED, m.STOPPING)
    why = "bound to [/manager], which is being stopped"
    assert stop_first(REL, states, "/manager") == ([("/a", m.Event(m.BOUND_ENDED, reason=why))] if first else [])
    assert stop_first(REL, states, "/a") == []  # (none is bound to it)


def test_the_fleet_stops_the_nodes_bound_to_a_node_first_and_starts_none_again_meanwhile():
    fleet = Fleet(clock=lambda: 0.0)
    fleet.relate(of([("/manager", NodePolicy()), ("/loader", bound_to("/manager"))]))
    fleet.add("/manager")
    fleet.add("/loader", rules=m.Rules(policy=bound_to("/manager")))
    running(fleet, "/manager", 10)
    running(fleet, "/loader", 11)
    carried = []

    def carry(name, actions):
        carried.append((name, [a.kind for a in actions]))
    assert fleet.unbind("/manager", carry) == ["/loader"] and fleet.unbinding == {"/manager"}
    assert carried == [("/loader", [m.BEGIN_STOP])] and fleet.records["/manager"].state == m.RUNNING
    fleet.step("/loader", m.Event(m.DOWN), carry)  # (its partner runs, but is about to be stopped)
    assert fleet.records["/loader"].state == m.DETACHED
    fleet.bound_stopped("/manager")
    assert not fleet.unbinding
    assert fleet.unbind("/loader", carry) == [] and not fleet.unbinding
