"""ROS graph names: join, resolve, private `~`, anonymous names, validity.

Semantics follow rosgraph.names (ROS Noetic) exactly, because launch files,
the master and every client library agree on them.
"""

from __future__ import annotations

import re
import sys

SEP = "/"
PRIV_NAME = "~"
REMAP = ":="
ANYTYPE = "*"
# the launch's name as a client of the master, which resolves the launch's keys against it (a literal `~x` lands at
# /roslaunch/x), as roslaunch's
CALLER_ID = "/roslaunch"

_LEGAL_NAME = re.compile(r"^[\~\/A-Za-z][\w\/]*$")


def is_global(name: str) -> bool:
    return bool(name) and name[0] == SEP


def is_private(name: str) -> bool:
    return bool(name) and name[0] == PRIV_NAME


def canonicalize_name(name: str) -> str:
    """Remove duplicate and trailing separators (`//a/b/` -> `/a/b`)."""
    # Nearly every name is canonical already, and the master and the loader ask for each name they see.
    if not name or name == SEP or ("//" not in name and name[-1] != SEP):
        return name
    parts = [p for p in name.split(SEP) if p]
    return (SEP if name[0] == SEP else "") + SEP.join(parts)


def ns_join(ns: str, name: str) -> str:
    """Join a namespace and a name; global and private names are left alone."""
    if is_private(name) or is_global(name):
        return name
    if ns == PRIV_NAME:
        return PRIV_NAME + name
    if not ns:
        return name
    if ns[-1] == SEP:
        return ns + name
    return ns + SEP + name


def namespace(name: str) -> str:
    """The namespace of a name, with a trailing slash (`/a/b` -> `/a/`; that of "" is `/`, as rosgraph says)."""
    if not name:
        return SEP
    if name[-1] == SEP:
        name = name[:-1]
    return name[: name.rfind(SEP) + 1] or SEP


def make_global_ns(ns: str) -> str:
    """`a/b` -> `/a/b/`. Private names have no global form."""
    if is_private(ns):
        raise ValueError("cannot turn [%s] into a global name" % ns)
    if not is_global(ns):
        ns = SEP + ns
    if ns[-1] != SEP:
        ns += SEP
    return ns


def resolve_name(name: str, namespace_: str, remappings: dict[str, str] | None = None) -> str:
    """Resolve `name` against the node name or namespace `namespace_` (the master: against the caller id).

    A private name (`~x`) is resolved against `namespace_` itself (a node's
    full name); a relative one against the namespace of `namespace_`; ""
    names the namespace of `namespace_` (`/` for an empty caller id).
    """
    if not name:
        return namespace(namespace_)
    name = canonicalize_name(name)
    first = name[0]  # (is_global and is_private, inline: the master resolves a key in nearly every call)
    if first == SEP:
        resolved = name
    elif first == PRIV_NAME:
        resolved = canonicalize_name(namespace_ + SEP + name[1:])
    else:
        resolved = namespace(namespace_) + name
    return remappings.get(resolved, resolved) if remappings else resolved


def anonymous_name(id_: str, pid: int | None = None) -> str:
    """`id_<host>_<pid>_<random>`, as rosgraph.names.anonymous_name makes it (`pid`: this process's, unless
    the name is made for another: a launch's, by the process that reads its files, run/apart.py)."""
    import os  # lazy: only $(anon) needs these (socket costs ~2 ms to import), and the pure modules that
    import random  # import this one (the node state machine, the plan diff) load no I/O module through it
    import socket
    name = "%s_%s_%s_%s" % (id_, socket.gethostname(), os.getpid() if pid is None else pid,
                            random.randint(0, sys.maxsize))
    return name.replace(".", "_").replace("-", "_").replace(":", "_")


class AnonNames:
    """The names `$(anon id)` made in a run's loads, by file and id in the order they were asked for: a
    reload of the run (run/reload.py) is given the same ones, so an anonymous node stays the same node.
    (A first load that is not a run's needs none: `anonymous_name` makes each.) `pid`: the launch's, whose
    names they are, where its files are read by a process of their own (run/apart.py)."""

    __slots__ = ("kept", "_asked", "pid")

    def __init__(self, pid: int | None = None) -> None:
        self.kept: dict[tuple[str, str], list[str]] = {}
        self._asked: dict[tuple[str, str], int] = {}
        self.pid = pid

    def start_load(self) -> None:
        self._asked = {}

    def name(self, id_: str, filename: str | None) -> str:
        key = (filename or "", id_)
        n = self._asked.get(key, 0)
        self._asked[key] = n + 1
        names = self.kept.setdefault(key, [])
        if n == len(names):
            names.append(anonymous_name(id_, self.pid))
        return names[n]


def is_legal_name(name: str | None) -> bool:
    if name is None:
        return False
    if name == "":
        return True
    m = _LEGAL_NAME.match(name)
    return m is not None and m.group(0) == name and "//" not in name
