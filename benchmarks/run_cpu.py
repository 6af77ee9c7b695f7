#!/usr/bin/env python3
"""A whole run's CPU (issue 36): N roscpp nodes started, all registered, stopped by a Ctrl-C, side by side.

    python3 benchmarks/run_cpu.py [--nodes 100] [--reps 7] [--cmd LABEL=COMMAND ...]

What a launcher costs a robot is not only its start: every node it stops, and
every exit of a node it supervises, is its work too. For each repetition and
each command (roslaunch and our `launch` by default, in alternating order), a
Debian rosmaster is started on a free port, then the launcher on a file of N
tiny roscpp nodes (../shared/bench's tiny_node, as benchmarks/reload.py builds
it); once all N are registered it gets SIGINT, and once it has exited its CPU
is read:

- `start`: its CPU until all were registered, with what its children that
  had ended by then took (our launch reads its files in a child of its own);
- `run`: its CPU over the whole run, start and stop (its own threads, read
  from its /proc entry while it is a zombie: never the nodes').

Both come from /proc/PID/stat, in clock ticks (10 ms): a median over several
repetitions, not one run, says how two commands differ.

It prints the median of each, and each command's ratio to the first command
(the reference). The machine's other load moves these figures: compare
commands of one run, not runs.
"""

from __future__ import annotations

import argparse
import os
import shlex
import signal
import statistics
import subprocess
import sys
import tempfile
import time
import xmlrpc.client

# (this folder is on the path of a script run from it)
from common import debian_rosmaster, free_port, launcher_commands, make_package, workspace_env
import reload  # (the same roscpp node as its benchmark's)

TICK = os.sysconf("SC_CLK_TCK")


def stat_cpu(pid: int) -> tuple[float, float]:
    """(own CPU, CPU of its children waited for), in seconds, from /proc/PID/stat."""
    with open("/proc/%d/stat" % pid) as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICK, (int(fields[13]) + int(fields[14])) / TICK


def registered(master: xmlrpc.client.ServerProxy) -> int:
    """How many of the launch's nodes (`/gK/nNNN`) the master knows (as publishers, subscribers or services)."""
    try:
        _, _, state = master.getSystemState("/run_cpu")
    except (OSError, xmlrpc.client.Error):
        return 0
    return len({n for kind in state for _, nodes in kind for n in nodes if n.rsplit("/", 1)[1].startswith("n")})


def one_run(argv: list[str], launch: str, env: dict, n: int) -> dict:
    port = free_port()
    uri = "http://127.0.0.1:%d/" % port
    env = dict(env, ROS_MASTER_URI=uri)
    with debian_rosmaster(port, env, uri):
        master = xmlrpc.client.ServerProxy(uri)
        launcher = subprocess.Popen(argv + [launch], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + 60
        while registered(master) < n:
            if time.monotonic() > deadline or launcher.poll() is not None:
                launcher.kill()
                raise SystemExit("%s: not all %d nodes registered" % (" ".join(argv), n))
            time.sleep(0.01)
        own, children = stat_cpu(launcher.pid)
        launcher.send_signal(signal.SIGINT)
        os.waitid(os.P_PID, launcher.pid, os.WEXITED | os.WNOWAIT)  # (a zombie: its /proc entry holds its CPU)
        whole, _ = stat_cpu(launcher.pid)
        launcher.wait()
        return {"start": own + children, "run": whole + children}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--nodes", type=int, default=100)
    ap.add_argument("--reps", type=int, default=7)
    ap.add_argument("--cmd", action="append", default=[],
                    help="LABEL=COMMAND (default: roslaunch, and our launch beside this Python)")
    a = ap.parse_args()
    cmds = launcher_commands(a.cmd)
    with tempfile.TemporaryDirectory(prefix="run-cpu-") as root:
        pkg = make_package(os.path.join(root, "pkgs"), "bench_reload")
        reload.tiny_node(os.path.join(pkg, "tiny_node"))
        launch = os.path.join(root, "nodes.launch")
        with open(launch, "w") as f:
            f.write(reload.launch_text(a.nodes))
        env = workspace_env(root)
        results: dict[str, list[dict]] = {label: [] for label, _ in cmds}
        for rep in range(a.reps):
            for label, command in (cmds if rep % 2 == 0 else cmds[::-1]):
                results[label].append(one_run(shlex.split(command), launch, env, a.nodes))
    print("%d nodes, %d repetitions, CPU seconds (median)" % (a.nodes, a.reps))
    base = None
    for label, _ in cmds:
        start = statistics.median(r["start"] for r in results[label])
        run = statistics.median(r["run"] for r in results[label])
        base = base or (start, run)
        print("  %-12s start %.3f (%.2f)  whole run %.3f (%.2f)" % (label, start, start / base[0], run,
                                                                  run / base[1]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
