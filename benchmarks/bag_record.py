#!/usr/bin/env python3
"""Bags under load, ours vs Debian's rosbag (C++), one after the other on the same kind of roscpp publishers.

record: for each recorder (ours: `python -m launcher.bag record`; the reference: /usr/lib/rosbag/record),
on a fresh Debian rosmaster, N roscpp talkers each publish R messages/s for T seconds once the
recorder is subscribed; when every talker says "done" the recorder gets SIGINT. Reported: messages
lost (published - in the bag, read by rosbags) and the recorder's CPU seconds (rusage), and the ratio.
Two loads: 5 x 2,000 small messages/s for 10 s, and 1 x 30 messages/s of 1 MB for 10 s.

play: a bag of 1 topic at 1 kHz (exact 1 ms stamps) played by each player to a roscpp subscriber that
notes each arrival's wall time; the timing error of message i is (arrival_i - arrival_0) - (stamp_i - stamp_0).
Reported: p50/p99/max of |error| in ms.

    python3 benchmarks/bag_record.py [--seconds 10] [--play-seconds 5] [--only record|play] [--load small|large]
                                     [--abba] [--ours DIR]

--abba runs each load's recorders as reference, ours, ours, reference (a drift of the machine's load cancels
out) and gives the ratio of the sums; --ours DIR takes "ours" from another checkout (before/after a change).
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path[:0] = [os.path.join(ROOT, "tests"), os.path.join(ROOT, "tests", "integration"), ROOT]

from running import compile_roscpp  # noqa: E402  (the tests' roscpp build, cached by content)

from common import ROS_PATH, free_port  # (this folder is on the path of a script run from it)

REFERENCE_RECORD = "/usr/lib/rosbag/record"
REFERENCE_PLAY = "/usr/lib/rosbag/play"


def wait_for(cond, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > deadline:
            raise SystemExit("timed out waiting for %s" % what)
        time.sleep(0.02)


class Graph:
    def __init__(self, tmp: str):
        self.port = free_port()
        self.env = dict(os.environ, PATH=ROS_PATH + ":" + os.environ.get("PATH", ""),
                        ROS_MASTER_URI="http://127.0.0.1:%d/" % self.port, ROS_IP="127.0.0.1",
                        ROS_HOME=os.path.join(tmp, "home"), PYTHONPATH=ROOT)
        self.master = subprocess.Popen(["rosmaster", "--core", "-p", str(self.port)], env=self.env,
                                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        import xmlrpc.client
        proxy = xmlrpc.client.ServerProxy(self.env["ROS_MASTER_URI"])

        def up() -> bool:
            try:
                proxy.getPid("/bench")
                return True
            except OSError:
                return False
        wait_for(up, 20, "rosmaster")

    def stop(self) -> None:
        os.killpg(self.master.pid, signal.SIGINT)
        self.master.wait(10)


def count_messages(path: str) -> dict[str, int]:
    from rosbags.rosbag1 import Reader
    with Reader(path) as reader:
        return {t: i.msgcount for t, i in reader.topics.items()}


def record_run(kind: str, tmp: str, talker: str, nodes: int, rate: float, seconds: float, pad: int,
               ours: str = ROOT) -> tuple:
    graph = Graph(tmp)
    graph.env["PYTHONPATH"] = ours
    bag = os.path.join(tmp, "%s-%d-%d.bag" % (kind, nodes, pad))
    topics = ["/load%d" % i for i in range(nodes)]
    argv = ([sys.executable, "-m", "launcher.bag", "record"] if kind == "ours" else [REFERENCE_RECORD])
    rec = subprocess.Popen(argv + ["-O", bag, "-q"] + topics, env=graph.env, stdout=subprocess.DEVNULL,
                           stderr=subprocess.DEVNULL, start_new_session=True)
    count = int(rate * seconds)
    talkers = [subprocess.Popen([talker, t, "m", str(count), str(rate), "1", str(pad)], env=graph.env,
                                stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, start_new_session=True)
               for t in topics]
    for t in talkers:
        assert t.stdout is not None
        line = t.stdout.readline()  # "done" once all its messages are out
        assert line.strip() == "done", line
    time.sleep(1.0)  # what is in flight reaches the recorder (a benchmark, not a test: a fixed settle time)
    os.killpg(rec.pid, signal.SIGINT)
    _, status, usage = os.wait4(rec.pid, 0)
    for t in talkers:
        os.killpg(t.pid, signal.SIGINT)
        t.wait(10)
    graph.stop()
    counts = count_messages(bag)
    lost = nodes * count - sum(counts.get(t, 0) for t in topics)
    return lost, usage.ru_utime + usage.ru_stime


def play_bag(tmp: str, seconds: float) -> str:
    from rosbags.rosbag1 import Writer
    path = os.path.join(tmp, "khz.bag")
    writer = Writer(path)
    writer.open()
    conn = writer.add_connection("/khz", "std_msgs/msg/String", msgdef="string data\n",
                                 md5sum="992ce8a1687cec8c8bd883ec73ca41d1")
    t0 = 1_700_000_000 * 10**9
    for i in range(int(seconds * 1000)):
        data = b"k %d" % i
        writer.write(conn, t0 + i * 1_000_000, len(data).to_bytes(4, "little") + data)
    writer.close()
    return path


def play_run(kind: str, tmp: str, listener: str, bag: str, expected: int) -> list[float]:
    graph = Graph(tmp)
    out = os.path.join(tmp, "arrivals-%s.txt" % kind)
    sub = subprocess.Popen([listener, "/khz", "stamp"], env=graph.env, stdout=open(out, "w"),
                           stderr=subprocess.DEVNULL, start_new_session=True)
    argv = ([sys.executable, "-m", "launcher.bag", "play"] if kind == "ours" else [REFERENCE_PLAY])
    subprocess.run(argv + ["-q", "--wait-for-subscribers", bag], env=graph.env, stdout=subprocess.DEVNULL,
                   stderr=subprocess.DEVNULL, check=True, timeout=120)
    wait_for(lambda: sum(1 for _ in open(out)) >= expected, 30, "the arrivals")
    os.killpg(sub.pid, signal.SIGINT)
    sub.wait(10)
    graph.stop()
    arrivals = [float(x) for x in open(out).read().split()]
    return [abs((a - arrivals[0]) - i * 0.001) * 1000 for i, a in enumerate(arrivals)]


def pct(values: list[float], p: float) -> float:
    s = sorted(values)
    return s[min(len(s) - 1, int(p * len(s)))]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--play-seconds", type=float, default=5.0)
    ap.add_argument("--only", choices=("record", "play"), help="run one half")
    ap.add_argument("--load", choices=("small", "large"), help="record one load only")
    ap.add_argument("--abba", action="store_true", help="record: reference, ours, ours, reference")
    ap.add_argument("--ours", default=ROOT, help="the checkout whose recorder is ours (default: this one)")
    o = ap.parse_args()
    tmp = tempfile.mkdtemp(prefix="bagbench-")
    talker = compile_roscpp("bag_talker.cpp", os.path.join(tmp, "talker"))
    listener = compile_roscpp("bag_listener.cpp", os.path.join(tmp, "listener"))
    loads = {"small": ("5 x 2000 small msg/s", 5, 2000.0, 0), "large": ("30 msg/s of 1 MB", 1, 30.0, 1 << 20)}
    order = ("reference", "ours", "ours", "reference") if o.abba else ("reference", "ours")
    for key, (label, nodes, rate, pad) in loads.items() if o.only != "play" else ():
        if o.load and key != o.load:
            continue
        cpu = {"reference": 0.0, "ours": 0.0}
        for kind in order:
            lost, seconds = record_run(kind, tmp, talker, nodes, rate, o.seconds, pad, o.ours)
            cpu[kind] += seconds
            print("record %-22s %-9s lost %6d  cpu %6.2f s" % (label, kind, lost, seconds), flush=True)
        print("record %-22s cpu ratio ours/rosbag: %.2f" % (label, cpu["ours"] / max(cpu["reference"], 1e-6)))
    bag = play_bag(tmp, o.play_seconds)
    for kind in ("reference", "ours") if o.only != "record" else ():
        errors = play_run(kind, tmp, listener, bag, int(o.play_seconds * 1000))
        print("play 1 kHz %-9s |error| p50 %.3f ms  p99 %.3f ms  max %.3f ms" % (
            kind, pct(errors, 0.5), pct(errors, 0.99), max(errors)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
