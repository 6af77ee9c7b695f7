"""plan.plan: a run's plan as a pure description (its other machines given to it), and its checks of the nodes."""

from __future__ import annotations

import pytest

from launcher.model.config import LaunchConfig, Machine, Node, NodePolicy
from launcher.model.errors import LaunchError
from launcher.plan.plan import Plan

FAR = Machine("robot2", "192.0.2.10", env_loader="/opt/env.sh")


def _plan(*nodes: Node, remote: frozenset = frozenset({"robot2"})) -> Plan:
    config = LaunchConfig(nodes=nodes, machines={"robot2": FAR, "here": Machine("here", "localhost")})
    return Plan(config, "http://192.0.2.1:11311/", {}, remote_machines=remote)


def test_the_nodes_of_the_machines_given_as_other_hosts_are_remote_by_machine():
    plan = _plan(Node("p", "t", "a", machine_name="robot2"), Node("p", "t", "b", machine_name="here"),
                 Node("p", "t", "c"), Node("p", "t", "d", machine_name="robot2"))
    assert [plan.remote(n) for n in plan.config.nodes] == [True, False, False, True]
    assert {m: [n.name for n in ns] for m, ns in plan.remote_nodes().items()} == {"robot2": ["a", "d"]}
    local = _plan(*plan.config.nodes, remote=frozenset())
    assert not any(local.remote(n) for n in local.config.nodes) and local.remote_nodes() == {}


@pytest.mark.parametrize("required, node, words", [
    (False, Node("p", "t", "a", respawn=True, required=True, filename="x.launch", line=4),
     "x.launch:4: respawn and required cannot both be set to true (node [/a])"),
    (True, Node("p", "t", "a", respawn=True, filename="x.launch", line=5),
     "x.launch:5: respawn and required cannot both be set to true (node [/a], --required)"),
])
def test_respawn_with_required_is_an_error_at_the_node(required, node, words):
    with pytest.raises(LaunchError) as e:
        _plan(node).check_nodes(required)
    assert str(e.value) == words


@pytest.mark.parametrize("node, words", [
    (Node("p", "t", "a", machine_name="nowhere", filename="x.launch", line=6),
     "x.launch:6: unknown machine [nowhere]: no <machine> tag declares it (node [/a])"),
    (Node("p", "t", "t", machine_name="gone", test_name="t", filename="y.test", line=2),
     "y.test:2: unknown machine [gone]: no <machine> tag declares it (test [/t])"),
])
def test_a_node_or_test_on_an_unknown_machine_refuses_the_run_as_roslaunchs(node, words):
    config = LaunchConfig(nodes=(Node("p", "t", "ok", machine_name="here"),) + (() if node.is_test else (node,)),
                          tests=(node,) if node.is_test else (), machines={"here": Machine("here", "localhost")})
    with pytest.raises(LaunchError) as e:
        Plan(config, "http://192.0.2.1:11311/", {}).check_nodes(False)
    assert str(e.value) == words


def test_checked_nodes_bind_a_local_nodelet_loader_to_its_manager_and_refuse_wait_cycles():
    manager = Node("nodelet", "nodelet", "manager", args="manager")
    loader = Node("nodelet", "nodelet", "cam", args="load cam/Driver manager")
    far = Node("nodelet", "nodelet", "far", args="load cam/Driver /manager", machine_name="robot2")
    plan = _plan(manager, loader, far)
    plan.check_nodes(False)
    policies = {n.name: n.policy for n in plan.config.nodes}
    assert policies["cam"].bind_to == "/manager" and policies["far"] is None  # (a remote loader is not bound)
    # the relations this machine's fleet is given: the loader bound to its manager; the other machine's none
    assert plan.relations.bound == {"/manager": ("/cam",)} and plan.relations.stop_before == {"/manager": ("/cam",)}
    far_bound = _plan(manager, Node("p", "t", "b", policy=NodePolicy(bind_to="/manager"), machine_name="robot2"),
                      Node("p", "t", "c", policy=NodePolicy(wait_for=(("node", "/manager"),))))
    assert far_bound.relations.partner == {} and far_bound.relations.stop_before == {"/manager": ("/c",)}
    cycle = _plan(Node("p", "t", "a", policy=NodePolicy(wait_for=(("node", "/b"),))),
                  Node("p", "t", "b", policy=NodePolicy(wait_for=(("node", "/a"),))))
    with pytest.raises(LaunchError):
        cycle.check_nodes(False)
