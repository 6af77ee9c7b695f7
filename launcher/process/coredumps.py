"""Core dumps (`enable_coredumps`): the node may dump core, and when it does, the user is told where.

The launcher's own core limit is left as it is (usually 0). For a node with
`enable_coredumps`, the soft limit is raised to the hard one just around its
spawn, so that only that process inherits it (the spawn is synchronous on the
loop's thread, and no other thread starts processes). A `preexec_fn` would do
it in the child instead, but Python code between fork and exec is unsafe next
to the console's writer thread.

When such a node dies, its exit is looked at before it is reaped
(`waitid(P_PIDFD, ..., WNOWAIT)`): the kernel says whether a core was
written (CLD_DUMPED). Then, as rosmon does, the kernel's `core_pattern` says
where it went: piped to systemd-coredump (`coredumpctl gdb <pid>` gets it),
to apport (/var/crash), or a file named by the pattern, relative to the
node's working directory.
"""

from __future__ import annotations

import os
import resource
import socket
import time
from typing import TYPE_CHECKING

from launcher.compat import P_PIDFD
from launcher.output import console

if TYPE_CHECKING:  # (annotations only)
    from launcher.fleet.runner import RunningNode

CORE_PATTERN = "/proc/sys/kernel/core_pattern"
CORE_USES_PID = "/proc/sys/kernel/core_uses_pid"


def raise_core_limit() -> tuple[int, int] | None:
    """Raise the soft core limit to the hard one; the limits to restore (None: nothing changed)."""
    try:
        limits = resource.getrlimit(resource.RLIMIT_CORE)
        resource.setrlimit(resource.RLIMIT_CORE, (limits[1], limits[1]))
    except (OSError, ValueError):
        return None
    return limits


def restore_core_limit(limits: tuple[int, int]) -> None:
    try:
        resource.setrlimit(resource.RLIMIT_CORE, limits)
    except (OSError, ValueError):
        pass


def _read(path: str) -> str:
    try:
        with open(path) as f:
            return f.read().strip()
    except OSError:
        return ""


def core_location(pid: int, cwd: str, executable: str, pattern: str | None = None,
                  uses_pid: bool | None = None, now: float | None = None) -> str:
    """Where the kernel put the core of `pid`, in words a user can act on."""
    pattern = _read(CORE_PATTERN) if pattern is None else pattern
    if uses_pid is None:
        uses_pid = _read(CORE_USES_PID) == "1"
    if pattern.startswith("|"):
        if "systemd-coredump" in pattern:
            return "get it with: coredumpctl gdb %d" % pid
        if "apport" in pattern:
            return "apport keeps it under /var/crash"
        return "piped to %s" % pattern[1:].split()[0]
    comm = os.path.basename(executable)[:15]
    specifiers = {"p": str(pid), "P": str(pid), "i": str(pid), "I": str(pid), "e": comm, "E": executable.replace("/", "!"),
                  "t": str(int(time.time() if now is None else now)), "h": socket.gethostname(), "%": "%",
                  "u": str(os.getuid()), "g": str(os.getgid())}
    out, i = [], 0
    while i < len(pattern):
        if pattern[i] == "%" and i + 1 < len(pattern):
            out.append(specifiers.get(pattern[i + 1], "%" + pattern[i + 1]))
            i += 2
        else:
            out.append(pattern[i])
            i += 1
    path = "".join(out) or "core"
    if uses_pid and "%p" not in pattern:
        path += ".%d" % pid
    return os.path.join(cwd or os.getcwd(), path)


class CoreDumpReporter:
    """A supervisor watcher: says where the core of a node with `enable_coredumps` went."""

    def started(self, proc: RunningNode) -> None:
        pass

    def exiting(self, proc: RunningNode) -> None:
        if not proc.spec.policy.enable_coredumps or proc.pidfd is None:
            return
        try:
            info = os.waitid(P_PIDFD, proc.pidfd, os.WEXITED | os.WNOHANG | os.WNOWAIT)
        except (OSError, AttributeError):
            return
        if info is None or info.si_code != os.CLD_DUMPED:
            return
        # (a zombie still has its comm: the name the kernel gives %e, even behind a launch-prefix)
        where = core_location(proc.pid, proc.spec.command.cwd, _read("/proc/%d/comm" % proc.pid) or proc.spec.argv[0])
        if where.startswith("/"):
            where = ("core dumped to %s" if os.path.exists(where) else "core dump expected at %s") % where
        console.printerrlog("[%s] dumped core (signal %d): %s" % (proc.name, info.si_status, where))
