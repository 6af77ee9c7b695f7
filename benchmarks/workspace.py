#!/usr/bin/env python3
"""A large workspace: `--nodes` and `--dump-params` of a launch that uses 20 of 750 packages, roslaunch vs us.

    PATH=/usr/bin:$PATH python3 benchmarks/workspace.py [--reps 7] [--ours "python3 -m launcher"]

To compare with the interpreter roslaunch runs on (Debian's), without an `env` wrapper's
extra exec on our side only:

    PYTHONPATH=$PWD PATH=/usr/bin:$PATH python3 benchmarks/workspace.py --ours "/usr/bin/python3 -m launcher"

The workspace is generated (750 packages in 25 folders, each with package.xml,
src/, config/, launch/ and scripts/) and dated an hour back, as a workspace that
was not just written is; the launch file includes one launch file of each of 20
packages (a node and a `<rosparam load>` each). roslaunch crawls every package
on every start (ros/ros_comm#535); we keep the crawl in ROS_HOME's crawl cache
(launcher/workspace/crawlcache.py). Runs alternate (ABBA) and the ratio is the median of
the paired ratios ours/roslaunch. Outputs are compared, and must be equal.
"""

from __future__ import annotations

import argparse
import os
import shlex
import statistics
import subprocess
import tempfile
import time

PACKAGES, FOLDERS, USED = 750, 25, 20
MANIFEST = ('<?xml version="1.0"?>\n<package format="2">\n  <name>%s</name>\n  <version>1.0.0</version>\n'
            '  <description>generated</description>\n  <maintainer email="m@example.com">m</maintainer>\n'
            '  <license>BSD</license>\n  <buildtool_depend>catkin</buildtool_depend>\n</package>\n')


def make_workspace(root: str) -> str:
    src = os.path.join(root, "src")
    for i in range(PACKAGES):
        name = "pkg_%03d" % i
        d = os.path.join(src, "folder_%02d" % (i % FOLDERS), name)
        for sub in ("src", "config", "launch", "scripts"):
            os.makedirs(os.path.join(d, sub))
        with open(os.path.join(d, "package.xml"), "w") as f:
            f.write(MANIFEST % name)
        for k in range(3):
            with open(os.path.join(d, "src", "file_%d.cpp" % k), "w") as f:
                f.write("int f%d() { return %d; }\n" % (k, k))
        with open(os.path.join(d, "config", "params.yaml"), "w") as f:
            f.write("# %s parameters\nrate: %d\nframe_id: %s_link\ngains: [1.0, 2.0, 3.0]\n" % (name, i, name))
        exe = os.path.join(d, "scripts", "node")
        with open(exe, "w") as f:
            f.write("#!/bin/sh\nexec sleep 100\n")
        os.chmod(exe, 0o755)
        with open(os.path.join(d, "launch", "node.launch"), "w") as f:
            f.write('<launch>\n  <node pkg="%s" type="node" name="%s_node">\n'
                    '    <rosparam command="load" file="$(find %s)/config/params.yaml"/>\n'
                    '  </node>\n</launch>\n' % (name, name, name))
    main = os.path.join(root, "main.launch")
    with open(main, "w") as f:
        f.write("<launch>\n%s</launch>\n" % "".join(
            '  <include file="$(find pkg_%03d)/launch/node.launch"/>\n' % (i * (PACKAGES // USED))
            for i in range(USED)))
    old = time.time() - 3600
    for d, _dirs, files in os.walk(root):
        for name in files:
            os.utime(os.path.join(d, name), (old, old))
        os.utime(d, (old, old))
    return main


def run(cmd: list[str], env: dict[str, str]) -> tuple[float, bytes]:
    t0 = time.perf_counter()
    out = subprocess.run(cmd, env=env, capture_output=True, check=True).stdout
    return time.perf_counter() - t0, out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reps", type=int, default=7)
    ap.add_argument("--ours", default="python3 -m launcher")
    ap.add_argument("--reference", default="roslaunch")
    opts = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        main_launch = make_workspace(tmp)
        env = dict(os.environ, ROS_PACKAGE_PATH=os.path.join(tmp, "src"), ROS_HOME=os.path.join(tmp, "home"),
                   CMAKE_PREFIX_PATH="")
        for mode in ("--nodes", "--dump-params"):
            ours = shlex.split(opts.ours) + [mode, main_launch]
            ref = shlex.split(opts.reference) + [mode, main_launch]
            run(ours, env)  # the first run crawls and fills the cache, as the first launch of a day does
            ratios, t_ours, t_ref = [], [], []
            for rep in range(opts.reps):
                pair = [(ours, t_ours), (ref, t_ref)] if rep % 2 == 0 else [(ref, t_ref), (ours, t_ours)]
                outs = {}
                for cmd, times in pair:
                    t, out = run(cmd, env)
                    times.append(t)
                    outs[cmd is ours] = out
                if outs[True] != outs[False]:
                    raise SystemExit("outputs differ for %s" % mode)
                ratios.append(t_ours[-1] / t_ref[-1])
            print("%-14s roslaunch %.3f s  ours %.3f s  ratio %.3f (median of %d paired runs)"
                  % (mode, statistics.median(t_ref), statistics.median(t_ours), statistics.median(ratios), opts.reps))


if __name__ == "__main__":
    main()
