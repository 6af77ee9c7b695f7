"""The log directory: run dir + `latest`, and the background disk checks."""

from __future__ import annotations

import asyncio
import os
import time

import pytest

from launcher.output import logdir


def test_log_root_follows_ros_log_dir_then_ros_home(tmp_path):
    assert logdir.log_root({"ROS_LOG_DIR": "/x/logs", "ROS_HOME": "/h"}) == "/x/logs"
    assert logdir.log_root({"ROS_HOME": "/h"}) == "/h/log"
    assert logdir.log_root({}) == os.path.join(os.path.expanduser("~"), ".ros", "log")


def test_run_dir_and_latest_link(tmp_path):
    env = {"ROS_LOG_DIR": str(tmp_path / "log")}
    first = logdir.make_run_log_dir(env, "run-1")
    logdir.point_latest(first)
    second = logdir.make_run_log_dir(env, "run-2")
    assert os.path.isdir(first) and os.path.isdir(second)
    assert os.readlink(tmp_path / "log" / "latest") == first  # (not yet: the run's launch log comes first)
    logdir.point_latest(second)
    assert os.readlink(tmp_path / "log" / "latest") == second


def test_latest_points_at_a_run_whose_launch_log_has_its_first_line(tmp_path, monkeypatch):
    """`launcher status` asked at any moment of a start reads `latest` as a run of `launch`'s, never as a directory
    without its launch log (which it would take for roslaunch's)."""
    from launcher.operate import lastrun
    from launcher.output import runlog
    env = {"ROS_LOG_DIR": str(tmp_path / "log")}
    seen = []
    linked = logdir.point_latest

    def point_latest(run_dir):
        seen.append(lastrun._our_launch_logs(run_dir))  # (what a reader of the run would find at that moment)
        linked(run_dir)
    monkeypatch.setattr(runlog, "point_latest", point_latest)
    log = runlog.RunLog(env)
    try:
        run_dir = log.open("run-7")
    finally:
        log.close()
    assert seen == [[log.path]] and os.readlink(tmp_path / "log" / "latest") == run_dir


def test_check_warns_over_threshold_with_roslaunch_words(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "big.log").write_bytes(b"x" * 5000)
    over = asyncio.run(logdir.check_once(str(tmp_path), 4096))
    assert (True, "WARNING: disk usage in log directory [%s] is over 4KiB.\n"
                  "It's recommended that you use the 'rosclean' command." % tmp_path) in over
    under = asyncio.run(logdir.check_once(str(tmp_path), 10**9))
    assert (False, "Done checking log file disk usage. Usage is <1GB.") in under
    # roslaunch's threshold, 2**30 bytes: its words are "1GB"
    under = asyncio.run(logdir.check_once(str(tmp_path), logdir.DEFAULT_THRESHOLD))
    assert (False, "Done checking log file disk usage. Usage is <1GB.") in under


def test_background_check_runs_later_and_cancels_at_once(tmp_path, capsys):
    calls = []

    async def slow_check(root, threshold):
        calls.append(time.monotonic())
        await asyncio.sleep(100)
        return []

    async def main():
        t0 = time.monotonic()
        task = asyncio.ensure_future(logdir.watch_log_disk(str(tmp_path), 1, first_delay=0.05, check=slow_check))
        while not calls:
            await asyncio.sleep(0.01)
        started = calls[0] - t0
        t1 = time.monotonic()
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        return started, time.monotonic() - t1
    started, cancel_took = asyncio.run(main())
    assert started >= 0.05  # never during start-up
    assert cancel_took < 0.05


def test_disk_usage_is_apparent_size(tmp_path):
    for i in range(50):
        (tmp_path / ("f%d" % i)).write_bytes(b"x" * 100)
    sparse = tmp_path / "sparse"
    with open(sparse, "wb") as f:
        f.truncate(10 << 20)  # 10 MB apparent, nothing on disk: du -sb counts it, as roslaunch's check
    assert asyncio.run(logdir.disk_usage_bytes(str(tmp_path))) >= 5000 + (10 << 20)


def test_disk_space_is_what_statvfs_and_df_say(tmp_path, monkeypatch):
    """Free is what a user may still write (f_bavail), total the whole filesystem: a disk with less than 1 GiB
    or 5 % free is named nearly full, in the units the README gives."""
    fs = os.statvfs(str(tmp_path))
    free, total = fs.f_bavail * fs.f_frsize, fs.f_blocks * fs.f_frsize
    full = free < logdir.LOW_DISK_BYTES or free < total * logdir.LOW_DISK_FRACTION
    assert (logdir.disk_space_warning(str(tmp_path)) is not None) == full

    class NearlyFull:
        f_frsize, f_blocks, f_bavail = 4096, 25 * 2 ** 20, 2 ** 17  # 100 GiB, 512 MiB of it free

    monkeypatch.setattr(logdir.os, "statvfs", lambda path: NearlyFull)
    assert logdir.disk_space_warning(str(tmp_path / "not-yet")) == (
        "WARNING: the disk holding the log directory [%s] is nearly full: %s free of %s."
        % (tmp_path / "not-yet", logdir.format_size(2 ** 29, measured=True),
           logdir.format_size(100 * 2 ** 30, measured=True)))
    NearlyFull.f_bavail = 10 * 2 ** 20  # 40 GiB free: not full
    assert logdir.disk_space_warning(str(tmp_path)) is None


def test_du_is_found_on_path_as_which_finds_it(tmp_path, monkeypatch):
    import shutil
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    (bin_dir / "du").write_text("#!/bin/sh\n")
    (bin_dir / "du").chmod(0o755)
    (bin_dir / "nice").mkdir()  # (a folder of that name is not a program)
    (bin_dir / "plain").write_text("not executable")
    monkeypatch.setenv("PATH", str(bin_dir))
    assert logdir._du_argv("/x") == [str(bin_dir / "du"), "-sb", "/x"]
    for name in ("du", "nice", "plain", "absent"):
        assert logdir._on_path(name) == shutil.which(name), name
