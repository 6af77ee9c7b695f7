"""What differs between the Pythons the launcher runs on (CPython 3.8, Ubuntu 20.04's and the ros:noetic
images', to 3.13), in one place: the rest of the code is written for 3.8 and reaches for a newer call
only through here."""

from __future__ import annotations

import asyncio
import contextlib
import contextvars
import errno
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


# Before 3.10, subprocess starts a child with fork(): each start makes every page of the launch copy-on-write, and
# the launch then takes a fault for each page it writes (a 100-node start on Ubuntu 20.04's Python 3.8: 55,000
# faults, 0.09 s of its 0.28 s of CPU, 11% of its time to all registered). From 3.10 subprocess uses vfork().
# Before it a node is started with glibc's posix_spawn (a vfork too), called through libc; its working directory
# is set by posix_spawn_file_actions_addchdir_np (glibc 2.29; Ubuntu 20.04 has 2.31). One difference from Popen's
# child, as with Python's own os.posix_spawn: glibc leaves its two internal signals (32 and 33, below SIGRTMIN,
# which no program can use) ignored in the child. glibc's constants:
_POSIX_SPAWN_SETSIGDEF = 0x04
_POSIX_SPAWN_SETSID = 0x80


class NodeSpawner:
    """Starts a node's process as subprocess.Popen(argv, cwd=, env=, stdout=, stderr=, close_fds=True,
    start_new_session=True) does, without fork(): `spawn` returns its pid, or raises Popen's OSError."""

    def __init__(self, libc: Any):
        import ctypes
        import signal

        self._ctypes = ctypes
        self._libc = libc
        ptr, c_int = ctypes.c_void_p, ctypes.c_int  # (declared: a pointer passed as a bare int would be cut to 32 bits)
        libc.posix_spawn.argtypes = [ctypes.POINTER(c_int), ctypes.c_char_p, ptr, ptr, ptr, ptr]
        libc.posix_spawn_file_actions_init.argtypes = [ptr]
        libc.posix_spawn_file_actions_destroy.argtypes = [ptr]
        libc.posix_spawn_file_actions_adddup2.argtypes = [ptr, c_int, c_int]
        libc.posix_spawn_file_actions_addchdir_np.argtypes = [ptr, ctypes.c_char_p]
        libc.posix_spawnattr_init.argtypes = [ptr]
        libc.posix_spawnattr_setsigdefault.argtypes = [ptr, ptr]
        libc.posix_spawnattr_setflags.argtypes = [ptr, ctypes.c_short]
        libc.sigemptyset.argtypes = [ptr]
        libc.sigaddset.argtypes = [ptr, c_int]
        self._environ = ctypes.c_void_p.in_dll(libc, "environ")  # (where env is None: the launch's own)
        # one attribute set for every start: a session of its own, SIGPIPE and SIGXFSZ back to their defaults
        # (the interpreter ignores them; Popen's restore_signals does the same)
        self._attr = ctypes.create_string_buffer(1024)  # (posix_spawnattr_t: 336 bytes on glibc)
        sigdef = ctypes.create_string_buffer(256)  # (sigset_t: 128)
        libc.posix_spawnattr_init(self._attr)
        libc.sigemptyset(sigdef)
        for sig in (signal.SIGPIPE, signal.SIGXFSZ):
            libc.sigaddset(sigdef, sig)
        libc.posix_spawnattr_setsigdefault(self._attr, sigdef)
        libc.posix_spawnattr_setflags(self._attr, _POSIX_SPAWN_SETSID | _POSIX_SPAWN_SETSIGDEF)
        self._closed_inherited = False

    def spawn(self, argv: list, cwd: str, env: dict | None, stdout: int | None, stderr: int | None) -> int:
        ctypes, libc = self._ctypes, self._libc
        if not self._closed_inherited:
            _not_inherited_from_here()
            self._closed_inherited = True
        args = [_c_string(a) for a in argv]
        envp = None
        if env is not None:
            envp = []
            for key, value in env.items():
                key = _c_string(key)
                if b"=" in key:
                    raise ValueError("illegal environment variable name")
                envp.append(key + b"=" + _c_string(value))
        path = os.fsencode(argv[0])
        candidates = [path] if os.path.dirname(path) else \
            [os.path.join(os.fsencode(d), path) for d in os.get_exec_path(env)]
        c_argv = (ctypes.c_char_p * (len(args) + 1))(*args)
        c_envp = (ctypes.c_char_p * (len(envp) + 1))(*envp) if envp is not None else None
        envp_pointer = ctypes.cast(c_envp, ctypes.c_void_p) if c_envp is not None else self._environ
        actions = ctypes.create_string_buffer(1024)  # (posix_spawn_file_actions_t: 80 bytes on glibc)
        libc.posix_spawn_file_actions_init(actions)
        try:
            for fd, target in ((stdout, 1), (stderr, 2)):
                if fd is not None:
                    libc.posix_spawn_file_actions_adddup2(actions, fd, target)
            if cwd:
                libc.posix_spawn_file_actions_addchdir_np(actions, os.fsencode(cwd))
            pid = ctypes.c_int()
            err = first_error = 0
            for candidate in candidates:  # (as Popen: each folder of PATH; the first error not "no such file")
                err = libc.posix_spawn(ctypes.byref(pid), candidate, actions, self._attr, c_argv, envp_pointer)
                if err == 0:
                    return pid.value
                if err not in (errno.ENOENT, errno.ENOTDIR) and not first_error:
                    first_error = err
            err = first_error or err
        finally:
            libc.posix_spawn_file_actions_destroy(actions)
        if err == errno.ENOENT and cwd and not os.path.isdir(cwd):
            raise FileNotFoundError(err, os.strerror(err), cwd)  # (Popen's words for a missing cwd)
        raise OSError(err, os.strerror(err), argv[0])


def _c_string(text: Any) -> bytes:
    data = os.fsencode(text)
    if b"\0" in data:
        raise ValueError("embedded null byte")
    return data


def _not_inherited_from_here() -> None:
    """What the launch inherited open (a shell's `3>file`) is not passed on to its nodes, as Popen's close_fds
    sees to; everything the launch opens itself is opened close-on-exec (PEP 446)."""
    try:
        fds = [int(fd) for fd in os.listdir("/proc/self/fd")]
    except OSError:
        return
    for fd in fds:
        if fd > 2:
            try:
                if os.get_inheritable(fd):
                    os.set_inheritable(fd, False)
            except OSError:
                pass  # (the listing's own descriptor, closed by now)


@functools.lru_cache(maxsize=None)
def node_spawner() -> NodeSpawner | None:
    """A NodeSpawner where subprocess would fork (before 3.10) and glibc has what it needs; else None: Popen."""
    if sys.version_info >= (3, 10):
        return None
    try:
        if not os.confstr("CS_GNU_LIBC_VERSION"):
            return None
        libc = _libc()
        if not hasattr(libc, "posix_spawn_file_actions_addchdir_np"):
            return None
        return NodeSpawner(libc)
    except (OSError, ValueError, AttributeError):
        return None


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
