"""The host this machine's ROS servers put in their URIs and listen on: rosgraph.network's rules of the environment.

ROS_HOSTNAME, else ROS_IP, else the machine's name (or, when that is a loopback
name, the address of the interface that routes outwards). Its own module: the
master, the launch's API server and a launch's checks all ask, and a launch
that uses a master found running loads none of our master's code to ask.
"""

from __future__ import annotations

import socket
from typing import Mapping


def address_override(environ: Mapping[str, str]) -> str | None:
    """ROS_HOSTNAME, else ROS_IP (rosgraph.network.get_address_override, environment part)."""
    if "ROS_HOSTNAME" in environ:
        return environ["ROS_HOSTNAME"]
    if "ROS_IP" in environ:
        return environ["ROS_IP"]
    return None


def bind_address(environ: Mapping[str, str]) -> str:
    """Where to listen: all interfaces, or loopback when ROS_IP/ROS_HOSTNAME is a loopback name."""
    override = address_override(environ)
    ipv6 = environ.get("ROS_IPV6") == "on"
    if override and (override == "localhost" or override.startswith("127.") or override == "::1"):
        if ipv6:
            return "::1"
        return override if override.startswith("127.") else "127.0.0.1"
    return "::" if ipv6 else "0.0.0.0"


def listen_address(host: str) -> str:
    """Where a server whose URIs name `host` listens: loopback only when that is a loopback name (as rospy does),
    else every interface."""
    if host in ("localhost", "::1") or host.startswith("127."):
        return host if host != "localhost" else "127.0.0.1"
    return "0.0.0.0"


def advertised_host(environ: Mapping[str, str]) -> str:
    """The host name put in URIs (rosgraph.network.get_host_name)."""
    host = address_override(environ)
    if host:
        return host
    try:
        host = socket.gethostname()
    except OSError:
        host = ""
    if not host or host == "localhost" or host.startswith("127."):
        host = _local_address(environ)
    return host


def _local_address(environ: Mapping[str, str]) -> str:
    # the address of the interface that routes outwards (no packet is sent by a UDP connect)
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.connect(("192.0.2.1", 9))
            addr = s.getsockname()[0]
            if addr and not addr.startswith("0."):
                return addr
    except OSError:
        pass
    return "::1" if environ.get("ROS_IPV6") == "on" else "127.0.0.1"
