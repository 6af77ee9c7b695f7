"""Operating a running launch with real rospy/roscpp nodes: status, start/stop/restart, the token, logs,
events, --no-start, the second Ctrl-C, /diagnostics (read by Debian's rostopic), and roslaunch's API
compared with Debian's roslaunch."""

from __future__ import annotations

import json
import os
import re
import signal
import stat
import subprocess
import sys
import time
import xmlrpc.client

import pytest

from helpers import ROS_PATH, ROS_PYTHON, free_port, ignoring, pid_alive, until
from running import (Launcher, RosMaster, compile_roscpp, get_param, kill_leftovers, make_package, master_proxy,
                     master_up, ros_env, write_launch)

pytestmark = pytest.mark.integration

# READY_FILE is written once init_node has returned (a SIGINT during init_node can wedge rospy:
# see test_run_shutdown.py), so that stops in these tests are clean
Spinner = """#!%s
import os, rospy
rospy.init_node("spinner")
if os.environ.get("READY_DIR"):
    open(os.path.join(os.environ["READY_DIR"], rospy.get_name().replace("/", "_") + "-%%d" %% os.getpid()), "w").close()
rospy.spin()
""" % ROS_PYTHON
Ticker = """#!%s
import rospy
rospy.init_node("ticker")
n = 0
while not rospy.is_shutdown():
    n += 1
    rospy.loginfo("tick %%d", n)
    rospy.sleep(0.2)
""" % ROS_PYTHON
IgnoreIntTerm = "#!/bin/sh\ntrap '' INT TERM\nexec sleep 1000\n"
# holds 64 MiB until the file release exists in $READY_DIR, then frees it
Holder = """#!/usr/bin/env python3
import os, time
block = bytearray(64 << 20)
for i in range(0, len(block), 4096):
    block[i] = 1
while not os.path.exists(os.path.join(os.environ["READY_DIR"], "release")):
    time.sleep(0.05)
del block
time.sleep(1000)
"""


@pytest.fixture
def pkgs(tmp_path, ros_env):
    pkg = make_package(str(tmp_path / "pkgs"), "op_tests",
                       {"spinner": Spinner, "ticker": Ticker, "ignore_int_term": IgnoreIntTerm,
                        "holder": Holder})
    compile_roscpp("param_node.cpp", os.path.join(pkg, "param_cpp"))
    return str(tmp_path / "pkgs")


def tool(env: dict, *args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "launcher.cli.tool"] + list(args), env=env, capture_output=True,
                          text=True, timeout=timeout)


def status(env: dict, starting: bool = False) -> dict:
    """The nodes by name; with `starting`, {} while the launch is not up yet (exit status 3)."""
    r = tool(env, "status", "--json")
    if starting and r.returncode == 3:
        return {}
    assert r.returncode == 0, r.stderr
    return {n["name"]: n for n in json.loads(r.stdout)["nodes"]}


def ready(tmp_path, name: str, pid: int) -> bool:
    return os.path.exists(tmp_path / "ready" / ("%s-%d" % (name.replace("/", "_"), pid)))


def start_launch(tmp_path, pkgs, body: str, *args: str) -> tuple[Launcher, dict]:
    os.makedirs(tmp_path / "ready", exist_ok=True)
    env = ros_env(str(tmp_path), free_port(), pkgs)
    env["READY_DIR"] = str(tmp_path / "ready")
    launch = write_launch(str(tmp_path), body)
    return Launcher(list(args) + [launch], env, str(tmp_path)), env


def running_ready(tmp_path, env, names) -> dict:
    """Wait until every node in `names` runs and its rospy init is complete; the status."""
    def check():
        st = status(env, starting=True)
        return st if st and all(st[n]["state"] == "running" and ready(tmp_path, n, st[n]["pid"]) for n in names) \
            else None
    return until(check, 60, 0.2, what="nodes %s running and initialized" % (names,))


def test_status_reports_real_pids_and_restart_counts(tmp_path, pkgs):
    lp, env = start_launch(tmp_path, pkgs, """
      <node pkg="op_tests" type="spinner" name="py" respawn="true"/>
      <node pkg="op_tests" type="param_cpp" name="cpp"><param name="out" value="%s/cpp.txt"/></node>
    """ % tmp_path)
    try:
        until(lambda: os.path.exists(tmp_path / "cpp.txt"), 60, what="roscpp node up")
        st = running_ready(tmp_path, env, ["/py"])
        pids = lp.started_pids()
        assert st["/py"]["pid"] == pids["py-2"] and st["/cpp"]["pid"] == pids["cpp-3"]
        assert st["/py"]["restarts"] == 0 and st["/cpp"]["state"] == "running"
        os.kill(pids["py-2"], signal.SIGKILL)
        st = until(lambda: (lambda s: s if s["/py"]["restarts"] == 1 and s["/py"]["state"] == "running" else None)(
            status(env)), 30, 0.2, what="respawn seen in status: %s" % lp.stdout[-2000:])
        assert st["/py"]["pid"] == lp.started_pids()["py-2"] != pids["py-2"]
        assert st["/py"]["exit_signal"] is None  # a running node shows its run, the exit is in the events
        table = tool(env, "status")
        assert table.returncode == 0
        row = [line.split() for line in table.stdout.splitlines() if line.startswith("/py ")][0]
        # (REG: its new run registers a moment after it runs)
        assert [row[1], row[3], row[5]] == ["running", str(st["/py"]["pid"]), "1"] and row[2] in ("yes", "no")
        events = tool(env, "events", "--json")
        lines = [json.loads(line) for line in events.stdout.splitlines()]
        assert {"node": "/py", "state": "respawning", "exit_signal": 9}.items() <= \
            [e for e in lines if e["state"] == "respawning"][0].items()
    finally:
        lp.close()


