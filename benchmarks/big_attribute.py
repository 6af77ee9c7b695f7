#!/usr/bin/env python3
"""Big attribute benchmark: the load of one attribute of 0.1, 1 and 5 MB, ours vs roslaunch.

One launch file per case: a `<param>` whose value is the big attribute, and a node. The
value is plain text (no substitution), `$(arg a)` repeated (a substitution every 8
characters), or `$(anon x)` repeated behind a '(' (the text that took roslaunch's one
rescan per `$(...)` on our side too, before issue 21). Both commands run `--nodes` (the load)
and `--dump-params` (the load, and the value written back) side by side, ABBA, as a user
runs them (whole process, wall time); outputs are compared. roslaunch rescans the string
once per `$(...)`, so it gets `--cap` seconds per run: a run over it is reported as such
(and not repeated).

    python3 benchmarks/big_attribute.py [--reps 3] [--sizes 0.1,1,5] [--cap 60]

Debian's roslaunch needs Debian's python: it is run with /usr/bin first on PATH.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time

from common import ROS_PATH  # (this folder is on the path of a script run from it)

HERE = os.path.dirname(os.path.abspath(__file__))

VALUES = {
    "plain": lambda n: "x" * n,
    "arg": lambda n: "$(arg a)" * (n // 8),
    "anon-paren": lambda n: "(" + "$(anon x)" * (n // 9),
}


def our_command() -> list[str]:
    """The `launch` console script next to this interpreter (what a venv user runs), else -m."""
    script = os.path.join(os.path.dirname(sys.executable), "launch")
    return [script] if os.path.exists(script) else [sys.executable, "-m", "launcher"]


def run_once(argv: list[str], env: dict[str, str], cap: float) -> tuple[float | None, str, int]:
    """(wall seconds or None past `cap`, stdout, exit code)."""
    with tempfile.TemporaryFile() as out:
        t0 = time.perf_counter()
        p = subprocess.Popen(argv, env=env, stdout=out, stderr=subprocess.DEVNULL, stdin=subprocess.DEVNULL,
                             start_new_session=True)
        # (the exit waited for by wait4, which returns at once: Popen.wait(timeout) polls, every
        # 50 ms at worst; a timer kills a run past the cap)
        timer = threading.Timer(cap, os.killpg, (p.pid, signal.SIGKILL))
        timer.start()
        _, status, _ = os.wait4(p.pid, 0)
        wall = time.perf_counter() - t0
        timer.cancel()
        p.returncode = os.waitstatus_to_exitcode(status)
        if wall >= cap:
            return None, "", p.returncode
        out.seek(0)
        return wall, out.read().decode("utf-8", "replace"), p.returncode


def normalise(mode: str, text: str):
    if mode == "nodes":
        return sorted(line for line in text.splitlines() if line.strip())
    import re

    import yaml
    # anonymous names differ per run: host_pid_random
    return json.dumps(yaml.safe_load(re.sub(r"x_[A-Za-z0-9_]+?_\d+_\d+", "ANON", text)), sort_keys=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--sizes", default="0.1,1,5", help="megabytes")
    ap.add_argument("--values", default=",".join(VALUES))
    ap.add_argument("--modes", default="nodes,dump-params")
    ap.add_argument("--cap", type=float, default=60.0, help="seconds a run may take")
    args = ap.parse_args()

    import compileall  # (as benchmarks/parse.py: Debian's roslaunch runs from .pyc files, so do we)

    import launcher
    compileall.compile_dir(os.path.dirname(launcher.__file__), quiet=1)
    work = tempfile.mkdtemp(prefix="big-attribute-")
    env = {k: v for k, v in os.environ.items() if not k.startswith("ROS_")}
    env.update(ROS_HOME=os.path.join(work, "home"), ROS_PACKAGE_PATH=work)
    ref = shutil.which("roslaunch", path=ROS_PATH)
    cmds = [("roslaunch", [ref], dict(env, PATH=ROS_PATH + ":" + env.get("PATH", "")))] if ref else []
    cmds.append(("ours", our_command(), env))
    rows = []
    try:
        for value in args.values.split(","):
            for size in (float(s) for s in args.sizes.split(",")):
                n = int(size * 1_000_000)
                path = os.path.join(work, "%s-%g.launch" % (value, size))
                with open(path, "w") as f:
                    f.write('<launch><arg name="a" value="v"/><param name="p" value="%s"/>'
                            '<node pkg="rospy" type="x" name="n"/></launch>' % VALUES[value](n))
                for mode in args.modes.split(","):
                    walls: dict[str, list[float]] = {label: [] for label, _, _ in cmds}
                    capped: set[str] = set()
                    outputs = {}
                    ratios = []
                    for rep in range(args.reps):
                        this = {}
                        for label, argv, cmd_env in (cmds if rep % 2 == 0 else cmds[::-1]):
                            if label in capped:
                                continue
                            wall, text, rc = run_once(argv + ["--" + mode, path], cmd_env, args.cap)
                            if wall is None:
                                capped.add(label)
                                continue
                            walls[label].append(wall)
                            this[label] = wall
                            outputs.setdefault(label, normalise(mode, text) if rc == 0 else "exit %d" % rc)
                        if len(this) == 2:
                            ratios.append(this["ours"] / this["roslaunch"])
                    row = {"value": value, "MB": size, "mode": mode}
                    for label in walls:
                        row[label] = ("> %g s" % args.cap if label in capped
                                      else round(statistics.median(walls[label]), 3))
                    if ratios:
                        row["ratio_median"] = round(statistics.median(ratios), 3)
                    elif "roslaunch" in capped and walls["ours"]:
                        row["ratio_median"] = "< %.4f" % (statistics.median(walls["ours"]) / args.cap)
                    if len(outputs) == 2:
                        row["outputs_identical"] = outputs["ours"] == outputs["roslaunch"]
                    rows.append(row)
                    print(json.dumps(row), flush=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
