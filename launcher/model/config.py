"""The LaunchConfig data model: what a set of launch files asks for, as pure data.

The XML loader produces it; introspection (`--nodes`, `--args`, ...) and the
runtime consume it. Nothing here knows about XML, sockets or processes.

The records are namedtuples (`model/record.py`): immutable, compared, hashed and
printed by field, built in C from a tuple (a big launch makes thousands of them),
and without the import cost of `dataclasses` (~5 ms: it pulls in `inspect`) or
`typing` (~3 ms, and ~1.5 ms more to make these classes with `typing.NamedTuple`).
"""

from __future__ import annotations

from launcher.model.names import SEP
from launcher.model.record import record

TYPE_CHECKING = False  # (typing.TYPE_CHECKING without importing typing: the annotations are text)
if TYPE_CHECKING:
    from typing import Any


@record
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


@record
class NodePolicy:
    """How a node is supervised beyond roslaunch (the extension attributes of `<node>`, or the
    defaults a `<launch>`, `<group>` or `<include>` gives the nodes inside it; the nearest wins).

    `Node.policy` is None when the launch uses none of them: behaviour is then exactly roslaunch's.
    Times are seconds, sizes bytes; None means "not set" (no limit, the CLI's default).
    """

    respawn_on: str = "always"  # "always" (roslaunch) | "failure": not after a success
    success_exit_codes: frozenset[int] = frozenset({0})
    respawn_backoff: float = 1.0  # each consecutive failure multiplies the delay by this
    respawn_delay_max: float | None = None  # cap of the growing delay
    respawn_min_uptime: float = 1.0  # a run shorter than this is a failed start
    respawn_max_retries: int | None = None  # restarts after failed starts in a row; one more failure: FATAL
    on_fatal: str = "none"  # "none" | "shutdown": a FATAL node ends the launch with status 1
    restart_warn_threshold: int | None = None  # rosmon: warn once the node restarted this often
    sigint_timeout: float | None = None  # this node's stop escalation (None: the CLI's)
    sigterm_timeout: float | None = None
    spawn_delay: float = 0.0  # start this long after the launch starts its nodes
    wait_for: tuple[tuple[str, str], ...] = ()  # (kind, name): topic, service, param, node
    wait_timeout: float = 60.0
    hang_timeout: float | None = None  # no answer to getPid for this long = hung
    # stalled topics: the node's own publications of these topics (resolved as the node resolves them) are
    # watched; silent for watch_timeout s, or slower than watch_min_rate Hz over watch_window s = stalled
    watch_topics: tuple[str, ...] = ()
    watch_timeout: float | None = None
    watch_min_rate: float | None = None
    watch_window: float = 5.0
    on_stall: str = "restart"  # "restart" | "warn"
    bind_to: str = ""  # the node this one starts after and is stopped before (its resolved name)
    # registers="false": not a ROS node (a shell script, a tool that never calls the master): up once it runs,
    # not awaited for a registration (systemd's READY=1)
    registers: bool = True
    memory_limit: int | None = None  # bytes, RSS of the whole process group
    cpu_limit: float | None = None  # cores, over the last sample window
    on_limit: str = "warn"  # "warn" | "restart"
    enable_coredumps: bool = False
    log_max_size: int | None = None  # rotate this node's output log past this size (None: --log-max-size)
    log_backups: int | None = None  # rotated copies to keep (None: --log-backups)


@record
class Node:
    """A `<node>` (or, with `test_name` set, a `<test>`), fully substituted.

    `namespace` is global with a trailing slash (`/`, `/robot/`), as in
    roslaunch; `name` is the base name (already generated for `$(anon)`).
    """

    package: str
    type: str  # noqa: A003 - ROS's word
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
    policy: NodePolicy | None = None  # the supervision extensions, if any are set (None: roslaunch's behaviour)

    @property
    def is_test(self) -> bool:
        return self.test_name is not None

    @property
    def full_name(self) -> str:
        """Global node name, e.g. `/robot/driver`."""
        return self.namespace + self.name if self.namespace.endswith(SEP) else self.namespace + SEP + self.name


@record
class Param:
    """One parameter the launch sets: a global key and its typed value."""

    key: str
    value: Any
    filename: str = ""
    line: int = 0


_tuple_new = tuple.__new__


def new_param(key: str, value: Any, filename: str, line: int) -> Param:
    """Param(key, value, filename, line) without a Python-level constructor call (the loader's fast path)."""
    return _tuple_new(Param, (key, value, filename, line))


@record
class _LaunchConfigFields:
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
    yaml_files: tuple[str, ...]  # the YAML files its <rosparam file=...> loaded (what `launcher report` copies)


class LaunchConfig(_LaunchConfigFields):
    """Everything a launch asks for.

    `params` is ordered by first setting (later settings of the same key
    replace the value in place, as roslaunch's dict does); `clear_params`
    lists global namespaces (trailing slash) to delete before setting params.
    """

    __slots__ = ()

    # (a NamedTuple's own defaults would share one dict between all configs: each gets its own)
    def __new__(cls, nodes: tuple[Node, ...] = (), tests: tuple[Node, ...] = (),
                params: dict[str, Param] | None = None, clear_params: tuple[str, ...] = (),
                machines: dict[str, Machine] | None = None, files: tuple[str, ...] = (),
                warnings: tuple[str, ...] = (),
                rosparam_commands: tuple[tuple[str, str, str | None], ...] = (),
                yaml_files: tuple[str, ...] = ()) -> LaunchConfig:
        return _tuple_new(cls, (nodes, tests, {} if params is None else params, clear_params,
                                {} if machines is None else machines, files, warnings, rosparam_commands, yaml_files))

    def find_node(self, full_name: str) -> Node | None:
        for n in self.nodes + self.tests:
            if n.full_name == full_name:
                return n
        return None