def test_stop_start_restart_by_name_glob_and_regex(tmp_path, pkgs):
    lp, env = start_launch(tmp_path, pkgs, """
      <node pkg="op_tests" type="spinner" name="a"/>
      <group ns="g">
        <node pkg="op_tests" type="spinner" name="b" respawn="true"/>
        <node pkg="op_tests" type="spinner" name="c"/>
      </group>
    """)
    try:
        before = running_ready(tmp_path, env, ["/a", "/g/b", "/g/c"])
        r = tool(env, "stop", "/g/*")
        assert r.returncode == 0, r.stderr
        assert r.stdout.split("\n")[:2] == ["stopped /g/b", "stopped /g/c"]
        st = status(env)
        assert st["/g/b"]["state"] == st["/g/c"]["state"] == "stopped"  # /g/b respawns on exit, not after a stop
        assert not pid_alive(before["/g/b"]["pid"]) and not pid_alive(before["/g/c"]["pid"])
        assert st["/a"]["state"] == "running" and st["/a"]["pid"] == before["/a"]["pid"]
        assert master_proxy(int(env["ROS_MASTER_URI"].rsplit(":", 1)[1].strip("/"))).lookupNode("/t", "/g/b")[0] != 1

        r = tool(env, "start", "g/.*")  # a regex (as a glob it names nothing)
        assert r.returncode == 0 and r.stdout.split() == ["started", "/g/b", "started", "/g/c"], r.stderr
        after = running_ready(tmp_path, env, ["/g/b", "/g/c"])
        assert after["/g/b"]["pid"] != before["/g/b"]["pid"] and after["/g/b"]["restarts"] == 1
        assert after["/a"]["pid"] == before["/a"]["pid"]

        r = tool(env, "restart", "a")  # a name
        assert r.returncode == 0 and r.stdout == "restarted /a\n", r.stderr
        again = running_ready(tmp_path, env, ["/a"])
        assert again["/a"]["pid"] != before["/a"]["pid"] and not pid_alive(before["/a"]["pid"])
        assert again["/g/b"]["pid"] == after["/g/b"]["pid"] and again["/g/c"]["pid"] == after["/g/c"]["pid"]

        r = tool(env, "stop", "/nothing*")
        assert r.returncode == 1 and "no node matches [/nothing*]" in r.stderr
        r = tool(env, "logs", "/nosuch")
        assert r.returncode == 1 and "unknown node [/nosuch]" in r.stderr
        r = tool(env, "restart", "a", "--uri", "http://127.0.0.1:%d/" % free_port())
        assert r.returncode == 3 and "does not answer" in r.stderr
    finally:
        lp.close()


def test_mutating_call_without_the_token_is_refused(tmp_path, pkgs):
    lp, env = start_launch(tmp_path, pkgs, '<node pkg="op_tests" type="spinner" name="a"/>')
    try:
        running_ready(tmp_path, env, ["/a"])
        info = json.loads(tool(env, "status", "--json").stdout)
        assert stat.S_IMODE(os.stat(info["token_file"]).st_mode) == 0o600
        api = xmlrpc.client.ServerProxy(info["uri"])
        for verb in ("stop", "start", "restart"):
            with pytest.raises(xmlrpc.client.Fault) as e:
                getattr(api, verb + "_nodes")("not-the-token", "/a")
            assert e.value.faultCode == 2 and "needs this run's token" in e.value.faultString
        wrong = tmp_path / "wrong-token"
        wrong.write_text("0123\n")
        r = tool(env, "stop", "a", "--token-file", str(wrong))
        assert r.returncode == 4 and "needs this run's token" in r.stderr
        r = tool(env, "stop", "a", "--token-file", str(tmp_path / "missing"))
        assert r.returncode == 4 and "cannot read the run's token" in r.stderr
        st = status(env)
        assert st["/a"]["state"] == "running" and st["/a"]["pid"] == lp.started_pids()["a-2"]
        # with the token (what `launcher` reads from the file) it is obeyed
        with open(info["token_file"]) as f:
            assert api.stop_nodes(f.read().strip(), "/a")[2] == ["/a"]
        assert status(env)["/a"]["state"] == "stopped"
    finally:
        lp.close()


def test_logs_follow_a_screen_node_and_a_log_node(tmp_path, pkgs):
    lp, env = start_launch(tmp_path, pkgs, """
      <node pkg="op_tests" type="ticker" name="scr" output="screen"/>
      <node pkg="op_tests" type="ticker" name="lg" output="log"/>
    """)
    followers = []
    try:
        lp.wait_output(r"process\[lg-3\]: started")
        for node in ("/scr", "/lg"):
            out = open(tmp_path / ("follow%s.txt" % node.replace("/", "_")), "w")
            followers.append((node, out, subprocess.Popen([sys.executable, "-m", "launcher.cli.tool", "logs", "-f", node],
                                                          env=env, stdout=out, stderr=subprocess.STDOUT)))
        import re

        def ticks(node):
            with open(tmp_path / ("follow%s.txt" % node.replace("/", "_"))) as f:
                return [int(n) for n in re.findall(r"tick (\d+)", f.read())]
        for node, _, _ in followers:
            first = until(lambda: ticks(node), 60, 0.2, what="%s's output followed" % node)
            # it keeps following: later ticks arrive while the node runs
            until(lambda: max(ticks(node)) >= max(first) + 3, 30, 0.2, what="%s's new output followed" % node)
        r = tool(env, "logs", "lg", "-n", "2")
        assert r.returncode == 0 and len(r.stdout.splitlines()) == 2 and "tick" in r.stdout
    finally:
        for _, out, proc in followers:
            proc.send_signal(signal.SIGINT)
            proc.wait(10)
            out.close()
        lp.close()


