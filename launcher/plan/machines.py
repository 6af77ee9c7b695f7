"""Which of a launch's machines are this one: decided once per machine, not once per node and question."""

from __future__ import annotations

import socket
from typing import Any, Callable, Mapping


def is_local_host(host: str, environ: Mapping[str, str]) -> bool:
    """Is `host` this machine (so that a master for it may be started here, a node on it runs here)?"""
    if host in ("localhost", "::1") or host.startswith("127."):
        return True
    names = {socket.gethostname()}
    for key in ("ROS_HOSTNAME", "ROS_IP"):
        if environ.get(key):
            names.add(environ[key])
    if host in names:
        return True
    try:
        import psutil  # (16 ms of import, measured, that only a launch with <machine>s or a far master pays)
        local = {a.address.split("%")[0] for addrs in psutil.net_if_addrs().values() for a in addrs}
        resolved = {ai[4][0] for ai in socket.getaddrinfo(host, None)}
    except (OSError, ImportError, UnicodeError):  # (a malformed host name: idna refuses it)
        return False
    return bool(local & resolved)


def remote_machines(config: Any, environ: Mapping[str, str],
                    is_local: Callable[[str, Mapping[str, str]], bool] = is_local_host) -> frozenset[str]:
    """The names of the machines, among those the launch's nodes run on, that are other hosts.

    Each address is looked at once (a DNS lookup and the interface list each
    time): a launch of 500 nodes on two machines asks twice, not 1,500 times.
    Machines no node uses are not looked at (an address that does not resolve
    must cost nothing when nothing runs there).
    """
    remote = set()
    for name in {n.machine_name for n in config.nodes if n.machine_name}:
        machine = config.machines.get(name)
        if machine is not None and not (machine.is_local or is_local(machine.address, environ)):
            remote.add(name)
    return frozenset(remote)


def remote_test(remote: frozenset[str]) -> Callable[[Any], bool]:
    """node -> is it assigned to another machine? (for `node_specs`, the summary, the remote parent)"""
    return lambda node: bool(node.machine_name) and node.machine_name in remote
