"""Starting one node's process (`start_process`, from the plan's `ProcessSpec`), with roslaunch's failure
messages."""

from __future__ import annotations

import errno
import os
import signal
import subprocess
import time

from launcher.compat import node_spawner
from launcher.plan.specs import ProcessSpec
from launcher.output import console
from launcher.process.coredumps import raise_core_limit, restore_core_limit
from launcher.output.screen import Channels


class SpawnError(Exception):
    """A node's process could not be started; the message says why, in roslaunch's words."""


class Spawned:
    """A node's process started without subprocess (before Python 3.10: `compat.NodeSpawner`), with what the
    runners ask of a Popen: its pid, and its returncode (negative: the signal that killed it) from poll or wait."""

    def __init__(self, pid: int):
        self.pid = pid
        self.returncode: int | None = None

    def poll(self) -> int | None:
        if self.returncode is None:
            try:
                pid, status = os.waitpid(self.pid, os.WNOHANG)
            except ChildProcessError:  # (reaped by another: Popen says 0 too)
                self.returncode = 0
            else:
                if pid == self.pid:
                    self.returncode = _returncode(status)
        return self.returncode

    def wait(self, timeout: float | None = None) -> int:
        if timeout is not None:  # (as Popen: polled, up to 50 ms apart)
            deadline, delay = time.monotonic() + timeout, 0.0005
            while self.poll() is None:
                if time.monotonic() >= deadline:
                    raise subprocess.TimeoutExpired(str(self.pid), timeout)
                time.sleep(min(delay, max(0.0, deadline - time.monotonic())))
                delay = min(2 * delay, 0.05)
        if self.returncode is None:
            try:
                self.returncode = _returncode(os.waitpid(self.pid, 0)[1])
            except ChildProcessError:
                self.returncode = 0
        return self.returncode


def _returncode(status: int) -> int:
    """os.waitstatus_to_exitcode (3.9), as Popen's returncode."""
    return -os.WTERMSIG(status) if os.WIFSIGNALED(status) else os.WEXITSTATUS(status)


def spawn_error_message(name: str, argv: list[str], e: OSError) -> str:
    if e.errno == errno.ENOEXEC:
        return "Unable to launch [%s]. \nIf it is a script, you may be missing a '#!' declaration at the top." % name
    if e.errno in (errno.ENOENT, errno.EACCES):
        return ("[%s] got a '%s' error while attempting to run:\n\n%s\n\n"
                "Please make sure that all the executables in this command exist and have\n"
                "executable permission. This is often caused by a bad launch-prefix."
                % (name, e.strerror, " ".join(argv)))
    return "unable to launch [%s]: %s" % (" ".join(argv), e.strerror)


# the launcher's environment, read at the first node's start: nothing of ours changes os.environ (a run's plan reads
# a copy of it), so what a node inherits is this
_OWN_ENVIRON: dict[str, str] = {}


def node_environ(env: dict[str, str], changes: list[tuple[str, str]]) -> dict[str, str] | None:
    """The `env` to give Popen for a node: None (it inherits ours) where it is the launcher's own environment, as
    it is for most nodes of a shell with ROS_MASTER_URI set: subprocess would encode each of its variables again
    at each node's start (~10 ms of a 100-node start's CPU)."""
    if changes:
        return env
    if not _OWN_ENVIRON:
        _OWN_ENVIRON.update(os.environ)
    return None if env == _OWN_ENVIRON else env


