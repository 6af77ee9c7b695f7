#!/usr/bin/env python3
"""A master under a connection flood: `rosmaster --core` and our `launch --core`, side by side.

Each master runs under the stock open-file limit (`--nofile`, 1024 by default,
set with prlimit). A flooder holds `--slow` connections open on it, each with
a request head that never ends (reconnecting whenever the master drops one),
while a legitimate client calls getPid on a fresh connection every
`--interval` seconds, each call bounded by `--call-timeout`. Printed per
master: legitimate calls answered/attempted, the slowest answer, the
connections the flooder held, and the lines the master wrote to stderr.

    PATH=/usr/bin:$PATH python3 benchmarks/flood.py [--slow 3000] [--duration 30] [--nofile 1024]

Loopback only; bounded in connections (at most 10,000) and time (at most 300 s per master).
A master whose command is not installed is skipped.
"""

from __future__ import annotations

import argparse
import os
import resource
import selectors
import shlex
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
import xmlrpc.client

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
HOST = "127.0.0.1"
SLOW_HEAD = b"POST / HTTP/1.1\r\nHost: x\r\nContent-Le"  # never finished


def free_port() -> int:
    with socket.socket() as s:
        s.bind((HOST, 0))
        return s.getsockname()[1]


def get_pid(port: int, timeout: float) -> bool:
    """One legitimate getPid on its own connection; True if answered within `timeout`."""
    body = xmlrpc.client.dumps(("/legit",), "getPid").encode()
    deadline = time.monotonic() + timeout
    try:
        with socket.create_connection((HOST, port), timeout=timeout) as s:
            s.sendall(b"POST / HTTP/1.1\r\nHost: m\r\nContent-Length: %d\r\nConnection: close\r\n\r\n"
                      % len(body) + body)
            data = b""
            while True:
                s.settimeout(max(0.001, deadline - time.monotonic()))
                chunk = s.recv(65536)
                if not chunk:
                    break
                data += chunk
        return xmlrpc.client.loads(data.partition(b"\r\n\r\n")[2])[0][0][0] == 1
    except (OSError, ValueError, xmlrpc.client.Error, IndexError):
        return False


class Flooder(threading.Thread):
    """Keeps `count` half-sent requests open on the master, replacing those it drops."""

    def __init__(self, port: int, count: int):
        super().__init__(daemon=True)
        self.port = port
        self.count = count
        self.stop = threading.Event()
        self.sel = selectors.DefaultSelector()
        self.held = 0
        self.peak = 0
        self.dropped = 0

    def run(self) -> None:
        while not self.stop.is_set():
            while self.held < self.count and not self.stop.is_set():
                s = socket.socket()
                s.settimeout(0.2)
                try:
                    s.connect((HOST, self.port))
                    s.sendall(SLOW_HEAD)
                except OSError:
                    s.close()
                    break  # the backlog is full: look at the dropped ones, then retry
                s.setblocking(False)
                self.sel.register(s, selectors.EVENT_READ)
                self.held += 1
                self.peak = max(self.peak, self.held)
            for key, _ in self.sel.select(timeout=0.05):
                s = key.fileobj
                try:
                    gone = not s.recv(65536)
                except BlockingIOError:
                    gone = False
                except OSError:
                    gone = True
                if gone:
                    self.sel.unregister(s)
                    s.close()
                    self.held -= 1
                    self.dropped += 1
        for key in list(self.sel.get_map().values()):
            key.fileobj.close()
        self.sel.close()


def run_one(label: str, command: str, args: argparse.Namespace) -> dict:
    port = free_port()
    env = dict(os.environ, ROS_MASTER_URI="http://%s:%d/" % (HOST, port), ROS_IP=HOST)
    env.pop("ROS_HOSTNAME", None)
    env.setdefault("PYTHONPATH", ROOT)
    with tempfile.TemporaryDirectory() as home:
        env["ROS_HOME"] = env["ROS_LOG_DIR"] = home
        argv = ["prlimit", "--nofile=%d:%d" % (args.nofile, args.nofile)] + shlex.split(
            command.replace("{port}", str(port)))
        err_path = os.path.join(home, "stderr")
        with open(err_path, "wb") as err:
            proc = subprocess.Popen(argv, env=env, stdout=subprocess.DEVNULL, stderr=err)
        try:
            deadline = time.monotonic() + 30
            while not get_pid(port, 1.0):
                if time.monotonic() > deadline or proc.poll() is not None:
                    return {"label": label, "error": "master did not start"}
                time.sleep(0.1)
            flooder = Flooder(port, args.slow)
            flooder.start()
            attempted = answered = 0
            slowest = 0.0
            end = time.monotonic() + args.duration
            while time.monotonic() < end:
                t0 = time.monotonic()
                attempted += 1
                if get_pid(port, args.call_timeout):
                    answered += 1
                    slowest = max(slowest, time.monotonic() - t0)
                time.sleep(max(0.0, args.interval - (time.monotonic() - t0)))
            flooder.stop.set()
            flooder.join(10)
        finally:
            proc.terminate()
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        with open(err_path, "rb") as f:
            err_data = f.read()
    return {"label": label, "answered": answered, "attempted": attempted, "slowest_s": round(slowest, 3),
            "flood_peak": flooder.peak, "flood_dropped": flooder.dropped,
            "stderr_lines": err_data.count(b"\n"), "stderr_bytes": len(err_data),
            "stderr_head": err_data.decode(errors="replace").splitlines()[:args.show_stderr]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--slow", type=int, default=3000, help="half-sent connections held (at most 10000)")
    ap.add_argument("--duration", type=float, default=30.0, help="seconds of flood per master (at most 300)")
    ap.add_argument("--nofile", type=int, default=1024, help="open-file limit (soft and hard) of each master")
    ap.add_argument("--interval", type=float, default=0.5, help="seconds between legitimate calls")
    ap.add_argument("--call-timeout", type=float, default=1.0, help="a legitimate call answered later fails")
    ap.add_argument("--show-stderr", type=int, default=0, metavar="N", help="print the first N lines of stderr")
    ap.add_argument("--master", action="append", metavar="LABEL=COMMAND",
                    help="master command ({port} substituted); default: rosmaster and ours")
    args = ap.parse_args()
    args.slow = max(1, min(args.slow, 10000))
    args.duration = max(1.0, min(args.duration, 300.0))
    masters = args.master or ["rosmaster=rosmaster --core -p {port}",
                              "ours=%s -m launcher --core -p {port}" % sys.executable]
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    want = args.slow + 256
    if soft < want:  # the flooder's own sockets
        try:
            resource.setrlimit(resource.RLIMIT_NOFILE, (min(want, hard), hard))
        except (ValueError, OSError):
            pass
    for spec in masters:
        label, _, command = spec.partition("=")
        if not command:
            label, command = command or spec, spec
        if shutil.which(shlex.split(command)[0]) is None:
            print("%-10s skipped: %s is not installed" % (label, shlex.split(command)[0]))
            continue
        r = run_one(label, command, args)
        if "error" in r:
            print("%-10s %s" % (label, r["error"]))
            continue
        print("%-10s legitimate calls answered %d/%d (slowest %.3f s); flood held up to %d connections, "
              "%d dropped by the master; master stderr %d lines (%d bytes)"
              % (label, r["answered"], r["attempted"], r["slowest_s"], r["flood_peak"], r["flood_dropped"],
                 r["stderr_lines"], r["stderr_bytes"]), flush=True)
        for line in r["stderr_head"]:
            print("    | " + line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
