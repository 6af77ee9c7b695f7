#!/usr/bin/env python3
"""A master with hung subscribers: how long a real subscriber waits for its publisher, ours against rosmaster.

Issue 21's probe. `--hung` subscribers of /hung are listening sockets that
never accept (what a stopped or wedged node looks like from the master: the
kernel completes the connection, nobody reads); then a publisher registers on
/hung, then a real rospy subscriber of /other registers, then a real rospy
publisher of /other. Printed per master and hung count: the seconds from the
publisher's registration to the subscriber's first message (latched: it comes
right after the connection, so this is the publisherUpdate's delay plus a
TCPROS connection), bounded by `--wait` (both rospy nodes start beforehand
and register when told: right after the publisher of /hung, while the master
is calling the hung subscribers); how many of the hung subscribers the
master called; and the latency of the master's other calls (getPid, lookupNode,
getParam, hasParam: a client on a keep-alive connection every 5 ms) from the
hung publisher's registration on, over 3 s at least. tests/master/test_hung_subscribers.py
runs this scenario once against ours and checks the figures.

    PATH=/usr/bin:$PATH python3 benchmarks/hung_subscribers.py [--hung 0 --hung 1000] [--wait 10] [--reps 3]

Loopback only; bounded in sockets (at most 5,000 hung) and time (`--wait`, at most 120 s).
A master whose command is not installed is skipped.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import select
import selectors
import shlex
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import urllib.parse
import xmlrpc.client

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
HOST = "127.0.0.1"
ROS_PYTHON = os.environ.get("ROS_PYTHON", "/usr/bin/python3")

# Each starts (rospy's start-up is half a second of CPU), says "init", and registers when told to on stdin:
# the registrations then come right after the hung subscribers' publisher, while the master calls them.
SUBSCRIBER = r"""
import sys, time, rospy
from std_msgs.msg import String
rospy.init_node("real_sub")
print("init", flush=True)
sys.stdin.readline()
rospy.Subscriber("/other", String, lambda m: print("got %.6f" % time.time(), flush=True))
print("subscribed", flush=True)
rospy.spin()
"""

PUBLISHER = r"""
import sys, time, rospy
from std_msgs.msg import String
rospy.init_node("real_pub")
print("init", flush=True)
sys.stdin.readline()
t0 = time.time()
pub = rospy.Publisher("/other", String, queue_size=1, latch=True)
print("registered %.6f" % t0, flush=True)
pub.publish(String("x"))
rospy.spin()
"""


def free_port() -> int:
    with socket.socket() as s:
        s.bind((HOST, 0))
        return s.getsockname()[1]


class RawClient:
    """A keep-alive XML-RPC client doing as little as possible (its own time is not the master's)."""

    def __init__(self, uri: str):
        u = urllib.parse.urlsplit(uri)
        self.sock = socket.create_connection((u.hostname, u.port), timeout=10)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.buf = b""

    def call(self, method: str, params: tuple) -> tuple:
        body = xmlrpc.client.dumps(params, method).encode()
        self.sock.sendall(b"POST / HTTP/1.1\r\nHost: m\r\nContent-Type: text/xml\r\nContent-Length: %d\r\n\r\n"
                          % len(body) + body)
        buf = self.buf
        while b"\r\n\r\n" not in buf:
            buf += self._recv()
        head, _, rest = buf.partition(b"\r\n\r\n")
        length = int(head.lower().split(b"content-length:", 1)[1].split(b"\r\n", 1)[0])
        while len(rest) < length:
            rest += self._recv()
        self.buf = rest[length:]
        return xmlrpc.client.loads(rest[:length])[0][0]

    def _recv(self) -> bytes:
        chunk = self.sock.recv(65536)
        if not chunk:
            raise ConnectionError("master closed the connection")
        return chunk

    def close(self) -> None:
        self.sock.close()


class Prober(threading.Thread):
    """The master's other calls, one every 5 ms on a keep-alive connection; latencies in seconds."""

    def __init__(self, uri: str):
        super().__init__(daemon=True)
        self.client = RawClient(uri)
        self.stop = threading.Event()
        self.latencies: list[float] = []
        self.error: str | None = None

    def run(self) -> None:
        calls = [("getPid", ("/probe",)), ("lookupNode", ("/probe", "/hung_7")),
                 ("getParam", ("/probe", "/rosdistro")), ("hasParam", ("/probe", "/nope"))]
        i = 0
        try:
            while not self.stop.wait(0.005):
                method, args = calls[i % len(calls)]
                i += 1
                t0 = time.perf_counter()
                code = self.client.call(method, args)[0]
                self.latencies.append(time.perf_counter() - t0)
                if code not in (1, -1):
                    raise ValueError("%s answered code %r" % (method, code))
        except (OSError, ValueError, xmlrpc.client.Error) as e:
            self.error = "%s: %s" % (type(e).__name__, e)
        finally:
            self.client.close()


def called(sockets: list[socket.socket], timeout: float) -> int:
    """How many of the never-accepted `sockets` hold a connection (the master called them), waiting up to `timeout`."""
    sel = selectors.DefaultSelector()
    for s in sockets:
        sel.register(s, selectors.EVENT_READ)
    seen = 0
    deadline = time.monotonic() + timeout
    while seen < len(sockets) and time.monotonic() < deadline:
        for key, _ in sel.select(0.1):
            sel.unregister(key.fileobj)  # (it stays readable: looking again would cost this process a CPU)
            seen += 1
    sel.close()
    return seen


def read_line(proc: subprocess.Popen, prefix: str, deadline: float) -> str | None:
    """The first line of `proc`'s stdout starting with `prefix`, or None at `deadline`."""
    while True:
        left = deadline - time.monotonic()
        if left <= 0:
            return None
        # (poll, not select: with a thousand sockets open, this pipe's descriptor is past select's 1024)
        poller = select.poll()
        poller.register(proc.stdout, select.POLLIN)
        if poller.poll(left * 1000):
            line = proc.stdout.readline()
            if not line:
                return None
            if line.startswith(prefix):
                return line


def run_one(label: str, command: str, hung: int, wait: float, min_calls: int = 600) -> dict:
    """One run of the scenario: {"update_s" (None: not within `wait`), "called", "calls", "p99_ms", ...}
    or {"error"}; the other calls are timed `min_calls` times at least."""
    port = free_port()
    uri = "http://%s:%d/" % (HOST, port)
    home = tempfile.mkdtemp(prefix="hung-bench-")
    env = dict(os.environ, ROS_MASTER_URI=uri, ROS_HOME=home, ROS_LOG_DIR=os.path.join(home, "log"), ROS_IP=HOST)
    env.pop("ROS_HOSTNAME", None)
    env["PYTHONPATH"] = ROOT
    procs: list[subprocess.Popen] = []
    sockets: list[socket.socket] = []
    prober = None
    try:
        procs.append(subprocess.Popen(shlex.split(command.replace("{port}", str(port))), env=env,
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                      start_new_session=True))
        deadline = time.monotonic() + 30
        while True:
            try:
                client = RawClient(uri)
                client.call("getPid", ("/bench",))
                break
            except OSError:
                if time.monotonic() > deadline or procs[0].poll() is not None:
                    return {"master": label, "hung": hung, "error": "master did not start"}
                time.sleep(0.05)
        for i in range(hung):
            s = socket.socket()
            s.bind((HOST, 0))
            s.listen(16)  # never accepted: the request sits in the kernel, unanswered
            sockets.append(s)
            client.call("registerSubscriber", ("/hung_%d" % i, "/hung", "std_msgs/String",
                                               "http://%s:%d/" % (HOST, s.getsockname()[1])))
        ros_env = dict(env, PATH="/usr/bin:" + env.get("PATH", ""))
        ros_env.pop("PYTHONPATH")
        sub, pub = (subprocess.Popen([ROS_PYTHON, "-c", script], env=ros_env, stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                                     start_new_session=True) for script in (SUBSCRIBER, PUBLISHER))
        procs += [sub, pub]
        for p in (sub, pub):
            if read_line(p, "init", time.monotonic() + 60) is None:
                return {"master": label, "hung": hung, "error": "a rospy node did not start"}
        prober = Prober(uri)
        prober.start()
        client.call("registerPublisher", ("/hung_pub", "/hung", "std_msgs/String", "http://%s:1/" % HOST))
        sub.stdin.write("go\n")
        sub.stdin.flush()
        if read_line(sub, "subscribed", time.monotonic() + 30) is None:
            return {"master": label, "hung": hung, "error": "the rospy subscriber did not subscribe"}
        pub.stdin.write("go\n")
        pub.stdin.flush()
        registered = read_line(pub, "registered", time.monotonic() + 30)
        if registered is None:
            return {"master": label, "hung": hung, "error": "the rospy publisher did not register"}
        t0 = float(registered.split()[1])
        got = read_line(sub, "got", t0 - time.time() + time.monotonic() + wait)
        delay = float(got.split()[1]) - t0 if got else None
        reached = called(sockets, 10)
        while len(prober.latencies) < min_calls and prober.is_alive():
            time.sleep(0.05)
        prober.stop.set()
        prober.join(10)
        client.close()
    finally:
        if prober is not None:
            prober.stop.set()
        for p in reversed(procs):
            try:
                os.killpg(p.pid, signal.SIGINT)
                p.wait(10)
            except ProcessLookupError:
                pass
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()
        for s in sockets:
            s.close()
        shutil.rmtree(home, ignore_errors=True)
    if prober.error:
        return {"master": label, "hung": hung, "error": "the master's other calls failed: " + prober.error}
    lat = sorted(prober.latencies)
    return {"master": label, "hung": hung, "update_s": None if delay is None else round(delay, 4),
            "called": reached, "calls": len(lat), "p50_ms": round(lat[len(lat) // 2] * 1000, 2),
            "p99_ms": round(lat[int(len(lat) * 0.99)] * 1000, 2), "max_ms": round(lat[-1] * 1000, 2)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--hung", type=int, action="append", help="hung subscribers (repeatable; default 0 and 1000)")
    ap.add_argument("--wait", type=float, default=10.0, help="seconds a subscriber's update may take")
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--master", action="append", metavar="LABEL=COMMAND",
                    help="master command ({port} substituted); default: rosmaster and ours")
    a = ap.parse_args()
    counts = [max(0, min(n, 5000)) for n in (a.hung or [0, 1000])]
    wait = max(1.0, min(a.wait, 120.0))
    masters = a.master or ["rosmaster=rosmaster --core -p {port}",
                           "ours=%s -m launcher --core -p {port}" % sys.executable]
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    want = max(counts) + 256
    if soft < want:  # the hung subscribers' sockets
        resource.setrlimit(resource.RLIMIT_NOFILE, (min(want, hard), hard))
    runs: dict[tuple[str, int], list[dict]] = {}
    for rep in range(a.reps):
        for spec in (masters if rep % 2 == 0 else masters[::-1]):
            label, _, command = spec.partition("=")
            if shutil.which(shlex.split(command)[0]) is None:
                print("%s skipped: %s is not installed" % (label, shlex.split(command)[0]), file=sys.stderr)
                continue
            for hung in counts:
                r = run_one(label, command, hung, wait)
                r["rep"] = rep
                print(json.dumps(r), flush=True)
                runs.setdefault((label, hung), []).append(r)
    print("\n%-10s %6s  %-28s %s" % ("master", "hung", "update delay s (median, max)", "other calls p99 ms (max)"))
    for (label, hung), rs in runs.items():
        ok = [r for r in rs if "error" not in r]
        delays = [r["update_s"] for r in ok]
        if not ok:
            print("%-10s %6d  %s" % (label, hung, rs[0]["error"]))
            continue
        shown = ["> %g" % wait if d is None else "%.3f" % d for d in
                 (sorted(delays, key=lambda d: float("inf") if d is None else d)[len(delays) // 2],
                  None if None in delays else max(delays))]
        print("%-10s %6d  %-28s %.2f (%.2f)" % (label, hung, ", ".join(shown),
                                                  statistics.median(r["p99_ms"] for r in ok),
                                                  max(r["p99_ms"] for r in ok)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