def spawn(spec: ProcessSpec, append: bool = False, channels: Channels | None = None) -> subprocess.Popen | Spawned:
    """Start the node's process in a new session/process group. Raises SpawnError.

    `channels`: the ptys/pipes the launcher relays the node's terminal-bound streams through
    (output/screen.py); their node ends are closed here once the node holds them.

    Signals the launcher handles are reset to their default disposition by exec
    itself; ones it inherited *ignored* (a background shell ignores SIGINT) are
    restored by `restore_default_signals_for_children` (the Supervisor calls it).
    """
    stdout = stderr = stdout_file = None
    if channels is not None:
        stdout, stderr = channels.stdout, channels.stderr
    if spec.output == "log" and spec.stdout_path:
        # roslaunch: append when respawning, so earlier runs' output survives; always O_APPEND, so
        # that a rotation's truncation (output/logrotate.py) moves the node's writes to the start
        flags = os.O_WRONLY | os.O_CREAT | os.O_CLOEXEC | os.O_APPEND | (0 if append or spec.respawn else os.O_TRUNC)
        try:
            stdout = stdout_file = os.open(spec.stdout_path, flags, 0o666)  # (a bare fd: no file object per node)
        except OSError as e:
            raise SpawnError("[%s] ERROR: unable to configure logging [%s]" % (spec.name, e)) from None
    command = spec.command
    env = node_environ(command.env, command.env_changes)
    core_limit = raise_core_limit() if spec.policy.enable_coredumps else None  # inherited by this node only
    spawner = node_spawner()  # (None from Python 3.10: Popen, which uses vfork there)

    def start() -> subprocess.Popen | Spawned:
        if spawner is not None:
            return Spawned(spawner.spawn(command.argv, command.cwd, env, stdout, stderr))
        return subprocess.Popen(command.argv, cwd=command.cwd or None, env=env, stdout=stdout, stderr=stderr,
                                close_fds=True, start_new_session=True)
    try:
        try:
            return start()
        except FileNotFoundError as e:
            if not command.cwd or e.filename != command.cwd:
                raise
            # the working directory (ROS_HOME, ~/.ros by default) does not exist yet: create it, as
            # roslaunch does (only now: a makedirs before every spawn costs more than the spawn's setup)
            try:
                os.makedirs(command.cwd, exist_ok=True)
            except OSError:
                pass
            return start()
    except OSError as e:
        raise SpawnError(spawn_error_message(spec.name, spec.argv, e)) from None
    except ValueError:  # (a NUL, from an $(eval): no exec can be given it; this node fails, the launch goes on)
        raise SpawnError("[%s] cannot be started: its command line or environment holds a NUL character (\\0), "
                         "which no program can be given" % spec.name) from None
    finally:
        if channels is not None:
            channels.close_child_ends()
        if stdout_file is not None:
            os.close(stdout_file)
        if core_limit is not None:
            restore_core_limit(core_limit)


def _ignore(signum, frame) -> None:
    """Stands in for an inherited SIG_IGN: same effect here, but exec resets it in children."""


def restore_default_signals_for_children() -> None:
    """Make sure nodes start with SIGINT/SIGQUIT/SIGTERM/SIGHUP at their default disposition.

    exec keeps a signal *ignored* but resets a *handled* one to default. A
    launcher started as a background job inherits SIGINT and SIGQUIT ignored,
    and would pass that on to every node (which then could not be stopped by
    SIGINT). Replacing each inherited SIG_IGN with a do-nothing handler keeps
    the launcher's own behaviour and gives the nodes their defaults.
    """
    for sig in (signal.SIGINT, signal.SIGQUIT, signal.SIGTERM, signal.SIGHUP):
        try:
            if signal.getsignal(sig) == signal.SIG_IGN:
                signal.signal(sig, _ignore)
        except (ValueError, OSError):  # not the main thread: the runtime handles it
            pass


def start_process(spec: ProcessSpec, watchdog=None, append: bool = False,
                  channels: Channels | None = None) -> subprocess.Popen | Spawned | None:
    """Spawn a node as roslaunch does, by name: the process, or None after saying why it could not start.

    The no-orphans guard learns the new process group before anything else can
    fail, so that a launcher killed right now still leaves nothing behind.
    """
    try:
        popen = spawn(spec, append=append, channels=channels)
    except SpawnError as e:
        console.printerrlog(str(e))
        return None
    if watchdog is not None:
        watchdog.watch(popen.pid)
    console.printlog_bold("process[%s]: started with pid [%s]" % (spec.name, popen.pid))
    return popen
