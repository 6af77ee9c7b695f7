"""roslaunch's process API (`list_processes`, `process_info`, `get_node_names`), answered from the fleet.

One answer for the launch's own server, a remote child's, and the remote
parent's own server: each passes the node views it runs (`state.NodeStatus`)
and, for `process_info`, what it knows beyond them (the launch's server: the
command line, environment and package of each process).
"""

from __future__ import annotations

from typing import Any, Callable, Iterable

from launcher.fleet import state

# roslaunch keeps a process in its list of active ones while it runs or will respawn
ACTIVE = frozenset((state.RUNNING, state.RESPAWNING, state.HUNG))


def list_processes(nodes: Iterable[state.NodeStatus], core: Iterable[list] = ()) -> list:
    active, dead = list(core), []
    for s in nodes:
        (active if s.state in ACTIVE else dead).append([s.process, s.spawn_count])
    return [1, "processes on parent machine", [active, dead]]


def process_info(nodes: Iterable[state.NodeStatus], process_name: str,
                 details: Callable[[state.NodeStatus], dict[str, Any]] | None = None) -> list:
    for s in nodes:
        if s.process == process_name and s.state in ACTIVE:
            info = {"name": s.process, "pid": s.pid or 0, "alive": s.state == state.RUNNING,
                    "spawn_count": s.spawn_count}
            if s.exit_signal is not None or s.exit_code is not None:  # (Popen's returncode, as roslaunch's)
                info["exit_code"] = -s.exit_signal if s.exit_signal is not None else s.exit_code
            if details is not None:
                info.update(details(s))
            return [1, "process info", info]
    return [-1, "no process by that name", {}]


def node_names(nodes: Iterable[state.NodeStatus], core: Iterable[str] = ()) -> list:
    return [1, "node names", list(core) + [s.process for s in nodes if s.state in ACTIVE]]
