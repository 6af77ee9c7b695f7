"""What differs between the Pythons the launcher runs on (CPython 3.8, Ubuntu 20.04's and the ros:noetic
images', to 3.13), in one place: the rest of the code is written for 3.8 and reaches for a newer call
only through here."""

from __future__ import annotations

import asyncio
import contextlib
import contextvars
import functools
import os
import sys
from typing import Any, Callable, Iterator, TypeVar

T = TypeVar("T")

# waitid(2)'s id type for a pidfd (Linux 5.4); os.P_PIDFD came with Python 3.9.
P_PIDFD: int = getattr(os, "P_PIDFD", 3)


def pidfd_open(pid: int) -> int:
    """A file descriptor that becomes readable when process `pid` exits (Linux 5.3+): exits are events on the
    loop, never a thread per node or a poll. os.pidfd_open came with Python 3.9; before it the system call
    itself, through libc. OSError as os.pidfd_open raises it (ENOSYS on an older kernel)."""
    if hasattr(os, "pidfd_open"):
        return os.pidfd_open(pid)
    return _syscall_pidfd_open(pid)


_PIDFD_OPEN = 434  # one number on every Linux architecture: it came after the syscall tables were unified


def _syscall_pidfd_open(pid: int) -> int:
    import ctypes  # (only on 3.8, and once: the library handle is kept)

    libc = _libc()
    fd = libc.syscall(_PIDFD_OPEN, ctypes.c_int(pid), ctypes.c_uint(0))
    if fd < 0:
        err = ctypes.get_errno()
        raise OSError(err, os.strerror(err))
    return int(fd)


@functools.lru_cache(maxsize=None)
def _libc() -> Any:
    import ctypes

    libc = ctypes.CDLL(None, use_errno=True)
    libc.syscall.restype = ctypes.c_long
    return libc


async def to_thread(func: Callable[..., T], *args: Any) -> T:
    """asyncio.to_thread (3.9): `func(*args)` in the loop's default executor, with the caller's context."""
    loop = asyncio.get_running_loop()
    call = functools.partial(contextvars.copy_context().run, func, *args)
    return await loop.run_in_executor(None, call)


def orig_argv() -> list:
    """sys.orig_argv (3.10): the interpreter's whole command line, `python -m launcher ...` as it was typed;
    before 3.10 read back from the kernel (sys.argv has `-m launcher` made into the module's path)."""
    if hasattr(sys, "orig_argv"):
        return list(sys.orig_argv)
    try:
        with open("/proc/self/cmdline", "rb") as f:
            return [os.fsdecode(a) for a in f.read().split(b"\0")[:-1]]
    except OSError:
        return [sys.executable] + sys.argv


def removeprefix(text: str, prefix: str) -> str:
    """str.removeprefix (3.9)."""
    return text[len(prefix):] if prefix and text.startswith(prefix) else text


if sys.version_info >= (3, 10):
    Event = asyncio.Event
    Lock = asyncio.Lock
    Queue = asyncio.Queue
else:
    # Before 3.10 an asyncio primitive took the loop current when it was made (and failed in a thread with
    # none); since 3.10 it is bound to the loop that first waits on it, which this code expects: the fleet's
    # records and the run's services are made before `asyncio.run` starts the loop they wait on.

    class _BoundWhenUsed:
        @property
        def _loop(self) -> asyncio.AbstractEventLoop:
            loop = self.__dict__.get("_bound_loop")
            if loop is None:
                loop = self.__dict__["_bound_loop"] = asyncio.get_event_loop()
            return loop

        @_loop.setter
        def _loop(self, loop: Any) -> None:
            pass  # (what the base class's __init__ sets: the loop current when made, not taken)

    @contextlib.contextmanager
    def _any_loop() -> Iterator[None]:
        """The base classes' __init__ ask for the current loop, which raises where there is none: for that
        moment a placeholder is the running loop (the property above ignores what __init__ stores)."""
        if asyncio._get_running_loop() is not None:
            yield
            return
        asyncio._set_running_loop(_PLACEHOLDER)  # type: ignore[arg-type]
        try:
            yield
        finally:
            asyncio._set_running_loop(None)

    _PLACEHOLDER = object()

    class Event(_BoundWhenUsed, asyncio.Event):  # type: ignore[no-redef]
        def __init__(self) -> None:
            with _any_loop():
                asyncio.Event.__init__(self)

    class Lock(_BoundWhenUsed, asyncio.Lock):  # type: ignore[no-redef]
        def __init__(self) -> None:
            with _any_loop():
                asyncio.Lock.__init__(self)

    class Queue(_BoundWhenUsed, asyncio.Queue):  # type: ignore[no-redef]
        def __init__(self, maxsize: int = 0) -> None:
            with _any_loop():
                asyncio.Queue.__init__(self, maxsize)
            self._finished = Event()  # (what join() waits on: made with the placeholder above)
            self._finished.set()


if sys.version_info >= (3, 12):
    wait_for = asyncio.wait_for
else:
    async def wait_for(aw: Any, timeout: float | None) -> Any:
        """asyncio.wait_for, without its flaw before 3.12: a cancel that came as `aw` completed was lost (its
        caller got the result and ran on). A service's task cancelled at the launch's end so ran on for good,
        and the launch with it (`launcher test --reuse-master` under load: its master watch's call). Here the
        caller awaits `aw` itself, so a cancel is raised in it as in any await, and a timer cancels `aw` at the
        deadline: asyncio.TimeoutError, unless `aw` had its result by then. A timeout of 0 or less gives `aw` no
        step at all, as asyncio's does (a coroutine times out even if it would not have waited)."""
        fut = asyncio.ensure_future(aw)
        if timeout is None:
            return await fut
        expired = []

        def expire() -> None:
            expired.append(True)
            fut.cancel()
        timer = None
        if timeout <= 0:
            expire()
        else:
            timer = asyncio.get_running_loop().call_later(timeout, expire)
        try:
            return await fut
        except asyncio.CancelledError:
            if expired and fut.cancelled():
                raise asyncio.TimeoutError() from None
            raise
        finally:
            if timer is not None:
                timer.cancel()
