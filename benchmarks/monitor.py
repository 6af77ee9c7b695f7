#!/usr/bin/env python3
"""Resource monitoring cost: the launcher's CPU with N idle nodes under monitoring, median over a window.

    python3 benchmarks/monitor.py [--n 500] [--seconds 30] [--period 1] [--cmd 'python3 -m launcher'] [--compare]

Launches N idle nodes (each a `sleep`, one process per node, in a scratch
package) with our own master, waits until all have started and the start-up is
over, then reads the launcher's CPU time from /proc once a second for
`--seconds` and prints the median and the maximum, in percent of one core.
The goal (issue 11): median <= 1 %.

`--compare` runs the same launch a second time with sampling pushed out of
the window (`--monitor-period 100000`), so the monitor's own share shows as the
difference. `--readers` times one sample of the N groups read directly (what the
launcher does) and through psutil, in the same process, on the same nodes.
"""

from __future__ import annotations

import argparse
import os
import re
import shlex
import signal
import statistics
import subprocess
import sys
import tempfile
import time

from common import cpu_seconds, free_port, idle_launch  # (this folder is on the path of a script run from it)

HERE = os.path.dirname(os.path.abspath(__file__))


def make_launch(root: str, n: int) -> str:
    return idle_launch(root, "monitor_bench", n)


def measure(cmd: list[str], launch: str, root: str, n: int, seconds: float, extra: list[str],
            readers: bool) -> list[float]:
    env = dict(os.environ, ROS_PACKAGE_PATH=root, ROS_HOME=os.path.join(root, "home"),
               ROS_LOG_DIR=os.path.join(root, "log"))
    env["ROS_MASTER_URI"] = "http://127.0.0.1:%d/" % free_port()
    out = open(os.path.join(root, "out.txt"), "w+")
    p = subprocess.Popen(cmd + [launch, "--no-summary", "--skip-log-check"] + extra, env=env, stdout=out,
                         stderr=subprocess.STDOUT, start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while True:
            out.seek(0)
            pids = [int(x) for x in re.findall(r"started with pid \[(\d+)\]", out.read())]
            if len(pids) >= n:
                break
            if p.poll() is not None or time.monotonic() > deadline:
                out.seek(0)
                raise SystemExit("the launch did not start %d nodes:\n%s" % (n, out.read()[-2000:]))
            time.sleep(0.2)
        time.sleep(5)  # the start-up's own work (rosout warm-up, registrations) is not what is measured
        if readers:
            compare_readers(pids)
        percents = []
        before, t0 = cpu_seconds(p.pid), time.monotonic()
        for _ in range(int(seconds)):
            time.sleep(1.0)
            after, t1 = cpu_seconds(p.pid), time.monotonic()
            percents.append(100.0 * (after - before) / (t1 - t0))
            before, t0 = after, t1
        return percents
    finally:
        p.send_signal(signal.SIGINT)
        try:
            p.wait(60)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait()
        out.close()


def compare_readers(pids: list[int], rounds: int = 20) -> None:
    sys.path.insert(0, os.path.dirname(HERE))
    from launcher.health.resources import GroupReader
    groups = set(pids)
    reader = GroupReader()
    reader.read(groups)  # (the first reading opens the files)
    t = time.perf_counter()
    for _ in range(rounds):
        reader.read(groups)
    direct = (time.perf_counter() - t) / rounds
    reader.close()
    try:
        import psutil
    except ImportError:
        print("psutil not installed: direct read %.2f ms per sample" % (direct * 1e3))
        return
    t = time.perf_counter()
    for _ in range(rounds):
        totals = {}
        for proc in psutil.process_iter():
            try:
                with proc.oneshot():
                    pgid = os.getpgid(proc.pid)
                    if pgid in groups:
                        c = proc.cpu_times()
                        totals[pgid] = (c.user + c.system + c.children_user + c.children_system, proc.memory_info().rss)
            except (psutil.Error, OSError):
                continue
    via_psutil = (time.perf_counter() - t) / rounds
    print("one sample of %d groups: held /proc stat files %.2f ms, psutil %.2f ms (%.1fx)"
          % (len(groups), direct * 1e3, via_psutil * 1e3, via_psutil / direct))


def report(label: str, percents: list[float]) -> None:
    print("%s: launcher CPU over %d s: median %.2f %% of a core, mean %.2f %%, max %.2f %%"
          % (label, len(percents), statistics.median(percents), statistics.mean(percents), max(percents)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=500)
    ap.add_argument("--seconds", type=float, default=30)
    ap.add_argument("--period", type=float, default=1.0, help="--monitor-period given to the launcher")
    ap.add_argument("--cmd", default="%s -m launcher" % sys.executable)
    ap.add_argument("--compare", action="store_true", help="also run with sampling pushed out of the window")
    ap.add_argument("--readers", action="store_true", help="time the direct /proc read against psutil")
    args = ap.parse_args()
    cmd = shlex.split(args.cmd)
    with tempfile.TemporaryDirectory(prefix="monitor-bench-") as root:
        launch = make_launch(root, args.n)
        runs = [("monitor every %g s" % args.period, ["--monitor-period", str(args.period)])]
        if args.compare:
            runs.append(("no sample in the window", ["--monitor-period", "100000"]))
        for label, extra in runs:
            report("%d idle nodes, %s" % (args.n, label),
                   measure(cmd, launch, root, args.n, args.seconds, extra, args.readers and extra is runs[0][1]))


if __name__ == "__main__":
    main()
