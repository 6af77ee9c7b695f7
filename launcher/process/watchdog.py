"""The no-orphans guard: a helper process that kills every node's process group if the launcher dies.

Nodes run in their own sessions (so a Ctrl-C on the terminal reaches the
launcher only, which then stops them in order), so nothing in the kernel ties
them to the launcher: `PR_SET_PDEATHSIG` reaches direct children only, is tied
to the parent *thread*, and a node's own children never see it. Instead the
launcher starts this small helper at start-up and tells it, through a pipe, the
process group of every node it spawns (`+pgid`) and of every group that is gone
(`-pgid`). The pipe closes only when the launcher exits, however it exits; if
groups are still recorded then, the helper sends them SIGTERM, waits briefly,
then SIGKILL, including any process that left its group but stayed in the
node's session.
"""

from __future__ import annotations

import _signal  # (signal's C half: `signal` would bring enum, functools and collections, ~3 ms of the guard's start)
import os
import sys
import time

# How long the guard lets nodes handle SIGTERM before SIGKILL.
TERM_GRACE_S = 0.4
# After reading, the guard naps this long before reading again. A guard blocked in read() is woken
# by every `+pgid` line, and on a small machine the woken guard preempts the launcher in the middle
# of spawning: 100 such wake-ups cost ~18 ms of a 100-node start. While it naps, the lines just
# queue in the pipe (64 KiB, thousands of lines); the only price is noticing the launcher's death
# up to this much later.
READ_NAP_S = 0.05
# The guard imports this module, from its cached bytecode; a script is compiled from its source at every run
# (~4 ms of the 13 ms the guard's start took as `python -I -S watchdog.py`). The package's folder is its argument.
GUARD_MAIN = "import sys; sys.path.insert(0, sys.argv[1]); from launcher.process.watchdog import _guard_main; " \
             "_guard_main()"


def guard_argv() -> list[str]:
    """The guard's command: this interpreter, bare (`-I -S`), importing this module from the package's folder."""
    package_folder = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    bytecode = ["-B"] if sys.dont_write_bytecode else []  # (-I ignores $PYTHONDONTWRITEBYTECODE)
    return [sys.executable, "-I", "-S"] + bytecode + ["-c", GUARD_MAIN, package_folder]


class Watchdog:
    """The launcher's side of the guard (see module docstring)."""

    def __init__(self, pid: int, wfd: int):
        self.pid = pid
        self._wfd: int | None = wfd
        self._groups: set[int] = set()  # what the guard has on its list

    @classmethod
    def start(cls) -> Watchdog | None:
        """Start the guard: this module run by a bare interpreter (`GUARD_MAIN`), reading the pipe on its stdin.

        Spawned rather than forked: a fork of the launcher would make every
        page the launcher then writes a copy-on-write fault, ~5 ms of a
        100-node start; a separate `python -I -S` starts on the other core in
        a few ms. It runs in its own session, so a Ctrl-C or hangup of the
        terminal never reaches it; it ignores the signals anyway (`_serve`).
        """
        try:
            rfd, wfd = os.pipe()
        except OSError:
            return None
        try:
            pid = os.posix_spawn(sys.executable, guard_argv(), os.environ,
                                 file_actions=[(os.POSIX_SPAWN_DUP2, rfd, 0)], setsid=True)
        except OSError as e:
            os.close(wfd)
            from launcher.output import console  # (here: the guard imports this module, and nothing else of ours)
            console.printerrlog("WARNING: cannot start the no-orphans guard (%s): if launch is killed with "
                                "SIGKILL, its nodes will keep running" % e.strerror)
            return None
        finally:
            os.close(rfd)
        return cls(pid, wfd)

    def _send(self, line: str) -> None:
        if self._wfd is None:
            return
        try:
            os.write(self._wfd, line.encode())
        except OSError:  # the guard is gone: nothing more it can do
            self._close_fd()

    def watch(self, pgid: int) -> None:
        """Record a node's process group (right after spawning it)."""
        self._groups.add(pgid)
        self._send("+%d\n" % pgid)

    def forget(self, pgid: int) -> None:
        """The group is empty: never signal that id again."""
        self._groups.discard(pgid)
        self._send("-%d\n" % pgid)

    def _close_fd(self) -> None:
        if self._wfd is not None:
            try:
                os.close(self._wfd)
            except OSError:
                pass
            self._wfd = None

    def close(self) -> None:
        """Normal exit: let the guard go (it kills whatever is still recorded) and reap it.

        With nothing left on its list the guard has nothing to do, and it would read the
        end of the pipe only after its nap (READ_NAP_S): it is ended at once instead, so
        the launcher's exit does not wait for it.
        """
        self._close_fd()
        if not self._groups:
            try:
                os.kill(self.pid, _signal.SIGKILL)
            except OSError:
                pass
        try:
            os.waitpid(self.pid, 0)
        except ChildProcessError:
            pass


