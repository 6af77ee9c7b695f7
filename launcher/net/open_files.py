"""The process's open-file limit, and how many client connections a server may hold under it.

Every connection is a file. With the stock soft limit (1024) a flood of idle
clients used to exhaust it: accept() failed, node files could not be opened.
A run raises its soft limit to the hard one (as a server should), and each
XML-RPC server keeps its connection cap well below the limit, leaving the rest
to the launcher's own files (node pipes and log files, sockets to nodes).
"""

from __future__ import annotations

import resource

__all__ = ["raise_open_file_limit", "open_file_limit", "connection_cap", "callback_cap"]

MAX_CONNECTIONS = 32768  # above this, memory (buffers, objects) is the limit, not files
MAX_CALLBACKS = 4096  # the master's calls to nodes in flight: far more nodes than a graph has


def raise_open_file_limit() -> int:
    """Raise the soft RLIMIT_NOFILE to the hard limit; returns the soft limit now in force.

    Call once at the start of a run (`launch` and `--core`). Never fails: a
    limit that cannot be raised stays where it is.
    """
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if hard != resource.RLIM_INFINITY and (soft == resource.RLIM_INFINITY or soft >= hard):
        return soft
    target = hard
    if hard == resource.RLIM_INFINITY:
        target = 1024 * 1024  # Linux refuses an infinite soft limit above nr_open; this is its default
    try:
        resource.setrlimit(resource.RLIMIT_NOFILE, (target, hard))
    except (ValueError, OSError):
        return soft
    return target


def open_file_limit() -> int:
    """The soft RLIMIT_NOFILE in force (a large number when unlimited)."""
    soft = resource.getrlimit(resource.RLIMIT_NOFILE)[0]
    return 1024 * 1024 if soft == resource.RLIM_INFINITY else soft


def connection_cap(limit: int | None = None) -> int:
    """The connections the master's server may hold: half the open-file limit, less a margin.

    The other half is the launcher's: node pipes and log files, the in-process
    node's server and its sockets, the master's notifications to nodes.
    """
    if limit is None:
        limit = open_file_limit()
    return max(16, min(MAX_CONNECTIONS, limit // 2 - 64))


def callback_cap(limit: int | None = None) -> int:
    """The master's calls to nodes that may be in flight at once: a quarter of the open-file limit.

    Each holds a socket until it is answered or its deadline passes; a node
    that hangs holds one at a time, so this is how many may hang before the
    others' callbacks wait for a deadline.
    """
    if limit is None:
        limit = open_file_limit()
    return max(16, min(MAX_CALLBACKS, limit // 4))
