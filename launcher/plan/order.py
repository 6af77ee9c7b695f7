"""The order among a launch's nodes: who waits for whom (`wait_for="node:..."`, `bind_to`, a nodelet loader's
manager), checked for cycles.

A node that waits for another starts after it and is stopped before it (the
supervisor's shutdown); a cycle of such waits could neither start nor stop,
so it is an error naming every member's file and line. A node bound to
another (`bind_to`) is also stopped while that one is down and started again
after it; a `nodelet load PKG/TYPE MANAGER` node is bound to its manager
without a word in the launch file (`bind_nodelets`).
"""

from __future__ import annotations

from typing import Callable, Iterable

from launcher.model import shellwords
from launcher.model.config import LaunchConfig, Node, NodePolicy
from launcher.model.errors import LaunchError
from launcher.model.names import resolve_name


def waits(node: Node) -> list[str]:
    """The node names `node` waits for: to register, or for a line of their output."""
    # (an output condition is NODE:PATTERN; a node name holds no colon)
    return [name.partition(":")[0] for kind, name in (node.policy.wait_for if node.policy else ())
            if kind in ("node", "output")]


def check_output_waits(nodes: Iterable[Node], is_remote: Callable[[Node], bool]) -> None:
    """A LaunchError for a `wait_for="output:NODE:PATTERN"` the launcher cannot watch: NODE must be a node of
    this launch on this machine (its output file is read here), and so must the node that waits."""
    nodes = list(nodes)
    local = {n.full_name for n in nodes if not is_remote(n)}
    for node in nodes:
        for kind, name in node.policy.wait_for if node.policy else ():
            if kind != "output":
                continue
            watched = name.partition(":")[0]
            if is_remote(node):
                why = "[%s] runs on another machine" % node.full_name
            elif watched not in local:
                known = any(n.full_name == watched for n in nodes)
                why = "[%s] %s" % (watched, "runs on another machine" if known else "is no node of this launch")
            else:
                continue
            raise LaunchError("wait_for output:%s: %s; a node's output is watched for the nodes of this machine "
                              "only" % (name, why), node.filename or None, node.line or None)


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


def nodelet_manager(node: Node) -> str | None:
    """The manager node a `nodelet load PKG/TYPE MANAGER` node loads its nodelet into, or None (another
    command, `standalone`, `manager`, not the nodelet tool).

    Resolved as the tool resolves it: it calls the service `MANAGER/load_nodelet` from the loader's own
    namespace (`~` under the loader's name), through the loader's remaps (its `<remap>`s and the `a:=b` of
    its args); the manager is that service's node. Words with `:=` are no words of the tool's command line
    (roscpp's removeROSArgs)."""
    if node.package != "nodelet" or node.type != "nodelet":
        return None
    try:
        words = shellwords.split(node.args)
    except ValueError:
        return None  # (the command line is refused where it is made, with file and line)
    plain = [w for w in words if ":=" not in w]
    if len(plain) < 3 or plain[0] != "load":
        return None
    full_name = node.full_name
    remaps = list(node.remap_args) + [tuple(w.split(":=", 1)) for w in words
                                      if ":=" in w and not w.startswith("_")]
    mapping = {resolve_name(a, full_name): resolve_name(b, full_name) for a, b in remaps if a and b}
    service = resolve_name(plain[2].rstrip("/") + "/load_nodelet", full_name, mapping)
    manager = service.rsplit("/", 1)[0]
    return manager or None


def bind_nodelets(config: LaunchConfig, is_remote: Callable[[Node], bool]) -> LaunchConfig:
    """The launch with each nodelet loader bound to its manager (as `bind_to` would: start after it has
    registered, stop before it, stop and start again with it), where both are nodes of this launch on
    this machine (the supervisor that binds them runs them both). A loader's own `bind_to` stands."""
    local = {n.full_name for n in config.nodes if not is_remote(n)}
    nodes = []
    changed = False
    for node in config.nodes:
        manager = nodelet_manager(node) if node.full_name in local else None
        policy = node.policy or NodePolicy()
        if manager is not None and manager in local and manager != node.full_name and not policy.bind_to:
            wait = ("node", manager)
            waits = policy.wait_for if wait in policy.wait_for else policy.wait_for + (wait,)
            node = node._replace(policy=policy._replace(bind_to=manager, wait_for=waits))
            changed = True
        nodes.append(node)
    return config._replace(nodes=tuple(nodes)) if changed else config
