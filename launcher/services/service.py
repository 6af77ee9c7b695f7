"""The seams between a run's services, as Protocols: a service, the master session as the others see it, the run's
nodes as the servers and watchers read and steer them, the run's stop signals as the services heed them.

`run/runtime.Run` starts the services and hands each the others it needs;
each names here what it uses of another, not the other's class, so a
front-end's own (rostest's master session) fits where it matches by shape.
Types only: nothing here runs, so a module may import it for its annotations at
no cost.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Callable, Coroutine, Optional, Protocol

if TYPE_CHECKING:  # (annotations only: importing this module loads nothing of ours)
    import asyncio

    from launcher.fleet.runner import Runner
    from launcher.fleet.state import Fleet
    from launcher.health.stall import StallWatch
    from launcher.master.server import Master
    from launcher.model.graph import Graph
    from launcher.plan.specs import ProcessSpec
    from launcher.remote.parent import RemoteParent


class Signals(Protocol):
    """The run's stop signals as its services heed them (`run.runtime.StopSignals`)."""

    event: asyncio.Event  # set at the first stop signal
    on_signal: Optional[Callable[[], None]]  # told of each one once the nodes exist (the launch's phase decides)

    def check(self) -> None: ...  # raise the run's Stopped if a stop signal came

    async def guard(self, step: Coroutine[Any, Any, Any]) -> Any: ...  # the step, or Stopped at a stop signal


class Service(Protocol):
    """One of a run's services: what the run stops, in the reverse of the order it started them."""

    async def stop(self) -> None:
        """Undo what its start did, if it did anything (a service that could not start stops as nothing)."""


class PlainService(Service, Protocol):
    """A service whose start needs nothing from the others (the API server, rosout, /diagnostics, the log-disk
    check, the metrics server, the watch of a master found running)."""

    async def start(self) -> None: ...


class Params(Protocol):
    """The run's parameter server: our master's tree (`masterlink.LocalParams`) or a master found running's
    (`masterlink.RemoteParams`), one await each."""

    async def has(self, key: str) -> bool: ...

    async def get(self, key: str) -> Any: ...  # (a parameter's value: any XML-RPC value)

    async def set(self, key: str, value: Any) -> None: ...

    async def delete(self, key: str) -> None: ...

    async def upload(self, clear: list[str], params: list[tuple[str, Any]]) -> None: ...


class MasterLink(Service, Protocol):
    """The run's master session as the other services see it (`masterlink.MasterSession`, rostest's
    `RostestMaster`): where the master is, whose it is, the run id, the parameters, the graph."""

    uri: str
    run_id: str
    core: bool  # `launch --core`: the master is the run
    external: bool  # a master was already running (not ours)
    master: Optional[Master]  # ours, when we run it
    params: Optional[Params]  # once found

    @property
    def graph(self) -> Graph: ...

    async def run_id_after_restart(self, seen: Optional[str]) -> str: ...

    async def restore_parameters(self) -> None: ...


class RunNodes(Service, Protocol):
    """The run's nodes as the API server, the master's watcher, /diagnostics and the metrics read and steer them
    (`nodeservice.NodeService`). The fleet and the runners are None until the nodes are started."""

    fleet: Optional[Fleet]
    made: asyncio.Event  # set once the fleet and its nodes are made (`start`)
    supervisor: Optional[Runner]  # this machine's runner
    remote: Optional[RemoteParent]  # the other machines' runner, when nodes run there
    stall: Optional[StallWatch]  # the watched topics

    def spec(self, node_name: str) -> Optional[ProcessSpec]: ...

    def package_of(self, process_name: str) -> str: ...

    def remote_names(self) -> list[str]: ...

    def parent_calls(self) -> tuple[str, ...]: ...

    def parent_call(self, method: str, params: list) -> Any: ...  # (an XML-RPC answer: any value)

    async def control(self, verb: str, name: str, remote: bool) -> str: ...
