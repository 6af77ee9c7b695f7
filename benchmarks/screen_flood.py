#!/usr/bin/env python3
"""A 20 MB/s screen flood on a terminal, side by side: the launcher's CPU, the lines lost, out of order or broken.

    python3 benchmarks/screen_flood.py [--rate 20] [--seconds 20] [--nodes 1] [--reps 1]
        [--cmd LABEL=COMMAND ...] [--views none,ui] [--floor] [--stops HZ]

Each run starts a launch under a pty (the terminal a user has: `--views` `ui` also
attaches the live view, `launcher ui` in tmux, before the flood) with `--nodes`
output="screen" nodes; once all are up, each writes `--rate`/`--nodes` MB/s of
numbered 100-byte lines for `--seconds`, in writes that cut lines anywhere, then
exits. This script reads the terminal as fast as it comes (a `cat` into a file)
and afterwards checks every line: `lost` is a line the terminal never showed
whole, `ooo` a whole line after a later one of its node, `broken` a terminal line
made of pieces of flood lines (two nodes' lines mixed mid-line). The launcher's
CPU (user + system, % of one core) is taken from /proc over the flood, from the
moment the nodes start writing to the last node's exit line; the view's own
process is not counted in it. `via Python` is what the launch log's last note
says of the screen relay (output/screen.py): bytes relayed as read, in whole
lines with no per-line work, and those handled line by line (a launcher without
the note: `?`). `CPU%@rate` is the CPU per byte relayed, as % of a core at
`--rate` (a loaded machine's scheduling may hold the flood below its rate: the
pty buffers 20 KiB, a millisecond of it). `--floor` adds a C relay per node (read the node's pty, append
to a file, write the terminal): what the kernel's pty work alone costs.

`--stops HZ` stops the launcher and continues it HZ times a second during the
flood (0.3 ms each), as Ctrl-Z and fg or a sampling profiler do: a write to the
terminal it waits in then ends with part of it taken. Measured 11-29, 500 a
second, PYTHONUNBUFFERED=1 (the launch's stdout the raw descriptor), one node, 10
s: lost lines before (main ddd3348) 11,226 and 85 broken, after (console's
write_all) 0, the C floor 0. (A `--cmd` that names another tree's package by
PYTHONPATH with `-m launcher` must be run from outside this repository: `-m` puts
the current folder first.)

The view's own CPU: measured 11-29 (this machine, 10 s, 2 reps), `launcher ui` read every byte of the flood and
took 89.6 and 90.1% of a core; after the views ask ten times a second for at most 32 KiB of a node's newest output
(`@most`, services/server.py's launcher_output), 10.1 and 10.0%, and the launcher's CPU with the view attached went
from 23.5/25.3 to 20.8/20.8.

Under roslaunch the node writes to the terminal itself (its CPU is the node's);
roslaunch's rosmaster/rosout are separate processes and not counted.

Measured 11-27 on the shared 2-core VM (load 8-12), CPU%@rate, one node, 20 s:
roslaunch 0.4; before (main 0da1a3f) 36.1, with `launcher ui` 30.1, 1 line lost
and 2 broken (a launcher line put in the middle of a node's); after 21.6, with
`launcher ui` 25.7, none lost, out of order or broken, 400 MB relayed as read and
0 line by line; the C floor 18.3, all of it the kernel's (its tty layer: a read of
a pty gives 4 KiB; splice(2) pty -> pipe -> terminal with tee(2) to the file
measured no cheaper). Of ours, the user part is 5 and the system part 16.5.
A second run (2 reps, no view): roslaunch 0.3/0.2, before 28.8/25.3 (1 lost,
1-2 broken), after 23.5/22.5 (none), the floor 22.6/23.2.
Two nodes, 10 s: broken lines roslaunch 10,367 (its nodes' writes cut lines),
before 34,519, after 0. `--journal` (every byte line by line): before 42.8,
after 32.4.
"""

from __future__ import annotations

import argparse
import fcntl
import os
import re
import shlex
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import termios
import threading
import time

from common import ROS_PATH, free_port, tool_command  # (this folder is on the path of a script run from it)

