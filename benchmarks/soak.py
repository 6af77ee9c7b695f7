#!/usr/bin/env python3
"""A long run's memory (issue 36): the launch's RSS, minute by minute, through an hour of crash loops.

    python3 benchmarks/soak.py [--minutes 60] [--nodes 30] [--kills-per-s 4] [--views web,events]

A launch of N tiny roscpp nodes (../shared/bench's tiny_node, as benchmarks/reload.py builds it;
$LAUNCHER_BENCH, bench.py's path, says where that is instead), each
`respawn="true"`, is started with our launcher; then, every 1/`--kills-per-s` s, one node's process whose
run is older than the launcher's `respawn_min_uptime` (1 s: a younger one's end is a failed start, backed
off) gets SIGKILL, and is started again by the launch. The views attached read the launch all along, as
an operator's would: `web` is `launcher web` with a raw client reading the page's event stream (the web
view long-polls the launch's change stream, samples and output), `events` is `launcher events -f`,
`watch` is `launcher status --watch` (the status again at each change). Each minute the launch's RSS
(VmRSS of its process), its high-water mark, the kills so far and the restarts the launch counted are
printed; at the end, whether the RSS after the second minute stayed within 2 MB (the issue's bound).
"""

from __future__ import annotations

import argparse
import json
import os
import random
import shlex
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time

from common import free_port, make_package, tool_command  # (this folder is on the path of a script run from it)
import reload  # (the same roscpp node as its benchmark's)

FLAT_BYTES = 2 * 1000 * 1000  # the bound: within 2 MB of the second minute
MIN_AGE_S = 1.5  # a run killed younger than respawn_min_uptime (1 s) is a failed start: backed off, then fatal


def vm(pid: int, field: str) -> int:
    """A field of /proc/PID/status in bytes (VmRSS, VmHWM)."""
    with open("/proc/%d/status" % pid) as f:
        for line in f:
            if line.startswith(field + ":"):
                return int(line.split()[1]) * 1024
    return 0


def node_pids(log_dir: str) -> list[int]:
    """The pids of the launch's tiny nodes (their __log:= argument is under the run's log directory)."""
    pids = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open("/proc/%s/comm" % entry) as f:
                if f.read().strip() != "tiny_node":
                    continue
            with open("/proc/%s/cmdline" % entry, "rb") as f:
                if b"__log:=" + log_dir.encode() not in f.read():
                    continue
        except OSError:
            continue
        pids.append(int(entry))
    return pids


class Chaos(threading.Thread):
    """SIGKILL to one node a period, chosen among those seen running for MIN_AGE_S at least."""

    def __init__(self, log_dir: str, period: float):
        super().__init__(daemon=True)
        self.log_dir, self.period = log_dir, period
        self.kills = 0
        self.stop = threading.Event()
        self.seen: dict[int, float] = {}

    def run(self) -> None:
        rng = random.Random(36)
        next_at = time.monotonic()
        while not self.stop.is_set():
            now = time.monotonic()
            alive = node_pids(self.log_dir)
            self.seen = {pid: self.seen.get(pid, now) for pid in alive}
            old = [pid for pid, first in self.seen.items() if now - first >= MIN_AGE_S]
            if old:
                try:
                    os.kill(rng.choice(old), signal.SIGKILL)
                    self.kills += 1
                except OSError:
                    pass
            next_at += self.period
            self.stop.wait(max(0.0, next_at - time.monotonic()))


