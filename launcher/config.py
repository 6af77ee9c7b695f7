"""The LaunchConfig data model: what a set of launch files asks for, as pure data.

The XML loader produces it; introspection (`--nodes`, `--args`, ...) and the
runtime consume it. Nothing here knows about XML, sockets or processes.

The classes behave as frozen dataclasses (fields set once, equality, hash and
repr by field, assignment refused) but are written out by hand: `dataclasses`
costs ~5 ms to import (it pulls in `inspect`) and its frozen `__init__` sets each
field through `object.__setattr__`, while a big launch makes thousands of them.
"""

from __future__ import annotations

from operator import itemgetter
from typing import Any

from launcher.names import SEP


class FrozenInstanceError(AttributeError):
    """Assignment to a field of a LaunchConfig object (they are immutable)."""


class _Record:
    """Fields in the instance `__dict__`, filled by `__init__` directly (no `__setattr__`)."""

    __slots__ = ("__dict__",)
    _fields: tuple[str, ...] = ()

    def __setattr__(self, name: str, value: Any) -> None:
        raise FrozenInstanceError("cannot assign to field '%s'" % name)

    def __delattr__(self, name: str) -> None:
        raise FrozenInstanceError("cannot delete field '%s'" % name)

    def astuple(self) -> tuple:
        """The field values, in field order (dataclasses.astuple without the deep copy)."""
        d = self.__dict__
        return tuple([d[f] for f in self._fields])

    def __eq__(self, other: object) -> bool:
        if other.__class__ is self.__class__:
            return self.astuple() == other.astuple()  # type: ignore[attr-defined]
        return NotImplemented

    def __hash__(self) -> int:
        return hash(self.astuple())

    def __repr__(self) -> str:
        d = self.__dict__
        return "%s(%s)" % (type(self).__qualname__, ", ".join("%s=%r" % (f, d[f]) for f in self._fields))

    def __reduce__(self) -> tuple:
        return (type(self), self.astuple())


class Machine(_Record):
    """A `<machine>` tag."""

    __slots__ = ()
    _fields = ("name", "address", "env_loader", "ssh_port", "user", "password", "assignable", "timeout",
               "filename", "line")
    name: str
    address: str
    env_loader: str | None
    ssh_port: int
    user: str | None
    password: str | None
    assignable: bool
    timeout: float
    filename: str
    line: int

    def __init__(self, name: str, address: str, env_loader: str | None = None, ssh_port: int = 22,
                 user: str | None = None, password: str | None = None, assignable: bool = True,
                 timeout: float = 10.0, filename: str = "", line: int = 0):
        d = self.__dict__
        d["name"] = name
        d["address"] = address
        d["env_loader"] = env_loader
        d["ssh_port"] = ssh_port
        d["user"] = user
        d["password"] = password
        d["assignable"] = assignable
        d["timeout"] = timeout
        d["filename"] = filename
        d["line"] = line

    @property
    def is_local(self) -> bool:
        return self.address in ("localhost", "127.0.0.1", "::1") or self.address.startswith("127.")


class Node(_Record):
    """A `<node>` (or, with `test_name` set, a `<test>`), fully substituted.

    `namespace` is global with a trailing slash (`/`, `/robot/`), as in
    roslaunch; `name` is the base name (already generated for `$(anon)`).
    """

    __slots__ = ()
    _fields = ("package", "type", "name", "namespace", "args", "remap_args", "env_args", "respawn",
               "respawn_delay", "required", "output", "cwd", "launch_prefix", "machine_name", "filename",
               "line", "test_name", "time_limit", "retry")
    package: str
    type: str
    name: str
    namespace: str
    args: str
    remap_args: tuple[tuple[str, str], ...]
    env_args: tuple[tuple[str, str], ...]
    respawn: bool
    respawn_delay: float
    required: bool
    output: str | None  # "log" | "screen" | None (= log)
    cwd: str | None  # "ROS_HOME" | "node" | None (= ROS_HOME)
    launch_prefix: str | None
    machine_name: str | None
    filename: str
    line: int
    # <test> only
    test_name: str | None
    time_limit: float | None
    retry: int

    def __init__(self, package: str, type: str, name: str, namespace: str = SEP,  # noqa: A002 - ROS's word
                 args: str = "", remap_args: tuple[tuple[str, str], ...] = (),
                 env_args: tuple[tuple[str, str], ...] = (), respawn: bool = False, respawn_delay: float = 0.0,
                 required: bool = False, output: str | None = None, cwd: str | None = None,
                 launch_prefix: str | None = None, machine_name: str | None = None, filename: str = "",
                 line: int = 0, test_name: str | None = None, time_limit: float | None = None, retry: int = 0):
        self.__dict__.update(package=package, type=type, name=name, namespace=namespace, args=args,
                             remap_args=remap_args, env_args=env_args, respawn=respawn,
                             respawn_delay=respawn_delay, required=required, output=output, cwd=cwd,
                             launch_prefix=launch_prefix, machine_name=machine_name, filename=filename,
                             line=line, test_name=test_name, time_limit=time_limit, retry=retry)

    @property
    def is_test(self) -> bool:
        return self.test_name is not None

    @property
    def full_name(self) -> str:
        """Global node name, e.g. `/robot/driver`."""
        return self.namespace + self.name if self.namespace.endswith(SEP) else self.namespace + SEP + self.name


