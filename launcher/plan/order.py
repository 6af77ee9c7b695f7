"""The order among a launch's nodes: who waits for whom (`wait_for="node:..."`, `bind_to`), checked for cycles.

A node that waits for another starts after it and is stopped before it (the
supervisor's shutdown); a cycle of such waits could neither start nor stop,
so it is an error naming every member's file and line.
"""

from __future__ import annotations

from typing import Iterable

from launcher.model.config import Node
from launcher.model.errors import LaunchError


def waits(node: Node) -> list[str]:
    """The node names `node` waits for."""
    return [name for kind, name in (node.policy.wait_for if node.policy else ()) if kind == "node"]


def check_cycles(nodes: Iterable[Node]) -> None:
    """A LaunchError if the waits among the nodes of this launch form a cycle."""
    by_name = {n.full_name: n for n in nodes}
    state: dict[str, int] = {}  # 1: on the path being walked, 2: done

    def walk(name: str, path: list[str]) -> None:
        state[name] = 1
        path.append(name)
        for nxt in waits(by_name[name]):
            if nxt not in by_name:
                continue
            if state.get(nxt) == 1:
                cycle = path[path.index(nxt):] + [nxt]
                members = [by_name[n] for n in cycle[:-1]]
                where = "; ".join("%s at %s:%d" % (n.full_name, n.filename, n.line) for n in members)
                first = members[0]
                raise LaunchError("nodes wait for each other in a cycle (wait_for node: / bind_to), so none "
                                  "could start: %s (%s)" % (" -> ".join(cycle), where),
                                  first.filename or None, first.line or None)
            if state.get(nxt) is None:
                walk(nxt, path)
        path.pop()
        state[name] = 2

    for name in by_name:
        if state.get(name) is None:
            walk(name, [])