LINE_BYTES = 100
FLOOD = """#!%(python)s
import os, sys, time
name, rate, seconds, go = sys.argv[1], float(sys.argv[2]) * 1e6, float(sys.argv[3]), sys.argv[4]
while not os.path.exists(go):
    time.sleep(0.01)
pad = b"abcdefghijklmnopqrstuvwxyz0123456789" * 4
def line(i):  # %(bytes)d bytes, each line its own (the checker makes them again)
    head = b"%%s %%08d ~" %% (name.encode(), i)
    return head + pad[i %% 36:i %% 36 + %(bytes)d - 2 - len(head)] + b"~\\n"
total = int(rate * seconds) // %(bytes)d
write = (4093, 8191, 1500, 12001)  # sizes that cut lines anywhere, as a block-buffered node does
start, i, k, sent = time.monotonic(), 0, 0, 0
pending, at = b"", 0
while i < total or at < len(pending):
    if sent > (time.monotonic() - start) * rate:  # (paced; a node held back catches up as it can)
        time.sleep(0.001)
        continue
    size = write[k %% 4]
    if len(pending) - at < size and i < total:  # (the next lines made, 500 at a time)
        due = min(total, i + 500)
        pending, at = pending[at:] + b"".join(line(j) for j in range(i, due)), 0
        i = due
    n = os.write(1, pending[at:at + size])
    at += n
    sent += n
    k += 1
""" % {"bytes": LINE_BYTES, "python": sys.executable}
PACKAGE_XML = ('<?xml version="1.0"?>\n<package format="2"><name>bench_flood</name><version>0.0.1</version>'
               '<description>bench</description><maintainer email="b@example.com">b</maintainer>'
               '<license>BSD</license></package>\n')
# the floor: one C relay per node, as little as can be done with a pty in the path
RELAY_C = r"""
#include <errno.h>
#include <poll.h>
#include <unistd.h>
static char buf[1 << 20];
int main(void) {  /* fd 3: the node's pty, fd 4: its log file, fd 1: the terminal */
  struct pollfd p = {3, POLLIN, 0};
  for (;;) {
    if (poll(&p, 1, -1) < 0) continue;
    ssize_t got = 0, n;
    while (got < (ssize_t)sizeof buf && (n = read(3, buf + got, sizeof buf - got)) > 0) got += n;
    if (got == 0) return 0;
    if (write(4, buf, got) < 0) return 1;
    for (ssize_t o = 0; o < got; o += n) if ((n = write(1, buf + o, got - o)) <= 0) return 1;
  }
}
"""


def expected_line(name: bytes, i: int) -> bytes:
    pad = b"abcdefghijklmnopqrstuvwxyz0123456789" * 4
    head = b"%s %08d ~" % (name, i)
    return head + pad[i % 36:i % 36 + LINE_BYTES - 2 - len(head)] + b"~"


def cpu(pid: int) -> tuple[float, float]:
    """(user, system) seconds of `pid` (all its threads)."""
    with open("/proc/%d/stat" % pid) as f:
        fields = f.read().rsplit(")", 1)[1].split()
    tick = os.sysconf("SC_CLK_TCK")
    return int(fields[11]) / tick, int(fields[12]) / tick


def check(path: str, names: list[str], per_node: int) -> dict:
    """What the terminal showed of the flood: lost, out-of-order and broken lines."""
    with open(path, "rb") as f:
        text = f.read().replace(b"\r", b"")
    seen = {n.encode(): set() for n in names}
    last = {n.encode(): -1 for n in names}
    ooo = broken = 0
    flood = re.compile(rb"^(flood\d+) (\d{8}) ~")
    framed = re.compile(rb"^<\d>flood\d+-\d+: ")  # (--journal: the framing journald reads from the stream)
    for line in text.split(b"\n"):
        if b"~" not in line:
            continue
        if line.startswith(b"<"):
            line = framed.sub(b"", line)
        m = flood.match(line)
        if m and m.group(1) in seen and line == expected_line(m.group(1), int(m.group(2))):
            name, i = m.group(1), int(m.group(2))
            if i < last[name]:
                ooo += 1
            last[name] = max(last[name], i)
            seen[name].add(i)
        else:
            broken += 1
    lost = sum(per_node - len(s) for s in seen.values())
    return {"lost": lost, "ooo": ooo, "broken": broken, "bytes": len(text)}