class Param(tuple):
    """One parameter the launch sets: a global key and its typed value.

    A big launch sets thousands: a Param is a tuple underneath (built in C, a third of the
    memory of an object with a __dict__), with the other records' behaviour on top: fields by
    name, equality only with another Param, assignment refused.
    """

    __slots__ = ()
    _fields = ("key", "value", "filename", "line")
    key: str = property(itemgetter(0))  # type: ignore[assignment]
    value: Any = property(itemgetter(1))
    filename: str = property(itemgetter(2))  # type: ignore[assignment]
    line: int = property(itemgetter(3))  # type: ignore[assignment]

    def __new__(cls, key: str, value: Any, filename: str = "", line: int = 0) -> Param:
        return _tuple_new(cls, (key, value, filename, line))

    __setattr__ = _Record.__setattr__
    __delattr__ = _Record.__delattr__

    def __repr__(self) -> str:
        return "%s(%s)" % (type(self).__qualname__, ", ".join("%s=%r" % fv for fv in zip(self._fields, self)))

    def astuple(self) -> tuple:
        return tuple(self)

    def __eq__(self, other: object) -> bool:
        if other.__class__ is self.__class__:
            return tuple.__eq__(self, other)
        # (not NotImplemented for other tuples: their __eq__ would compare the contents)
        return False if isinstance(other, tuple) else NotImplemented

    def __ne__(self, other: object) -> bool:
        if other.__class__ is self.__class__:
            return tuple.__ne__(self, other)
        return True if isinstance(other, tuple) else NotImplemented

    __hash__ = tuple.__hash__  # (as a frozen dataclass: the hash of the field values' tuple)

    def __reduce__(self) -> tuple:
        return (type(self), tuple(self))


_tuple_new = tuple.__new__


def new_param(key: str, value: Any, filename: str, line: int) -> Param:
    """Param(key, value, filename, line) without a Python-level constructor call (the loader's fast path)."""
    return _tuple_new(Param, (key, value, filename, line))


class LaunchConfig(_Record):
    """Everything a launch asks for.

    `params` is ordered by first setting (later settings of the same key
    replace the value in place, as roslaunch's dict does); `clear_params`
    lists global namespaces (trailing slash) to delete before setting params.
    """

    __slots__ = ()
    _fields = ("nodes", "tests", "params", "clear_params", "machines", "files", "warnings", "rosparam_commands")
    nodes: tuple[Node, ...]
    tests: tuple[Node, ...]
    params: dict[str, Param]
    clear_params: tuple[str, ...]
    machines: dict[str, Machine]
    files: tuple[str, ...]
    warnings: tuple[str, ...]
    # <rosparam command="delete|dump">, in document order, to run before params are set
    # (as roslaunch's setup executables): ("delete", key, None) or ("dump", key, file)
    rosparam_commands: tuple[tuple[str, str, str | None], ...]

    def __init__(self, nodes: tuple[Node, ...] = (), tests: tuple[Node, ...] = (),
                 params: dict[str, Param] | None = None, clear_params: tuple[str, ...] = (),
                 machines: dict[str, Machine] | None = None, files: tuple[str, ...] = (),
                 warnings: tuple[str, ...] = (), rosparam_commands: tuple[tuple[str, str, str | None], ...] = ()):
        self.__dict__.update(nodes=nodes, tests=tests, params={} if params is None else params,
                             clear_params=clear_params, machines={} if machines is None else machines,
                             files=files, warnings=warnings, rosparam_commands=rosparam_commands)

    def find_node(self, full_name: str) -> Node | None:
        for n in self.nodes + self.tests:
            if n.full_name == full_name:
                return n
        return None
