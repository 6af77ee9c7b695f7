"""Hang detection: a node alive but no longer answering its own XML-RPC API (`hang_timeout`) is killed.

What `rosnode ping` does, without any change to the node: once the node's run
has registered with the master (the fleet's record says so, and at which URI:
health/registration.py tells it as the master does, an earlier run's
registration does not count), its `getPid` is called every S/3 seconds. No
answer for S seconds (a SIGSTOPped node, a deadlocked rospy callback thread,
a roscpp node whose spinner is stuck) means `hung`: reported, its process group
SIGKILLed. Its exit then goes the usual way: respawned if it respawns, the
launch ends if it is required.

A node hung before it registered is not noticed: there is nothing to ask yet.
"""

from __future__ import annotations

import asyncio
from typing import TYPE_CHECKING

from launcher.fleet.state import LOCAL_HOST, Change
from launcher.model.names import CALLER_ID
from launcher.net import xmlrpc

if TYPE_CHECKING:  # (annotations only)
    from launcher.fleet.runner import ChildProcess, Runner, RunningNode


class HangDetector:
    """Probes every running node that has a `hang_timeout` once its run has registered (a supervisor watcher:
    `started`, `exiting`; and a listener of the supervisor's fleet)."""

    def __init__(self, supervisor: Runner):
        self.supervisor = supervisor
        self.loop = asyncio.get_running_loop()
        self.tasks: dict[RunningNode, asyncio.Task] = {}  # NodeProcess -> the probe of its current run
        self.registered: dict[RunningNode, str] = {}  # NodeProcess -> XML-RPC URI of its current run, probed
        supervisor.fleet.listeners.append(self._changed)

    def started(self, proc: RunningNode) -> None:
        self._cancel(proc)  # (a new run is probed once it registers)

    def exiting(self, proc: RunningNode) -> None:
        self._cancel(proc)

    def close(self) -> None:
        if self._changed in self.supervisor.fleet.listeners:
            self.supervisor.fleet.listeners.remove(self._changed)
        for task in self.tasks.values():
            task.cancel()
        self.tasks.clear()
        self.registered.clear()

    def _changed(self, change: Change) -> None:
        old, new = change.old, change.new
        if (new.registered, new.uri) == (old.registered, old.uri) or new.host != LOCAL_HOST:
            return
        proc = self.supervisor.node(new.name)
        if proc is None or not proc.spec.policy.hang_timeout:
            return
        self._cancel(proc)
        if new.registered and self._current(proc, proc.popen):
            self.registered[proc] = new.uri
            self.tasks[proc] = self.loop.create_task(self._probe(proc, proc.popen, new.uri,
                                                                 proc.spec.policy.hang_timeout))

    def _cancel(self, proc: RunningNode) -> None:
        self.registered.pop(proc, None)
        task = self.tasks.pop(proc, None)
        if task is not None:
            task.cancel()

    def _current(self, proc: RunningNode, popen: ChildProcess | None) -> bool:
        return proc.popen is popen and proc.alive and not proc.stopping and not self.supervisor.shutting_down

    async def _probe(self, proc: RunningNode, popen: ChildProcess | None, uri: str, timeout: float) -> None:
        period = timeout / 3.0
        last_answer = self.loop.time()
        while self._current(proc, popen):
            started = self.loop.time()
            # a probe never outlasts the hang deadline: the verdict comes at last_answer + timeout
            if await self._get_pid(uri, max(0.001, min(period, last_answer + timeout - started))) is not None:
                last_answer = self.loop.time()
            elif self.loop.time() >= last_answer + timeout:
                if self._current(proc, popen):
                    self._hung(proc, timeout)
                return
            await asyncio.sleep(max(0.0, started + period - self.loop.time()))

    async def _get_pid(self, uri: str, timeout: float) -> int | None:
        try:
            code, _msg, pid = await xmlrpc.call(uri, "getPid", CALLER_ID, timeout=timeout)
        except (OSError, asyncio.TimeoutError, xmlrpc.Fault, xmlrpc.XmlRpcError, ValueError, TypeError):
            return None
        return pid if code == 1 and isinstance(pid, int) else None

    def _hung(self, proc: RunningNode, timeout: float) -> None:
        self.tasks.pop(proc, None)
        self.registered.pop(proc, None)
        self.supervisor.hung(proc, "no answer to getPid for %g s" % timeout)  # (reported, and killed)
