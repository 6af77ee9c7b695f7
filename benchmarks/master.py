#!/usr/bin/env python3
"""Master throughput: our `launch --core` against the reference `rosmaster --core`, side by side.

K client processes, each a sequential keep-alive HTTP/1.1 XML-RPC client,
call a fixed mix of Master/Parameter Server methods for T seconds against a
master preloaded with 200 parameters and 50 publishers (the scenario of
../shared/bench `bench.py master`). Masters alternate in ABBA order over
the repetitions; the summary gives medians and paired ratios ours/reference.

    PATH=/usr/bin:$PATH python3 benchmarks/master.py [--reps 4] [--k 8] [--duration 10]

The reference is skipped (absolute numbers only) when `rosmaster` is not installed.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import random
import shlex
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
import urllib.parse
import xmlrpc.client

from common import free_port  # (this folder is on the path of a script run from it)

MIX = {"getParam": 30, "setParam": 15, "hasParam": 5, "registerPublisher": 10, "unregisterPublisher": 5,
       "lookupNode": 15, "getSystemState": 10, "getPid": 5, "getParamNames": 5}


class RawClient:
    """Keep-alive XML-RPC client doing as little as possible, so that the master is the bottleneck."""

    def __init__(self, uri: str):
        u = urllib.parse.urlsplit(uri)
        self.sock = socket.create_connection((u.hostname, u.port))
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.buf = b""

    def call(self, method: str, params: tuple) -> bytes:
        body = xmlrpc.client.dumps(params, method).encode()
        self.sock.sendall(b"POST / HTTP/1.1\r\nHost: m\r\nContent-Type: text/xml\r\nContent-Length: %d\r\n\r\n"
                          % len(body) + body)
        buf = self.buf
        while b"\r\n\r\n" not in buf:
            chunk = self.sock.recv(65536)
            if not chunk:
                raise ConnectionError("master closed the connection")
            buf += chunk
        head, _, rest = buf.partition(b"\r\n\r\n")
        length = int(head.lower().split(b"content-length:", 1)[1].split(b"\r\n", 1)[0])
        while len(rest) < length:
            chunk = self.sock.recv(65536)
            if not chunk:
                raise ConnectionError("master closed the connection")
            rest += chunk
        self.buf = rest[length:]
        return rest[:length]


def worker(uri: str, wid: int, k: int, start: float, duration: float, queue: mp.Queue) -> None:
    rng = random.Random(wid)
    cli = RawClient(uri)
    me = "/bench_w%d" % wid
    api = "http://127.0.0.1:%d/" % (40000 + wid)  # never called back: nobody subscribes to these topics
    ops = [op for op, w in MIX.items() for _ in range(w)]
    cli.call("registerPublisher", (me, "/bench/w%d/t0" % wid, "std_msgs/String", api))
    while time.time() < start:
        time.sleep(0.001)
    end = start + duration
    lat: list[int] = []
    faults = 0
    while True:
        op = ops[rng.randrange(len(ops))]
        if op == "getParam":
            args: tuple = (me, "/bench/p%d" % rng.randrange(200))
        elif op == "setParam":
            args = (me, "/bench/w%d/p%d" % (wid, rng.randrange(50)), rng.random())
        elif op == "hasParam":
            args = (me, "/bench/p%d" % rng.randrange(400))
        elif op == "registerPublisher":
            args = (me, "/bench/w%d/t%d" % (wid, rng.randrange(20)), "std_msgs/String", api)
        elif op == "unregisterPublisher":
            args = (me, "/bench/w%d/t%d" % (wid, 1 + rng.randrange(19)), api)
        elif op == "lookupNode":
            args = (me, "/bench_w%d" % rng.randrange(k))
        else:
            args = (me,)
        t0 = time.perf_counter()
        reply = cli.call(op, args)
        t1 = time.perf_counter()
        if time.time() >= end:
            break
        if b"<fault>" in reply:
            faults += 1
        lat.append(int((t1 - t0) * 1e6))
    queue.put({"lat": lat, "faults": faults})


def cpu_seconds(pid: int) -> float:
    try:
        with open("/proc/%d/stat" % pid) as f:
            fields = f.read().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except OSError:
        return float("nan")


def measure(label: str, cmd: str, k: int, duration: float) -> dict:
    port = free_port()
    uri = "http://127.0.0.1:%d/" % port
    home = tempfile.mkdtemp(prefix="master-bench-")
    env = dict(os.environ, ROS_MASTER_URI=uri, ROS_HOME=home, ROS_LOG_DIR=os.path.join(home, "log"), ROS_IP="127.0.0.1")
    proc = subprocess.Popen(shlex.split(cmd) + ["-p", str(port)], env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        px = xmlrpc.client.ServerProxy(uri)
        deadline = time.monotonic() + 30
        while True:
            try:
                if px.getPid("/bench")[0] == 1:
                    break
            except OSError:
                pass
            if time.monotonic() > deadline or proc.poll() is not None:
                raise RuntimeError("%s did not come up" % cmd)
            time.sleep(0.05)
        multi = xmlrpc.client.MultiCall(px)
        for i in range(200):
            multi.setParam("/bench_pre", "/bench/p%d" % i, i)
        for i in range(50):
            multi.registerPublisher("/bench_pre%d" % (i % 10), "/bench/pre/t%d" % i, "std_msgs/String",
                                    "http://127.0.0.1:%d/" % (41000 + i % 10))
        tuple(multi())
        queue: mp.Queue = mp.Queue()
        start = time.time() + 1.0 + 0.1 * k
        workers = [mp.Process(target=worker, args=(uri, i, k, start, duration, queue)) for i in range(k)]
        for w in workers:
            w.start()
        while time.time() < start:
            time.sleep(0.01)
        cpu0 = cpu_seconds(proc.pid)
        results = [queue.get(timeout=duration + 60) for _ in workers]
        cpu1 = cpu_seconds(proc.pid)
        for w in workers:
            w.join(10)
    finally:
        try:
            os.killpg(proc.pid, signal.SIGINT)
            proc.wait(10)
        except ProcessLookupError:
            pass
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        shutil.rmtree(home, ignore_errors=True)
    lat = sorted(x for r in results for x in r["lat"])
    return {"master": label, "calls_per_s": round(len(lat) / duration, 1),
            "p50_ms": lat[len(lat) // 2] / 1000, "p99_ms": lat[int(len(lat) * 0.99)] / 1000,
            "faults": sum(r["faults"] for r in results), "master_cpu_s": round(cpu1 - cpu0, 2)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--reps", type=int, default=4)
    ap.add_argument("--k", type=int, default=8)
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--ours", default="launch --core")
    ap.add_argument("--reference", default="rosmaster --core")
    a = ap.parse_args()
    masters = [("ours", a.ours)]
    if shutil.which(shlex.split(a.reference)[0]):
        masters.insert(0, ("rosmaster", a.reference))
    else:
        print("reference %r not found: absolute numbers only" % a.reference, file=sys.stderr)
    runs: dict[str, list[dict]] = {label: [] for label, _ in masters}
    for rep in range(a.reps):
        order = masters if rep % 4 in (0, 3) else masters[::-1]  # ABBA
        for label, cmd in order:
            r = measure(label, cmd, a.k, a.duration)
            r["rep"] = rep
            runs[label].append(r)
            print(json.dumps(r), flush=True)
    summary: dict = {"k": a.k, "duration_s": a.duration, "reps": a.reps, "median": {}, "ratios_vs_rosmaster": {}}
    for label, rs in runs.items():
        summary["median"][label] = {m: statistics.median(r[m] for r in rs)
                                    for m in ("calls_per_s", "p50_ms", "p99_ms", "master_cpu_s")}
    if "rosmaster" in runs:
        for m in ("calls_per_s", "p50_ms", "p99_ms"):
            summary["ratios_vs_rosmaster"][m] = round(statistics.median(
                o[m] / r[m] for o, r in zip(runs["ours"], runs["rosmaster"])), 3)
    print(json.dumps({"summary": summary}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
