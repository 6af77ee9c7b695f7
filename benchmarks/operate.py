#!/usr/bin/env python3
"""Operating a running launch: what `launcher status` costs the operator and the launcher.

    python3 benchmarks/operate.py [--nodes 500] [--runs 20] [--clients 10] [--seconds 30]

1. `launcher status --json` on a running N-node launch, wall time of the whole
   command (Python's start included), median and max of `--runs`. Goal (issue 16): <= 100 ms at 500 nodes.
2. The launcher's own CPU (its process only, not the nodes) while `--clients`
   clients each ask for the status once a second (launcher_status over XML-RPC,
   as `launcher status` does), against the same launch idle. Goal: <= 2% of a core.

The nodes are `sleep` processes (a status costs the same whatever a node
runs, and 500 real ROS nodes would swamp a small machine). Run from the
repository: the launcher package is copied to a temporary directory and its
bytecode compiled there, as an installed package has it.
A bare `python -c pass` is timed alternately with the status: on a loaded
machine the interpreter's own start is most of the figure.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import xmlrpc.client

import psutil

from common import free_port, stop_process  # (this folder is on the path of a script run from it)

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def make_launch(tmp: str, n: int) -> str:
    pkg = os.path.join(tmp, "pkgs", "bench_op")
    os.makedirs(pkg)
    with open(os.path.join(pkg, "package.xml"), "w") as f:
        f.write('<?xml version="1.0"?><package format="2"><name>bench_op</name><version>0.0.1</version>'
                '<description>b</description><maintainer email="b@example.com">b</maintainer>'
                '<license>BSD</license></package>\n')
    with open(os.path.join(pkg, "idle"), "w") as f:
        f.write("#!/bin/sh\nexec sleep 100000\n")
    os.chmod(os.path.join(pkg, "idle"), 0o755)
    path = os.path.join(tmp, "bench.launch")
    with open(path, "w") as f:
        f.write("<launch>\n%s\n</launch>\n" % "\n".join(
            '<node pkg="bench_op" type="idle" name="n%03d" ns="g%d"/>' % (i, i % 10) for i in range(n)))
    return path


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--nodes", type=int, default=500)
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--clients", type=int, default=10)
    ap.add_argument("--seconds", type=float, default=30.0)
    opts = ap.parse_args()
    tmp = tempfile.mkdtemp(prefix="bench-operate-")
    port = free_port()
    env = dict(os.environ, PYTHONPATH=REPO, ROS_MASTER_URI="http://127.0.0.1:%d/" % port, ROS_IP="127.0.0.1",
               ROS_HOME=os.path.join(tmp, "home"), ROS_LOG_DIR=os.path.join(tmp, "log"),
               ROS_PACKAGE_PATH=os.path.join(tmp, "pkgs"))
    # bytecode compiled once, as a pip install does (PYTHONDONTWRITEBYTECODE would otherwise make every
    # `launcher status` compile the launcher's modules from source)
    import shutil
    copy = os.path.join(tmp, "src")
    shutil.copytree(os.path.join(REPO, "launcher"), os.path.join(copy, "launcher"),
                    ignore=shutil.ignore_patterns("__pycache__"))
    subprocess.run([sys.executable, "-m", "compileall", "-q", os.path.join(copy, "launcher")], check=True)
    env["PYTHONPATH"] = copy
    launch = make_launch(tmp, opts.nodes)
    out = open(os.path.join(tmp, "launch.out"), "wb")
    lp = subprocess.Popen([sys.executable, "-m", "launcher", "--skip-log-check", launch], env=env, stdout=out,
                          stderr=subprocess.STDOUT)
    status_cmd = [sys.executable, "-m", "launcher.cli.tool", "status", "--json"]
    try:
        deadline = time.monotonic() + 120
        while True:
            r = subprocess.run(status_cmd, env=env, capture_output=True, text=True)
            if r.returncode == 0:
                info = json.loads(r.stdout)
                if sum(1 for n in info["nodes"] if n["state"] == "running") == opts.nodes:
                    break
            if time.monotonic() > deadline or lp.poll() is not None:
                raise SystemExit("the launch did not bring its %d nodes up" % opts.nodes)
            time.sleep(0.5)
        time.sleep(3)  # let the start settle

        # alternated with a bare interpreter start, which on a loaded machine is most of the figure
        times, bare = [], []
        for _ in range(opts.runs):
            t0 = time.perf_counter()
            r = subprocess.run(status_cmd, env=env, capture_output=True)
            times.append(time.perf_counter() - t0)
            assert r.returncode == 0
            t0 = time.perf_counter()
            subprocess.run([sys.executable, "-c", "pass"], env=env)
            bare.append(time.perf_counter() - t0)
        median = statistics.median(times)
        print(json.dumps({"scenario": "status-json", "nodes": opts.nodes, "runs": opts.runs,
                          "median_ms": round(median * 1000, 1), "max_ms": round(max(times) * 1000, 1),
                          "bare_python_median_ms": round(statistics.median(bare) * 1000, 1),
                          "load_average": os.getloadavg()[0],
                          "goal": "median <= 100 ms", "ok": median <= 0.100}))

        launcher = psutil.Process(lp.pid)

        def cpu_over(seconds: float) -> float:
            c0 = sum(launcher.cpu_times()[:2])
            t0 = time.monotonic()
            time.sleep(seconds)
            return (sum(launcher.cpu_times()[:2]) - c0) / (time.monotonic() - t0)

        idle = cpu_over(opts.seconds / 2)
        uri = info["uri"]
        stop = threading.Event()
        calls = [0]

        def poller(offset: float) -> None:
            proxy = xmlrpc.client.ServerProxy(uri)
            time.sleep(offset)
            while not stop.is_set():
                t = time.monotonic()
                json.loads(proxy.launcher_status()[2])
                calls[0] += 1
                stop.wait(max(0.0, 1.0 - (time.monotonic() - t)))

        threads = [threading.Thread(target=poller, args=(i / opts.clients,), daemon=True)
                   for i in range(opts.clients)]
        for t in threads:
            t.start()
        time.sleep(1.5)
        busy = cpu_over(opts.seconds)
        stop.set()
        for t in threads:
            t.join()
        print(json.dumps({"scenario": "status-polling-cpu", "nodes": opts.nodes, "clients": opts.clients,
                          "calls": calls[0], "launcher_cpu_idle_pct": round(100 * idle, 2),
                          "launcher_cpu_polled_pct": round(100 * busy, 2), "goal": "polled <= 2% of a core",
                          "ok": busy <= 0.02}))
    finally:
        stop_process(lp, 120)
        out.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
