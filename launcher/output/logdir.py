"""The log directory: where it is, the run's directory and `latest` link, and the background disk checks."""

from __future__ import annotations

import asyncio
import os
import subprocess
from typing import Awaitable, Callable, Mapping

from launcher.model.errors import LaunchError
from launcher.output import console
from launcher.workspace.roshome import log_root
from launcher.model.units import LOG_CHECK_THRESHOLD, format_size

# roslaunch's threshold: 2**30 bytes, which its messages call "1GB" (`1GiB` in our units).
DEFAULT_THRESHOLD = LOG_CHECK_THRESHOLD  # (roslaunch's, model.units: what a plan holds unless told)
# Warn when the disk holding the logs has less than this free (or less than 5 %).
LOW_DISK_BYTES = 1073741824
LOW_DISK_FRACTION = 0.05
# First check after start-up has settled (it must never compete with spawning),
# then again at this interval while the launch runs.
FIRST_CHECK_DELAY_S = 2.0
RECHECK_INTERVAL_S = 600.0

def make_run_log_dir(environ: Mapping[str, str], run_id: str) -> str:
    """Create `<log root>/<run_id>` (`point_latest` then points `latest` at it, as rosgraph.roslogging does)."""
    run_dir = os.path.join(log_root(environ), run_id)
    try:
        os.makedirs(run_dir, exist_ok=True)
    except OSError as e:
        raise LaunchError("unable to create directory for log files [%s]: %s" % (run_dir, e.strerror)) from None
    return run_dir


def point_latest(run_dir: str) -> None:
    """Point `latest`, beside the run's directory, at it: once the launch log has its first line, so that
    `launcher status` reading `latest` at that moment finds a run of `launch`'s, not a directory it cannot tell
    from roslaunch's."""
    latest = os.path.join(os.path.dirname(run_dir), "latest")
    try:
        if os.path.lexists(latest):
            if not os.path.islink(latest):
                console.printerrlog("INFO: cannot create a symlink to latest log directory")
                return
            # replace atomically: another launch may be reading it
            tmp = latest + ".%d" % os.getpid()
            os.symlink(run_dir, tmp)
            os.replace(tmp, latest)
        else:
            os.symlink(run_dir, latest)
    except OSError as e:
        console.printerrlog("INFO: cannot create a symlink to latest log directory: %s" % e)


def _du_argv(path: str) -> list[str] | None:
    du = _on_path("du")
    if not du:
        return None
    argv = [du, "-sb", path]
    nice = _on_path("nice")
    # low priority: the check must never compete with the nodes
    return [nice, "-n", "19"] + argv if nice else argv


def _on_path(name: str) -> str | None:
    """The program `name` on PATH, as shutil.which finds it: shutil imports its compressors, about 0.3 MB that
    a launch would keep for weeks for this one look-up."""
    for folder in os.get_exec_path():
        path = os.path.join(folder, name)
        if os.access(path, os.X_OK) and not os.path.isdir(path):
            return path
    return None


def _walk_size(path: str) -> int:
    total = 0
    for dirpath, dirnames, filenames in os.walk(path):
        for name in filenames + dirnames:
            try:
                total += os.lstat(os.path.join(dirpath, name)).st_size
            except OSError:
                pass
    return total


async def disk_usage_bytes(path: str) -> int:
    """Apparent size of everything under `path` (what roslaunch's `du -sb` reports).

    `du` runs as a low-priority child that is killed if the launch ends first
    (a cancelled check never delays the shutdown); without `du`, a walk in a
    worker thread.
    """
    argv = _du_argv(path)
    if argv is None:
        return await asyncio.get_running_loop().run_in_executor(None, _walk_size, path)
    proc = await asyncio.create_subprocess_exec(*argv, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                                                stdin=subprocess.DEVNULL)
    try:
        out, _ = await proc.communicate()
    except asyncio.CancelledError:
        try:
            proc.kill()
        except ProcessLookupError:
            pass
        raise
    try:
        return int(out.split()[0])
    except (IndexError, ValueError):
        return 0


def disk_space_warning(root: str) -> str | None:
    """A warning if the disk holding `root` is nearly full: statvfs, the space a user (not root) may still use,
    as `df` shows it (psutil.disk_usage is this call, and importing psutil costs the launch 2.5 MB)."""
    try:
        fs = os.statvfs(root if os.path.exists(root) else os.path.dirname(root) or "/")
    except OSError:
        return None
    free, total = fs.f_bavail * fs.f_frsize, fs.f_blocks * fs.f_frsize
    if free < LOW_DISK_BYTES or free < total * LOW_DISK_FRACTION:
        return ("WARNING: the disk holding the log directory [%s] is nearly full: %s free of %s."
                % (root, format_size(free, measured=True), format_size(total, measured=True)))
    return None


async def check_once(root: str, threshold: int) -> list[tuple[bool, str]]:
    """One round of checks: [(is_warning, message)]."""
    messages: list[tuple[bool, str]] = []
    if os.path.isdir(root):
        usage = await disk_usage_bytes(root)
        # roslaunch's own lines for its threshold
        limit = "1GB" if threshold == DEFAULT_THRESHOLD else format_size(threshold)
        if usage > threshold:
            messages.append((True, "WARNING: disk usage in log directory [%s] is over %s.\n"
                                   "It's recommended that you use the 'rosclean' command." % (root, limit)))
        else:
            messages.append((False, "Done checking log file disk usage. Usage is <%s." % limit))
    warning = disk_space_warning(root)
    if warning:
        messages.append((True, warning))
    return messages


async def watch_log_disk(root: str, threshold: int, *, first_delay: float = FIRST_CHECK_DELAY_S,
                         interval: float = RECHECK_INTERVAL_S,
                         check: Callable[[str, int], Awaitable[list[tuple[bool, str]]]] = check_once) -> None:
    """Check the log directory in the background now and then, until cancelled.

    roslaunch runs `du -sb` synchronously before anything starts; here the walk
    runs at low priority once start-up is over, so a big log directory never
    delays the nodes. Only warnings are repeated.
    """
    await asyncio.sleep(first_delay)
    first = True
    while True:
        try:
            messages = await check(root, threshold)
        except Exception:  # noqa: BLE001 - a failing check must never take the launch down
            messages = []
        for is_warning, msg in messages:
            if is_warning:
                console.printerrlog(msg)
            elif first:
                console.printlog(msg)
        first = False
        await asyncio.sleep(interval)
