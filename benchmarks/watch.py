#!/usr/bin/env python3
"""The cost of watching topics (watch_topic): the launcher's CPU, and its master's latency meanwhile.

One launch of 11 roscpp publishers (tests/integration/nodes/bag_talker.cpp): one sends 30 messages/s of
1 MB on /big, ten send 100 small messages/s each on /small0../small9. Three runs of it, one after the
other, on the launch's own master:

- watch: ours, every publisher with watch_topic (and watch_min_rate), so the launcher subscribes to all
  eleven over TCPROS (30 MB/s and 1,000 messages/s come in, nothing deserialized);
- plain: ours, the same launch without watch_topic;
- roslaunch: Debian's roslaunch with the plain launch (its rosmaster a process of its own; it cannot watch).

Once every publisher has registered and a settle time has passed, for --seconds: the launching
process's CPU (utime + stime of /proc/PID/stat, all its threads; the nodes are other processes) in % of
one core, what the publishers sent to subscribers (roscpp's getBusStats: the watches do get
30 MB/s and 1,030 messages/s), and the latency of master calls made by a client meanwhile (getSystemState and lookupNode in
turn, a new connection each, about 50 a second): p50, p99 and max in ms.

    python3 benchmarks/watch.py [--seconds 20] [--only watch|plain|roslaunch]
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import xmlrpc.client

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path[:0] = [os.path.join(ROOT, "tests"), os.path.join(ROOT, "tests", "integration"), ROOT]

from running import compile_roscpp, make_package  # noqa: E402  (the tests' roscpp build and package maker)

from common import ROS_PATH, free_port  # (this folder is on the path of a script run from it)

SMALL = 10
CLK_TCK = os.sysconf("SC_CLK_TCK")


def wait_for(cond, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > deadline:
            raise SystemExit("timed out waiting for %s" % what)
        time.sleep(0.05)


def launch_file(tmp: str, watch: bool) -> str:
    def node(name: str, topic: str, rate: int, pad: int, min_rate: int) -> str:
        attrs = ' watch_topic="%s" watch_timeout="2" watch_min_rate="%d"' % (topic, min_rate) if watch else ""
        return ('  <node pkg="watchbench" type="talker" name="%s" args="%s m 0 %d 0 %d"%s/>\n'
                % (name, topic, rate, pad, attrs))
    body = node("big", "/big", 30, 1 << 20, 20)
    body += "".join(node("small%d" % i, "/small%d" % i, 100, 0, 50) for i in range(SMALL))
    path = os.path.join(tmp, "%s.launch" % ("watch" if watch else "plain"))
    with open(path, "w") as f:
        f.write("<launch>\n%s</launch>\n" % body)
    return path


def cpu_s(pid: int) -> float:
    with open("/proc/%d/stat" % pid) as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLK_TCK  # utime, stime (fields 14 and 15)


def sent(master: xmlrpc.client.ServerProxy, nodes: list[str]) -> tuple[int, int]:
    """(bytes, messages) the nodes have sent over their TCPROS connections (roscpp's getBusStats): proof that
    the watches get what is published."""
    total_bytes = total_msgs = 0
    for node in nodes:
        try:
            uri = master.lookupNode("/bench", node)[2]
            stats = xmlrpc.client.ServerProxy(uri).getBusStats("/bench")
        except (OSError, xmlrpc.client.Error):
            continue
        # roscpp answers [publications, subscriptions] (no code, message, value), a publication being
        # [topic, [[connection id, bytes sent, bytes sent, messages sent, 0]]]
        for _topic, conns in stats[0]:
            for conn in conns:
                total_bytes += int(conn[1])
                total_msgs += int(conn[3])
    return total_bytes, total_msgs


def run_one(kind: str, tmp: str, seconds: float, settle: float) -> dict:
    port = free_port()
    uri = "http://127.0.0.1:%d/" % port
    env = dict(os.environ, ROS_MASTER_URI=uri, ROS_IP="127.0.0.1", ROS_HOME=os.path.join(tmp, "home-" + kind),
               ROS_PACKAGE_PATH=tmp)
    if kind == "roslaunch":
        env["PATH"] = ROS_PATH + ":" + env.get("PATH", "")
        argv = ["roslaunch", "--no-summary", "-p", str(port), launch_file(tmp, False)]
    else:
        env["PYTHONPATH"] = ROOT
        env["PATH"] = ROS_PATH + ":" + env.get("PATH", "")
        argv = [sys.executable, "-m", "launcher", "--no-summary", "-p", str(port), launch_file(tmp, kind == "watch")]
    proc = subprocess.Popen(argv, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    master = xmlrpc.client.ServerProxy(uri)

    def registered() -> bool:
        try:
            pubs = master.getSystemState("/bench")[2][0]
        except OSError:
            return False
        return sum(1 for topic, _ in pubs if topic == "/big" or topic.startswith("/small")) == SMALL + 1
    try:
        wait_for(registered, 60, "the publishers (%s)" % kind)
        time.sleep(settle)  # the watches subscribe after a first message (a benchmark: a fixed settle time)
        lat = []
        names = ["/big"] + ["/small%d" % i for i in range(SMALL)]
        sent0 = sent(master, names)
        cpu0, t0 = cpu_s(proc.pid), time.monotonic()
        i = 0
        while time.monotonic() - t0 < seconds:
            started = time.monotonic()
            if i % 2:
                xmlrpc.client.ServerProxy(uri).lookupNode("/bench", "/big")
            else:
                xmlrpc.client.ServerProxy(uri).getSystemState("/bench")
            lat.append(time.monotonic() - started)
            i += 1
            time.sleep(max(0.0, started + 0.02 - time.monotonic()))
        cpu1, t1 = cpu_s(proc.pid), time.monotonic()
        sent1 = sent(master, names)
        if proc.poll() is not None:
            raise SystemExit("the %s launch ended early (%s)" % (kind, proc.returncode))
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGINT)
            try:
                proc.wait(30)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
    lat.sort()
    return {"cpu_pct": 100.0 * (cpu1 - cpu0) / (t1 - t0), "calls": len(lat),
            "mb_s": (sent1[0] - sent0[0]) / (t1 - t0) / 1e6, "msg_s": (sent1[1] - sent0[1]) / (t1 - t0),
            "p50_ms": lat[len(lat) // 2] * 1000, "p99_ms": lat[min(len(lat) - 1, int(len(lat) * 0.99))] * 1000,
            "max_ms": lat[-1] * 1000}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--settle", type=float, default=4.0, help="seconds after the publishers registered")
    ap.add_argument("--only", choices=("watch", "plain", "roslaunch"))
    o = ap.parse_args()
    tmp = tempfile.mkdtemp(prefix="watchbench-")
    try:
        pkg = make_package(tmp, "watchbench", {})
        compile_roscpp("bag_talker.cpp", os.path.join(pkg, "talker"))
        results = {}
        for kind in ("watch", "plain", "roslaunch"):
            if o.only and kind != o.only:
                continue
            r = results[kind] = run_one(kind, tmp, o.seconds, o.settle)
            print("%-9s launcher cpu %5.2f %% of a core   master p50 %6.2f ms  p99 %6.2f ms  max %6.2f ms  (%d calls)"
                  "   sent to subscribers %.1f MB/s, %.0f msg/s"
                  % (kind, r["cpu_pct"], r["p50_ms"], r["p99_ms"], r["max_ms"], r["calls"], r["mb_s"], r["msg_s"]),
                  flush=True)
        if "watch" in results and "plain" in results:
            w, p = results["watch"], results["plain"]
            print("watching costs %.2f %% of a core (goal <= 2); master p99 %.2f ms watching vs %.2f ms not (x%.2f)"
                  % (w["cpu_pct"] - p["cpu_pct"], w["p99_ms"], p["p99_ms"], w["p99_ms"] / max(p["p99_ms"], 1e-6)))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
