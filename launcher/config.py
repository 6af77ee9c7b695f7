"""The LaunchConfig data model: what a set of launch files asks for, as pure data.

The XML loader produces it; introspection (`--nodes`, `--args`, ...) and the
runtime consume it. Nothing here knows about XML, sockets or processes.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from launcher.names import SEP


@dataclass(frozen=True)
class Machine:
    """A `<machine>` tag."""

    name: str
    address: str
    env_loader: str | None = None
    ssh_port: int = 22
    user: str | None = None
    password: str | None = None
    assignable: bool = True
    timeout: float = 10.0
    filename: str = ""
    line: int = 0

    @property
    def is_local(self) -> bool:
        return self.address in ("localhost", "127.0.0.1", "::1") or self.address.startswith("127.")


@dataclass(frozen=True)
class Node:
    """A `<node>` (or, with `test_name` set, a `<test>`), fully substituted.

    `namespace` is global with a trailing slash (`/`, `/robot/`), as in
    roslaunch; `name` is the base name (already generated for `$(anon)`).
    """

    package: str
    type: str
    name: str
    namespace: str = SEP
    args: str = ""
    remap_args: tuple[tuple[str, str], ...] = ()
    env_args: tuple[tuple[str, str], ...] = ()
    respawn: bool = False
    respawn_delay: float = 0.0
    required: bool = False
    output: str | None = None  # "log" | "screen" | None (= log)
    cwd: str | None = None  # "ROS_HOME" | "node" | None (= ROS_HOME)
    launch_prefix: str | None = None
    machine_name: str | None = None
    filename: str = ""
    line: int = 0
    # <test> only
    test_name: str | None = None
    time_limit: float | None = None
    retry: int = 0

    @property
    def is_test(self) -> bool:
        return self.test_name is not None

    @property
    def full_name(self) -> str:
        """Global node name, e.g. `/robot/driver`."""
        return self.namespace + self.name if self.namespace.endswith(SEP) else self.namespace + SEP + self.name


@dataclass(frozen=True)
class Param:
    """One parameter the launch sets: a global key and its typed value."""

    key: str
    value: Any
    filename: str = ""
    line: int = 0


@dataclass(frozen=True)
class LaunchConfig:
    """Everything a launch asks for.

    `params` is ordered by first setting (later settings of the same key
    replace the value in place, as roslaunch's dict does); `clear_params`
    lists global namespaces (trailing slash) to delete before setting params.
    """

    nodes: tuple[Node, ...] = ()
    tests: tuple[Node, ...] = ()
    params: dict[str, Param] = field(default_factory=dict)
    clear_params: tuple[str, ...] = ()
    machines: dict[str, Machine] = field(default_factory=dict)
    files: tuple[str, ...] = ()
    warnings: tuple[str, ...] = ()
    # <rosparam command="delete|dump">, in document order, to run before params are set
    # (as roslaunch's setup executables): ("delete", key, None) or ("dump", key, file)
    rosparam_commands: tuple[tuple[str, str, str | None], ...] = ()

    def find_node(self, full_name: str) -> Node | None:
        for n in self.nodes + self.tests:
            if n.full_name == full_name:
                return n
        return None
