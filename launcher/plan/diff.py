"""The difference of two plans of one launch (a reload): the parameters to set and delete, the nodes to start, stop and restart, each with why, and the nodes whose supervision settings alone changed.

A pure function of the two loaded `LaunchConfig`s and of what each node's
command (`plan.command.node_command`: argv, environment, working directory)
is made of beyond the node's own fields: its executable, which the caller looks
up with the same package index for both plans, so that only what the files say
(or a package that now has another executable) makes a difference. `launcher reload --dry-run` prints it and
a reload (`run/reload.py`) applies it: the same record, so a reload does
exactly what the dry run said.

Rules (issue 23):
- a parameter the new files set with another value (or type) or that is new
  is set; one the old files set and the new ones do not is deleted; nothing
  else on the master is touched (what nodes and tools set at run time, `/run_id`,
  `/roslaunch/uris/*`);
- a node restarts when its process changes (command line, environment, working
  directory, remaps, machine, output, launch-prefix) or when a parameter under
  its private namespace (its `<param>`/`<rosparam>` children, or any other
  launch-set `~` key of it) is set or deleted;
- a change of only its supervision settings (respawn, respawn_delay, required,
  the `NodePolicy` extensions) is applied where it stands, without a restart;
- a node only in the new files starts, one only in the old ones stops.
"""

from __future__ import annotations

from typing import Any, Iterable, Mapping, NamedTuple

from launcher.model.config import LaunchConfig, Node, NodePolicy

# what a node's process is made of (a change restarts it); the rest of `Node` but its place in the
# files is supervision (applied without a restart)
PROCESS_FIELDS = ("package", "type", "args", "remap_args", "env_args", "output", "cwd", "launch_prefix",
                  "machine_name")
SUPERVISION_FIELDS = ("respawn", "respawn_delay", "required")
NEVER_TOUCHED = ("/run_id",)
NEVER_TOUCHED_UNDER = ("/roslaunch/uris/",)


class NodeChange(NamedTuple):
    """One node to start, stop, restart or supervise anew, and why (in words)."""

    name: str  # its global name, /robot/driver
    why: str


class Difference(NamedTuple):
    """What a reload does, in the order it does it: parameters (deletes, then sets), stops, starts."""

    delete: tuple[str, ...] = ()
    set: tuple[tuple[str, Any], ...] = ()  # noqa: A003 - the master's word
    stop: tuple[NodeChange, ...] = ()  # removed from the files
    restart: tuple[NodeChange, ...] = ()  # changed: stopped, then started as new
    start: tuple[NodeChange, ...] = ()  # new in the files
    supervise: tuple[NodeChange, ...] = ()  # only supervision settings changed: applied, no restart

    @property
    def empty(self) -> bool:
        return not any(self)

    def as_dict(self) -> dict:
        """The JSON form (`launcher reload --json`, the events file's `reload` line)."""
        return {"delete": list(self.delete), "set": {k: v for k, v in self.set},
                "stop": {c.name: c.why for c in self.stop}, "restart": {c.name: c.why for c in self.restart},
                "start": {c.name: c.why for c in self.start}, "supervise": {c.name: c.why for c in self.supervise}}


def same_value(a: Any, b: Any) -> bool:
    """Equal and of the same type, all the way down (1, 1.0 and True are three values to the master's clients)."""
    if type(a) is not type(b):
        return False
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(same_value(v, b[k]) for k, v in a.items())
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(same_value(x, y) for x, y in zip(a, b))
    return a == b


def _touchable(key: str) -> bool:
    return key not in NEVER_TOUCHED and not key.startswith(NEVER_TOUCHED_UNDER)


def _short(value: Any, limit: int = 60) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[:limit - 3] + "..."


def _owner(key: str, private: Mapping[str, str]) -> str | None:
    """The node whose private namespace holds `key` (the longest such name: /a/b/c under /a/b, not /a)."""
    cut = len(key)
    while True:
        cut = key.rfind("/", 0, cut)
        if cut <= 0:
            return None
        owner = private.get(key[:cut])
        if owner is not None:
            return owner


def _field_words(field: str, old: Any, new: Any) -> str:
    return "%s %s -> %s" % (field, _short(old), _short(new))


def _policy_changes(old: NodePolicy | None, new: NodePolicy | None) -> list[str]:
    a, b = old or NodePolicy(), new or NodePolicy()
    return [_field_words(f, getattr(a, f), getattr(b, f)) for f in NodePolicy._fields if getattr(a, f) != getattr(b, f)]


