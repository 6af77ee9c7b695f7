#!/usr/bin/env python3
"""rosout under load: N roscpp publishers x R messages/s x T seconds, ours vs Debian's rosout.

For each rosout (ours: `launcher.net.rosout.Rosout` in its own process; the reference: Debian's
/usr/lib/rosout/rosout), on a fresh Debian rosmaster:
  1. start N real roscpp nodes that log "waiting" until /rosout_test/go is set,
  2. once every node's "waiting" line is in rosout.log (so rosout is connected), set it,
  3. each node logs R*T numbered lines at R per second, then "done",
  4. wait until rosout.log holds every line (or stops growing), read rosout's CPU time, stop it.
Reports missing lines and CPU seconds for both, and the ratio ours/reference.

    python3 benchmarks/rosout_load.py [--nodes 5] [--rate 2000] [--seconds 10] [--repeat 1]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import xmlrpc.client

import psutil

from common import ROS_PATH, free_port  # (this folder is on the path of a script run from it)

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
REFERENCE_ROSOUT = "/usr/lib/rosout/rosout"


def _cpp_source() -> str:
    # One roscpp logging node for the tests and this benchmark: take it from the tests.
    path = os.path.join(ROOT, "tests", "integration", "test_rosout_nodes.py")
    text = open(path, encoding="utf-8").read()
    return re.search(r'CPP_LOGGER = r"""(.*?)"""', text, re.S).group(1)


def compile_logger(build: str) -> str:
    src = os.path.join(build, "cpp_logger.cpp")
    with open(src, "w") as f:
        f.write(_cpp_source())
    flags = subprocess.run(["pkg-config", "--cflags", "--libs", "roscpp"], capture_output=True,
                           text=True, check=True).stdout.split()
    exe = os.path.join(build, "cpp_logger")
    subprocess.run(["g++", "-O2", "-o", exe, src] + flags, check=True)
    return exe


def wait_for(cond, timeout: float, what: str):
    deadline = time.monotonic() + timeout
    while True:
        value = cond()
        if value:
            return value
        if time.monotonic() > deadline:
            raise SystemExit("timed out waiting for %s" % what)
        time.sleep(0.05)


def serve(master_uri: str, log_dir: str) -> None:
    """Child mode: run our rosout until SIGINT/SIGTERM, then stop it cleanly."""
    sys.path.insert(0, ROOT)
    from launcher.net.rosout import Rosout

    async def main() -> None:
        rosout = Rosout(master_uri, log_dir, host="127.0.0.1")
        await rosout.start()
        done = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, done.set)
        print("ready", flush=True)
        await done.wait()
        await rosout.stop()
        print(json.dumps({"received": rosout.received, "undecodable": rosout.undecodable}),
              flush=True)
    asyncio.run(main())


def count_lines(path: str, nodes: list[str], per_node: int) -> tuple[int, dict[str, str]]:
    """(load lines present, {node: last line seen}) in rosout.log."""
    seen: dict[str, set[int]] = {n: set() for n in nodes}
    last: dict[str, str] = {}
    pat = re.compile(r"^\d+\.\d{9} INFO (\S+) \[[^\]]*\] \[topics: [^\]]*\] (.*)$")
    try:
        with open(path, encoding="utf-8", errors="replace") as f:
            for line in f:
                m = pat.match(line.rstrip("\n"))
                if not m or m.group(1) not in seen:
                    continue
                text = m.group(2)
                last[m.group(1)] = text
                if text.startswith("load "):
                    seen[m.group(1)].add(int(text[5:]))
    except FileNotFoundError:
        pass
    return sum(len(v & set(range(per_node))) for v in seen.values()), last


def find_rosout_log(root: str) -> str | None:
    for dirpath, _, files in os.walk(root):
        if "rosout.log" in files:
            return os.path.join(dirpath, "rosout.log")
    return None


def run_once(impl: str, exe: str, args: argparse.Namespace, work: str) -> dict:
    port = free_port()
    uri = "http://127.0.0.1:%d/" % port
    log_root = os.path.join(work, impl, "log")
    os.makedirs(log_root, exist_ok=True)
    env = {k: v for k, v in os.environ.items() if not k.startswith("ROS_")}
    env.update(PATH=ROS_PATH, ROS_MASTER_URI=uri, ROS_HOSTNAME="127.0.0.1", ROS_LOG_DIR=log_root,
               ROS_HOME=os.path.join(work, impl, "home"))
    procs: list[subprocess.Popen] = []

    def start(argv: list[str], **kw) -> subprocess.Popen:
        p = subprocess.Popen(argv, env=kw.pop("env", env), start_new_session=True,
                             stdout=kw.pop("stdout", subprocess.DEVNULL),
                             stderr=subprocess.DEVNULL, **kw)
        procs.append(p)
        return p

    try:
        start(["rosmaster", "--core", "-p", str(port)])
        master = xmlrpc.client.ServerProxy(uri)

        def master_up() -> bool:
            try:
                return master.getPid("/bench")[0] == 1
            except OSError:
                return False
        wait_for(master_up, 30, "rosmaster")
        if impl == "launcher":
            rosout = start([sys.executable, os.path.abspath(__file__), "--serve", uri,
                            os.path.join(log_root, "run")], env=dict(os.environ),
                           stdout=subprocess.PIPE, text=True)
            assert rosout.stdout.readline().strip() == "ready"
            path = os.path.join(log_root, "run", "rosout.log")
        else:
            rosout = start([REFERENCE_ROSOUT])
            path = wait_for(lambda: find_rosout_log(log_root), 30, "reference rosout.log")
        nodes = ["/load_%d" % i for i in range(args.nodes)]
        per_node = args.rate * args.seconds
        for n in nodes:
            start([exe, "__name:=" + n[1:], str(per_node), str(args.rate)])
        wait_for(lambda: len(count_lines(path, nodes, per_node)[1]) == len(nodes), 60,
                 "every node connected to rosout")
        cpu0 = psutil.Process(rosout.pid).cpu_times()
        t0 = time.monotonic()
        master.setParam("/bench", "/rosout_test/go", True)
        expected = per_node * len(nodes)
        got, stalled_since, last_got = 0, time.monotonic(), -1
        while got < expected:
            time.sleep(0.25)
            got, _ = count_lines(path, nodes, per_node)
            if got != last_got:
                last_got, stalled_since = got, time.monotonic()
            elif time.monotonic() - stalled_since > 5 and time.monotonic() - t0 > args.seconds:
                break
        wall = time.monotonic() - t0
        cpu1 = psutil.Process(rosout.pid).cpu_times()
        cpu = (cpu1.user + cpu1.system) - (cpu0.user + cpu0.system)
        rosout.send_signal(signal.SIGINT)
        extra = {}
        if impl == "launcher":
            out, _ = rosout.communicate(timeout=30)
            extra = json.loads(out.strip().splitlines()[-1])
        else:
            rosout.wait(30)
        got, _ = count_lines(path, nodes, per_node)
        return {"impl": impl, "expected": expected, "logged": got, "missing": expected - got,
                "cpu_s": round(cpu, 3), "wall_s": round(wall, 2), **extra}
    finally:
        for p in procs:
            if p.poll() is None:
                try:
                    os.killpg(p.pid, signal.SIGINT)
                except ProcessLookupError:
                    pass
        for p in procs:
            try:
                p.wait(5)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait(5)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--nodes", type=int, default=5)
    ap.add_argument("--rate", type=int, default=2000)
    ap.add_argument("--seconds", type=int, default=10)
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--only", choices=["launcher", "reference"])
    ap.add_argument("--serve", nargs=2, metavar=("MASTER_URI", "LOG_DIR"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.serve:
        serve(*args.serve)
        return
    work = tempfile.mkdtemp(prefix="rosout_load_")
    try:
        exe = compile_logger(work)
        impls = [args.only] if args.only else ["launcher", "reference"]
        results = []
        for rep in range(args.repeat):
            order = impls if rep % 2 == 0 else impls[::-1]
            for impl in order:
                r = run_once(impl, exe, args, os.path.join(work, "r%d" % rep))
                print(json.dumps(r), flush=True)
                results.append(r)
        ours = [r["cpu_s"] for r in results if r["impl"] == "launcher"]
        ref = [r["cpu_s"] for r in results if r["impl"] == "reference"]
        if ours and ref:
            # Paired per repetition (ABBA order), then the median: the machine is shared/noisy.
            ratios = sorted(o / max(r, 1e-9) for o, r in zip(ours, ref))
            mid = len(ratios) // 2
            median = ratios[mid] if len(ratios) % 2 else (ratios[mid - 1] + ratios[mid]) / 2
            print(json.dumps({"summary": "cpu ours/reference", "ours_cpu_s": ours,
                              "reference_cpu_s": ref, "median_ratio": round(median, 2),
                              "missing_ours": sum(r["missing"] for r in results
                                                  if r["impl"] == "launcher"),
                              "missing_reference": sum(r["missing"] for r in results
                                                       if r["impl"] == "reference")}))
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
