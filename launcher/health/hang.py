"""Hang detection: a node alive but no longer answering its own XML-RPC API (`hang_timeout`) is killed.

What `rosnode ping` does, without any change to the node: once the node's run
has registered with the master (lookupNode gives a URI whose getPid answers
with a process of this run's group: an earlier run's registration, left by a
killed process, does not count), its `getPid` is called every S/3 seconds. No
answer for S seconds (a SIGSTOPped node, a deadlocked rospy callback thread,
a roscpp node whose spinner is stuck) means `hung`: reported, its process group
SIGKILLed. Its exit then goes the usual way: respawned if it respawns, the
launch ends if it is required.

A node hung before it registered is not noticed: there is nothing to ask yet.
"""

from __future__ import annotations

import asyncio
import os
from typing import Any

from launcher.net import xmlrpc

CALLER_ID = "/roslaunch"
# Until the node has registered, the master is asked at most this often per node.
REGISTRATION_POLL_S = 0.5


class HangDetector:
    """Probes every running node that has a `hang_timeout` (a supervisor watcher: `started`, `exiting`)."""

    def __init__(self, master_uri: str, supervisor: Any):
        self.master_uri = master_uri
        self.supervisor = supervisor
        self.loop = asyncio.get_running_loop()
        self.tasks: dict[Any, asyncio.Task] = {}  # NodeProcess -> the probe of its current run
        self.registered: dict[Any, str] = {}  # NodeProcess -> XML-RPC URI of its current run, once probed

    def started(self, proc: Any) -> None:
        timeout = proc.spec.policy.hang_timeout
        if timeout:
            self._cancel(proc)
            self.tasks[proc] = self.loop.create_task(self._probe(proc, proc.popen, timeout))

    def exiting(self, proc: Any) -> None:
        self._cancel(proc)

    def close(self) -> None:
        for task in self.tasks.values():
            task.cancel()
        self.tasks.clear()
        self.registered.clear()

    def _cancel(self, proc: Any) -> None:
        self.registered.pop(proc, None)
        task = self.tasks.pop(proc, None)
        if task is not None:
            task.cancel()

    def _current(self, proc: Any, popen: Any) -> bool:
        return proc.popen is popen and proc.alive and not proc.stopping and not self.supervisor.shutting_down

    async def _probe(self, proc: Any, popen: Any, timeout: float) -> None:
        period = timeout / 3.0
        uri = await self._registered(proc, popen, max(period, REGISTRATION_POLL_S))
        if uri is None:
            return
        self.registered[proc] = uri
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

    async def _registered(self, proc: Any, popen: Any, period: float) -> str | None:
        return await registered_uri(self.master_uri, proc, lambda: self._current(proc, popen), period)

    async def _get_pid(self, uri: str, timeout: float) -> int | None:
        try:
            code, _msg, pid = await xmlrpc.call(uri, "getPid", CALLER_ID, timeout=timeout)
        except (OSError, asyncio.TimeoutError, xmlrpc.Fault, xmlrpc.XmlRpcError, ValueError, TypeError):
            return None
        return pid if code == 1 and isinstance(pid, int) else None

    def _hung(self, proc: Any, timeout: float) -> None:
        self.tasks.pop(proc, None)
        self.registered.pop(proc, None)
        self.supervisor.hung(proc, "no answer to getPid for %g s" % timeout)  # (reported, and killed)


async def registered_uri(master_uri: str, proc: Any, current: Any, period: float) -> str | None:
    """The node's XML-RPC URI, once this run of it (a process of its group) has registered (None: the run
    ended first, `current()` is false). An earlier run's registration, left by a killed process, does not
    count: the URI must answer getPid with a pid of this run's group."""
    while True:
        await asyncio.sleep(period)
        if not current():
            return None
        try:
            code, _msg, uri = await xmlrpc.call(master_uri, "lookupNode", CALLER_ID, proc.spec.node_name,
                                                timeout=period)
        except (OSError, asyncio.TimeoutError, xmlrpc.Fault, xmlrpc.XmlRpcError, ValueError, TypeError):
            continue
        if code != 1 or not isinstance(uri, str):
            continue
        try:
            code, _msg, pid = await xmlrpc.call(uri, "getPid", CALLER_ID, timeout=period)
        except (OSError, asyncio.TimeoutError, xmlrpc.Fault, xmlrpc.XmlRpcError, ValueError, TypeError):
            continue
        if code == 1 and isinstance(pid, int) and _in_group(pid, proc.pgid):
            return uri


def _in_group(pid: int, pgid: int | None) -> bool:
    """Is `pid` a process of the run's group (the node, or what its launch-prefix started)?"""
    try:
        return os.getpgid(pid) == pgid
    except OSError:
        return False
