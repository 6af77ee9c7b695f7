#!/usr/bin/env python3
"""The cost of `launch --metrics` scraped every second: the launcher's CPU, and its master's latency meanwhile.

One launch of N idle nodes (each a `sleep`, a process per node, in a scratch package) with our own master and
`--metrics`. Once every node has started and a settle time has passed, windows of --window seconds alternate,
--pairs times: in one a scraper GETs /metrics every second (as Prometheus would: a new connection each time), in the
other nobody does (the scraper is a process of its own, as Prometheus is). Throughout, a client calls the master about 50 times a second (getSystemState and lookupNode in
turn, a new connection each), and the launching process's CPU (all its threads: the scrapes run in threads of
its own) is read from /proc/PID/task/*/schedstat at each window's edges.

Printed: per window kind, the median CPU in % of one core and the master's p50/p99/max over all its windows'
calls; the scrape's cost (scraping minus not, the median of the pairs' differences) and the p99 ratio. Goals
(issue 35): <= 1 % of a core, p99 within 10 %.

The idle nodes' CPU and memory do not move, so each scrape formats only what changed (services/metrics.Formatter):
--formatting also times, in this process, the formatting of an N-node snapshot whose every node's CPU and memory
changed since the last (the worst case for a robot whose nodes all work), in ms and % of a core at one scrape a
second.

--control runs the same with the scraper asking for /nothing (404): the scraping process's own share of a busy
machine, the launch doing nothing for it.

    python3 benchmarks/metrics.py [--n 500] [--window 20] [--pairs 3] [--formatting] [--control]
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import xmlrpc.client

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, ROOT)

from common import cpu_seconds, free_port, idle_launch  # noqa: E402  (this folder is on the path of a script run from it)

ACCEPT = "application/openmetrics-text;version=1.0.0,text/plain;version=0.0.4;q=0.5,*/*;q=0.1"  # Prometheus's


def make_launch(root: str, n: int) -> str:
    return idle_launch(root, "metrics_bench", n)


class Caller(threading.Thread):
    """Master calls about every 20 ms, each on a new connection; their latencies, by the window they fell in."""

    def __init__(self, uri: str):
        super().__init__(daemon=True)
        self.uri = uri
        self.window: list[float] | None = None
        self.stop = threading.Event()

    def run(self) -> None:
        i = 0
        while not self.stop.is_set():
            started = time.monotonic()
            proxy = xmlrpc.client.ServerProxy(self.uri)
            if i % 2:
                proxy.lookupNode("/bench", "/rosout")
            else:
                proxy.getSystemState("/bench")
            took = time.monotonic() - started
            window = self.window
            if window is not None:
                window.append(took)
            i += 1
            time.sleep(max(0.0, started + 0.02 - time.monotonic()))


SCRAPER = """
import sys, time, urllib.error, urllib.request
url, accept = sys.argv[1], sys.argv[2]
while True:
    started = time.monotonic()
    try:
        with urllib.request.urlopen(urllib.request.Request(url, headers={"Accept": accept}), timeout=10) as answer:
            size = len(answer.read())
    except urllib.error.HTTPError as e:  # (--control: /nothing)
        size = len(e.read())
    print(size, time.monotonic() - started, flush=True)
    time.sleep(max(0.0, started + 1.0 - time.monotonic()))
