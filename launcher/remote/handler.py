"""The parent's XML-RPC API, the calls a machine's child makes (roslaunch.server.ROSLaunchParentHandler).

A child registers (`register(NAME, CHILD_URI)`: its session's link hands it
the machine's nodes from then on), reports its nodes' starts in its `log`
lines ("process[talker-3]: started with pid [1234]") and their deaths with
`process_died(PROCESS, EXIT_CODE)`; each is told to the fleet as the node's
event, through the parent (`Parent.tell`). The process API (`list_processes`,
`process_info`, `get_node_names`: `fleet.processes`) answers for this
machine's nodes, as roslaunch's parent does. What a call's words mean is
`remote.session`'s (pure); this is its adapter to the parent's children.
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any, Callable, Mapping, Optional, Protocol

from launcher.fleet import lifecycle, processes, state
from launcher.fleet.lifecycle import Event
from launcher.net.xmlrpc import Fault
from launcher.output import console
from launcher.remote import session

if TYPE_CHECKING:  # (annotations only)
    from launcher.remote.link import RemoteChild, RemoteNode

PARENT_CALLS = ("register", "list_children", "process_died", "log")  # what only the children call


class Parent(Protocol):
    """What the handler reads of the parent (`remote.parent.RemoteParent`), and tells it of the nodes."""

    children: Mapping[str, RemoteChild]  # by roslaunch's child name, "ADDRESS-COUNTER"
    fleet: Optional[state.Fleet]  # None until the nodes' records exist (the parent's attach)

    def tell(self, rn: RemoteNode, event: Event) -> list[lifecycle.Action]: ...


class ParentHandler:
    """roslaunch's parent API, answered for `parent`'s children (see module docstring)."""

    def __init__(self, parent: Parent):
        self.parent = parent

    def call(self, method: str, params: list) -> Any:
        """One call, by its method's name: the server's dispatch, and the launch's own server's for PARENT_CALLS."""
        fn = self._API.get(method)
        if fn is None:
            raise Fault(-1, "method [%s] is not supported" % method)
        return fn(self, *params)

    def register(self, client: str, uri: str) -> list:
        child = self.parent.children.get(client)
        if child is None:
            return [-1, "unknown child [%s]" % client, 0]
        child.uri = uri
        child.registered.set()
        return [1, "registered", 1]

    def list_children(self) -> list:
        return [1, "roslaunch children", [c.uri for c in self.parent.children.values() if c.uri is not None]]

    def process_died(self, process_name: str, exit_code: Any) -> list:
        if self.parent.fleet is not None:
            for child in self.parent.children.values():
                rn = child.node_for_process(process_name)
                if rn is not None:
                    code, sig = session.died(exit_code)
                    self.parent.tell(rn, Event(lifecycle.PROCESS_EXITED, exit_code=code, exit_signal=sig,
                                               process=process_name))
                    child.process_died()
                    break
        return [1, "", 0]

    def log(self, client: str, level: int, message: str) -> list:
        text = "[%s]: %s" % (client, message)
        kind, started = session.log_kind(level, message)
        if kind == session.ERROR:
            console.printerrlog(text)
        elif kind == session.STARTED:
            console.printlog_bold(text)
            child = self.parent.children.get(client)
            rn = child.node_for_process(started[0]) if started and child else None
            if rn is not None and self.parent.fleet is not None:
                self.parent.tell(rn, Event(lifecycle.SPAWNED, pid=started[1], process=started[0]))
        else:
            console.printlog(text)
        return [1, "", 1]

    def _local(self) -> list[state.NodeStatus]:
        return [s for s in self.parent.fleet or () if s.host == state.LOCAL_HOST]

    def list_processes(self) -> list:
        return processes.list_processes(self._local())

    def process_info(self, process_name: str) -> list:
        return processes.process_info(self._local(), process_name)

    def get_pid(self) -> list:
        pid = os.getpid()
        return [1, str(pid), pid]

    def get_node_names(self) -> list:
        return processes.node_names(self._local())

    _API: dict[str, Callable[..., list]] = {
        "register": register, "list_children": list_children, "process_died": process_died, "log": log,
        "list_processes": list_processes, "process_info": process_info, "get_pid": get_pid,
        "get_node_names": get_node_names}
