#!/usr/bin/env python3
"""Start-up budget: how long `launch --nodes` and a run's first spawn take, and which heavy modules they import.

    python3 benchmarks/startup_budget.py [--reps 10] [--launch python3 -m launcher]

It reports; it asserts nothing (what a start imports is a cost to watch, not a
rule to test). For each of `launch --nodes small.launch` and `launch
small.launch` (our own master on a free port, stopped by SIGINT once its first
node runs) it prints the median and min wall time over `--reps` runs and the median
VmHWM (peak resident memory, at the first spawn for a run), then, from
one extra run under `python -X importtime`, which modules of HEAVY got
imported and the ten largest imports by cumulative time.

Then what a run's CPU and memory at its first node are made of (`decompose`): the
interpreter alone, the standard library's modules the launch imports on its way
to its first node (apart: those it imports for one use each, SINGLE_USE, and
those only asyncio brings, ASYNCIO_ONLY, what a run loop of our own would save,
its INSPECT part on its own), ours, and the rest (the run itself: its plan, its
master, its parameters, the first spawn), each part measured within one fresh
interpreter and its median over `--reps` of them.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shlex
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time

from common import cpu_seconds, vm_hwm_mb  # (this folder is on the path of a script run from it)

# Modules a start should not need, or needs only for a reason worth seeing.
HEAVY = ("argparse", "asyncio", "dataclasses", "email", "http.client", "lxml", "psutil", "uuid", "xmlrpc.client",
         "yaml", "inspect", "typing_extensions", "platform", "gettext", "locale")
NODE = "#!/bin/sh\nexec sleep 100\n"
# The modules `launch` imports on its way to its first node (cli/launch.py's own steps: the plan's module, asyncio
# without TLS, the run's module); what the run imports later (the /diagnostics publisher's node) is not counted.
RUN_IMPORTS = ("import launcher.cli.launch as cli; import launcher.run.load; cli._import_asyncio_without_tls(); "
               "import launcher.run.runtime")
# The modules a run loads only because asyncio does: coroutines' inspect (with ast and dis), base_events'
# concurrent.futures. (Ours import logging, traceback and typing themselves; net.xmlrpc_server imports inspect
# for `isawaitable`, which a loop of our own would not need.)
ASYNCIO_ONLY = ("asyncio", "_asyncio", "concurrent", "inspect", "ast", "_ast", "dis", "opcode", "_opcode")
# Of asyncio's own, inspect with ast and dis: its coroutines and tasks import them for a few type checks, one of
# which add_signal_handler makes at every handler, so that a run on asyncio cannot leave them out.
INSPECT = ("inspect", "ast", "_ast", "dis", "opcode", "_opcode")
# Standard library modules a run imports for one use each, apart: what a run without that use would save.
SINGLE_USE = (("ctypes: the subreaper's prctl", ("ctypes", "_ctypes")),
              ("pyexpat: XML-RPC responses, package.xml", ("xml", "pyexpat")))
# A fresh interpreter's CPU seconds and peak MB, then again after it has imported each group of modules in turn
# (a JSON list of lists): the parts of one process, so that a part is not the difference of two noisy processes.
MEASURE = """
import importlib, sys, time
sys.modules["ssl"] = None  # (as the launch: asyncio without TLS)
def now():  # (the scheduler's CPU clock: rusage's is sampled at the tick; VmHWM: ru_maxrss keeps the forking
    # parent's size across the exec)
    with open("/proc/self/status") as f:
        hwm = [int(line.split()[1]) for line in f if line.startswith("VmHWM:")][0]
    return [time.process_time(), hwm / 1024.0]
points = [now()]
import json
for group in json.loads(sys.argv[1]):
    for name in group:
        try:
            importlib.import_module(name)
        except ImportError:
            pass
    points.append(now())
