#!/usr/bin/env python3
"""A crash loop's cost (issue 36): N respawning roscpp nodes, one killed every 1/K s, side by side.

    python3 benchmarks/crash_loop.py [--nodes 30] [--kills-per-s 4] [--seconds 30] [--reps 2] [--cmd LABEL=COMMAND ...]

A robot's node that crashes again and again is restarted for as long as it
does, for weeks maybe: each restart's work is what its launcher costs the robot
meanwhile. For each repetition and command (roslaunch and our `launch` by
default, in alternating order) with no master running, so that each starts its
own (roslaunch: rosmaster and rosout as its children; ours: in its process), the
launcher runs N tiny roscpp nodes (../shared/bench's tiny_node) with
respawn="true". Once all are registered, every 1/K s one of them older than
1.5 s gets SIGKILL, for `--seconds`.

The figure is the CPU of the launcher's own processes over that time (the
launcher and its children that are not nodes: roslaunch's rosmaster and rosout
too, which do for it what our launch does in its process), from /proc/PID/stat
in clock ticks: per kill, and as a share of one core. It prints the medians and
each command's ratio to the first. The machine's other load moves these
figures: compare commands of one run, not runs.
"""

from __future__ import annotations

import argparse
import os
import random
import shlex
import signal
import statistics
import subprocess
import sys
import tempfile
import time
import xmlrpc.client

# (this folder is on the path of a script run from it)
from common import free_port, launcher_commands, make_package, stop_process, workspace_env
import reload  # (the same roscpp node as its benchmark's)

TICK = os.sysconf("SC_CLK_TCK")
NODE = "tiny_node"
MIN_AGE_S = 1.5  # a run killed younger than respawn_min_uptime (1 s) would be a failed start, backed off


def launch_text(n: int) -> str:
    return "<launch>\n%s</launch>\n" % "".join(
        '  <node pkg="bench_crash" type="tiny_node" name="n%03d" respawn="true"><param name="rate" value="1"/>'
        '</node>\n' % i for i in range(n))


def children(pid: int) -> list[int]:
    """The processes whose parent is `pid`."""
    found = []
    try:
        for tid in os.listdir("/proc/%d/task" % pid):
            with open("/proc/%d/task/%s/children" % (pid, tid)) as f:
                found.extend(int(c) for c in f.read().split())
    except OSError:
        pass  # (it ended meanwhile)
    return found


def proc_stat(pid: int) -> tuple[str, int, float]:
    """(its command name, its start in ticks since boot, its CPU seconds) from /proc/PID/stat; OSError if gone."""
    with open("/proc/%d/stat" % pid) as f:
        text = f.read()
    name = text[text.index("(") + 1:text.rindex(")")]
    fields = text.rsplit(")", 1)[1].split()
    return name, int(fields[19]), (int(fields[11]) + int(fields[12])) / TICK


def tree(pid: int) -> list[int]:
    """`pid` and every process below it."""
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        todo.extend(children(p))
    return out


def launcher_cpu(pid: int) -> dict[int, float]:
    """The CPU seconds of each process of the launcher's that is not a node."""
    cpu = {}
    for p in tree(pid):
        try:
            name, _, seconds = proc_stat(p)
        except OSError:
            continue
        if name != NODE:
            cpu[p] = seconds
    return cpu


def uptime_ticks() -> float:
    """Now, in clock ticks since boot (the clock of a process's start in /proc/PID/stat)."""
    with open("/proc/uptime") as f:
        return float(f.read().split()[0]) * TICK


def old_nodes(pid: int, now_ticks: float) -> list[int]:
    """The launcher's nodes that have run for MIN_AGE_S at least."""
    found = []
    for p in tree(pid):
        try:
            name, started, _ = proc_stat(p)
        except OSError:
            continue
        if name == NODE and now_ticks - started >= MIN_AGE_S * TICK:
            found.append(p)
    return found


def registered(master: xmlrpc.client.ServerProxy) -> int:
    try:
        _, _, state = master.getSystemState("/crash_loop")
    except (OSError, xmlrpc.client.Error):
        return 0
    return len({n for kind in state for _, nodes in kind for n in nodes if n.startswith("/n")})


def one_run(argv: list[str], launch: str, env: dict, a: argparse.Namespace, rng: random.Random) -> dict:
    port = free_port()
    uri = "http://127.0.0.1:%d/" % port
    env = dict(env, ROS_MASTER_URI=uri)
    launcher = subprocess.Popen(argv + [launch], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                start_new_session=True)
    try:
        master = xmlrpc.client.ServerProxy(uri)
        deadline = time.monotonic() + 60
        while registered(master) < a.nodes:
            if time.monotonic() > deadline or launcher.poll() is not None:
                raise SystemExit("%s: not all %d nodes registered" % (" ".join(argv), a.nodes))
            time.sleep(0.05)
        time.sleep(1.0)  # (the start's tail: rosout's connections)
        before = launcher_cpu(launcher.pid)
        began = time.monotonic()
        kills = 0
        while time.monotonic() - began < a.seconds:
            time.sleep(1.0 / a.kills_per_s)
            nodes = old_nodes(launcher.pid, uptime_ticks())
            if nodes:
                try:
                    os.kill(rng.choice(nodes), signal.SIGKILL)
                    kills += 1
                except ProcessLookupError:
                    pass
        after = launcher_cpu(launcher.pid)
        elapsed = time.monotonic() - began
        cpu = sum(after[p] - before[p] for p in after if p in before)
        return {"kills": kills, "cpu": cpu, "per_kill_ms": cpu / max(kills, 1) * 1e3, "core_pct": cpu / elapsed * 100}
    finally:
        stop_process(launcher, 30, group=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--nodes", type=int, default=30)
    ap.add_argument("--kills-per-s", type=float, default=4.0)
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--cmd", action="append", default=[],
                    help="LABEL=COMMAND (default: roslaunch, and our launch beside this Python)")
    a = ap.parse_args()
    cmds = launcher_commands(a.cmd)
    rng = random.Random(1)
    with tempfile.TemporaryDirectory(prefix="crash-loop-") as root:
        pkg = make_package(os.path.join(root, "pkgs"), "bench_crash")
        reload.tiny_node(os.path.join(pkg, NODE))
        launch = os.path.join(root, "crash.launch")
        with open(launch, "w") as f:
            f.write(launch_text(a.nodes))
        env = workspace_env(root)
        results: dict[str, list[dict]] = {label: [] for label, _ in cmds}
        for rep in range(a.reps):
            for label, command in (cmds if rep % 2 == 0 else cmds[::-1]):
                results[label].append(one_run(shlex.split(command), launch, env, a, rng))
    print("%d respawning nodes, %.3g kills a second for %g s, %d repetitions: the launcher's CPU (median)"
          % (a.nodes, a.kills_per_s, a.seconds, a.reps))
    base = None
    for label, _ in cmds:
        per_kill = statistics.median(r["per_kill_ms"] for r in results[label])
        core = statistics.median(r["core_pct"] for r in results[label])
        kills = statistics.median(r["kills"] for r in results[label])
        base = base or per_kill
        print("  %-12s %6.2f ms a kill (%.2f)  %5.1f%% of a core  %d kills" % (label, per_kill, per_kill / base,
                                                                              core, kills))
    return 0


if __name__ == "__main__":
    sys.exit(main())