def test_no_start_then_launcher_start(tmp_path, pkgs):
    lp, env = start_launch(tmp_path, pkgs, """
      <param name="shared/value" value="set"/>
      <node pkg="op_tests" type="spinner" name="a"/>
      <node pkg="op_tests" type="spinner" name="b"/>
    """, "--no-start")
    try:
        port = int(env["ROS_MASTER_URI"].rsplit(":", 1)[1].strip("/"))
        st = until(lambda: (lambda s: s if len(s) == 2 else None)(status(env, starting=True)) if master_up(port) and get_param(port, "/shared/value")
                   else None, 30, 0.2, what="launch up with its parameters")
        assert st["/a"]["state"] == st["/b"]["state"] == "stopped" and st["/a"]["pid"] is None
        assert "started with pid" not in lp.stdout
        r = tool(env, "start", "a")
        assert r.returncode == 0, r.stderr
        st = running_ready(tmp_path, env, ["/a"])
        assert st["/a"]["pid"] == lp.started_pids()["a-2"] and st["/b"]["state"] == "stopped"
    finally:
        lp.close()


def test_launcher_start_of_a_fatal_node_gives_it_all_its_retries_again(tmp_path, pkgs):
    """As supervisorctl's start of a FATAL program: the failure count starts afresh, so the node gets
    respawn_max_retries restarts again before it is FATAL once more (not one try)."""
    make_package(pkgs, "crash_tests", {"crash": "#!/bin/sh\necho crashing\nexit 3\n"})
    lp, env = start_launch(tmp_path, pkgs, """
      <node pkg="crash_tests" type="crash" name="crash" respawn="true" respawn_delay="0.1" respawn_max_retries="2"/>
      <node pkg="op_tests" type="spinner" name="keep"/>
    """)
    try:
        fatal = lambda: (lambda s: s if s.get("/crash", {}).get("state") == "fatal" else None)(  # noqa: E731
            status(env, starting=True))
        st = until(fatal, 60, 0.2, what="crash FATAL")
        assert st["/crash"]["failures"] == 3 and st["/crash"]["restarts"] == 2, st["/crash"]
        r = tool(env, "start", "crash")
        assert r.returncode == 0, r.stderr
        st = until(lambda: (lambda s: s if s["/crash"]["restarts"] > 2 and s["/crash"]["state"] == "fatal" else None)(
            status(env)), 60, 0.2, what="crash FATAL again")
        # three more runs (the start and two respawns), the count again from 0 to 3
        assert st["/crash"]["restarts"] == 5 and st["/crash"]["failures"] == 3, st["/crash"]
        assert lp.stderr.count("FATAL: failed 3 starts in a row (respawn_max_retries=2)") == 2, lp.stderr
    finally:
        lp.close()


def test_second_ctrl_c_kills_the_nodes_still_stopping(tmp_path, pkgs):
    lp, env = start_launch(tmp_path, pkgs, """
      <node pkg="op_tests" type="ignore_int_term" name="stubborn"/>
      <node pkg="op_tests" type="ignore_int_term" name="stubborn2"/>
    """)
    try:
        lp.wait_output(r"process\[stubborn2-3\]: started")
        pids = lp.started_pids()
        # (started is spawned: a loaded machine may not have run their `trap` yet, and the first SIGINT ends them)
        until(lambda: all(ignoring(pid, signal.SIGINT, signal.SIGTERM) for pid in pids.values()), 30,
              what="both nodes ignoring SIGINT and SIGTERM")
        lp.signal(signal.SIGINT)
        lp.wait_output(r"\[stubborn-2\] killing on exit")
        t0 = time.monotonic()
        lp.signal(signal.SIGINT)
        assert lp.wait(30) == 0
        assert time.monotonic() - t0 < 5.0  # not the 15 s + 2 s of the escalation
        assert not pid_alive(pids["stubborn-2"]) and not pid_alive(pids["stubborn2-3"])
        assert "second stop signal: killing 2 node(s) still stopping with SIGKILL: stubborn2-3, stubborn-2" \
            in lp.stderr or "second stop signal: killing 2 node(s) still stopping with SIGKILL: stubborn-2, " \
            "stubborn2-3" in lp.stderr
    finally:
        lp.close()


def test_diagnostics_read_by_rostopic_echo(tmp_path, pkgs):
    lp, env = start_launch(tmp_path, pkgs, """
      <node pkg="op_tests" type="spinner" name="a"/>
      <group ns="g"><node pkg="op_tests" type="spinner" name="b"/></group>
    """)
    try:
        running_ready(tmp_path, env, ["/a", "/g/b"])
        ros = dict(env, PATH=ROS_PATH)
        echo = subprocess.run(["rostopic", "echo", "-n", "1", "/diagnostics"], env=ros, capture_output=True,
                              text=True, timeout=60)
        assert echo.returncode == 0, echo.stderr
        out = echo.stdout
        assert 'name: "/a"' in out and 'name: "/g/b"' in out and "level: 0" in out and 'message: "running"' in out
        assert 'value: "%d"' % lp.started_pids()["a-2"] in out
    finally:
        lp.close()
    lp, env = start_launch(tmp_path, pkgs, '<node pkg="op_tests" type="spinner" name="a"/>', "--no-diagnostics")
    try:
        running_ready(tmp_path, env, ["/a"])
        topics = subprocess.run(["rostopic", "list"], env=dict(env, PATH=ROS_PATH), capture_output=True, text=True,
                                timeout=60).stdout.split()
        assert "/rosout" in topics and "/diagnostics" not in topics
    finally:
        lp.close()


def _diagnostics(env: dict) -> str:
    echo = subprocess.run(["rostopic", "echo", "-n", "1", "/diagnostics"], env=dict(env, PATH=ROS_PATH),
                          capture_output=True, text=True, timeout=60)
    assert echo.returncode == 0, echo.stderr
    return echo.stdout


