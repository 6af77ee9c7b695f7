"""`<param command="...">`: every command parameter of a load run at once, bounded by the cores.

A robot's launch time is dominated by `<param command="xacro ...">` (a second or
more each), which roslaunch runs one after another as it reads the file
(ros/ros_comm#1513). The loader instead records each as a `CommandParam` in
place of its value, and once the whole launch is read, `run_all` runs those
whose parameter is still set (one that a later tag overwrote never runs), at
most one per core at a time. Errors are raised in file order, each with the
file:line of its own `<param>`; on a terminal a progress line says which
commands are running and for how long.
"""

from __future__ import annotations

import os
import sys
import time

from launcher.model import shellwords

TYPE_CHECKING = False  # (typing.TYPE_CHECKING without importing typing: ~3 ms a start; the annotations are text)
if TYPE_CHECKING:
    from typing import Any, Callable, Mapping, TextIO

# subprocess and concurrent.futures are imported where a command runs: together they cost ~15 ms
# (logging, threading, ...) that every `launch --nodes` of a file without command params would pay.

TIMEOUT_S = 60.0  # how long a command parameter may run
PROGRESS_AFTER_S = 0.5  # a terminal is told what runs once it takes this long
PROGRESS_PERIOD_S = 0.25
_ARG_MAX = os.sysconf("SC_ARG_MAX") if hasattr(os, "sysconf") else 2 * 1024 * 1024  # the kernel's limit on argv + env


class CommandError(Exception):
    """A command parameter failed; the message says how (the loader adds the <param>'s file and line)."""


class CommandParam:
    """Stands in for the value of a `<param command=...>` until `run_all` has run it."""

    __slots__ = ("command", "name", "finish", "result")

    def __init__(self, command: str, name: str, finish: Callable[[str], Any]):
        self.command = command
        self.name = name  # the parameter's name, for errors
        self.finish = finish  # the command's output -> the parameter's value (type=, file:line errors)
        self.result: Any = None


def run_command(command: str, name: str, environ: Mapping[str, str]) -> str:
    """The output of one command parameter's command, as roslaunch takes it; CommandError otherwise."""
    import subprocess
    what = "Cannot load command parameter [%s]: " % name
    if len(command) > _ARG_MAX:
        raise CommandError(what + "the command is %d characters long, more than a command line may be on this "
                                  "system (ARG_MAX, %d bytes)" % (len(command), _ARG_MAX))
    try:
        argv = shellwords.split(command)
    except ValueError as e:
        raise CommandError(what + "cannot split command [%s]: %s" % (command, e)) from None
    if not argv:
        raise CommandError(what + "the command is empty")
    try:
        p = subprocess.run(argv, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                           timeout=TIMEOUT_S, env=dict(environ))
    except FileNotFoundError:
        raise CommandError(what + "no such command [%s]" % argv[0]) from None
    except subprocess.TimeoutExpired:
        raise CommandError(what + "command [%s] did not finish within %g seconds" % (command, TIMEOUT_S)) from None
    except OSError as e:
        raise CommandError(what + "cannot run [%s]: %s" % (command, e.strerror or e)) from None
    err = p.stderr.decode("utf-8", "replace")
    if p.returncode != 0:
        msg = what + "command [%s] returned with code [%s]" % (command, p.returncode)
        if err.strip():
            msg += "\nstderr of the command:\n" + err.rstrip()
        raise CommandError(msg)
    if err:
        sys.stderr.write(err)  # roslaunch lets the command's stderr through
    try:
        return p.stdout.decode("utf-8")
    except UnicodeDecodeError:
        raise CommandError(what + "the output of [%s] is not UTF-8" % command) from None


def run_all(pending: list[CommandParam], environ: Mapping[str, str], terminal: TextIO | None = None) -> None:
    """Run every pending command (at most one per core at a time) and set each one's `result`.

    The first failure in file order is raised (its `finish` turns a CommandError into a located
    LaunchError); `terminal`, when given, shows what runs while it takes long.
    """
    if not pending:
        return
    from concurrent.futures import FIRST_COMPLETED, Future, ThreadPoolExecutor, wait
    if len(pending) == 1:  # (no thread for the common single robot_description)
        pending[0].result = pending[0].finish(_outcome(pending[0], environ))
        return
    workers = min(len(pending), os.cpu_count() or 1)
    with ThreadPoolExecutor(max_workers=workers, thread_name_prefix="param-command") as pool:
        started = time.monotonic()
        futures = {pool.submit(_outcome, p, environ): p for p in pending}
        not_done: set[Future] = set(futures)
        shown = False
        while not_done:
            _done, not_done = wait(not_done, timeout=PROGRESS_PERIOD_S, return_when=FIRST_COMPLETED)
            if terminal is not None and not_done and time.monotonic() - started >= PROGRESS_AFTER_S:
                _progress(terminal, [futures[f] for f in not_done if f.running()], len(pending) - len(not_done),
                          len(pending), time.monotonic() - started)
                shown = True
        if shown:
            terminal.write("\r\033[K")  # (clear the progress line)
            terminal.flush()
    for p, f in zip(pending, futures):
        p.result = p.finish(f.result())


def _outcome(p: CommandParam, environ: Mapping[str, str]) -> str | CommandError:
    """The command's output, or its CommandError (raised later, in file order, by `finish`)."""
    try:
        return run_command(p.command, p.name, environ)
    except CommandError as e:
        return e


def _progress(out: TextIO, running: list[CommandParam], done: int, total: int, seconds: float) -> None:
    names = ", ".join(p.name for p in running[:3]) + (" ..." if len(running) > 3 else "")
    line = "running command parameters (%d of %d done, %.1f s): %s" % (done, total, seconds, names)
    try:
        width = os.get_terminal_size(out.fileno()).columns or 80  # (0: a terminal that did not say)
    except (OSError, ValueError, AttributeError):
        width = 80
    out.write("\r\033[K" + line[:max(10, width - 1)])
    out.flush()
