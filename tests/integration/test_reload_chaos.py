"""Reload under chaos (issue 37): reloads that add a node, remove it and change parameters, one after another,
while the launch's nodes are SIGKILLed at random; afterwards the processes (from /proc) and the master (Debian's
`rosnode list` and `rosparam get /`) are exactly what the file says.

The nodes are real roscpp nodes (tests/integration/nodes/param_node.cpp: each writes the private parameter it
read at start-up to its ~out file, then spins), all with respawn="true", so that a killed node comes back."""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import threading
import time

import pytest
import yaml

from helpers import ROS_PATH, free_port, until
from running import Launcher, compile_roscpp, make_package, node_processes, ros_env
from test_reload import RUN_TIME, flatten

pytestmark = pytest.mark.integration

FIXED = ("a", "b", "c", "d")  # in the file throughout
RELOADS = 120  # add a node, remove it, change parameters: forty times each
KILL_EVERY_S = 0.1  # one node SIGKILLed this often while the reloads run

NODE = ('  <node pkg="rc_tests" type="param_cpp" name="%s" respawn="true" respawn_delay="0.1">\n'
        '    <param name="out" value="$(dirname)/%s.txt"/><param name="value" type="str" value="%s"/>\n  </node>\n')


def launch_text(extra: str | None, value: int) -> str:
    """The file: the fixed nodes (a's private parameter and the global /g being `value`), and `extra`."""
    nodes = [NODE % (name, name, value if name == "a" else 0) for name in FIXED]
    if extra is not None:
        nodes.append(NODE % (extra, extra, "new"))
    return '<launch>\n  <param name="g" value="%d"/>\n%s</launch>\n' % (value, "".join(nodes))


@pytest.fixture
def pkgs(tmp_path, ros_env):
    pkg = make_package(str(tmp_path / "pkgs"), "rc_tests", {})
    compile_roscpp("param_node.cpp", os.path.join(pkg, "param_cpp"))
    return str(tmp_path / "pkgs")


class Chaos:
    """The launch of this test's file and what the test reads of it from outside."""

    def __init__(self, tmp_path, pkgs: str):
        self.tmp = tmp_path
        self.launch = tmp_path / "chaos.launch"
        self.env = ros_env(str(tmp_path), free_port(), pkgs)
        self.ros = dict(self.env, PATH=ROS_PATH + ":" + self.env.get("PATH", ""))  # Debian's tools

    def tool(self, *args: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "launcher.cli.tool"] + list(args), env=self.env,
                              capture_output=True, text=True, timeout=120)

    def reload(self) -> dict:
        r = self.tool("reload", "--json")
        assert r.stdout, r.stderr
        return json.loads(r.stdout)

    def registered(self) -> list[str]:
        out = subprocess.run(["rosnode", "list"], env=self.ros, capture_output=True, text=True, timeout=60).stdout
        return sorted(out.split())

    def params(self) -> dict:
        """The parameters Debian's `rosparam list` names, with their values (`rosparam get /`), less what the
        launch sets at run time. (A removed node's emptied namespace, `/x0: {}`, is no parameter: the master
        keeps it after the deleteParam of its last key, as Debian's rosmaster does, and rosparam list shows
        none.)"""
        out = subprocess.run(["rosparam", "get", "/"], env=self.ros, capture_output=True, text=True, timeout=60,
                             check=True).stdout
        listed = subprocess.run(["rosparam", "list"], env=self.ros, capture_output=True, text=True, timeout=60,
                                check=True).stdout.split()
        values = {k: v for k, v in flatten(yaml.safe_load(out)).items() if not k.startswith(RUN_TIME) and v != {}}
        assert sorted(values) == sorted(k for k in listed if not k.startswith(RUN_TIME))
        return values

    def dump_params(self) -> dict:
        r = subprocess.run([sys.executable, "-m", "launcher", "--dump-params", str(self.launch)], env=self.env,
                           capture_output=True, text=True, timeout=60, check=True)
        return flatten(yaml.safe_load(r.stdout))

    def processes(self) -> dict[str, list[int]]:
        """The launch's live node processes (found in /proc by their __log:= in this test's log directory): node
        name -> pids (two: a node running twice)."""
        return node_processes(self.env["ROS_LOG_DIR"])


