#!/usr/bin/env python3
"""Supervision benchmarks, side by side with roslaunch: startup, shutdown, respawn, log check.

Runs the shared driver (`bench.py`, alternated ABBA, paired ratios) for each
scenario of issue 4 and prints the ratio ours/roslaunch next to its goal:

    python3 benchmarks/supervise.py [--reps 5] [--only startup,shutdown,...]

(with the Python `launcher` is installed in; Debian's ROS tools are put first
on PATH for the driver and roslaunch).

`--bench` points at bench.py (default: $LAUNCHER_BENCH, else ../shared/bench/bench.py
beside the checkout). Our command is the `launch` script next to this Python (not
a pyenv shim, which adds ~0.1 s of bash to every start).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile

from common import ROS_PATH, vmhwm_note  # (this folder is on the path of a script run from it)

# the project's shared driver, beside the checkout
SHARED_BENCH = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "..", "shared", "bench",
                            "bench.py")

# (name, bench.py arguments, metric, goal description, check(ratio or value) -> bool)
SCENARIOS = [
    ("startup", ["startup", "--n", "100"], "t_all_reg", "100 nodes registered: ratio <= 0.45",
     lambda r: r <= 0.45),
    ("startup-core", ["startup", "--n", "20", "--master-cmd", "none"], "t_all_reg",
     "20 nodes, own master: ratio (no goal; roslaunch auto-starts rosmaster+rosout)", None),
    ("shutdown-stubborn", ["shutdown", "--n", "20", "--modes", "stubborn"], "shutdown_clean_s",
     "20 nodes ignoring SIGINT, 2 s/1 s: ratio <= 0.45", lambda r: r <= 0.45),
    ("shutdown-stubborn-term", ["shutdown", "--n", "20", "--modes", "stubborn-term"], "shutdown_clean_s",
     "20 nodes ignoring SIGINT+SIGTERM, 2 s/1 s: ratio (no goal)", None),
    ("shutdown-100", ["shutdown", "--n", "100", "--modes", "normal"], "shutdown_clean_s",
     "100 normal roscpp nodes: ratio <= 0.55", lambda r: r <= 0.55),
    ("respawn", ["respawn", "--kills", "20", "--runs", "2"], "t_newpid_s",
     "kill -9 -> new pid: our median <= 10 ms", None),
    ("logcheck", ["logcheck", "--files", "200000"], "ready_s",
     "startup with 200k log files no slower than with an empty log dir", None),
]


def our_launch() -> str:
    """Our `launch` script: next to this Python, else on PATH (a pyenv shim resolved to its target)."""
    exe = os.path.join(os.path.dirname(sys.executable), "launch")
    if os.path.exists(exe):
        return exe
    for d in os.environ.get("PATH", "").split(os.pathsep):
        cand = os.path.join(d, "launch")
        if os.path.exists(cand) and "/shims" not in d:
            return cand
    try:
        return subprocess.check_output(["pyenv", "which", "launch"], text=True).strip()
    except (OSError, subprocess.CalledProcessError):
        raise SystemExit("cannot find the `launch` command: install the package (pip install -e .)")


def run_bench(bench: str, args: list[str], reps: int, extra: list[str]) -> list[dict]:
    with tempfile.NamedTemporaryFile("r", suffix=".jsonl") as out:
        argv = [sys.executable, bench] + args + ["--cmd", "roslaunch", "--cmd", "new=%s" % our_launch(),
                                                 "--reps", str(reps), "--jsonl", out.name] + extra
        env = dict(os.environ, PATH=ROS_PATH + ":" + os.environ.get("PATH", ""))
        subprocess.run(argv, env=env, stdout=subprocess.DEVNULL, check=False)
        return [json.loads(line) for line in out if line.strip()]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--bench", default=os.environ.get("LAUNCHER_BENCH", os.path.normpath(SHARED_BENCH)))
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--only", default="", help="comma-separated scenario names")
    ap.add_argument("--extra", default="", help="extra bench.py arguments")
    a = ap.parse_args()
    only = set(filter(None, a.only.split(",")))
    failed = False
    for name, args, metric, goal, check in SCENARIOS:
        if only and name not in only:
            continue
        records = run_bench(a.bench, args, a.reps, a.extra.split())
        summaries = [r for r in records if "summary" in r]
        for s in summaries:
            metrics = s.get("metrics", {})
            ratios = s.get("ratios", {})
            mine = metrics.get("new", {}).get(metric, {})
            ref = metrics.get("roslaunch", {}).get(metric, {})
            if name == "respawn":
                value = mine.get("median")
                ok = value is not None and value <= 0.010
                print("%-24s %s: ours %.1f ms, roslaunch %.1f ms  [%s]  (%s)"
                      % (name, metric, 1000 * value, 1000 * ref.get("median", float("nan")),
                         "ok" if ok else "MISSED", goal))
                failed |= not ok
                continue
            if name == "logcheck":
                big = metrics.get("new:big", {}).get(metric, {}).get("median")
                empty = metrics.get("new:empty", {}).get(metric, {}).get("median")
                rbig = ratios.get("new:big", {}).get(metric)
                rempty = ratios.get("new:empty", {}).get(metric)
                print("%-24s %s: ours big %.3f s / empty %.3f s (paired vs roslaunch:big %.2f / %.2f); "
                      "roslaunch big %.3f / empty %.3f  (%s)"
                      % (name, metric, big, empty, rbig, rempty,
                         metrics.get("roslaunch:big", {}).get(metric, {}).get("median", float("nan")),
                         metrics.get("roslaunch:empty", {}).get(metric, {}).get("median", float("nan")), goal))
                continue
            ratio = ratios.get("new", {}).get(metric)
            ok = None if check is None or ratio is None else check(ratio)
            print("%-24s %s: ours %.3f s, roslaunch %.3f s, paired ratio %s  [%s]  (%s)  %s"
                  % (name, metric, mine.get("median", float("nan")), ref.get("median", float("nan")),
                     "%.3f" % ratio if ratio is not None else "n/a",
                     "-" if ok is None else ("ok" if ok else "MISSED"), goal, vmhwm_note(metrics)))
            failed |= ok is False
        sys.stdout.flush()
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