def test_over_a_limit_shows_in_status_events_and_diagnostics(tmp_path, pkgs):
    """memory_limit (on_limit="warn"): while over it, /diagnostics (read by Debian's rostopic) says WARN naming the
    limit and the value, `launcher status` shows it (text and JSON), and the events file has a line for the
    crossing and one for the return under it, each with the node's host."""
    lp, env = start_launch(tmp_path, pkgs, """
      <node pkg="op_tests" type="holder" name="holder" memory_limit="32MiB"/>
      <node pkg="op_tests" type="spinner" name="a"/>
    """, "--monitor-period", "0.2")
    try:
        st = until(lambda: (lambda s: s if s.get("/holder", {}).get("over_limit") else None)(status(env, True)), 60,
                   0.2, what="holder over its memory_limit")
        assert st["/holder"]["over_limit"] == {"memory_limit": 32 << 20} and st["/a"]["over_limit"] == {}
        assert st["/holder"]["state"] == "running" and st["/holder"]["restarts"] == 0
        table = tool(env, "status").stdout.splitlines()
        assert table[1].split()[-2:] == ["OVER", "LIMIT"]
        row = [line for line in table if line.startswith("/holder ")][0]
        assert re.search(r"memory_limit 32MiB \(uses \d+(\.\d)?MB\)$", row), table
        assert [line for line in table if line.startswith("/a ")][0].endswith(" -")
        out = _diagnostics(env)
        assert re.search(r'level: 1\s+name: "/holder"\s+message: "running, over memory_limit 32MiB '
                         r'\(uses \d+(\.\d)?MB\)"', out), out
        assert re.search(r'key: "memory_limit"\s+value: "33554432"', out), out
        (tmp_path / "ready" / "release").touch()
        until(lambda: status(env)["/holder"]["over_limit"] == {}, 60, 0.2, what="holder back under its limit")
        assert "OVER LIMIT" not in tool(env, "status").stdout
        out = _diagnostics(env)
        assert re.search(r'level: 0\s+name: "/holder"\s+message: "running"', out), out
        events = [json.loads(line) for line in tool(env, "events", "--json").stdout.splitlines()]
        limit = [(e["node"], e["host"], e["state"], e["over_limit"], e["reason"].split(":")[0])
                 for e in events if "memory_limit" in e["reason"]]
        assert limit == [("/holder", "localhost", "running", {"memory_limit": 32 << 20}, "over memory_limit"),
                         ("/holder", "localhost", "running", {}, "back under memory_limit")]
        text = tool(env, "events").stdout
        assert re.search(r"/holder running pid \d+ restarts 0 over memory_limit \(over memory_limit: uses ", text), text
        assert " on localhost" not in text  # a local node's host goes without saying
    finally:
        lp.close()


def _api_answers(uri: str, node: str | None = "a-2") -> dict:
    api = xmlrpc.client.ServerProxy(uri)
    answers = {"list_processes": api.list_processes(), "get_node_names": api.get_node_names(),
               "unknown": api.process_info("nosuch"), "pid": api.get_pid()[0]}
    if node:
        info = api.process_info(node)
        info[2].pop("env", None)
        info[2].pop("pid", None)
        info[2].pop("run_id", None)
        info[2]["args"] = [a for a in info[2]["args"] if not a.startswith("__log:=")]
        answers["process_info"] = info
    for core in ("master", "rosout-1"):
        try:
            answers[core] = api.process_info(core)
        except xmlrpc.client.Fault as e:
            answers[core] = "fault %d %s" % (e.faultCode, e.faultString)
    return answers


def _core_answers_agree(ours: dict, theirs: dict, argv: list[str], started_master: bool) -> None:
    """process_info of the master and rosout-1 (taken out of both answers): as Debian's roslaunch, but for the
    in-process pid and command line (the launcher's own), respawn (never apart from the launch) and Debian's
    fault for the master (it marshals os.environ, an object: see LaunchServer._core_info)."""
    pid = ours.pop("launcher_pid", None)
    theirs.pop("launcher_pid", None)
    ours = {core: ours.pop(core) for core in ("master", "rosout-1")}
    theirs = {core: theirs.pop(core) for core in ("master", "rosout-1")}
    if not started_master:
        assert ours["master"] == theirs["master"] == ours["rosout-1"] == theirs["rosout-1"] == \
            [-1, "no process by that name", {}]
        return
    assert theirs["master"] == "fault 1 <class 'TypeError'>:dictionary key must be string"
    code, msg, rosout = theirs["rosout-1"]
    assert (code, msg, rosout["respawn"], rosout["pid"] != pid) == (1, "process info", True, True)
    for name, expected in (("rosout-1", dict(rosout, respawn=False)),
                           ("master", dict(rosout, name="master", package="rosmaster", required=True, respawn=False,
                                           log_output=False))):
        code, msg, info = ours[name]
        assert (code, msg, info["pid"], bool(info["run_id"])) == (1, "process info", pid, True)
        assert info["args"] == argv
        for key in ("pid", "args", "env", "run_id"):
            info.pop(key), expected.pop(key)
        assert info == expected