class Killer(threading.Thread):
    """SIGKILLs one of the launch's node processes, chosen at random, every KILL_EVERY_S until halted."""

    def __init__(self, chaos: Chaos):
        super().__init__(daemon=True)
        self.chaos = chaos
        self.halt = threading.Event()
        self.killed = 0
        self.rng = random.Random(37)

    def run(self) -> None:
        while not self.halt.wait(KILL_EVERY_S):
            procs = self.chaos.processes()
            if procs:
                try:
                    os.kill(procs[self.rng.choice(sorted(procs))][0], signal.SIGKILL)
                    self.killed += 1
                except OSError:
                    pass


def test_reloads_while_nodes_are_killed_leave_the_processes_and_the_master_as_the_file_says(tmp_path, pkgs):
    chaos = Chaos(tmp_path, pkgs)
    chaos.launch.write_text(launch_text(None, 0))
    launcher = Launcher([str(chaos.launch)], chaos.env, str(tmp_path))

    def running() -> dict[str, int]:
        return {name: len(pids) for name, pids in chaos.processes().items()}
    try:
        until(lambda: running() == dict.fromkeys(FIXED, 1), 60, 0.1, what="the fixed nodes running")
        # the launch's own nodes (rosout, /diagnostics' publisher) are on the master beside the file's
        until(lambda: set(chaos.registered()) >= {"/" + n for n in FIXED}, 60, 0.2, what="the nodes registered")
        own = set(chaos.registered()) - {"/" + n for n in FIXED}
        assert "/rosout" in own
        killer = Killer(chaos)
        killer.start()
        extra, value, answers = None, 0, []
        start = time.monotonic()
        try:
            for i in range(RELOADS):
                kind = i % 3
                if kind == 0:
                    extra = "x%d" % i  # a node added
                elif kind == 1:
                    extra = None  # and removed
                else:
                    value += 1  # a parameter changed: /g (set) and a's private one (a restarts)
                chaos.launch.write_text(launch_text(extra, value))
                t = time.monotonic()
                answer = chaos.reload()
                answers.append(time.monotonic() - t)
                assert answer["ok"] and answer["applied"], answer
                assert launcher.proc.poll() is None, launcher.stderr
        finally:
            killer.halt.set()
            killer.join()
        took = time.monotonic() - start
        assert killer.killed >= RELOADS // 2  # (the chaos was real)
        expected = sorted(FIXED + ((extra,) if extra else ()))

        # the processes: one per node of the file, none of a removed one, none twice
        until(lambda: running() == dict.fromkeys(expected, 1), 60, 0.1,
              what="exactly one process for each of the file's nodes %s" % expected)
        # the master: Debian's rosnode list names them (and the launch's own) and no other
        want = sorted({"/" + n for n in expected} | own)
        try:
            until(lambda: chaos.registered() == want, 30, 0.5, what="rosnode list is %s" % want)
        except AssertionError as e:
            raise AssertionError("%s: %s" % (e, chaos.registered())) from None
        # Debian's rosparam: what a fresh --dump-params of the file says
        on_master = chaos.params()
        assert on_master == chaos.dump_params()
        assert on_master["/g"] == value and on_master["/a/value"] == str(value)
        # each node's current run read its parameters as the file has them
        for name in expected:
            out = tmp_path / ("%s.txt" % name)
            want_value = "new" if name == extra else (str(value) if name == "a" else "0")
            until(lambda: out.exists() and ("private=%s\n" % want_value) in out.read_text(), 30, 0.1,
                  what="%s read value %s" % (name, want_value))
        # the launch's own view agrees
        status = json.loads(chaos.tool("status", "--json").stdout)
        assert sorted(n["name"] for n in status["nodes"]) == ["/" + n for n in expected]
        assert {n["state"] for n in status["nodes"]} == {"running"}
        print("%d reloads in %.1f s (slowest answer %.2f s) while %d nodes were SIGKILLed"
              % (RELOADS, took, max(answers), killer.killed))
    finally:
        launcher.close()
