#!/usr/bin/env python3
"""Four `<param command=...>` of 1 s each (xacro-like): `--dump-params` wall time, roslaunch vs us, side by side.

    PATH=/usr/bin:$PATH python3 benchmarks/command_params.py [--reps 5] [--ours "python3 -m launcher"]

roslaunch runs command parameters one after another as it reads the file
(~4 s here); we run them together once the file is read, one per core at most
(launcher/xml/commands.py): the goal is <= ceil(4 / cores) + 0.3 s. Runs
alternate and outputs must be equal.
"""

from __future__ import annotations

import argparse
import math
import os
import shlex
import statistics
import subprocess
import tempfile
import time

COMMANDS = 4


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--ours", default="python3 -m launcher")
    ap.add_argument("--reference", default="roslaunch")
    opts = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        launch = os.path.join(tmp, "xacro_like.launch")
        with open(launch, "w") as f:
            f.write("<launch>\n%s</launch>\n" % "".join(
                '  <param name="robot_%d/robot_description" command="sh -c \'sleep 1; echo urdf_%d\'"/>\n' % (i, i)
                for i in range(COMMANDS)))
        env = dict(os.environ, ROS_HOME=os.path.join(tmp, "home"))
        times: dict[str, list[float]] = {"ours": [], "reference": []}
        outs: dict[str, bytes] = {}
        for rep in range(opts.reps):
            order = ("ours", "reference") if rep % 2 == 0 else ("reference", "ours")
            for which in order:
                cmd = shlex.split(opts.ours if which == "ours" else opts.reference) + ["--dump-params", launch]
                t0 = time.perf_counter()
                outs[which] = subprocess.run(cmd, env=env, capture_output=True, check=True).stdout
                times[which].append(time.perf_counter() - t0)
            if outs["ours"] != outs["reference"]:
                raise SystemExit("outputs differ")
        cores = os.cpu_count() or 1
        ours, ref = statistics.median(times["ours"]), statistics.median(times["reference"])
        print("%d commands of 1 s, %d cores: roslaunch %.2f s, ours %.2f s (goal <= %.1f s), ratio %.2f"
              % (COMMANDS, cores, ref, ours, math.ceil(COMMANDS / cores) + 0.3, ours / ref))


if __name__ == "__main__":
    main()
