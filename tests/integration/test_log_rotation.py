"""Node output logs are rotated past --log-max-size: a node writing fast never fills the disk."""

from __future__ import annotations

import glob
import os

from helpers import free_port, until
from running import Launcher, make_package, ros_env, write_launch

# writes 256 KiB chunks at ~4 MiB/s to stdout, and the total so far to $TOTAL
Writer = """#!/usr/bin/env python3
import os, sys, time
chunk = b"x" * 1023 + b"\\n"
total = 0
while True:
    sys.stdout.buffer.write(chunk * 256)
    sys.stdout.buffer.flush()
    total += 256 * 1024
    with open(os.environ["TOTAL"] + ".tmp", "w") as f:
        f.write(str(total))
    os.replace(os.environ["TOTAL"] + ".tmp", os.environ["TOTAL"])
    time.sleep(0.0625)
"""

MAX = 1 << 20
RATE = 4 << 20


def test_a_fast_writer_is_rotated_and_bounded(tmp_path):
    pkgs = str(tmp_path / "pkgs")
    make_package(pkgs, "rot", {"writer": Writer})
    env = ros_env(str(tmp_path), free_port(), pkgs)
    env["TOTAL"] = str(tmp_path / "total")
    launch = write_launch(str(tmp_path), '<node pkg="rot" type="writer" name="chatty" output="log"/>')
    lp = Launcher(["--log-max-size", "1MB", "--log-backups", "2", launch], env, str(tmp_path))
    try:
        launch_log = lp.wait_output(r"\.\.\. logging to (\S+)").group(1)
        run_dir = os.path.dirname(launch_log)
        stdout_log = os.path.join(run_dir, "chatty-2-stdout.log")  # (rosout is process 1, as in roslaunch)

        def written():
            try:
                return int(open(env["TOTAL"]).read())
            except (OSError, ValueError):
                return 0
        bound = 3 * (MAX + 2 * RATE)  # each file: the limit plus what a check period (1 s) lets through, twice over
        until(lambda: written() > bound + MAX and os.path.exists(stdout_log + ".2"), 60,
              what="more written than the files may hold")
        files = glob.glob(stdout_log + "*")
        assert sorted(files) == [stdout_log, stdout_log + ".1", stdout_log + ".2"]  # never a third copy
        on_disk = sum(os.path.getsize(f) for f in files)
        assert on_disk <= bound < written(), (on_disk, written())
        with open(stdout_log + ".1", "rb") as f:
            head = f.read(2048)
        assert head.startswith(b"x" * 1023 + b"\n") and b"\0" not in head  # no hole: the node appends
        assert "rotated %s at " % stdout_log in open(launch_log).read()
    finally:
        lp.close()


def test_a_node_sets_its_own_limit(tmp_path):
    """log_max_size/log_backups on the node win over --log-max-size (here 0: no rotation for the others)."""
    pkgs = str(tmp_path / "pkgs")
    make_package(pkgs, "rot", {"writer": Writer})
    env = ros_env(str(tmp_path), free_port(), pkgs)
    env["TOTAL"] = str(tmp_path / "total")
    launch = write_launch(str(tmp_path), '<node pkg="rot" type="writer" name="chatty" output="log" '
                                         'log_max_size="1MiB" log_backups="1"/>')
    lp = Launcher(["--log-max-size", "0", launch], env, str(tmp_path))
    try:
        run_dir = os.path.dirname(lp.wait_output(r"\.\.\. logging to (\S+)").group(1))
        stdout_log = os.path.join(run_dir, "chatty-2-stdout.log")
        until(lambda: os.path.exists(stdout_log + ".1") and os.path.getsize(stdout_log + ".1") > 0, 60,
              what="a rotation")
        until(lambda: int(open(env["TOTAL"]).read()) > 2 * (MAX + 2 * RATE), 60, what="more written")
        assert sorted(glob.glob(stdout_log + "*")) == [stdout_log, stdout_log + ".1"]
    finally:
        lp.close()