"""


class Scraper:
    """A process apart that GETs /metrics every second, as Prometheus would (in the benchmark's own process its
    reading of the text would hold the GIL of the client timing the master)."""

    def __init__(self, url: str, root: str):
        self.url = url
        self.log = os.path.join(root, "scrapes.txt")
        self.proc: subprocess.Popen | None = None

    def start(self) -> None:
        with open(self.log, "a") as out:
            self.proc = subprocess.Popen([sys.executable, "-c", SCRAPER, self.url, ACCEPT], stdout=out)

    def stop(self) -> None:
        if self.proc is not None:
            self.proc.terminate()
            self.proc.wait()
            self.proc = None

    def results(self) -> tuple[list[int], list[float]]:
        with open(self.log) as f:
            rows = [line.split() for line in f if line.strip()]
        return [int(r[0]) for r in rows], [float(r[1]) for r in rows]


def pct(values: list[float], q: float) -> float:
    values = sorted(values)
    return values[min(len(values) - 1, int(len(values) * q))] * 1000


def formatting(n: int, rounds: int = 20) -> float:
    """ms of CPU to format an n-node snapshot whose every node's CPU and memory moved since the last scrape."""
    from launcher.master.callstats import CallStats
    from launcher.services import metrics
    calls = CallStats()
    for method in ("getPid", "lookupNode", "registerPublisher", "getParam", "getSystemState"):
        calls.observe(method, 0.0003)

    def snap(k: int) -> metrics.Snapshot:
        columns = {"state": ("running",) * n, "running": (True,) * n, "registered": (True,) * n,
                   "restarts": (0,) * n, "last_exit_code": (None,) * n, "cpu_seconds": (1.5 + k,) * n,
                   "rss": (123456 + k,) * n}
        return metrics.Snapshot("run", tuple(("/n%d" % i, "localhost") for i in range(n)), columns, (), calls.copy(),
                                (n, 10, 2 * n))
    formatter = metrics.Formatter()
    formatter.render(snap(0))
    started = time.process_time()
    for k in range(rounds):
        formatter.render(snap(k + 1))
    return (time.process_time() - started) / rounds * 1000


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=500)
    ap.add_argument("--window", type=float, default=20.0)
    ap.add_argument("--pairs", type=int, default=3)
    ap.add_argument("--settle", type=float, default=10.0)
    ap.add_argument("--formatting", action="store_true")
    ap.add_argument("--control", action="store_true", help="the scraper asks for /nothing (answered 404 at once): "
                    "what the scraping process itself costs the machine, the launch doing no work for it")
    o = ap.parse_args()
    root = tempfile.mkdtemp(prefix="metricsbench-")
    port, metrics_port = free_port(), free_port()
    uri = "http://127.0.0.1:%d/" % port
    env = dict(os.environ, ROS_PACKAGE_PATH=root, ROS_HOME=os.path.join(root, "home"), ROS_LOG_DIR=os.path.join(
        root, "log"), ROS_MASTER_URI=uri, ROS_IP="127.0.0.1", PYTHONPATH=ROOT)
    out = open(os.path.join(root, "out.txt"), "w+")
    proc = subprocess.Popen([sys.executable, "-m", "launcher", make_launch(root, o.n), "-p", str(port), "--no-summary",
                             "--skip-log-check", "--metrics", str(metrics_port)], env=env, stdout=out,
                            stderr=subprocess.STDOUT, start_new_session=True)
    caller = Caller(uri)
    scraper = Scraper("http://127.0.0.1:%d/%s" % (metrics_port, "nothing" if o.control else "metrics"), root)
    try:
        deadline = time.monotonic() + 300
        while True:
            out.seek(0)
            if len(re.findall(r"started with pid \[\d+\]", out.read())) >= o.n:
                break
            if proc.poll() is not None or time.monotonic() > deadline:
                out.seek(0)
                raise SystemExit("the launch did not start its nodes:\n" + out.read()[-2000:])
            time.sleep(0.5)
        time.sleep(o.settle)
        caller.start()
        cpu: dict[str, list[float]] = {"scraped": [], "not scraped": []}
        lat: dict[str, list[float]] = {"scraped": [], "not scraped": []}
        for pair in range(o.pairs):
            for kind in (("scraped", "not scraped") if pair % 2 == 0 else ("not scraped", "scraped")):
                if kind == "scraped":
                    scraper.start()
                time.sleep(1.0)  # (the scraper's start, or the last scrape's end, is outside the window)
                window: list[float] = []
                c0, t0 = cpu_seconds(proc.pid), time.monotonic()
                caller.window = window
                time.sleep(o.window)
                caller.window = None
                c1, t1 = cpu_seconds(proc.pid), time.monotonic()
                scraper.stop()
                cpu[kind].append(100.0 * (c1 - c0) / (t1 - t0))
                lat[kind] += window
                print("  pair %d %-11s launcher cpu %5.2f %% of a core, master p99 %6.2f ms (%d calls)"
                      % (pair + 1, kind, cpu[kind][-1], pct(window, 0.99), len(window)), flush=True)
        if proc.poll() is not None:
            raise SystemExit("the launch ended early (%s)" % proc.returncode)
    finally:
        caller.stop.set()
        scraper.stop()
        sizes, times = scraper.results() if os.path.exists(scraper.log) else ([], [])
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGINT)
            try:
                proc.wait(60)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
        shutil.rmtree(root, ignore_errors=True)
    for kind in ("not scraped", "scraped"):
        print("%-11s launcher cpu median %5.2f %% of a core   master p50 %6.2f ms  p99 %6.2f ms  max %6.2f ms  "
              "(%d calls)" % (kind, statistics.median(cpu[kind]), pct(lat[kind], 0.5), pct(lat[kind], 0.99),
                              pct(lat[kind], 1.0), len(lat[kind])))
    cost = statistics.median([s - n for s, n in zip(cpu["scraped"], cpu["not scraped"])])
    ratio = pct(lat["scraped"], 0.99) / max(pct(lat["not scraped"], 0.99), 1e-6)
    print("%d nodes: a scrape a second costs %.2f %% of a core (goal <= 1); master p99 scraped / not: x%.3f "
          "(goal <= 1.10); %d scrapes of %d kB, each answered in %.1f ms (median)"
          % (o.n, cost, ratio, len(times), statistics.median(sizes) // 1000 if sizes else 0,
             statistics.median(times) * 1000 if times else 0))
    if o.formatting:
        ms = formatting(o.n)
        print("formatting a %d-node snapshot whose every CPU and memory value moved: %.1f ms, %.2f %% of a core at "
              "a scrape a second" % (o.n, ms, ms / 10))
    return 0


if __name__ == "__main__":
    sys.exit(main())
