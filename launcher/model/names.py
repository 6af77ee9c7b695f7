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


def anonymous_name(id_: str) -> str:
    """`id_<host>_<pid>_<random>`, as rosgraph.names.anonymous_name makes it."""
    import os  # lazy: only $(anon) needs these (socket costs ~2 ms to import), and the pure modules that
    import random  # import this one (the node state machine, the plan diff) load no I/O module through it
    import socket
    name = "%s_%s_%s_%s" % (id_, socket.gethostname(), os.getpid(), random.randint(0, sys.maxsize))
    return name.replace(".", "_").replace("-", "_").replace(":", "_")


def is_legal_name(name: str | None) -> bool:
    if name is None:
        return False
    if name == "":
        return True
    m = _LEGAL_NAME.match(name)
    return m is not None and m.group(0) == name and "//" not in name
