"""What a TCPROS connection says of itself to a node's getBusInfo and getBusStats: its id among the node's
connections, and roscpp's description of its socket (which `rosnode info` parses)."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import socket

_next_connection_id = 0


def new_connection_id() -> int:
    global _next_connection_id
    _next_connection_id += 1
    return _next_connection_id


def transport_info(sock: socket.socket | None) -> str:
    """roscpp's connection description, which `rosnode info` parses for ports and socket."""
    if sock is None:
        return "TCPROS connection"
    try:
        local_port = sock.getsockname()[1]
        host, port = sock.getpeername()[:2]
        return "TCPROS connection on port %d to [%s:%d on socket %d]" % (
            local_port, host, port, sock.fileno())
    except OSError:
        return "TCPROS connection"