def difference(old: LaunchConfig, new: LaunchConfig, old_commands: Mapping[str, Any] | None = None,
               new_commands: Mapping[str, Any] | None = None, remote: frozenset[str] = frozenset()) -> Difference:
    """What changes from `old` to `new`. `*_commands`: node name -> what its command is made of beyond its
    fields (its executable's path: argv, environment and cwd are functions of that, the node's fields and the
    launch's environment), for the nodes of this machine.
    `remote`: the nodes of other machines, whose respawn is their child's unless they have a NodePolicy (the
    child got it with the node: a change of it is a restart)."""
    old_commands = old_commands or {}
    new_commands = new_commands or {}
    old_params, new_params = old.params, new.params

    delete = tuple(k for k in old_params if k not in new_params and _touchable(k))
    sets = tuple((k, p.value) for k, p in new_params.items()
                 if _touchable(k) and (k not in old_params or not same_value(old_params[k].value, p.value)))

    old_nodes = {n.full_name: n for n in old.nodes}
    new_nodes = {n.full_name: n for n in new.nodes}
    # each node's params that were set or deleted: the nodes (of either plan) whose private namespace holds them
    private = {name: name for name in new_nodes}
    private.update((name, name) for name in old_nodes)
    param_changes: dict[str, list[str]] = {}
    for key in delete:
        owner = _owner(key, private)
        if owner is not None:
            param_changes.setdefault(owner, []).append("parameter %s deleted" % key)
    for key, value in sets:
        owner = _owner(key, private)
        if owner is not None:
            was = "set" if key not in old_params else "changed %s -> %s" % (_short(old_params[key].value), _short(value))
            param_changes.setdefault(owner, []).append("parameter %s %s" % (key, was))

    stop = tuple(NodeChange(name, "removed from the launch") for name in old_nodes if name not in new_nodes)
    start: list[NodeChange] = []
    restart: list[NodeChange] = []
    supervise: list[NodeChange] = []
    for name, node in new_nodes.items():
        before = old_nodes.get(name)
        if before is None:
            start.append(NodeChange(name, "new in the launch"))
            continue
        why = _process_changes(before, node, old_commands.get(name), new_commands.get(name))
        if node.machine_name and node.machine_name == before.machine_name and not _same_machine(
                old.machines.get(node.machine_name), new.machines.get(node.machine_name)):
            why.append("machine %s changed" % node.machine_name)
        if name in remote:
            why += _child_supervision(before, node)
        why += param_changes.get(name, [])
        if why:
            restart.append(NodeChange(name, "; ".join(why)))
            continue
        rules = [_field_words(f, getattr(before, f), getattr(node, f)) for f in SUPERVISION_FIELDS
                 if getattr(before, f) != getattr(node, f)] + _policy_changes(before.policy, node.policy)
        if rules:
            supervise.append(NodeChange(name, "; ".join(rules)))
    return Difference(delete, sets, stop, tuple(restart), tuple(start), tuple(supervise))


def _child_supervision(old: Node, new: Node) -> list[str]:
    """The supervision of a node of another machine that its child holds (roslaunch's respawn, when the node
    has no NodePolicy: the parent's restart policy is not in charge of it)."""
    if (old.policy is None) != (new.policy is None):
        return ["its restarts move between its machine's child and this launch (supervision attributes %s)"
                % ("added" if new.policy is not None else "removed")]
    if new.policy is None:
        return [_field_words(f, getattr(old, f), getattr(new, f)) + " (its machine's child respawns it)"
                for f in ("respawn", "respawn_delay") if getattr(old, f) != getattr(new, f)]
    return []


def _same_machine(a: Any, b: Any) -> bool:
    """The same machine, wherever in the files it is declared."""
    if a is None or b is None:
        return a is b
    return a._replace(filename="", line=0) == b._replace(filename="", line=0)


def _process_changes(old: Node, new: Node, old_command: Any, new_command: Any) -> list[str]:
    why = [_field_words(f, getattr(old, f), getattr(new, f)) for f in PROCESS_FIELDS if getattr(old, f) != getattr(new, f)]
    if not why and old_command != new_command:
        why.append("executable %s -> %s" % (_short(old_command, 120), _short(new_command, 120)))
    return why


def lines(diff: Difference) -> Iterable[str]:
    """The difference in words, one change a line (`launcher reload --dry-run`)."""
    for key in diff.delete:
        yield "delete parameter %s" % key
    for key, value in diff.set:
        yield "set parameter %s = %s" % (key, _short(value))
    for verb, changes in (("stop", diff.stop), ("restart", diff.restart), ("start", diff.start),
                          ("supervise", diff.supervise)):
        for c in changes:
            yield "%s %s: %s" % (verb, c.name, c.why)