def test_api_answers_as_debian_roslaunch(tmp_path, pkgs):
    body = """
      <node pkg="op_tests" type="spinner" name="a"/>
      <group ns="g"><node pkg="op_tests" type="spinner" name="b" respawn="true"/></group>
      <node pkg="op_tests" type="spinner" name="c"/>
    """
    answers = {}
    for which in ("roslaunch", "ours"):
        port = free_port()
        env = ros_env(str(tmp_path / which), port, pkgs)
        env["READY_DIR"] = str(tmp_path / "ready")
        os.makedirs(tmp_path / "ready", exist_ok=True)
        launch = write_launch(str(tmp_path), body, "%s.launch" % which)
        if which == "roslaunch":
            proc = subprocess.Popen(["roslaunch", launch, "-p", str(port)], env=dict(env, PATH=ROS_PATH),
                                    stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        else:
            lp = Launcher([launch, "-p", str(port)], env, str(tmp_path))
        try:
            uris = until(lambda: (lambda v: v if v and len(v.get("uris", {})) else None)(master_up(port) and get_param(port, "/roslaunch")),
                         60, 0.2, what="%s registered on its master" % which)["uris"]
            (key, uri), = uris.items()
            assert key == "host_127_0_0_1__%s" % uri.rsplit(":", 1)[1].strip("/")
            api = xmlrpc.client.ServerProxy(uri)
            until(lambda: sum(1 for f in os.listdir(tmp_path / "ready")) >= (3 if which == "roslaunch" else 6), 60,
                  0.2, what="nodes up")
            b_pid = api.process_info("g/b-3")[2]["pid"]
            c_pid = api.process_info("c-4")[2]["pid"]
            os.kill(b_pid, signal.SIGKILL)  # respawned: active, spawned twice
            os.kill(c_pid, signal.SIGKILL)  # dead
            until(lambda: api.process_info("g/b-3")[2].get("spawn_count") == 2 and api.list_processes()[2][1], 30,
                  0.2, what="%s saw the deaths" % which)
            answers[which] = _api_answers(uri)
            answers[which]["launcher_pid"] = api.get_pid()[2]
        finally:
            _stop(proc if which == "roslaunch" else lp)
    ours, theirs = answers["ours"], answers["roslaunch"]
    _core_answers_agree(ours, theirs, lp.proc.args, started_master=True)
    assert ours == theirs


def _stop(p) -> None:
    """Ctrl-C for Debian's tool (a Popen in a session of its own) or ours (a Launcher), and wait for it."""
    if isinstance(p, Launcher):
        p.close()
    else:
        os.killpg(p.pid, signal.SIGINT)
        p.wait(30)


def _registered_api(port: int) -> str:
    """The URI of the one launch registered on the master, its key checked as roslaunch's."""
    uris = until(lambda: (lambda v: v if v and len(v.get("uris", {})) else None)(master_up(port) and get_param(
        port, "/roslaunch")), 60, 0.2, what="a launch registered on the master")["uris"]
    (key, uri), = uris.items()
    assert key == "host_127_0_0_1__%s" % uri.rsplit(":", 1)[1].strip("/")
    return uri


def test_core_serves_roslaunch_api_as_debian_roscore(tmp_path, pkgs):
    """`launch --core` registers and serves roslaunch's API as roscore does; a launch on a running master lists
    neither the master nor rosout, as roslaunch's; `launcher status` finds a bare core and says it has no nodes."""
    launch = write_launch(str(tmp_path), '<node pkg="op_tests" type="spinner" name="a"/>')
    os.makedirs(tmp_path / "ready", exist_ok=True)
    answers = {}
    for which in ("roscore", "ours"):
        port = free_port()
        env = ros_env(str(tmp_path / which), port, pkgs)
        env["READY_DIR"] = str(tmp_path / "ready")
        if which == "roscore":
            core = subprocess.Popen(["roscore", "-p", str(port)], env=dict(env, PATH=ROS_PATH), stdout=subprocess.DEVNULL,
                                    stderr=subprocess.DEVNULL, start_new_session=True)
        else:
            core = Launcher(["--core", "-p", str(port)], env, str(tmp_path))
        try:
            uri = _registered_api(port)
            api = xmlrpc.client.ServerProxy(uri)
            until(lambda: api.get_node_names()[2] == ["master", "rosout-1"], 30, 0.2, what="%s's core processes" % which)
            answers[which] = _api_answers(uri, node=None)
            answers[which]["launcher_pid"] = api.get_pid()[2]
            if which == "ours":
                st = tool(env, "status")
                assert st.returncode == 0 and st.stdout.splitlines()[1:] == ["no nodes"], st.stdout + st.stderr
                assert json.loads(tool(env, "status", "--json").stdout)["nodes"] == []
            # a launch on the running master: its own API lists neither the master nor rosout
            xmlrpc.client.ServerProxy("http://127.0.0.1:%d/" % port).deleteParam("/test", "/roslaunch")
            if which == "roscore":
                proc = subprocess.Popen(["roslaunch", launch], env=dict(env, PATH=ROS_PATH), stdout=subprocess.DEVNULL,
                                        stderr=subprocess.DEVNULL, start_new_session=True)
            else:
                lp = Launcher([launch], env, str(tmp_path))
            try:
                uri = _registered_api(port)
                until(lambda: xmlrpc.client.ServerProxy(uri).get_node_names()[2] == ["a-1"], 60, 0.2,
                      what="%s's launch running" % which)
                answers[which + " launch"] = _api_answers(uri, node="a-1")
            finally:
                _stop(proc if which == "roscore" else lp)
        finally:
            _stop(core)
    ours, theirs = answers["ours"], answers["roscore"]
    _core_answers_agree(ours, theirs, core.proc.args, started_master=True)
    assert ours == theirs
    ours, theirs = answers["ours launch"], answers["roscore launch"]
    _core_answers_agree(ours, theirs, [], started_master=False)
    assert ours == theirs


CLIENT = """
import socket, sys, xmlrpc.client
class Transport(xmlrpc.client.Transport):
    def make_connection(self, host):
        conn = super().make_connection(host)
        conn.source_address = (sys.argv[2], 0)
        return conn
try:
    print(xmlrpc.client.ServerProxy(sys.argv[1], transport=Transport()).getPid("/outsider")[0])
except (OSError, xmlrpc.client.ProtocolError) as e:
    print("refused: %r" % e)
"""


@pytest.fixture
def netns(tmp_path):
    """A network namespace on a veth pair: this machine is 10.231.77.1, clients are .2 and .3 (not ours)."""
    if os.geteuid() != 0 or subprocess.run(["ip", "netns", "list"], capture_output=True).returncode != 0:
        pytest.skip("needs root and iproute2 to make a network namespace")
    name = "launcher-op-%d" % os.getpid()
    host_if, ns_if = "lop%dh" % (os.getpid() % 10000), "lop%dn" % (os.getpid() % 10000)
    steps = [["ip", "netns", "add", name],
             ["ip", "link", "add", host_if, "type", "veth", "peer", "name", ns_if],
             ["ip", "link", "set", ns_if, "netns", name],
             ["ip", "addr", "add", "10.231.77.1/29", "dev", host_if],
             ["ip", "link", "set", host_if, "up"],
             ["ip", "-n", name, "addr", "add", "10.231.77.2/29", "dev", ns_if],
             ["ip", "-n", name, "addr", "add", "10.231.77.3/29", "dev", ns_if],
             ["ip", "-n", name, "link", "set", ns_if, "up"],
             ["ip", "-n", name, "link", "set", "lo", "up"]]
    try:
        for step in steps:
            r = subprocess.run(step, capture_output=True, text=True)
            if r.returncode != 0:
                pytest.skip("cannot make a network namespace: %s: %s" % (" ".join(step), r.stderr.strip()))
        yield name
    finally:
        subprocess.run(["ip", "link", "del", host_if], capture_output=True)
        subprocess.run(["ip", "netns", "del", name], capture_output=True)


def test_master_allow_refuses_clients_from_other_networks(tmp_path, netns):
    port = free_port()
    env = dict(os.environ)
    for key in ("ROS_IP", "ROS_HOSTNAME", "ROS_MASTER_URI"):
        env.pop(key, None)  # the master listens on every interface
    env.update(ROS_HOME=str(tmp_path / "home"), ROS_LOG_DIR=str(tmp_path / "log"))
    lp = Launcher(["--core", "-p", str(port), "--allow", "10.231.77.2/32"], env, str(tmp_path))
    try:
        until(lambda: master_up(port), 30, what="master up")
        lp.wait_output(r"master answers only clients from loopback, this machine and: 10\.231\.77\.2/32")

        def from_outside(source: str) -> str:
            return subprocess.run(["ip", "netns", "exec", netns, sys.executable, "-c", CLIENT,
                                   "http://10.231.77.1:%d/" % port, source], capture_output=True, text=True,
                                  timeout=30).stdout.strip()
        assert from_outside("10.231.77.2") == "1"  # allowed: served
        refused = from_outside("10.231.77.3")
        # closed unanswered (reset, broken pipe or an empty reply): never an XML-RPC answer or fault
        assert refused.startswith("refused:"), refused
        assert master_proxy(port).getPid("/local")[0] == 1  # this machine is always served
    finally:
        lp.close()


def test_several_launches_on_one_master(tmp_path, pkgs):
    master = RosMaster(str(tmp_path))
    env = ros_env(str(tmp_path), master.port, pkgs)
    env["READY_DIR"] = str(tmp_path / "ready")
    os.makedirs(tmp_path / "ready", exist_ok=True)
    one = Launcher([write_launch(str(tmp_path), '<node pkg="op_tests" type="spinner" name="one"/>', "one.launch")],
                   env, str(tmp_path))
    two = Launcher([write_launch(str(tmp_path), '<node pkg="op_tests" type="spinner" name="two"/>', "two.launch")],
                   env, str(tmp_path))
    try:
        until(lambda: len((get_param(master.port, "/roslaunch") or {}).get("uris", {})) == 2, 60, 0.2,
              what="both launches registered")
        r = tool(env, "status")
        assert r.returncode == 2 and "2 launches use the master" in r.stderr and "--launch" in r.stderr
        assert "(pid %d)" % one.pid in r.stderr and "(pid %d)" % two.pid in r.stderr
        r = tool(env, "status", "--json", "--launch", str(two.pid))
        assert r.returncode == 0 and [n["name"] for n in json.loads(r.stdout)["nodes"]] == ["/two"]
        one.close()
        # the launch that ended took its key off the master: the other is found alone again
        until(lambda: len(get_param(master.port, "/roslaunch")["uris"]) == 1, 30, 0.2, what="key removed")
        r = tool(env, "status", "--json")
        assert r.returncode == 0 and json.loads(r.stdout)["pid"] == two.pid
    finally:
        one.close()
        two.close()
        master.stop()


def test_completion_offers_the_running_launchs_node_names(tmp_path, pkgs):
    lp, env = start_launch(tmp_path, pkgs, """
      <node pkg="op_tests" type="spinner" name="arm_driver"/>
      <node pkg="op_tests" type="spinner" name="arm_camera"/>
      <node pkg="op_tests" type="spinner" name="base"/>
    """)
    try:
        until(lambda: len(status(env, starting=True)) == 3, 60, 0.2, what="the launch answers")
        for line in ("launcher restart /arm", "launcher logs /arm_c"):
            r = tool(env, "__complete", line)
            expected = ["/arm_camera", "/arm_driver"] if line.endswith("/arm") else ["/arm_camera"]
            assert r.returncode == 0 and r.stdout.split() == expected, (line, r.stdout, r.stderr)
    finally:
        lp.close()


def _registered_count(port: int) -> int:
    return len(((master_up(port) and get_param(port, "/roslaunch")) or {}).get("uris", {}))


def test_debian_roscore_beside_a_launch_and_a_killed_one(tmp_path, pkgs):
    """Debian's roscore registers under /roslaunch/uris too (it is a roslaunch run), and a launch killed with
    kill -9 leaves its key behind: neither is a candidate, and `launcher` uses the one launch of ours that runs,
    without asking. A name almost right gets the close one; once the launch has ended (roscore still up),
    status reads the run's end from its log directory."""
    port = free_port()
    env = ros_env(str(tmp_path), port, pkgs)
    env["READY_DIR"] = str(tmp_path / "ready")
    os.makedirs(tmp_path / "ready", exist_ok=True)
    core = subprocess.Popen(["roscore", "-p", str(port)], env=dict(env, PATH=ROS_PATH), stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    killed = lp = None
    try:
        until(lambda: _registered_count(port) == 1, 60, 0.2, what="roscore registered")
        killed = Launcher([write_launch(str(tmp_path), '<node pkg="op_tests" type="spinner" name="gone"/>',
                                        "gone.launch")], env, str(tmp_path))
        killed.wait_output(r"process\[gone-1\]: started", 60)
        until(lambda: _registered_count(port) == 2, 30, 0.2, what="the launch to kill registered")
        os.kill(killed.pid, signal.SIGKILL)
        killed.wait(10)
        lp = Launcher([write_launch(str(tmp_path), '<group ns="r2"><node pkg="op_tests" type="spinner" name="talker"/>'
                                    '</group>', "r2.launch")], env, str(tmp_path))
        until(lambda: _registered_count(port) == 3, 60, 0.2, what="the launch registered beside roscore")
        st = running_ready(tmp_path, env, ["/r2/talker"])  # (`launcher status --json`, exit status 0)
        assert list(st) == ["/r2/talker"]
        r = tool(env, "status")
        assert r.returncode == 0 and "launch http://" in r.stdout and "(pid %d," % lp.pid in r.stdout, r.stderr

        r = tool(env, "stop", "talker")
        assert r.returncode == 1 and r.stderr == "launcher: no node matches [talker]; did you mean /r2/talker?\n"
        r = tool(env, "logs", "talkr")
        assert r.returncode == 1 and r.stderr.endswith("; did you mean /r2/talker?\n"), r.stderr
        assert status(env)["/r2/talker"]["state"] == "running"
        r = tool(env, "stop", "/r2/talker")
        assert r.returncode == 0 and r.stdout == "stopped /r2/talker\n", r.stderr
        run_id = json.loads(tool(env, "status", "--json").stdout)["run_id"]

        lp.close()  # roscore goes on: the launch's end is read from the run's log directory
        r = tool(env, "status")
        assert r.returncode == 3, r.stdout + r.stderr
        assert r.stderr == "", r.stderr  # (the last run has ended: that no launch runs on roscore goes without saying)
        assert re.match(r"the last run, %s, ended at \d{4}-\d\d-\d\d \d\d:\d\d:\d\d \(stopped by SIGINT\)\n" % run_id,
                        r.stdout), r.stdout
        rows = {line.split()[0]: line.split() for line in r.stdout.splitlines()[3:]}
        assert rows["/r2/talker"][1:3] == ["stopped", "-"] and rows["/gone"][1] == "running", r.stdout
    finally:
        for launch in (lp, killed):
            if launch is not None:
                launch.close()
        _stop(core)


# a roscpp node (rosconsole colours every line, into a file too) and a rospy one
TICKING = """
  <node pkg="op_tests" type="info_cpp" name="cpp" output="log">
    <env name="ROSCONSOLE_STDOUT_LINE_BUFFERED" value="1"/>
  </node>
  <node pkg="op_tests" type="spinner" name="py" respawn="true"/>
"""


def test_logs_keep_colours_only_for_a_terminal_or_with_color(tmp_path, pkgs):
    compile_roscpp("info_node.cpp", os.path.join(pkgs, "op_tests", "info_cpp"))
    lp, env = start_launch(tmp_path, pkgs, TICKING)
    try:
        until(lambda: "tick 3" in tool(env, "logs", "cpp").stdout, 60, 0.2, what="the roscpp node's output")
        r = tool(env, "logs", "cpp", "-n", "2")
        assert r.returncode == 0 and "tick" in r.stdout and "\x1b" not in r.stdout, repr(r.stdout)
        with open(status(env)["/cpp"]["stdout_log"]) as f:
            assert "\x1b[0m[ INFO]" in f.read()  # (what the node wrote)
        r = tool(env, "logs", "cpp", "-n", "2", "--color")
        assert r.returncode == 0 and r.stdout.count("\x1b[0m[ INFO]") == 2, repr(r.stdout)
        r = tool(env, "logs", "cpp", "-n", "2", "--color=never")
        assert r.returncode == 0 and r.stdout.count("[ INFO]") == 2 and "\x1b" not in r.stdout, repr(r.stdout)
    finally:
        lp.close()


def test_after_the_launch_ended_status_events_and_logs_read_the_last_run(tmp_path, pkgs):
    """A finished run: `launcher status`, `events` and `logs` say it is the last run and when it ended (or that
    it ended without a word, killed), each node's state at the end, and its output; `--run` reads an earlier
    run; a roslaunch run as the latest is said to be one."""
    compile_roscpp("info_node.cpp", os.path.join(pkgs, "op_tests", "info_cpp"))
    lp, env = start_launch(tmp_path, pkgs, TICKING)
    try:
        running_ready(tmp_path, env, ["/py"])
        first = json.loads(tool(env, "status", "--json").stdout)["run_id"]
        until(lambda: "tick 3" in tool(env, "logs", "cpp").stdout, 60, 0.2, what="the roscpp node's output")
    finally:
        lp.close()  # Ctrl-C: the launch stops by itself, with its master

    r = tool(env, "status")
    # the launch has ended (its master with it): said on stdout, with no word about the master on stderr
    assert r.returncode == 3 and r.stderr == "", r.stderr
    headline, logs_line = r.stdout.splitlines()[:2]
    # (the reason is the events file's last line, launch_ended)
    assert re.fullmatch(r"the last run, %s, ended at \d{4}-\d\d-\d\d \d\d:\d\d:\d\d \(stopped by SIGINT\)" % first,
                        headline), headline
    assert logs_line == "its logs: %s" % (tmp_path / "log" / first)
    rows = {line.split()[0]: line.split() for line in r.stdout.splitlines()[3:]}
    assert rows["/py"][1:3] == rows["/cpp"][1:3] == ["stopped", "-"], r.stdout
    r = tool(env, "events")
    assert r.returncode == 0 and r.stderr == headline + "\n", r.stderr  # (one line: how the run ended)
    assert re.search(r"/py stopped pid \d+", r.stdout) and re.search(r"/cpp running pid \d+", r.stdout), r.stdout
    r = tool(env, "logs", "cpp", "-n", "-1")
    assert r.returncode == 0 and "tick 3" in r.stdout and "\x1b" not in r.stdout and r.stderr == headline + "\n"

    lp = Launcher(lp.proc.args[3:], env, str(tmp_path))  # the same launch again, then killed
    try:
        st = running_ready(tmp_path, env, ["/py"])
        second = json.loads(tool(env, "status", "--json").stdout)["run_id"]
        os.kill(lp.pid, signal.SIGKILL)
        assert lp.wait(10) == -signal.SIGKILL
    finally:
        lp.close()
    r = tool(env, "status")
    assert r.returncode == 3 and r.stderr == "", r.stderr
    assert re.match(r"the last run, %s, ended without a word after its last event at [-\d: ]+: its launch "
                    r"\(pid %d\) was killed\n" % (second, lp.pid), r.stdout), r.stdout
    # its nodes went with it (the launch's watchdog kills them): stopped, never `running` with a dead pid
    until(lambda: not pid_alive(st["/py"]["pid"]), 10, 0.1, what="the killed launch's node gone")
    rows = {line.split()[0]: line.split() for line in r.stdout.splitlines()[3:]}
    assert rows["/py"][1:3] == rows["/cpp"][1:3] == ["stopped", "-"], r.stdout
    nodes = {n["name"]: n for n in json.loads(tool(env, "status", "--json").stdout)["nodes"]}
    assert {(n["state"], n["reason"]) for n in nodes.values()} == {("stopped", "the launch was killed")}, nodes
    r = tool(env, "status", "--run", first)
    assert r.returncode == 0 and r.stdout.startswith("the run, %s, ended at " % first) and r.stderr == ""

    # Debian's roslaunch, with its own master, is the latest run
    port = int(env["ROS_MASTER_URI"].rsplit(":", 1)[1].strip("/"))
    proc = subprocess.Popen(["roslaunch", lp.proc.args[-1]], env=dict(env, PATH=ROS_PATH),
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        until(lambda: _registered_count(port) == 1, 60, 0.2, what="roslaunch registered")
    finally:
        _stop(proc)
        kill_leftovers(str(tmp_path))  # (its master, when the SIGINT came while roslaunch was starting it)
    r = tool(env, "status")
    # one line on stdout says so (status 3: nothing of ours runs); stderr, in one line, why no launch was read
    # (its master gone, or still going with roslaunch's key on it)
    assert r.returncode == 3 and re.fullmatch(r"the last run, [-\w]+, is roslaunch's \(or roscore's\), not a run of "
                                              r"`launch`: it has no launcher-events.jsonl, .*\n", r.stdout), r.stdout
    assert r.stderr.startswith("launcher: ") and r.stderr.count("\n") == 1, r.stderr
    # --json says the same as one JSON object: a script reading the status gets JSON whatever the run is
    r = tool(env, "status", "--json")
    said = json.loads(r.stdout)
    assert r.returncode == 3 and said["error"].startswith("the last run, %s, is roslaunch's" % said["run_id"])
    assert os.path.basename(said["log_dir"]) == said["run_id"] and os.path.isdir(said["log_dir"])


Crasher = "#!/bin/sh\nsleep 0.5\nexit 3\n"


def test_a_crash_looping_nodes_last_exit_shows_while_it_runs_again(tmp_path, pkgs):
    """Why does it keep restarting? A node exiting 3 every 0.5 s under respawn: each of ten samples 0.3 s apart,
    mostly while it runs again, has last_exit_code 3 (exit_code is the current run's), and so has the table's
    LAST EXIT column."""
    make_package(pkgs, "crash_tests", {"crasher": Crasher})
    lp, env = start_launch(tmp_path, pkgs, '<node pkg="crash_tests" type="crasher" name="crasher" respawn="true"/>')
    try:
        until(lambda: status(env, starting=True).get("/crasher", {}).get("restarts", 0) >= 1, 60, 0.2,
              what="the crasher restarted once")
        states = set()
        for _ in range(10):
            r = tool(env, "status", "--json")
            assert r.returncode == 0, r.stderr
            node = {n["name"]: n for n in json.loads(r.stdout)["nodes"]}["/crasher"]
            assert (node["last_exit_code"], node["last_exit_signal"]) == (3, None), node
            assert node["last_exit_at"] <= time.time()
            states.add(node["state"])
            if node["state"] == "running":
                assert node["exit_code"] is None  # (the current run's)
            table = tool(env, "status")
            row = [line.split() for line in table.stdout.splitlines() if line.startswith("/crasher ")][0]
            assert row[6:8] == ["code", "3"], table.stdout  # (after NODE STATE REG PID UPTIME RESTARTS)
            time.sleep(0.3)
        assert "running" in states  # (seen while it runs again, not only between its runs)
    finally:
        lp.close()


def test_a_live_launch_whose_master_does_not_answer_is_warned_about(tmp_path, pkgs):
    """A launch on a separate `launch --core` whose master is stopped (SIGSTOP): it runs, but no call reaches it;
    `launcher status` warns that the master does not answer, and says the launch has not ended."""
    os.makedirs(tmp_path / "ready", exist_ok=True)
    port = free_port()
    env = dict(ros_env(str(tmp_path), port, pkgs), READY_DIR=str(tmp_path / "ready"))
    core = Launcher(["--core", "-p", str(port)], env, str(tmp_path))
    launch = None
    try:
        until(lambda: master_up(port), 60, 0.2, what="the core's master")
        launch = Launcher([write_launch(str(tmp_path), '<node pkg="op_tests" type="spinner" name="py"/>')], env,
                          str(tmp_path))
        running_ready(tmp_path, env, ["/py"])
        assert tool(env, "status").stderr == ""
        os.kill(core.pid, signal.SIGSTOP)
        try:
            r = tool(env, "status")
        finally:
            os.kill(core.pid, signal.SIGCONT)
        assert r.returncode == 3 and r.stderr.startswith("launcher: cannot reach the master at %s" %
                                                         env["ROS_MASTER_URI"]), r.stderr
        assert re.match(r"the last run, [-\w]+, has not ended: its launch \(pid \d+\) still runs, but cannot be "
                        r"reached\n", r.stdout), r.stdout
        assert launch.proc.poll() is None
    finally:
        if launch is not None:
            launch.close()
        core.close()
