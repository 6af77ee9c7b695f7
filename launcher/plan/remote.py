"""The launch's nodes on other machines as the plan sees them: binned by machine, and what is checked at load.

Pure: a function of the loaded launch. A remote host must reach the master
and the parent (a loopback address is an error naming the `<machine>`'s file
and line), and a node's supervision extensions that a roslaunch child cannot
be told are warned about (its launch XML is roslaunch's). Which machines are
other hosts is `plan.machines`' (it asks the network); `remote/` runs the nodes.
"""

from __future__ import annotations

from typing import Callable, Iterable, Mapping

from launcher.model.config import Machine, Node, NodePolicy
from launcher.model.errors import LaunchError

# The NodePolicy fields a roslaunch child cannot be told (its launch XML is roslaunch's), with what they need.
NOT_ON_OTHER_MACHINES = (("memory_limit", "resource limits"), ("cpu_limit", "resource limits"),
                         ("on_limit", "resource limits"), ("enable_coredumps", "core dumps"),
                         ("hang_timeout", "hang detection"), ("sigint_timeout", "per-node stop timeouts"),
                         ("sigterm_timeout", "per-node stop timeouts"), ("log_max_size", "output log rotation"),
                         ("log_backups", "output log rotation"))
_DEFAULT_POLICY = NodePolicy()


def machine_nodes(nodes: Iterable[Node], machines: Mapping[str, Machine],
                  is_remote: Callable[[Node], bool]) -> dict[str, list[Node]]:
    """The remote nodes binned by machine name, in launch order."""
    binned: dict[str, list[Node]] = {}
    for node in nodes:
        if is_remote(node):
            binned.setdefault(machines[node.machine_name].name, []).append(node)
    return binned


def check_addresses(master_uri: str, advertised_host: str, machines: list[Machine]) -> None:
    """A remote host must reach the master and the parent: loopback addresses are an error (file:line)."""
    import urllib.parse  # (only a launch with other machines asks: urllib.parse and ipaddress cost ~0.4 MB)
    host = urllib.parse.urlsplit(master_uri).hostname or ""
    for what, name, var in (("ROS_MASTER_URI", host, "ROS_MASTER_URI"),
                            ("this machine's ROS address", advertised_host, "ROS_IP or ROS_HOSTNAME")):
        if name in ("localhost", "::1", "ip6-localhost") or name.startswith("127."):
            m = machines[0]
            raise LaunchError("%s [%s] is a loopback address, which machine [%s] at [%s] cannot reach: set %s to "
                              "an address of this computer that the other machines can reach"
                              % (what, master_uri if var == "ROS_MASTER_URI" else name, m.name, m.address, var),
                              m.filename or None, m.line or None)


def policy_warnings(node: Node, machine: Machine) -> list[str]:
    """Warnings (file:line) for the node's supervision extensions that cannot work on another machine."""
    policy = node.policy
    if policy is None:
        return []
    unsupported: dict[str, list[str]] = {}
    for field, what in NOT_ON_OTHER_MACHINES:
        if getattr(policy, field) != getattr(_DEFAULT_POLICY, field):
            unsupported.setdefault(what, []).append(field)
    where = "%s:%d: " % (node.filename, node.line) if node.filename and node.line else ""
    return ["%snode [%s] runs on machine [%s] (%s): %s cannot be applied there (its roslaunch child runs it) "
            "and %s ignored" % (where, node.full_name, machine.name, machine.address, what + " (" + ", ".join(fields)
                                + ")", "is" if len(fields) == 1 else "are")
            for what, fields in unsupported.items()]


def same_host(a: Machine, b: Machine) -> bool:
    """The same machine to reach, wherever it is declared and by whichever name."""
    return (a.address, a.user, a.ssh_port, a.env_loader) == (b.address, b.user, b.ssh_port, b.env_loader)
