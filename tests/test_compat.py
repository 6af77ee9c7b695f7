"""launcher/compat.py: the newer calls as 3.8 gets them, each doing what the newer Python's does."""

from __future__ import annotations

import asyncio
import os
import select
import subprocess
import sys
import threading
import time

from launcher import compat


def test_pidfd_by_the_system_call_becomes_readable_at_the_exit():
    """The libc path (3.8's) on every Python: readable only once the process has exited, and waitid reads it."""
    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(0.3)"])
    fd = compat._syscall_pidfd_open(child.pid)
    try:
        assert select.select([fd], [], [], 0)[0] == []
        started = time.monotonic()
        assert select.select([fd], [], [], 10)[0] == [fd]
        assert time.monotonic() - started < 5
        info = os.waitid(compat.P_PIDFD, fd, os.WEXITED | os.WNOHANG)
        assert info is not None and info.si_pid == child.pid and info.si_status == 0
    finally:
        os.close(fd)
        child.wait()


def test_pidfd_of_no_process_is_an_oserror():
    try:
        compat._syscall_pidfd_open(2 ** 22 + 12345)  # (past pid_max's default: no such process)
    except OSError as e:
        assert e.errno in (3, 22)  # ESRCH, EINVAL
    else:
        raise AssertionError("no OSError")


def test_to_thread_runs_off_the_loop_with_the_callers_context():
    import contextvars
    var = contextvars.ContextVar("var")

    async def main():
        var.set("mine")
        return await compat.to_thread(lambda a: (a, threading.current_thread() is threading.main_thread(),
                                                 var.get()), 7)

    assert asyncio.run(main()) == (7, False, "mine")


def test_removeprefix():
    assert compat.removeprefix("TEST-a", "TEST-") == "a"
    assert compat.removeprefix("a-TEST-", "TEST-") == "a-TEST-"
    assert compat.removeprefix("abc", "") == "abc"


def test_primitives_made_before_the_loop_work_in_it():
    """As since 3.10: made where no loop runs (a record made before `asyncio.run`), bound to the loop that uses
    them, also after an earlier loop was closed and in a thread without one."""
    asyncio.run(asyncio.sleep(0))  # (leaves the main thread with no current loop)
    event, lock, queue = compat.Event(), compat.Lock(), compat.Queue()
    made_in_thread = []
    t = threading.Thread(target=lambda: made_in_thread.append(compat.Event()))
    t.start()
    t.join()

    async def main():
        asyncio.get_running_loop().call_later(0.01, event.set)
        await asyncio.wait_for(event.wait(), 5)
        async with lock:
            await queue.put(1)
        assert await queue.get() == 1
        queue.task_done()
        await asyncio.wait_for(queue.join(), 5)
        other = made_in_thread[0]
        asyncio.get_running_loop().call_soon(other.set)
        await asyncio.wait_for(other.wait(), 5)
        return True

    assert asyncio.run(main())
    assert isinstance(event, asyncio.Event) and isinstance(queue, asyncio.Queue)


