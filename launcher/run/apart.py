"""A launch's plan made in a process of its own: what only the making needs never enters the launch's memory.

Reading launch files takes the XML loader and its substitutions, and for
`<rosparam>` PyYAML and libyaml (about 2 MB once imported); a launch keeps
whatever it once imported for as long as it runs, weeks on a robot, and
CPython cannot unload a module. So `launch` reads its files in a child it
forks for that (`begin_apart`): the child makes the plan, sends it back
pickled through a pipe, and ends; the launch goes on with the plan alone.

The child is a fork, not a new interpreter: it starts in about a millisecond
with everything the launch had imported. It writes its warnings itself, to
the launch's own stdout and stderr, while the launch waits, so their order is
the one roslaunch prints. A LaunchError there is the launch's (its kind and
words: file and line); any other exception is a bug, which the launch names
in one line (the child prints its traceback with -v). A Ctrl-C ends both.
Where a fork would not be safe (a thread already runs, whose locks the child
would inherit held), or is not possible, the plan is made in the launch
itself, as before.

The making begins (`begin_apart`) before its value is needed (`Apart.result`):
`launch` forks the child before it imports asyncio and the run's modules, so
that the files are read on the other core while those imports go on here.
The value crosses with `_pickle`, the C half of `pickle`: the launch never
imports pickle's Python half (0.3 MB of its memory).
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import traceback
from _pickle import dumps, loads

from launcher.model.errors import LaunchError
from launcher.output import console

TYPE_CHECKING = False  # (typing.TYPE_CHECKING without importing typing; the annotations are text)
if TYPE_CHECKING:
    from typing import Any, Callable

MADE, REFUSED, FAILED = "made", "refused", "failed"  # what the child sends: its value, its LaunchError, a bug
INTERRUPTED = 130  # the child's exit status at a Ctrl-C


def begin_apart(make: Callable[[], object], verbose: bool = False) -> Apart:
    """`make()` begun in a forked child (in this process, made now, if a thread runs or no fork is to be had);
    its value, or its error, is `result()`'s."""
    if threading.active_count() > 1 or not hasattr(os, "fork"):
        return Apart.here(make)
    console.flush()
    for stream in (sys.stdout, sys.stderr):
        stream.flush()  # (the child must not write again what this process had buffered)
    read_end, write_end = os.pipe()
    # (SIGINT waits until the child has its own handler: a Ctrl-C at the fork must not make it a second launch)
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        pid = os.fork()
    except OSError:
        pid = -1
    if pid == 0:  # the child: ends in os._exit, never returns
        _child(make, read_end, write_end, mask, verbose)
    signal.pthread_sigmask(signal.SIG_SETMASK, mask)
    os.close(write_end)
    if pid < 0:  # (no fork to be had: here, then)
        os.close(read_end)
        return Apart.here(make)
    return Apart(pid, read_end)


class Apart:
    """A value being made in a child of this process (`begin_apart`): `result()` once, or `abandon()`."""

    def __init__(self, pid: int, read_end: int):
        self.pid = pid  # (0: made here, in `_made`)
        self._read_end = read_end
        self._made: tuple[str, Any] = ("", None)

    @classmethod
    def here(cls, make: Callable[[], object]) -> Apart:
        """Made in this process, now: its value, or its LaunchError (any other error is raised at once)."""
        apart = cls(0, -1)
        try:
            apart._made = (MADE, make())
        except LaunchError as e:
            apart._made = (REFUSED, e)
        return apart

    def result(self) -> Any:
        """The value (waiting for the child to send it); the child's LaunchError raised here, a bug of the child's
        as a RuntimeError, a Ctrl-C that ended the child as KeyboardInterrupt."""
        if not self.pid:
            kind, value = self._made
            if kind == REFUSED:
                raise value
            return value
        pid, self.pid = self.pid, 0
        try:
            with open(self._read_end, "rb") as answer:
                data = answer.read()
        except BaseException:  # (a Ctrl-C sent to the launch alone: its reader stops too, and its commands with it)
            os.kill(pid, signal.SIGINT)
            raise
        finally:
            _, status = os.waitpid(pid, 0)
        self._made = _answer(data, status)
        return self.result()

    def abandon(self) -> None:
        """The value will not be asked for (the launch ends before it takes it): the child, if it still runs, is
        stopped as a Ctrl-C stops it (with the command it runs for the plan), and reaped."""
        if self.pid:
            pid, self.pid = self.pid, 0
            os.close(self._read_end)  # (a child writing its answer gets EPIPE)
            ignored = signal.getsignal(signal.SIGINT) is signal.SIG_IGN  # (and so is it in the child)
            try:
                os.kill(pid, signal.SIGKILL if ignored else signal.SIGINT)
            except OSError:
                pass
            os.waitpid(pid, 0)


def _child(make: Callable[[], object], read_end: int, write_end: int, mask: set, verbose: bool) -> None:
    code = 0
    try:
        if signal.getsignal(signal.SIGINT) is not signal.SIG_IGN:  # (a background job's stays ignored)
            signal.signal(signal.SIGINT, _interrupt_once)
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)
        os.close(read_end)
        try:
            data = dumps((MADE, make()), -1)
        except LaunchError as e:
            data = dumps((REFUSED, _crossing(e)))
        except KeyboardInterrupt:
            data, code = b"", INTERRUPTED  # (the launch got the same Ctrl-C: it says nothing of ours)
        except BaseException as e:  # noqa: BLE001 - a bug of ours: the launch says so in one line
            if verbose:
                traceback.print_exc()
            data = dumps((FAILED, "%s: %s" % (type(e).__name__, e)))
        console.flush()
        for stream in (sys.stdout, sys.stderr):
            stream.flush()
        with open(write_end, "wb") as out:
            out.write(data)
    except BaseException:  # noqa: BLE001 - nothing of the child may run on as a second launch
        code = code or 1
    finally:
        os._exit(code)  # (not the launch's exit handlers: they are the launch's)


def _crossing(error: LaunchError) -> LaunchError:
    """The error as it can cross the pipe: itself where pickle gives it back with its words (a UsageError stays
    one: `launch` exits 2 for it), else a LaunchError of its words (one made with other arguments than its text)."""
    try:
        back = loads(dumps(error))
        if type(back) is type(error) and str(back) == str(error):
            return error
    except Exception:  # noqa: BLE001 - (any way it does not cross)
        pass
    return LaunchError(str(error))


_interrupted = False


def _interrupt_once(signum: int, frame: object) -> None:
    """The child's SIGINT: one KeyboardInterrupt (what runs a command for the plan stops it), then none, so
    that the child always reaches its os._exit."""
    global _interrupted
    if not _interrupted:
        _interrupted = True
        raise KeyboardInterrupt


def _answer(data: bytes, status: int) -> tuple[str, Any]:
    """What the child sent: (MADE, its value) or (REFUSED, its LaunchError); a bug of the child's raised as a
    RuntimeError, its Ctrl-C as KeyboardInterrupt."""
    if not data:  # (ended without an answer)
        if os.WIFEXITED(status) and os.WEXITSTATUS(status) == INTERRUPTED:
            raise KeyboardInterrupt  # (a Ctrl-C, which the launch got too)
        how = ("signal %d" % os.WTERMSIG(status) if os.WIFSIGNALED(status)
               else "exit status %d" % os.WEXITSTATUS(status))
        raise LaunchError("the process reading the launch files ended without a plan (%s)" % how)
    kind, value = loads(data)
    if kind == FAILED:
        raise RuntimeError("%s (while the launch files were read)" % value)
    return kind, value