def relay_note(log_dir: str) -> str:
    """The launch log's note on the screen relay (ours after issue 36), else '?'."""
    for root, _, files in os.walk(log_dir):
        for name in files:
            if name.startswith("roslaunch-") and name.endswith(".log"):
                with open(os.path.join(root, name), errors="replace") as f:
                    notes = re.findall(r"screen relay: (\d+) bytes .*, (\d+) line by line", f.read())
                if notes:
                    return "%.1f MB as read, %.1f MB line by line" % tuple(int(n) / 1e6 for n in notes[-1])
    return "?"


class Stopper(threading.Thread):
    """Stops the launcher's processes and continues them `hz` times a second, 0.3 ms each time, as Ctrl-Z and fg or
    a sampling profiler (py-spy) do: a write to the terminal the launcher waits in ends with part of it taken."""

    def __init__(self, pids: list[int], hz: float):
        super().__init__(daemon=True)
        self.pids, self.period, self.done = pids, 1.0 / hz, threading.Event()

    def run(self) -> None:
        while not self.done.is_set():
            self._send(signal.SIGSTOP)
            time.sleep(0.0003)
            self._send(signal.SIGCONT)
            self.done.wait(max(0.0, self.period - 0.0003))

    def _send(self, sig: int) -> None:
        for pid in self.pids:
            try:
                os.kill(pid, sig)
            except ProcessLookupError:
                pass

    def end(self) -> None:
        self.done.set()
        self.join()
        self._send(signal.SIGCONT)


class Terminal:
    """A pty the launch writes to, read as fast as it comes by `cat` into a file."""

    def __init__(self, path: str):
        self.master, self.slave = os.openpty()
        fcntl.ioctl(self.slave, termios.TIOCSWINSZ, struct.pack("HHHH", 50, 200, 0, 0))
        self.path = path
        self.out = open(path, "wb")
        self.cat = subprocess.Popen(["cat"], stdin=self.master, stdout=self.out)

    def wait_for(self, pattern: bytes, count: int, what: str, timeout: float) -> None:
        """Until `pattern` has come `count` times (the file read once, as it grows)."""
        found, pos = 0, 0
        deadline = time.monotonic() + timeout
        while True:
            base = max(0, pos - 300)  # (a match cut by the end of what was read is found whole next time)
            with open(self.path, "rb") as f:
                f.seek(base)
                data = f.read()
            found += sum(1 for m in re.finditer(pattern, data) if base + m.end() > pos)
            pos = base + len(data)
            if found >= count:
                return
            if time.monotonic() > deadline:
                raise SystemExit("no %s within %g s (see %s)" % (what, timeout, self.path))
            time.sleep(0.02)

    def close(self) -> None:
        os.close(self.slave)
        try:
            self.cat.wait(30)
        except subprocess.TimeoutExpired:
            self.cat.kill()
            self.cat.wait()
        os.close(self.master)
        self.out.close()


