"""The runner's seam: what the health watchers and the run's services call on a runner of nodes, as Protocols.

A runner carries out the fleet's actions for its nodes: the local supervisor
(`process.supervisor.Supervisor`) for this machine's, the remote parent
(`remote.parent.RemoteParent`) for the others'. The watchers of `health/`
stand below `process/` and `remote/` and cannot name their classes: they see
a runner through these Protocols, which the runners match by shape (no
registration, no base class). Types only: nothing here runs, so a module may
import it for its annotations at no cost.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Iterable, Optional, Protocol

if TYPE_CHECKING:  # (annotations only: importing this module loads nothing of ours)
    from launcher.fleet.state import Fleet
    from launcher.model.config import NodePolicy


class NodeSpec(Protocol):
    """What a watcher reads of a node's spec (`plan.specs.ProcessSpec`)."""

    name: str  # roslaunch's process name, e.g. robot/driver-2
    node_name: str  # the ROS node name, e.g. /robot/driver
    policy: NodePolicy  # its supervision settings (wait_for, watch_topic, limits, ...)
    argv: list[str]


class ChildProcess(Protocol):
    """A node's process, as a watcher compares it (`subprocess.Popen`): the same run or a later one?"""

    pid: int


class HeldNode(Protocol):
    """A node as readiness holds it: the runner's own key for it (a NodeProcess, a remote node's record)."""

    spec: NodeSpec


class RunningNode(HeldNode, Protocol):
    """One node as its runner keeps it (`process.supervisor.NodeProcess`): its spec and its current run."""

    popen: Optional[ChildProcess]  # the current run's process (None: not started, or ended)
    pid: Optional[int]
    pgid: Optional[int]
    pidfd: Optional[int]
    alive: bool  # its group leader runs

    @property
    def name(self) -> str: ...

    @property
    def stopping(self) -> bool: ...  # a stop of it is under way


class ReadinessRunner(Protocol):
    """What readiness (`health/readiness.py`) tells the runner of a held node: the supervisor or the remote
    parent."""

    def release(self, proc: HeldNode) -> None: ...

    def give_up_waiting(self, proc: HeldNode, why: str) -> None: ...

    def output_path(self, node_name: str) -> Optional[str]: ...


class Runner(ReadinessRunner, Protocol):
    """The local runner as the watchers of running nodes (hang, stall, resources) and the services see it."""

    fleet: Fleet
    shutting_down: bool  # the launch is stopping: no watcher acts any more
    procs: Iterable[RunningNode]  # every node process it runs or ran, leftovers included

    def node(self, name: str) -> Optional[RunningNode]: ...

    def hung(self, proc: RunningNode, reason: str) -> None: ...

    def stalled(self, proc: RunningNode, reason: str) -> None: ...

    def unstalled(self, proc: RunningNode, reason: str) -> None: ...

    def restart(self, proc: RunningNode, reason: str) -> None: ...

    def limit_crossed(self, proc: RunningNode, limit: str, maximum: Optional[float], what: str) -> None: ...
