#!/usr/bin/env python3
"""A screen node writing fast to stdout, under roslaunch and under ours: throughput and the launcher's CPU.

    python3 benchmarks/screen_output.py [--mb 64] [--reps 3] [--modes pipe,pty] [--cmd ...]

One output="screen" node writes `--mb` MB of 80-byte log lines (`yes | head -c`)
and a marker, once the launch is up. The launch's stdout is a pipe or a pty
(`--modes`) that this script reads as fast as it can. Under roslaunch the node
writes to that stdout itself; under ours the bytes pass through the launcher
(output/screen.py) and into the node's `-stdout.log`. Reported per command
and mode (median of `--reps`, commands alternated): MB/s from the start of the
flood to the marker, and the launcher process's CPU over that time (% of one
core; roslaunch's rosmaster is a separate process and not counted, ours is
in-process and idle).
"""

from __future__ import annotations

import argparse
import os
import re
import select
import shlex
import signal
import statistics
import subprocess
import sys
import tempfile
import time

from common import ROS_PATH, free_port  # (this folder is on the path of a script run from it)

LINE = "[ INFO] [1700000000.000000000]: a typical log line, padded to eighty characters...."
FLOOD = """#!/bin/sh
while [ ! -e "$GO" ]; do sleep 0.02; done
yes '%s' | head -c "$BYTES"
echo FLOOD-END
""" % LINE
PACKAGE_XML = ('<?xml version="1.0"?>\n<package format="2"><name>bench_screen</name><version>0.0.1</version>'
               '<description>bench</description><maintainer email="b@example.com">b</maintainer>'
               '<license>BSD</license></package>\n')


def cpu_seconds(pid: int) -> float:
    with open("/proc/%d/stat" % pid) as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def one_run(cmd: str, mode: str, nbytes: int, scratch: str) -> tuple[float, float]:
    """(MB/s, launcher CPU %) of one flood."""
    run = tempfile.mkdtemp(dir=scratch)
    port = free_port()
    go = os.path.join(run, "go")
    env = dict(os.environ, ROS_MASTER_URI="http://127.0.0.1:%d/" % port, ROS_HOME=os.path.join(run, "home"),
               ROS_LOG_DIR=os.path.join(run, "log"), ROS_IP="127.0.0.1", GO=go, BYTES=str(nbytes),
               ROS_PACKAGE_PATH=os.path.join(scratch, "pkgs"))
    env["PATH"] = ROS_PATH + ":" + env.get("PATH", "")
    launch = os.path.join(scratch, "flood.launch")
    if mode == "pty":
        reader, writer = os.openpty()
    else:
        reader, writer = os.pipe()
    proc = subprocess.Popen(shlex.split(cmd) + ["-p", str(port), launch], env=env, stdout=writer,
                            stderr=subprocess.DEVNULL, stdin=subprocess.DEVNULL, start_new_session=True)
    os.close(writer)
    tail = b""
    total = 0
    t0 = c0 = None
    try:
        deadline = time.monotonic() + 120
        while True:
            if time.monotonic() > deadline:
                raise SystemExit("%s (%s): no marker within 120 s" % (cmd, mode))
            if not select.select([reader], [], [], 1.0)[0]:
                continue
            try:
                data = os.read(reader, 1 << 16)
            except OSError:
                data = b""
            if not data:
                raise SystemExit("%s (%s): the launcher's output ended early" % (cmd, mode))
            total += len(data)
            tail = (tail + data)[-4096:]
            if t0 is None and re.search(rb"process\[flood-\d+\]: started", tail):
                time.sleep(0.5)  # (the launcher settles: rosout, the log check)
                c0 = cpu_seconds(proc.pid)
                t0 = time.monotonic()
                open(go, "w").close()
            elif t0 is not None and b"FLOOD-END" in tail:
                t1 = time.monotonic()
                c1 = cpu_seconds(proc.pid)
                break
        return nbytes / 1e6 / (t1 - t0), 100.0 * (c1 - c0) / (t1 - t0)
    finally:
        os.killpg(proc.pid, signal.SIGINT)
        end = time.monotonic() + 30
        while proc.poll() is None and time.monotonic() < end:  # keep reading: its last lines must get out
            if select.select([reader], [], [], 0.1)[0]:
                try:
                    os.read(reader, 1 << 16)
                except OSError:
                    pass
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        os.close(reader)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--mb", type=float, default=64)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--modes", default="pipe,pty")
    ap.add_argument("--cmd", action="append", help="LABEL=COMMAND (default: roslaunch and ours)")
    opts = ap.parse_args()
    here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    cmds = opts.cmd or ["roslaunch=roslaunch", "ours=env PYTHONPATH=%s %s -m launcher" % (here, sys.executable)]
    cmds = [c.split("=", 1) if "=" in c.split()[0] else (c, c) for c in cmds]
    nbytes = int(opts.mb * 1e6)
    with tempfile.TemporaryDirectory() as scratch:
        pkg = os.path.join(scratch, "pkgs", "bench_screen")
        os.makedirs(pkg)
        with open(os.path.join(pkg, "package.xml"), "w") as f:
            f.write(PACKAGE_XML)
        with open(os.path.join(pkg, "flood"), "w") as f:
            f.write(FLOOD)
        os.chmod(os.path.join(pkg, "flood"), 0o755)
        with open(os.path.join(scratch, "flood.launch"), "w") as f:
            f.write('<launch><node pkg="bench_screen" type="flood" name="flood" output="screen"/></launch>\n')
        for mode in opts.modes.split(","):
            results: dict[str, list[tuple[float, float]]] = {label: [] for label, _ in cmds}
            for rep in range(opts.reps):
                order = cmds if rep % 2 == 0 else list(reversed(cmds))  # alternated: a noisy machine
                for label, cmd in order:
                    results[label].append(one_run(cmd, mode, nbytes, scratch))
            for label, _ in cmds:
                rates = [r for r, _ in results[label]]
                cpus = [c for _, c in results[label]]
                print("%-5s %-10s %7.1f MB/s  launcher CPU %5.1f %%   (MB/s runs: %s)"
                      % (mode, label, statistics.median(rates), statistics.median(cpus),
                         ", ".join("%.0f" % r for r in rates)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
