"""Orphans re-parented to the launch (PID 1 of a container, or a child subreaper): reaped, never the launch's own children.

A node that double-forks leaves a grandchild whose parent becomes PID 1 of the
PID namespace (a container's `launch`), or the nearest child subreaper (the
launch elsewhere: `become_subreaper`, so that a daemonized grandchild stays
under the launch). Its exit then leaves a zombie with the launch unless the
launch waits for it. The launch's own children are waited for by their
runners (the supervisor by pidfd, asyncio's child watcher for `du` and ssh),
whose exit statuses must not be taken: a zombie is reaped here only if it is
no supervised node's pid and not in the launch's own process group (where
the launch's helper processes run; nodes run in groups of their own, and
their orphans in theirs or in sessions of their own).
"""

from __future__ import annotations

import asyncio
import ctypes
import os
import signal
from typing import Callable, Iterable

PR_SET_CHILD_SUBREAPER = 36


def become_subreaper() -> bool:
    """Have orphans of our descendants re-parented to us (Linux 3.4+); False where it cannot be done."""
    try:
        # (the process's own symbols, libc's among them: ctypes.util.find_library would run
        # ldconfig and import tempfile, shutil and their compressors at every launch's start)
        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def stat_fields(pid: int, proc: str = "/proc") -> list[str] | None:
    """/proc/PID/stat after the command's closing parenthesis: [state, ppid, pgrp, ...], or None if gone."""
    try:
        with open("%s/%d/stat" % (proc, pid), "rb") as f:
            data = f.read()
    except OSError:
        return None
    return data[data.rindex(b")") + 2:].decode().split()


def children(pid: int, proc: str = "/proc") -> list[int]:
    """The children of `pid` (every thread's: a child belongs to the thread that forked it)."""
    kids: list[int] = []
    try:
        tasks = os.listdir("%s/%d/task" % (proc, pid))
    except OSError:
        return kids
    for tid in tasks:
        try:
            with open("%s/%d/task/%s/children" % (proc, pid, tid)) as f:
                kids += [int(k) for k in f.read().split()]
        except OSError:
            continue
    return kids


def orphan_zombies(pid: int, own: Iterable[int], pgrp: int, proc: str = "/proc") -> list[int]:
    """The zombie children of `pid` that are neither in `own` nor in process group `pgrp`."""
    own = set(own)
    found = []
    for kid in children(pid, proc):
        if kid in own:  # (asked first: a supervised node's stat is never read, at each of the fleet's exits)
            continue
        fields = stat_fields(kid, proc)
        if fields is not None and fields[0] == "Z" and int(fields[2]) != pgrp:
            found.append(kid)
    return found


class Reaper:
    """Reaps orphan zombies at each SIGCHLD, on the loop."""

    def __init__(self, loop, own: Callable[[], Iterable[int]]):
        self.loop = loop
        self.own = own  # the pids whose exit statuses belong to a runner (the supervised nodes, the guard)
        self.reaped = 0
        loop.add_signal_handler(signal.SIGCHLD, self.reap)

    def reap(self) -> None:
        for pid in orphan_zombies(os.getpid(), self.own(), os.getpgrp()):
            try:
                os.waitpid(pid, os.WNOHANG)
                self.reaped += 1
            except ChildProcessError:
                pass

    async def stop_orphans(self, timeout: float = 1.0) -> list[int]:
        """At the end, once the nodes are stopped: the orphans still alive under us (a node's daemonized
        grandchildren) get SIGTERM, then SIGKILL after `timeout` s. Returns their pids."""
        me, pgrp = os.getpid(), os.getpgrp()
        own = set(self.own())
        left = []
        for kid in children(me):
            if kid in own:
                continue
            fields = stat_fields(kid)
            if fields is not None and fields[0] != "Z" and int(fields[2]) != pgrp:
                left.append(kid)
        for sig in (signal.SIGTERM, signal.SIGKILL):
            for pid in left:
                try:
                    os.kill(pid, sig)
                except ProcessLookupError:
                    pass
            deadline = self.loop.time() + timeout
            while self.loop.time() < deadline:
                self.reap()
                if all(stat_fields(pid) is None for pid in left):
                    return left
                await asyncio.sleep(0.02)
        return left

    def close(self) -> None:
        self.loop.remove_signal_handler(signal.SIGCHLD)
        self.reap()