def read_events(port: int, received: list[int]) -> None:
    """A page's event stream, read and counted (what a browser on the web view would get)."""
    try:
        conn = socket.create_connection(("127.0.0.1", port), timeout=None)
        conn.sendall(b"GET /events HTTP/1.1\r\nHost: 127.0.0.1:%d\r\n\r\n" % port)
        while True:
            data = conn.recv(65536)
            if not data:
                return
            received[0] += len(data)
    except OSError:
        return


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--minutes", type=int, default=60)
    ap.add_argument("--nodes", type=int, default=30)
    ap.add_argument("--kills-per-s", type=float, default=4.0)
    ap.add_argument("--views", default="web,events", help="comma-separated: web, events, watch (or none)")
    ap.add_argument("--cmd", default="%s -m launcher" % sys.executable)
    a = ap.parse_args()
    views = [v for v in a.views.split(",") if v and v != "none"]
    cmd = shlex.split(a.cmd)
    tool = tool_command(cmd)
    tmp = tempfile.mkdtemp(prefix="bench-soak-")
    pkg = make_package(os.path.join(tmp, "pkgs"), "bench_soak")
    if os.environ.get("LAUNCHER_BENCH"):  # (bench.py's path, as benchmarks/supervise.py takes it: a worktree's)
        reload.SHARED_BENCH = os.path.dirname(os.path.abspath(os.environ["LAUNCHER_BENCH"]))
    reload.tiny_node(os.path.join(pkg, "tiny_node"))
    launch = os.path.join(tmp, "soak.launch")
    with open(launch, "w") as f:
        f.write("<launch>\n%s</launch>\n" % "".join(
            '  <node pkg="bench_soak" type="tiny_node" name="n%02d" respawn="true"/>\n' % i for i in range(a.nodes)))
    log_dir = os.path.join(tmp, "log")
    env = dict(os.environ, ROS_MASTER_URI="http://127.0.0.1:%d/" % free_port(), ROS_HOME=os.path.join(tmp, "home"),
               ROS_LOG_DIR=log_dir, ROS_PACKAGE_PATH=os.path.join(tmp, "pkgs"), ROS_IP="127.0.0.1")
    out = open(os.path.join(tmp, "launch.out"), "w")
    launch_proc = subprocess.Popen(cmd + [launch, "--no-summary", "--skip-log-check"], env=env, stdout=out,
                                   stderr=subprocess.STDOUT, start_new_session=True)
    helpers: list[subprocess.Popen] = []
    chaos = Chaos(log_dir, 1.0 / a.kills_per_s)
    try:
        deadline = time.monotonic() + 120
        while len(node_pids(log_dir)) < a.nodes:
            if launch_proc.poll() is not None or time.monotonic() > deadline:
                raise SystemExit("the launch did not start %d nodes (its output: %s)" % (a.nodes, out.name))
            time.sleep(0.5)
        received = [0]
        if "web" in views:
            port = free_port()
            helpers.append(subprocess.Popen(tool + ["web", str(port)], env=env, stdout=subprocess.DEVNULL,
                                            stderr=subprocess.PIPE))
            web = helpers[-1].stderr
            web.readline()  # "the live view of ... at ..." (then drained: a full pipe would block the view)
            threading.Thread(target=lambda: web.read(), daemon=True).start()
            threading.Thread(target=read_events, args=(port, received), daemon=True).start()
        if "events" in views:
            helpers.append(subprocess.Popen(tool + ["events", "-f"], env=env, stdout=subprocess.DEVNULL,
                                            stderr=subprocess.DEVNULL))
        if "watch" in views:
            helpers.append(subprocess.Popen(tool + ["status", "--watch"], env=env, stdout=subprocess.DEVNULL,
                                            stderr=subprocess.DEVNULL))
        chaos.start()
        print("soak: %d tiny roscpp nodes, respawn, %g SIGKILLs/s, views: %s, %d minutes; launch pid %d (%s)"
              % (a.nodes, a.kills_per_s, ",".join(views) or "none", a.minutes, launch_proc.pid, " ".join(cmd)))
        print("%6s %10s %10s %10s %8s %10s %10s" % ("minute", "RSS MB", "vs min 2", "VmHWM MB", "kills", "restarts",
                                                    "page kB"))
        rss: list[int] = [vm(launch_proc.pid, "VmRSS")]
        print("%6d %10.2f %10s %10.2f %8d %10s %10d" % (0, rss[0] / 1e6, "", vm(launch_proc.pid, "VmHWM") / 1e6, 0,
                                                       "", received[0] // 1000), flush=True)
        start = time.monotonic()
        for minute in range(1, a.minutes + 1):
            time.sleep(max(0.0, start + 60 * minute - time.monotonic()))
            if launch_proc.poll() is not None:
                raise SystemExit("the launch ended (status %s): see %s" % (launch_proc.returncode, out.name))
            rss.append(vm(launch_proc.pid, "VmRSS"))
            counted = restarts(tool, env)
            print("%6d %10.2f %10s %10.2f %8d %10s %10d" % (
                minute, rss[-1] / 1e6, "%+.2f" % ((rss[-1] - rss[2]) / 1e6) if minute >= 2 else "",
                vm(launch_proc.pid, "VmHWM") / 1e6, chaos.kills, counted, received[0] // 1000), flush=True)
        after = rss[2:]
        if len(after) >= 2:
            spread = max(after) - min(after)
            print("RSS after the second minute: %.2f..%.2f MB, spread %.2f MB: %s (bound %.0f MB)"
                  % (min(after) / 1e6, max(after) / 1e6, spread / 1e6,
                     "flat" if spread <= FLAT_BYTES else "GROWS", FLAT_BYTES / 1e6))
    finally:
        chaos.stop.set()
        for h in helpers:
            h.send_signal(signal.SIGINT)
        for h in helpers:
            try:
                h.wait(10)
            except subprocess.TimeoutExpired:
                h.kill()
                h.wait()
        launch_proc.send_signal(signal.SIGINT)
        try:
            launch_proc.wait(60)
        except subprocess.TimeoutExpired:
            os.killpg(launch_proc.pid, signal.SIGKILL)
            launch_proc.wait()
        out.close()
        shutil.rmtree(tmp, ignore_errors=True)
    return 0


def restarts(tool: list[str], env: dict[str, str]) -> str:
    """The nodes' restarts so far, as `launcher status --json` has them (the launch's own count of the kills)."""
    try:
        text = subprocess.run(tool + ["status", "--json"], env=env, capture_output=True, text=True, timeout=30).stdout
    except subprocess.TimeoutExpired:
        return "?"
    try:
        info = json.loads(text)
    except ValueError:
        return "?"
    return str(sum(n.get("restarts", 0) for n in info.get("nodes", [])))


if __name__ == "__main__":
    sys.exit(main())