print(json.dumps(points))
"""
STARTED = re.compile(rb"process\[[^\]]+\]: started with pid")


def make_launch(root: str, nodes: int) -> tuple[str, dict[str, str]]:
    pkg = os.path.join(root, "pkgs", "budget_pkg")
    os.makedirs(pkg)
    with open(os.path.join(pkg, "package.xml"), "w") as f:
        f.write("<package><name>budget_pkg</name><version>0.0.0</version></package>")
    exe = os.path.join(pkg, "sleeper")
    with open(exe, "w") as f:
        f.write(NODE)
    os.chmod(exe, 0o755)
    launch = os.path.join(root, "small.launch")
    with open(launch, "w") as f:
        f.write("<launch>\n  <param name='p' value='1'/>\n%s</launch>\n" % "".join(
            "  <node pkg='budget_pkg' type='sleeper' name='n%d'/>\n" % i for i in range(nodes)))
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    env = dict(os.environ, ROS_PACKAGE_PATH=os.path.join(root, "pkgs"), ROS_HOME=os.path.join(root, "home"),
               ROS_LOG_DIR=os.path.join(root, "log"), ROS_MASTER_URI="http://127.0.0.1:%d/" % port,
               ROS_IP="127.0.0.1")
    env.pop("ROS_HOSTNAME", None)
    return launch, env


def time_nodes(cmd: list[str], launch: str, env: dict[str, str]) -> tuple[float, float, bytes]:
    """Seconds, peak resident MB (its VmHWM: the rusage of the ended process), stderr."""
    t0 = time.perf_counter()
    p = subprocess.Popen(cmd + ["--nodes", launch], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    err = p.stderr.read()
    _, status, usage = os.wait4(p.pid, 0)
    elapsed = time.perf_counter() - t0
    p.returncode = status
    if status:
        raise RuntimeError("launch --nodes failed:\n%s" % err.decode(errors="replace"))
    return elapsed, usage.ru_maxrss / 1024.0, err


def time_first_spawn(cmd: list[str], launch: str, env: dict[str, str]) -> tuple[float, float, bytes, float]:
    """Seconds from Popen to the first 'started with pid' line, the launch's VmHWM then (MB), stderr, and its CPU
    seconds then; the launch is then stopped."""
    t0 = time.perf_counter()
    p = subprocess.Popen(cmd + ["--skip-log-check", launch], env=env, stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, stdin=subprocess.DEVNULL)
    out = b""
    elapsed = hwm = cpu = float("nan")
    try:
        os.set_blocking(p.stdout.fileno(), True)
        while True:
            line = p.stdout.readline()
            if not line:
                raise RuntimeError("the launch ended before its first node started:\n%s" % out.decode())
            out += line
            if STARTED.search(line):
                elapsed = time.perf_counter() - t0
                hwm = vm_hwm_mb(p.pid)
                cpu = cpu_seconds(p.pid)
                break
    finally:
        p.send_signal(signal.SIGINT)
        _, err = p.communicate(timeout=60)
    return elapsed, hwm, err, cpu


def imports(stderr: bytes) -> list[tuple[int, str]]:
    """(cumulative µs, module) of each `-X importtime` line."""
    found = []
    for line in stderr.decode(errors="replace").splitlines():
        m = re.match(r"import time:\s+(\d+)\s+\|\s+(\d+)\s+\|(\s*)(\S+)", line)
        if m:
            found.append((int(m.group(2)), m.group(4)))
    return found


def report(name: str, times: list[float], hwms: list[float], stderr: bytes) -> None:
    mods = imports(stderr)
    names = {m for _, m in mods}
    print("%-12s median %.1f ms  min %.1f ms  VmHWM median %.1f MB  (%d runs)" % (
        name, statistics.median(times) * 1e3, min(times) * 1e3, statistics.median(hwms), len(times)))
    print("  heavy modules imported: %s" % (", ".join(h for h in HEAVY if h in names) or "none"))
    top = sorted(mods, reverse=True)[:10]
    print("  largest imports (cumulative): %s" % ", ".join("%s %.1f ms" % (m, us / 1e3) for us, m in top))


def measure_imports(py: str, groups: list[list[str]], reps: int) -> list[tuple[float, float]]:
    """(CPU s, peak MB) of a fresh interpreter `py` alone, then what importing each group added: medians of `reps`."""
    runs = [json.loads(subprocess.run([py, "-c", MEASURE, json.dumps(groups)], check=True, capture_output=True,
                                      text=True).stdout) for _ in range(reps)]
    parts = [[r[0] for r in runs]]  # the interpreter alone
    for i in range(1, len(groups) + 1):  # what each group added, within each run
        parts.append([[r[i][0] - r[i - 1][0], r[i][1] - r[i - 1][1]] for r in runs])
    return [(statistics.median(p[0] for p in part), statistics.median(p[1] for p in part)) for part in parts]


def decompose(py: str, spawns: list[tuple], reps: int) -> None:
    """What the first spawn's CPU and peak memory are made of (see the module's docstring). The standard library
    is imported in groups, the parts apart after the rest: each part is measured in the same processes as the rest,
    as what it adds to them."""
    names = json.loads(subprocess.run([py, "-c", RUN_IMPORTS + "; import json, sys; print(json.dumps("
                                       "[n for n, m in sys.modules.items() if m is not None]))"],
                                      check=True, capture_output=True, text=True).stdout)
    names = [n for n in names if n != "__main__"]
    ours = [n for n in names if n == "launcher" or n.startswith("launcher.")]
    stdlib = [n for n in names if n not in ours]

    def top_in(group: tuple[str, ...], among: list[str]) -> list[str]:
        return [n for n in among if n.split(".")[0] in group]
    single = [(label, top_in(group, stdlib)) for label, group in SINGLE_USE]
    inspect_part = top_in(INSPECT, stdlib)
    asyncio_rest = [n for n in top_in(ASYNCIO_ONLY, stdlib) if n not in inspect_part]
    apart = set(inspect_part + asyncio_rest).union(*(mods for _, mods in single))
    rest = [n for n in stdlib if n not in apart]
    groups = [("standard library, but for the parts below", rest)] + single + [
        ("asyncio's own: inspect, ast, dis", inspect_part), ("asyncio's own: the rest", asyncio_rest), ("ours", ours)]
    parts = measure_imports(py, [mods for _, mods in groups], reps)
    spawn = (statistics.median(r[3] for r in spawns), statistics.median(r[1] for r in spawns))
    parts.append(tuple(total - sum(p[i] for p in parts) for i, total in enumerate(spawn)))
    print("first spawn's CPU and peak memory, by part (%s, medians of %d):" % (py, reps))
    labels = ["interpreter alone"] + ["+ %s (%d modules)" % (label, len(mods)) for label, mods in groups]
    for part, (cpu, mb) in zip(labels + ["+ the run until its first spawn"], parts):
        print("  %-58s %6.1f ms  %5.1f MB" % (part, cpu * 1e3, mb))
    print("  %-58s %6.1f ms  %5.1f MB" % ("= the launch at its first spawn", spawn[0] * 1e3, spawn[1]))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--reps", type=int, default=10)
    ap.add_argument("--nodes", type=int, default=5, help="nodes in the small launch file")
    ap.add_argument("--launch", default="%s -m launcher" % sys.executable, help="the launch command")
    args = ap.parse_args()
    cmd = shlex.split(args.launch)
    py = cmd[0] if "python" in os.path.basename(cmd[0]) else None
    with tempfile.TemporaryDirectory(prefix="startup-budget-") as root:
        launch, env = make_launch(root, args.nodes)
        runs = {}
        for name, measure in (("--nodes", time_nodes), ("first spawn", time_first_spawn)):
            runs[name] = [measure(cmd, launch, env) for _ in range(args.reps)]
            traced = [py, "-X", "importtime"] + cmd[1:] if py else cmd
            report(name, [r[0] for r in runs[name]], [r[1] for r in runs[name]], measure(traced, launch, env)[2])
        if py is not None:  # (the parts are a Python's: a launch command that is not one has none to show)
            decompose(py, runs["first spawn"], args.reps)
    return 0


if __name__ == "__main__":
    sys.exit(main())