def test_orig_argv_is_the_whole_command_line():
    """`python -m launcher ...` as typed (roslaunch's process_info gives it): 3.8's sys.argv has the module's path."""
    code = "import json; from launcher import compat; print(json.dumps(compat.orig_argv()))"
    import json
    r = subprocess.run([sys.executable, "-c", code, "a b", "-p"], capture_output=True, text=True, timeout=60,
                       cwd=os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    assert json.loads(r.stdout) == [sys.executable, "-c", code, "a b", "-p"], r.stderr


def test_wait_for_raises_a_cancel_that_comes_as_its_awaitable_completes():
    """asyncio.wait_for before 3.12 returned the result instead (its caller ran on, cancelled for nothing): a
    service's looping task so outlived its stop, and the launch never ended."""
    async def go() -> str:
        inner = asyncio.get_running_loop().create_future()
        outer = asyncio.ensure_future(compat.wait_for(inner, 10.0))
        await asyncio.sleep(0)  # (outer now waits)
        inner.set_result("done")
        outer.cancel()  # (in the same step: its wake-up for the result is already queued)
        try:
            await outer
        except asyncio.CancelledError:
            return "cancelled"
        return "ran on"
    assert asyncio.run(go()) == "cancelled"


def test_wait_for_times_out_returns_and_passes_on_as_asyncio_does():
    async def slow() -> str:
        await asyncio.sleep(10)
        return "late"

    async def failing() -> None:
        raise ValueError("inner")

    async def go() -> list:
        got = []
        started = time.monotonic()
        try:
            await compat.wait_for(slow(), 0.05)
        except asyncio.TimeoutError:
            got.append(("timeout", time.monotonic() - started < 5))
        got.append(await compat.wait_for(asyncio.sleep(0, "now"), 5.0))
        got.append(await compat.wait_for(asyncio.sleep(0, "no limit"), None))
        try:
            await compat.wait_for(failing(), 5.0)
        except ValueError as e:
            got.append(str(e))
        task = asyncio.ensure_future(compat.wait_for(slow(), 5.0))
        await asyncio.sleep(0.01)
        task.cancel()  # (cancelled from outside: a cancel, not a timeout)
        try:
            await task
        except asyncio.CancelledError:
            got.append("cancelled")
        return got
    assert asyncio.run(go()) == [("timeout", True), "now", "no limit", "inner", "cancelled"]


def test_wait_for_with_no_time_left_is_asyncios():
    """A timeout of 0 or less: a coroutine gets no step (TimeoutError even if it would not have waited), a future
    that has its result gives it, as asyncio.wait_for does on every Python."""
    async def go(wait_for) -> list:
        got = []
        ready = asyncio.Event()
        ready.set()
        for timeout in (0, -1.0):
            try:
                got.append(await wait_for(ready.wait(), timeout))
            except asyncio.TimeoutError:
                got.append("timeout")
        done = asyncio.get_running_loop().create_future()
        done.set_result("had it")
        got.append(await wait_for(done, 0))
        return got
    assert asyncio.run(go(compat.wait_for)) == asyncio.run(go(asyncio.wait_for)) == ["timeout", "timeout", "had it"]


# Each case started by NodeSpawner (through libc, as Pythons before 3.10 start nodes) and by subprocess.Popen as
# the launch called it before, in a process of its own (the spawner marks what that process inherited
# close-on-exec): what each child reports of itself, and each failure's kind, errno and file name.
SPAWN_BOTH_WAYS = r"""
import json, os, shutil, subprocess, sys, tempfile
from launcher import compat
from launcher.process.spawn import Spawned

inherited = os.open(os.devnull, os.O_RDONLY)
os.set_inheritable(inherited, True)  # (as a shell's `3</dev/null` would be)
spawner = compat.NodeSpawner(compat._libc())
work = tempfile.mkdtemp()
REPORT = "echo cwd=$(pwd) foo=${FOO-unset} path=$PATH; ps -o pid=,pgid=,sid= -p $$; ls /proc/$$/fd; echo to-stderr >&2"
SIGNALS = ["grep", "-E", "^Sig(Ign|Blk)", "/proc/self/status"]  # (the started process's own, as it began: a shell's
# changes as it forks its commands)

def popen(argv, cwd, env, out, err):
    return subprocess.Popen(argv, cwd=cwd, env=env, stdout=out, stderr=err, close_fds=True,
                            start_new_session=True)

def libc(argv, cwd, env, out, err):
    return Spawned(spawner.spawn(argv, cwd, env, out, err))

results = {}
for way, start in (("popen", popen), ("libc", libc)):
    got = results[way] = []
    for env in (None, {"FOO": "bar", "PATH": "/usr/bin:/bin"}):
        path = os.path.join(work, way + "-out")
        out = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_CLOEXEC)
        child = start(["sh", "-c", REPORT], work, env, out, out)
        code = child.wait()
        os.lseek(out, 0, os.SEEK_END)
        start(SIGNALS, work, env, out, None).wait()
        os.close(out)
        lines = open(path).read().split("\n")
        pid, pgid, sid = lines[1].split()
        ignored = int(lines[-2].split()[1], 16) & ~(3 << 31)  # (glibc's posix_spawn leaves its own two signals,
        # 32 and 33, ignored: reserved to glibc, below SIGRTMIN, no program can use them)
        got.append([code, lines[0], pid == pgid == sid == str(child.pid), lines[-3], ignored] + lines[2:-3])
    for argv in (["sh", "-c", "exit 3"], ["sh", "-c", "kill -TERM $$"], ["sh", "-c", "kill -PIPE $$"]):
        got.append(start(argv, work, None, None, None).wait())
    script, data = os.path.join(work, "no-hash-bang"), os.path.join(work, "not-executable")
    for name, mode in ((script, 0o755), (data, 0o644)):
        with open(name, "w") as f:
            f.write("echo hi\n")
        os.chmod(name, mode)
    for argv, cwd in (([os.path.join(work, "none", "node")], work), (["no-such-command-here"], work), ([data], work),
                      ([script], work), (["sh"], os.path.join(work, "missing")), (["sh", "a\0b"], work)):
        try:
            start(argv, cwd, None, None, None).wait()
            got.append("started")
        except (OSError, ValueError) as e:
            got.append([type(e).__name__, getattr(e, "errno", None), getattr(e, "filename", None)])
shutil.rmtree(work)
print(json.dumps(results))
"""


def test_node_spawner_starts_a_node_as_popen_did():
    out = subprocess.run([sys.executable, "-c", SPAWN_BOTH_WAYS], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    results = __import__("json").loads(out.stdout)
    assert results["libc"] == results["popen"]
    (code, words, own_session, blocked, ignored, *fds), second = results["popen"][:2]
    assert code == 0 and own_session and words.startswith("cwd=/") and "foo=unset" in words
    assert blocked.split()[1] == "0000000000000000" and ignored == 0
    assert "foo=bar path=/usr/bin:/bin" in second[1]
    assert "3" not in fds and "0" in fds  # (the inherited 3 was not passed on)
    assert results["popen"][2:5] == [3, -15, -13]  # (SIGPIPE back to its default)
    failures = results["popen"][5:]
    assert [f[:2] for f in failures[:5]] == [["FileNotFoundError", 2], ["FileNotFoundError", 2],
                                            ["PermissionError", 13], ["OSError", 8], ["FileNotFoundError", 2]]
    assert failures[0][2].endswith("/none/node") and failures[1][2] == "no-such-command-here"
    assert failures[2][2].endswith("/not-executable") and failures[3][2].endswith("/no-hash-bang")
    assert failures[4][2].endswith("/missing") and failures[5] == ["ValueError", None, None]


def test_nodes_are_started_by_libc_where_subprocess_would_fork():
    spawner = compat.node_spawner()
    assert (spawner is None) == (sys.version_info >= (3, 10))