def one_run(label: str, cmd: str, view: bool, a: argparse.Namespace, scratch: str, rep: int) -> dict:
    run = os.path.join(scratch, "%s-%s-%d" % (label, "ui" if view else "none", rep))
    os.makedirs(run)
    port = free_port()
    go = os.path.join(run, "go")
    env = dict(os.environ, ROS_MASTER_URI="http://127.0.0.1:%d/" % port, ROS_HOME=os.path.join(run, "home"),
               ROS_LOG_DIR=os.path.join(run, "log"), ROS_IP="127.0.0.1", TERM="xterm",
               ROS_PACKAGE_PATH=os.path.join(scratch, "pkgs"))
    env["PATH"] = ROS_PATH + ":" + env.get("PATH", "")
    names = ["flood%d" % (i + 1) for i in range(a.nodes)]
    rate = a.rate / a.nodes
    per_node = int(rate * 1e6 * a.seconds) // LINE_BYTES
    launch = os.path.join(run, "flood.launch")
    with open(launch, "w") as f:
        f.write("<launch>%s</launch>\n" % "".join(
            '<node pkg="bench_flood" type="flood" name="%s" output="screen" args="%s %g %g %s"/>'
            % (n, n, rate, a.seconds, go) for n in names))
    term = Terminal(os.path.join(run, "terminal"))
    if a.journal:  # the launch's stdout is "the journal's stream": its lines framed one by one (output/journal.py)
        st = os.fstat(term.slave)
        env["JOURNAL_STREAM"] = "%d:%d" % (st.st_dev, st.st_ino)
    tmux = ["tmux", "-L", "flood-bench-%d" % os.getpid()]
    procs: list[subprocess.Popen] = []
    pids: list[int] = []
    launcher = None
    stopper = None
    try:
        if cmd == "@floor":
            relay = os.path.join(scratch, "relay")
            for n in names:
                node_m, node_s = os.openpty()
                attrs = termios.tcgetattr(node_s)
                attrs[1] &= ~termios.OPOST
                termios.tcsetattr(node_s, termios.TCSANOW, attrs)
                log = os.open(os.path.join(run, n + "-stdout.log"), os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
                r = subprocess.Popen([relay], stdout=term.slave, stdin=subprocess.DEVNULL, pass_fds=(3, 4),
                                     preexec_fn=lambda m=node_m, lg=log: (os.dup2(m, 100), os.dup2(lg, 101), os.dup2(100, 3),
                                                                         os.dup2(101, 4)))
                procs.append(subprocess.Popen([os.path.join(scratch, "pkgs", "bench_flood", "flood"), n, str(rate),
                                               str(a.seconds), go], stdout=node_s, stderr=node_s))
                os.close(node_m)
                os.close(node_s)
                os.close(log)
                procs.append(r)
                pids.append(r.pid)
            time.sleep(0.5)
        else:
            launcher = subprocess.Popen(shlex.split(cmd) + ["-p", str(port), launch], env=env, stdout=term.slave,
                                        stderr=term.slave, stdin=subprocess.DEVNULL, start_new_session=True)
            procs.append(launcher)
            pids.append(launcher.pid)
            term.wait_for(rb"process\[flood\d+-\d+\]: started", a.nodes, "node start", 120)
        view_pid = None
        if view:
            tool = tool_command(shlex.split(cmd))
            command = "env %s %s ui" % (" ".join(shlex.quote("%s=%s" % kv) for kv in env.items()),
                                        " ".join(shlex.quote(x) for x in tool))
            subprocess.run(tmux + ["new-session", "-d", "-s", "b", "-x", "120", "-y", "40", command], check=True)
            deadline = time.monotonic() + 60
            while view_pid is None:
                shown = subprocess.run(tmux + ["capture-pane", "-p", "-t", "b"], capture_output=True, text=True).stdout
                if "running" in shown:
                    view_pid = int(subprocess.check_output(tmux + ["display-message", "-p", "-t", "b",
                                                                   "#{pane_pid}"]))
                elif time.monotonic() > deadline:
                    raise SystemExit("the view did not show the launch")
                else:
                    time.sleep(0.3)
        time.sleep(1.0)  # (start-up's own work is not measured)
        c0 = [cpu(p) for p in pids]
        v0 = cpu(view_pid) if view_pid else (0.0, 0.0)
        t0 = time.monotonic()
        open(go, "w").close()
        if a.stops:
            stopper = Stopper(pids, a.stops)
            stopper.start()
        if launcher is None:  # the floor's relays: their CPU when they end (at the node's end)
            for p in procs[0::2]:
                p.wait(a.seconds * 10 + 60)
            c1 = []
            for p in procs[1::2]:
                _, status, usage = os.wait4(p.pid, 0)
                p.returncode = os.waitstatus_to_exitcode(status) if hasattr(os, "waitstatus_to_exitcode") else status
                c1.append((usage.ru_utime, usage.ru_stime))
            c0 = [(0.0, 0.0)] * len(c1)
            t1 = time.monotonic()
        else:
            term.wait_for(rb"\[flood\d+-\d+\] process has finished", a.nodes, "node exit", a.seconds * 10 + 60)
            t1 = time.monotonic()
            c1 = [cpu(p) for p in pids]
        if stopper is not None:
            stopper.end()
        v1 = cpu(view_pid) if view_pid else (0.0, 0.0)
        wall = t1 - t0
        user = sum(c[0] for c in c1) - sum(c[0] for c in c0)
        system = sum(c[1] for c in c1) - sum(c[1] for c in c0)
        relayed = rate * a.nodes * a.seconds  # (MB)
        result = {"cpu": 100 * (user + system) / wall, "at_rate": 100 * (user + system) / (relayed / a.rate),
                  "user": 100 * user / wall, "sys": 100 * system / wall,
                  "mbps": rate * a.nodes * a.seconds / wall, "view": 100 * (sum(v1) - sum(v0)) / wall}
    finally:
        if stopper is not None:
            stopper.end()
        subprocess.run(tmux + ["kill-server"], capture_output=True)
        for p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGINT)
        for p in procs:
            try:
                p.wait(60)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        term.close()
    result.update(check(term.path, names, per_node))
    result["python"] = relay_note(os.path.join(run, "log")) if cmd != "@floor" else "-"
    shutil.rmtree(os.path.join(run, "log"), ignore_errors=True)  # (hundreds of MB of copies)
    shutil.rmtree(os.path.join(run, "home"), ignore_errors=True)
    for name in os.listdir(run):
        if name.endswith("-stdout.log"):
            os.unlink(os.path.join(run, name))
    if not a.keep:
        os.unlink(term.path)
    return result


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rate", type=float, default=20.0, help="MB/s of all the nodes together")
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--nodes", type=int, default=1)
    ap.add_argument("--reps", type=int, default=1)
    ap.add_argument("--views", default="none,ui", help="none: no view; ui: `launcher ui` attached (ours only)")
    ap.add_argument("--cmd", action="append", help="LABEL=COMMAND (default: roslaunch and ours)")
    ap.add_argument("--floor", action="store_true", help="also a C relay per node (the kernel's pty work)")
    ap.add_argument("--keep", action="store_true", help="keep each run's terminal text")
    ap.add_argument("--stops", type=float, default=0.0,
                    help="stop and continue the launcher this many times a second during the flood (0: never)")
    ap.add_argument("--journal", action="store_true", help="the terminal passed off as journald's stream "
                    "(JOURNAL_STREAM): the relay frames each line as under systemd without journald's socket")
    a = ap.parse_args()
    here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    cmds = a.cmd or ["roslaunch=roslaunch", "ours=env PYTHONPATH=%s %s -m launcher" % (here, sys.executable)]
    cmds = [tuple(c.split("=", 1)) if "=" in c.split()[0] else (c, c) for c in cmds]
    if a.floor:
        cmds.append(("floor", "@floor"))
    scratch = tempfile.mkdtemp(prefix="screen-flood-")
    try:
        pkg = os.path.join(scratch, "pkgs", "bench_flood")
        os.makedirs(pkg)
        with open(os.path.join(pkg, "package.xml"), "w") as f:
            f.write(PACKAGE_XML)
        with open(os.path.join(pkg, "flood"), "w") as f:
            f.write(FLOOD)
        os.chmod(os.path.join(pkg, "flood"), 0o755)
        if a.floor:
            with open(os.path.join(scratch, "relay.c"), "w") as f:
                f.write(RELAY_C)
            subprocess.run(["cc", "-O2", "-o", os.path.join(scratch, "relay"), os.path.join(scratch, "relay.c")],
                           check=True)
        print("%g MB/s from %d node(s) for %g s on a pty, %d line(s) of %d bytes each; launcher CPU in %% of a core"
              % (a.rate, a.nodes, a.seconds, int(a.rate * 1e6 * a.seconds) // LINE_BYTES, LINE_BYTES))
        if a.stops:
            print("the launcher stopped and continued %g times a second, its stdout %s (PYTHONUNBUFFERED)"
                  % (a.stops, "unbuffered" if os.environ.get("PYTHONUNBUFFERED") else "buffered"))
        print("%-10s %-4s %6s %6s %6s %6s %8s %7s %6s %6s %9s  %s" % (
            "launcher", "view", "CPU%", "user", "sys", "MB/s", "CPU%@rate", "lost", "ooo", "broken", "view CPU%",
            "via Python"))
        for rep in range(a.reps):
            runs = [(label, cmd, view == "ui") for label, cmd in cmds for view in a.views.split(",")
                    if view == "none" or (label != "roslaunch" and cmd != "@floor")]
            for label, cmd, view in (runs if rep % 2 == 0 else list(reversed(runs))):
                r = one_run(label, cmd, view, a, scratch, rep)
                print("%-10s %-4s %6.1f %6.1f %6.1f %6.1f %8.1f %7d %6d %6d %9s  %s"
                      % (label, "ui" if view else "-", r["cpu"], r["user"], r["sys"], r["mbps"], r["at_rate"], r["lost"],
                         r["ooo"],
                         r["broken"], "%.1f" % r["view"] if view else "-", r["python"]), flush=True)
    finally:
        if not a.keep:
            shutil.rmtree(scratch, ignore_errors=True)
        else:
            print("kept in", scratch)
    return 0


if __name__ == "__main__":
    sys.exit(main())
