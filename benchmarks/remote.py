#!/usr/bin/env python3
"""Nodes on other machines: 20 roscpp nodes over two test hosts, our `launch` beside Debian's `roslaunch`.

The test hosts are those of the tests (tests/testhosts.py: network namespaces
with their own sshd, each root with a home of its own; root needed). Each
launcher is started with a launch file that puts half the nodes on each host.
Measured per run, alternating the commands (ABBA):

- start: from the launcher's start until every node is registered with the master;
- stop: from SIGINT until the launcher has exited and nothing but sshd is left on the hosts.

    PATH=/usr/bin:$PATH python3 benchmarks/remote.py [--nodes 20] [--reps 3] [--master running|own]

`--master running` (the default): a Debian rosmaster runs here on the test subnet before each
launch, as when `roscore` runs in another terminal. `--master own`: none runs, and each launcher
starts its own, as `roslaunch robot.launch` does on a robot (roslaunch runs rosmaster and rosout as
processes; ours are in the launcher).

Where the time goes (2-core machine, ours/ours, 20 nodes, running master). Start, ~0.45 s: ~0.07 s
until ssh runs (the interpreter, imports, the load); ~0.2 s for two ssh logins at once (the key
exchange is sntrup761x25519, ~45 ms of CPU a side); ~0.06 s until our child registers (Python and
asyncio's imports); ~0.05 s to spawn 10 nodes and see them register. roslaunch connects to the hosts
one after the other (paramiko), and its child is slower to start.

Stop, ~0.45 s: almost all of it is the nodes' own exit, which the benchmark measures too ("nodes
alone", with a running master: the same nodes started over ssh in sessions of their own, SIGINTed
from here with no launcher). A roscpp node takes 0.2-0.3 s to exit after SIGINT, and while it
unregisters from the master its main thread spins on the disabled callback queue (~0.1 s of CPU
each). Each node has a session of its own (roslaunch's os.setsid, our start_new_session), so the
kernel's sched_autogroup gives each spinning node a CPU share equal to the whole master's: 20 of
them on 2 cores take ~0.42 s (~0.34 s when they share one session). That is ~0.5x of roslaunch's
stop before any launcher does anything; ours adds ~0.04 s (the shutdown calls, ~20 ms to end the
sessions), roslaunch's child ~0.4 s (it stops its nodes ten at a time, in two waves).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import select
import shlex
import signal
import statistics
import subprocess
import sys
import tempfile
import time
import xmlrpc.client

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tests"))
from testhosts import TestHosts  # noqa: E402

from common import ROS_PATH, debian_rosmaster  # (this folder is on the path of a script run from it)

NODE_CPP = """#include <ros/ros.h>
int main(int argc, char** argv) { ros::init(argc, argv, "bench_node"); ros::NodeHandle nh; ros::spin(); return 0; }
"""


def build_package(root: str) -> str:
    pkg = os.path.join(root, "remote_bench")
    os.makedirs(pkg)
    with open(os.path.join(pkg, "package.xml"), "w") as f:
        f.write('<?xml version="1.0"?><package format="2"><name>remote_bench</name><version>0.0.1</version>'
                '<description>bench</description><maintainer email="b@example.com">b</maintainer>'
                '<license>BSD</license></package>\n')
    src = os.path.join(root, "node.cpp")
    with open(src, "w") as f:
        f.write(NODE_CPP)
    flags = subprocess.check_output(["pkg-config", "--cflags", "--libs", "roscpp"], text=True).split()
    subprocess.run(["g++", "-O1", "-o", os.path.join(pkg, "node"), src] + flags, check=True)
    return root


def registered(master: xmlrpc.client.ServerProxy) -> set[str]:
    """Nodes publishing /rosout (every roscpp node does, once registered)."""
    try:
        _code, _msg, (pubs, _subs, _srvs) = master.getSystemState("/bench")
    except OSError:
        return set()
    return next((set(nodes) for topic, nodes in pubs if topic == "/rosout"), set())


def leftovers(hosts: TestHosts) -> list[str]:
    return [line for h in hosts.hosts for line in h.process_lines() if "sshd" not in line]


def wait_exit(proc: subprocess.Popen, timeout: float) -> None:
    """Wait for the exit, seen when it happens: Popen.wait(timeout) polls with sleeps that grow to 50 ms,
    which would add ~25 ms to every stop measured."""
    fd = os.pidfd_open(proc.pid)
    try:
        if not select.select([fd], [], [], timeout)[0]:
            raise subprocess.TimeoutExpired(proc.args, timeout)
    finally:
        os.close(fd)
    proc.wait()


def run_once(argv: list[str], env: dict[str, str], names: set[str], master_uri: str, hosts: TestHosts,
             timeout: float = 120.0) -> tuple[float, float]:
    master = xmlrpc.client.ServerProxy(master_uri)
    t0 = time.monotonic()
    proc = subprocess.Popen(argv, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    try:
        while not names <= registered(master):
            if time.monotonic() - t0 > timeout or proc.poll() is not None:
                raise RuntimeError("%s: nodes not all registered (%d/%d)"
                                   % (argv[0], len(names & registered(master)), len(names)))
            time.sleep(0.02)
        started = time.monotonic() - t0
        t1 = time.monotonic()
        proc.send_signal(signal.SIGINT)
        wait_exit(proc, timeout)
        while leftovers(hosts):
            if time.monotonic() - t1 > timeout:
                raise RuntimeError("%s: processes left on the hosts: %s" % (argv[0], leftovers(hosts)))
            time.sleep(0.02)
        return started, time.monotonic() - t1
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        # unregister what a killed run left, so that the next run starts from an empty graph
        for name in registered(master):
            if name != "/rosout":
                try:
                    master.unregisterPublisher(name, "/rosout", "http://gone:1/")
                except OSError:
                    pass


def nodes_alone_stop(hosts: TestHosts, node: str, count: int, master_uri: str, timeout: float = 60.0) -> float:
    """The floor of any launcher's stop: the same nodes, started over ssh in sessions of their own (as
    roslaunch and our child start them), SIGINTed from here with no launcher: seconds until all exited."""
    master = xmlrpc.client.ServerProxy(master_uri)
    sessions, pidfds = [], []
    try:
        for h in hosts.hosts:
            script = "".join("setsid %s __name:=n%02d </dev/null >/dev/null 2>&1 & " % (node, i)
                             for i in range(count) if 1 + i % 2 == h.index) + "exec sleep 3600"
            sessions.append(subprocess.Popen(
                hosts.ssh_command().split() + ["-T", h.address, "%s env ROS_MASTER_URI=%s sh -c %s" % (
                    h.env_loader, master_uri, shlex.quote(script))],
                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        deadline = time.monotonic() + timeout
        while not {"/n%02d" % i for i in range(count)} <= registered(master):
            if time.monotonic() > deadline:
                raise RuntimeError("nodes alone: not all registered")
            time.sleep(0.02)
        pids = [int(line.split()[0]) for h in hosts.hosts for line in h.process_lines() if line.split()[1] == node]
        pidfds = [os.pidfd_open(pid) for pid in pids]
        t0 = time.monotonic()
        for pid in pids:
            os.kill(pid, signal.SIGINT)
        waiting = set(pidfds)
        while waiting:
            ready = select.select(list(waiting), [], [], max(0.0, deadline - time.monotonic()))[0]
            if not ready:
                raise RuntimeError("nodes alone: not all exited")
            waiting -= set(ready)
        return time.monotonic() - t0
    finally:
        for fd in pidfds:
            os.close(fd)
        for h in hosts.hosts:  # what did not exit, and the sessions' sleeps
            for line in h.process_lines():
                if "sshd" not in line:
                    try:
                        os.kill(int(line.split()[0]), signal.SIGKILL)
                    except OSError:
                        pass
        for p in sessions:
            p.wait()


@contextlib.contextmanager
def running_master(wanted: bool, master_uri: str, port: int, hosts: TestHosts, scratch: str):
    """A Debian rosmaster on the test subnet for the whole benchmark (or, not `wanted`, none)."""
    if not wanted:
        yield
        return
    menv = dict(os.environ, ROS_IP=hosts.gateway, ROS_HOME=os.path.join(scratch, "mh"))
    with debian_rosmaster(port, menv, master_uri):
        yield


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--nodes", type=int, default=20)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--master", choices=("running", "own"), default="running",
                    help="a Debian rosmaster runs before each launch, or each launcher starts its own")
    opts = ap.parse_args()
    why = TestHosts.unavailable()
    if why:
        print("cannot run: %s" % why, file=sys.stderr)
        return 2
    scratch = tempfile.mkdtemp(prefix="launcher-remote-bench-")
    pkgs = build_package(os.path.join(scratch, "pkgs"))
    # `launch` on the hosts' PATH: our launcher as the child too (LAUNCHER_REMOTE_PROGRAM=launch)
    bin_dir = os.path.join(scratch, "bin")
    os.makedirs(bin_dir)
    with open(os.path.join(bin_dir, "launch"), "w") as f:
        f.write('#!/bin/sh\nPYTHONPATH=%s exec %s -m launcher "$@"\n' % (ROOT, sys.executable))
    os.chmod(os.path.join(bin_dir, "launch"), 0o755)
    with TestHosts(2, env={"ROS_PACKAGE_PATH": pkgs, "PATH": bin_dir + ":" + ROS_PATH}) as hosts:
        port = 11000 + os.getpid() % 1000
        master_uri = "http://%s:%d/" % (hosts.gateway, port)
        with running_master(opts.master == "running", master_uri, port, hosts, scratch):
            machines = "".join('  <machine name="h%d" address="%s" env-loader="%s"/>\n'
                               % (h.index, h.address, h.env_loader) for h in hosts.hosts)
            nodes = "".join('  <node machine="h%d" pkg="remote_bench" type="node" name="n%02d"/>\n'
                            % (1 + i % 2, i) for i in range(opts.nodes))
            launch = os.path.join(scratch, "remote.launch")
            with open(launch, "w") as f:
                f.write("<launch>\n%s%s</launch>\n" % (machines, nodes))
            names = {"/n%02d" % i for i in range(opts.nodes)}
            env = hosts.env(ROS_MASTER_URI=master_uri, PATH=ROS_PATH, HOME=hosts.home,
                            ROS_PACKAGE_PATH=pkgs, ROS_LOG_DIR=os.path.join(scratch, "log"),
                            PYTHONPATH=ROOT)
            ours = [sys.executable, "-m", "launcher", "--skip-log-check", launch]
            commands = {"roslaunch": (["roslaunch", "--skip-log-check", launch], env),
                        "launch": (ours, env),  # Debian's roslaunch as the child
                        "launch/launch": (ours, dict(env, LAUNCHER_REMOTE_PROGRAM="launch"))}
            results: dict[str, list[tuple[float, float]]] = {k: [] for k in commands}
            alone: list[float] = []
            for rep in range(opts.reps):
                order = list(commands) if rep % 2 == 0 else list(reversed(commands))
                for label in order:
                    argv, cenv = commands[label]
                    start, stop = run_once(argv, cenv, names, master_uri, hosts)
                    results[label].append((start, stop))
                    print("rep %d %-13s start %.2f s  stop %.2f s" % (rep, label, start, stop), flush=True)
                if opts.master == "running":
                    alone.append(nodes_alone_stop(hosts, os.path.join(pkgs, "remote_bench", "node"), opts.nodes,
                                                  master_uri))
                    print("rep %d nodes alone   stop %.2f s" % (rep, alone[-1]), flush=True)
            base = results["roslaunch"]
            print("%s master, %d nodes, %d reps:" % (opts.master, opts.nodes, opts.reps))
            for label, runs in results.items():
                s = statistics.median(r[0] for r in runs)
                t = statistics.median(r[1] for r in runs)
                ratio = ""
                if label != "roslaunch":
                    ratio = "  (x%.2f start, x%.2f stop of roslaunch)" % (
                        s / statistics.median(r[0] for r in base), t / statistics.median(r[1] for r in base))
                print("%-13s median start %.2f s, stop %.2f s%s" % (label, s, t, ratio))
            if alone:
                a = statistics.median(alone)
                print("nodes alone   median stop %.2f s (x%.2f of roslaunch's stop: no launcher goes below it)"
                      % (a, a / statistics.median(r[1] for r in base)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
