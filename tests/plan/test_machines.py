"""plan.machines: which machines are other hosts, looked up once per machine, and node_specs without a Plan."""

from __future__ import annotations

import socket

from launcher.model.config import LaunchConfig, Machine, Node
from launcher.workspace.packages import PackageIndex
from launcher.plan.machines import remote_machines, remote_test
from launcher.plan.specs import node_specs
from launcher.model.runopts import RunOptions
from launcher.run.load import plan_for

FAR = "192.0.2.10"  # TEST-NET-1: never an address of this machine


def _config(n: int) -> LaunchConfig:
    nodes = tuple(Node("refpkg", "sleeper.sh", "far%d" % i, machine_name="robot2") for i in range(n))
    nodes += (Node("refpkg", "sleeper.sh", "here"), Node("refpkg", "sleeper.sh", "base", machine_name="base"))
    machines = {"robot2": Machine("robot2", FAR), "base": Machine("base", "localhost"),
                "unused": Machine("unused", "no-such-host.invalid")}
    return LaunchConfig(nodes=nodes, machines=machines)


def test_a_machine_address_is_looked_up_once_however_many_nodes_and_questions(monkeypatch):
    asked = []
    real = socket.getaddrinfo

    def counting(host, *args, **kwargs):
        asked.append(host)
        return real(host, *args, **kwargs)

    monkeypatch.setattr(socket, "getaddrinfo", counting)
    plan = plan_for(_config(50), "http://localhost:11311/", {})
    for _ in range(3):  # the checks, the summary, node_specs and the remote parent each ask
        assert [plan.remote(n) for n in plan.config.nodes] == [True] * 50 + [False, False]
    assert asked == [FAR]  # (the old Plan.remote: 150 lookups; a machine no node uses: none)


def test_remote_machines_are_those_of_nodes_on_other_hosts():
    seen = []

    def is_local(host, environ):
        seen.append(host)
        return host == "localhost"

    remote = remote_machines(_config(3), {}, is_local)
    assert remote == {"robot2"} and seen == [FAR]  # ("localhost" is local by its name, "unused" runs nothing)
    is_remote = remote_test(remote)
    assert [is_remote(n) for n in _config(1).nodes] == [True, False, False]


def test_node_specs_need_no_plan_only_what_the_plan_worked_out(tmp_path):
    config = _config(2)
    env = {"ROS_PACKAGE_PATH": str(tmp_path), "ROS_HOME": str(tmp_path)}
    said: list[str] = []
    specs, failed = node_specs(config, "http://localhost:11311/", env, PackageIndex(env), remote_test(frozenset({"robot2"})),
                               opts=RunOptions(screen=True), run_dir=str(tmp_path), first_number=1,
                               log=said.append, log_error=said.append)
    # (an empty workspace: each local node is reported as one that cannot be prepared, numbered all the same)
    assert specs == [] and failed == [("here-2", False), ("base-3", False)]
    # ... and said so through the run's console, given to it (the plan writes nothing itself)
    assert len(said) == 2 and all(s.startswith("ERROR: cannot launch node of type") for s in said), said