def _serve(rfd: int) -> None:
    """The guard's whole life: follow the pipe, then clean up what is left."""
    for sig in (_signal.SIGINT, _signal.SIGTERM, _signal.SIGHUP, _signal.SIGQUIT, _signal.SIGTSTP):
        _signal.signal(sig, _signal.SIG_IGN)
    devnull = os.open(os.devnull, os.O_RDWR)
    for fd in (0, 1, 2):
        os.dup2(devnull, fd)
    os.closerange(3, rfd)
    os.closerange(rfd + 1, 65536)
    groups: set[int] = set()
    buf = b""
    while True:
        try:
            chunk = os.read(rfd, 65536)
        except InterruptedError:
            continue
        if not chunk:
            break
        time.sleep(READ_NAP_S)
        buf += chunk
        *lines, buf = buf.split(b"\n")
        for line in lines:
            if line[:1] == b"+":
                groups.add(int(line[1:]))
            elif line[:1] == b"-":
                groups.discard(int(line[1:]))
    if groups:
        kill_groups(groups)


def group_members(groups: set[int], *, sessions: bool = True) -> list[int]:
    """Live pids whose process group (or, with `sessions`, session) is one of `groups`.

    A node's session id is its pgid, so `sessions` also finds what left the
    node's group but stayed in its session. Zombies are dead already and don't
    count. (Here rather than in its own module because the guard runs this
    module under `python -I -S`, and imports nothing else of ours.)
    """
    try:
        entries = os.listdir("/proc")
    except OSError:
        return []
    pids = []
    for entry in entries:
        if not entry.isdigit():
            continue
        try:
            with open("/proc/%s/stat" % entry, "rb") as f:
                stat = f.read()
        except OSError:
            continue
        fields = stat[stat.rfind(b")") + 2:].split()
        # fields: state ppid pgrp session ...
        if fields[0] != b"Z" and (int(fields[2]) in groups or (sessions and int(fields[3]) in groups)):
            pids.append(int(entry))
    return pids


def kill_groups(groups: set[int]) -> None:
    """SIGTERM every process of the groups (and their sessions), then SIGKILL what remains."""
    own = os.getpid()
    for sig, wait in ((_signal.SIGTERM, TERM_GRACE_S), (_signal.SIGKILL, 0.0)):
        pids = [p for p in group_members(groups) if p != own]
        if not pids:
            return
        for pgid in groups:
            try:
                os.killpg(pgid, sig)
            except OSError:
                pass
        for pid in pids:
            try:
                os.kill(pid, sig)
            except OSError:
                pass
        deadline = time.monotonic() + wait
        while wait and time.monotonic() < deadline:
            if not any(p != own for p in group_members(groups)):
                return
            time.sleep(0.02)


def _guard_main() -> None:
    """The guard process (`Watchdog.start`): the pipe is its stdin."""
    code = 0
    try:
        _serve(os.dup(0))
    except BaseException:
        code = 1
    finally:
        os._exit(code)
