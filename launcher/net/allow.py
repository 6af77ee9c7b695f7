"""Who may connect to a server: networks allowed by `--master-allow`, checked when a connection is accepted.

rosmaster answers anyone who can reach its port. An allow-list closes the
embedded master to strangers: a client from outside the listed networks has
its connection closed before a byte of it is read (an XML-RPC fault would
mean the call had been read). Loopback and this machine's own addresses are
always allowed, so that local nodes that set ROS_IP to a LAN address keep
working.
"""

from __future__ import annotations

import ipaddress
from typing import Iterable, Union

_Network = Union[ipaddress.IPv4Network, ipaddress.IPv6Network]
_LOOPBACK = ("127.0.0.0/8", "::1/128")


def parse_networks(cidrs: Iterable[str]) -> list[_Network]:
    """`10.0.0.0/8`, `192.168.1.7` (one host) or `fd00::/8`; ValueError naming the bad one."""
    networks = []
    for text in cidrs:
        try:
            networks.append(ipaddress.ip_network(text.strip(), strict=False))
        except ValueError:
            raise ValueError("not a network address or CIDR: %r (e.g. 192.168.1.0/24)" % text) from None
    return networks


def own_addresses() -> list[_Network]:
    """Every address of this machine's interfaces, each as a one-host network."""
    import psutil  # (only when an allow-list is given: most runs never need it)
    import socket
    own = []
    for addrs in psutil.net_if_addrs().values():
        for a in addrs:
            if a.family in (socket.AF_INET, socket.AF_INET6):
                try:
                    own.append(ipaddress.ip_network(a.address.split("%", 1)[0]))
                except ValueError:
                    pass
    return own


class AllowList:
    """The networks a server answers: the given ones, loopback and this machine's own addresses."""

    def __init__(self, cidrs: Iterable[str]):
        self.given = parse_networks(cidrs)
        self.networks = self.given + parse_networks(_LOOPBACK) + own_addresses()

    def allows(self, host: str) -> bool:
        try:
            address = ipaddress.ip_address(host.split("%", 1)[0])
        except ValueError:
            return False  # not an IP peer (a unix socket has none): not ours to allow
        if isinstance(address, ipaddress.IPv6Address) and address.ipv4_mapped is not None:
            address = address.ipv4_mapped  # a dual-stack socket shows IPv4 clients as ::ffff:a.b.c.d
        return any(address in network for network in self.networks)

    def __str__(self) -> str:
        return ", ".join(str(n) for n in self.given)
