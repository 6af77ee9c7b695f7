"""Which node of the launch a registration on the master is: the fleet told when a node's run registers, and
when that registration goes (each record's `registered` and `uri`).

A registration belongs to a node by its name; or else by the process that made it: the caller's pid (getPid
at the URI it registered) is of a node's process group. That is a wrapper script that starts the node under
a name of its own, or an anonymous rospy node (`init_node(..., anonymous=True)` with the launch's remappings
stripped) whose name the launch cannot know. Only this machine's nodes can be found by their process, and
only nodes that still await a registration are looked for (a node with `registers="false"` awaits none).

The registrations come from the run's graph (`model.graph`): our master tells it of each one as it happens;
a master found running is asked by its watcher (`services.masterwatch`), and what it answers may be a dead
run's registration, left behind: there a registration by name counts once the process answering at its URI
is of the run's group (a node of another machine: by its name alone).
"""

from __future__ import annotations

import asyncio
import os
from typing import Any

from launcher.fleet import lifecycle
from launcher.fleet.state import LOCAL_HOST, Change, Fleet
from launcher.model.graph import NODE, Graph, GraphChange
from launcher.model.names import CALLER_ID
from launcher.net import xmlrpc

CALL_TIMEOUT_S = 2.0
# a master found running: a registration whose process does not answer getPid is asked again this often, while
# the master still says it is there
RETRY_S = 1.0
# getPid calls in flight at once: a master found running reports a whole start's registrations in its watcher's
# first answer, and a hundred calls at once (a connection and its buffers each) left 0.9 MB in the launch's memory
CALLS_AT_ONCE = 8
_UP = (lifecycle.RUNNING, lifecycle.STALLED, lifecycle.HUNG)


def awaits(r: lifecycle.Record) -> bool:
    """Is this node's current run, of this machine, still expected to register?"""
    return r.state in _UP and r.host == LOCAL_HOST and not r.registered and r.pid is not None \
        and r.rules.policy.registers


def _in_group(pid: int, pgid: int) -> bool:
    try:
        return os.getpgid(pid) == pgid
    except OSError:
        return False


class Registrations:
    """The graph's node registrations, told to the fleet as its nodes' (a listener of both)."""

    def __init__(self, graph: Graph, fleet: Fleet, *, verify: bool = False):
        self.graph = graph
        self.fleet = fleet
        self.verify = verify  # a master found running: a registration by name is checked by its process
        self.by_uri: dict[str, str] = {}  # URI -> the node whose process registered there under another name
        self._tasks: set[asyncio.Task] = set()
        self._calls: asyncio.Semaphore | None = None  # (made on the loop, at the first call)
        graph.listeners.append(self._changed)

    def close(self) -> None:
        if self._changed in self.graph.listeners:
            self.graph.listeners.remove(self._changed)
        for task in self._tasks:
            task.cancel()
        self._tasks.clear()

    def _changed(self, change: GraphChange) -> None:
        if change.kind != NODE:
            return
        name, uri = change.name, change.uri
        record = self.fleet.records.get(name)
        if not change.present:
            if record is not None:
                self.fleet.registration(name, uri, False)
            owner = self.by_uri.pop(uri, None)
            if owner is not None and owner in self.fleet.records:
                self.fleet.registration(owner, uri, False)
            return
        if record is not None:
            if self.verify and record.host == LOCAL_HOST:
                self._spawn(self._check(name, uri))
            else:
                self.fleet.registration(name, uri, True)
        elif any(awaits(r) for r in self.fleet.records.values()):
            self._spawn(self._find_owner(uri))

    def _spawn(self, coro: Any) -> None:
        task = asyncio.get_running_loop().create_task(coro)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def _check(self, name: str, uri: str) -> None:
        """A registration by name on a master found running: this run's once its process is of the run's group."""
        while True:
            record = self.fleet.records.get(name)
            if record is None or not awaits(record) or self.graph.nodes.get(name) != uri:
                return
            pid = await self._get_pid(uri)
            record = self.fleet.records.get(name)
            if record is None or not awaits(record) or self.graph.nodes.get(name) != uri:
                return
            if pid is not None:
                if _in_group(pid, record.pid):  # (a node's process group is its first process's pid)
                    self.fleet.registration(name, uri, True)
                return  # (another process's: an earlier run's, left behind; the new run's comes with a new URI)
            await asyncio.sleep(RETRY_S)

    async def _find_owner(self, uri: str) -> None:
        pid = await self._get_pid(uri)
        if pid is None or uri not in self.graph.nodes.values():  # (gone while it was asked)
            return
        for r in list(self.fleet.records.values()):
            if awaits(r) and _in_group(pid, r.pid):
                self.by_uri[uri] = r.name
                self.fleet.registration(r.name, uri, True)
                return

    async def _get_pid(self, uri: str) -> int | None:
        if self._calls is None:
            self._calls = asyncio.Semaphore(CALLS_AT_ONCE)
        try:
            async with self._calls:
                code, _msg, pid = await xmlrpc.call(uri, "getPid", CALLER_ID, timeout=CALL_TIMEOUT_S)
        except (OSError, asyncio.TimeoutError, xmlrpc.Fault, xmlrpc.XmlRpcError, ValueError, TypeError):
            return None
        return pid if code == 1 and isinstance(pid, int) else None
