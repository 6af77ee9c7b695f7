"""plan.remote: the nodes of other machines binned by machine, and the load's checks of them (pure)."""

from __future__ import annotations

import pytest

from launcher.model.config import Machine, Node, NodePolicy
from launcher.model.errors import LaunchError
from launcher.plan.remote import check_addresses, machine_nodes, policy_warnings, same_host

FAR = Machine("robot2", "192.0.2.10", env_loader="/opt/env.sh", filename="robot.launch", line=3)


def test_the_remote_nodes_are_binned_by_machine_name_in_launch_order():
    nodes = [Node("p", "t", "a", machine_name="r2"), Node("p", "t", "here"), Node("p", "t", "b", machine_name="alias"),
             Node("p", "t", "c", machine_name="r3"), Node("p", "t", "d", machine_name="r2")]
    machines = {"r2": Machine("r2", "far"), "alias": Machine("r2", "far"), "r3": Machine("r3", "farther")}
    binned = machine_nodes(nodes, machines, lambda n: bool(n.machine_name))
    assert {m: [n.name for n in ns] for m, ns in binned.items()} == {"r2": ["a", "b", "d"], "r3": ["c"]}
    assert list(binned) == ["r2", "r3"]
    assert machine_nodes(nodes, machines, lambda n: False) == {}


@pytest.mark.parametrize("master, host, bad", [
    ("http://localhost:11311/", "192.0.2.1", "ROS_MASTER_URI [http://localhost:11311/]"),
    ("http://127.0.1.1:11311/", "192.0.2.1", "ROS_MASTER_URI [http://127.0.1.1:11311/]"),
    ("http://192.0.2.1:11311/", "127.0.0.1", "this machine's ROS address [127.0.0.1]"),
    ("http://192.0.2.1:11311/", "::1", "this machine's ROS address [::1]"),
    ("http://192.0.2.1:11311/", "ip6-localhost", "this machine's ROS address [ip6-localhost]"),
])
def test_a_loopback_address_the_other_machines_cannot_reach_is_an_error_at_the_machine_line(master, host, bad):
    with pytest.raises(LaunchError) as e:
        check_addresses(master, host, [FAR, Machine("r3", "192.0.2.11")])
    assert e.value.message.startswith(bad + " is a loopback address, which machine [robot2] at [192.0.2.10]")
    assert ("ROS_MASTER_URI" if bad.startswith("ROS_MASTER_URI") else "ROS_IP or ROS_HOSTNAME") in e.value.message
    assert (e.value.filename, e.value.line) == ("robot.launch", 3)


def test_addresses_the_other_machines_can_reach_pass():
    check_addresses("http://192.0.2.1:11311/", "robot1.local", [FAR])


def test_the_supervision_extensions_a_child_cannot_apply_are_warned_about_by_what_they_need():
    node = Node("p", "t", "cam", machine_name="robot2", filename="a.launch", line=7,
                policy=NodePolicy(memory_limit=500_000_000, cpu_limit=50.0, hang_timeout=5.0, respawn_max_retries=3))
    assert policy_warnings(node, FAR) == [
        "a.launch:7: node [/cam] runs on machine [robot2] (192.0.2.10): resource limits (memory_limit, cpu_limit) "
        "cannot be applied there (its roslaunch child runs it) and are ignored",
        "a.launch:7: node [/cam] runs on machine [robot2] (192.0.2.10): hang detection (hang_timeout) "
        "cannot be applied there (its roslaunch child runs it) and is ignored"]
    # what the parent applies itself (the restart policy) is no warning; nor is a node with no extension
    assert policy_warnings(node._replace(policy=NodePolicy(respawn_max_retries=3)), FAR) == []
    assert policy_warnings(node._replace(policy=None), FAR) == []


def test_the_same_host_is_the_same_address_user_port_and_env_loader_by_any_name():
    assert same_host(FAR, FAR._replace(name="alias", filename="other.launch", line=9, timeout=3.0))
    for change in ({"address": "192.0.2.11"}, {"user": "ros"}, {"ssh_port": 2222}, {"env_loader": "/other.sh"}):
        assert not same_host(FAR, FAR._replace(**change))
