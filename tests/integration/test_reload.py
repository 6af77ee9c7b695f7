"""`launcher reload` on a running launch of real rospy and roscpp nodes (issue 23), each reload checked from
outside: the nodes' processes found in /proc by their command lines (`__name:=`, `__log:=` in this test's log
directory), the parameters with Debian's `rosparam get /`, compared with a fresh `--dump-params` of the new
files."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest
import yaml

from helpers import ROS_PATH, ROS_PYTHON, free_port, pid_alive, until
from running import Launcher, compile_roscpp, make_package, node_processes, ros_env

pytestmark = pytest.mark.integration

# READY_DIR gets a file once init_node has returned: a SIGINT during init_node can wedge rospy
# (test_run_shutdown.py), so a node is stopped only once it is ready
Crasher = "#!/bin/sh\nexit 3\n"
Spinner = """#!%s
import os, rospy
rospy.init_node("spinner")
open(os.path.join(os.environ["READY_DIR"], "%%d" %% os.getpid()), "w").close()
rospy.spin()
""" % ROS_PYTHON

BASE = """<launch>
  <arg name="sim" default="true"/>
  <param name="g" value="1"/>
  <node pkg="rl_tests" type="spinner" name="a"><param name="rate" value="1"/></node>
  <node pkg="rl_tests" type="spinner" name="b" args="--x 1"/>
  <node pkg="rl_tests" type="param_cpp" name="cpp">
    <param name="out" value="$(dirname)/cpp.txt"/>
    <rosparam file="$(dirname)/cpp.yaml"/>
  </node>
  <group ns="shared"><rosparam file="$(dirname)/shared.yaml"/></group>
  <node pkg="rl_tests" type="spinner" name="$(anon anon)"/>
  <node if="$(arg sim)" pkg="rl_tests" type="spinner" name="sim"/>
  <node unless="$(arg sim)" pkg="rl_tests" type="spinner" name="real"/>
  <node pkg="rl_tests" type="spinner" name="r" respawn="true" respawn_max_retries="3"/>
</launch>
"""
BASE_NODES = 7  # a, b, cpp, anon, sim, r ... and rosout is the launcher's own


class Run:
    """A launch of BASE (as edited by a test) and what a test reads of it from outside."""

    def __init__(self, tmp_path, pkgs: str):
        self.tmp = tmp_path
        self.ready_dir = tmp_path / "ready"
        self.ready_dir.mkdir()
        self.port = free_port()
        self.env = ros_env(str(tmp_path), self.port, pkgs)
        self.env["READY_DIR"] = str(self.ready_dir)
        self.launch = tmp_path / "r.launch"
        self.launch.write_text(BASE)
        (tmp_path / "cpp.yaml").write_text("gains: {p: 1, i: 2}\n")
        (tmp_path / "shared.yaml").write_text("value: one\n")
        self.launcher = Launcher([str(self.launch)], self.env, str(tmp_path))

    def edit(self, old: str, new: str, file: str = "r.launch") -> None:
        path = self.tmp / file
        text = path.read_text()
        assert old in text, old
        path.write_text(text.replace(old, new))

    def pids(self) -> dict[str, int]:
        """The launch's node processes, found in /proc: ROS node name -> pid (the anonymous one as "anon")."""
        return {("anon" if name.startswith("anon_") else name): pids[-1]
                for name, pids in node_processes(self.env["ROS_LOG_DIR"]).items()}

    def ready(self, expected: set[str]) -> dict[str, int]:
        """Wait until exactly `expected` run, each ready (rospy's init done; the roscpp node wrote its file)."""
        def check():
            pids = self.pids()
            if set(pids) != expected:
                return None
            spinners = [pid for name, pid in pids.items() if name != "cpp"]
            if not all((self.ready_dir / str(pid)).exists() for pid in spinners):
                return None
            return pids
        return until(check, 60, 0.1, what="nodes %s running and ready (launch output: %s)"
                     % (sorted(expected), self.launcher.stdout[-1500:]))

    def tool(self, *args: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "launcher.cli.tool"] + list(args), env=self.env,
                              capture_output=True, text=True, timeout=120)

    def reload(self, *args: str) -> dict:
        r = self.tool("reload", "--json", *args)
        assert r.stdout, r.stderr
        return json.loads(r.stdout)

    def params(self) -> dict:
        """`rosparam get /` with Debian's tool, flattened to key -> value."""
        env = dict(self.env, PATH=ROS_PATH + ":" + self.env.get("PATH", ""))
        out = subprocess.run(["rosparam", "get", "/"], env=env, capture_output=True, text=True, timeout=60,
                             check=True).stdout
        return flatten(yaml.safe_load(out))

    def dump_params(self, *args: str) -> dict:
        r = subprocess.run([sys.executable, "-m", "launcher", "--dump-params", str(self.launch)] + list(args),
                           env=self.env, capture_output=True, text=True, timeout=60, check=True)
        return flatten(yaml.safe_load(r.stdout))

    def assert_params_are_the_files(self, *args: str, runtime: tuple[str, ...] = ()) -> None:
        """The master holds what a fresh --dump-params of the files says, apart from what is set at run time."""
        on_master = {k: v for k, v in self.params().items() if not k.startswith(RUN_TIME) and k not in runtime}
        dumped = self.dump_params(*args)
        anon = [k for k in on_master if k.startswith("/anon_")]
        assert not anon  # (the anonymous node has no params here: its name is this run's)
        assert on_master == dumped

    def close(self) -> None:
        self.launcher.close()


# set at run time by the launch itself, not by its files
RUN_TIME = ("/run_id", "/roslaunch/uris/", "/rosdistro", "/rosversion")


def flatten(tree: dict, prefix: str = "/") -> dict:
    """{key: value} of every leaf (--dump-params' keys are global already; rosparam's tree is nested)."""
    out = {}
    for k, v in (tree or {}).items():
        key = k if k.startswith("/") else prefix + k
        if isinstance(v, dict) and v:
            out.update(flatten(v, key + "/"))
        else:
            out[key] = v
    return out


BASE_NAMES = {"a", "b", "cpp", "anon", "sim", "r"}


@pytest.fixture
def pkgs(tmp_path, ros_env):
    pkg = make_package(str(tmp_path / "pkgs"), "rl_tests", {"spinner": Spinner, "crasher": Crasher})
    compile_roscpp("param_node.cpp", os.path.join(pkg, "param_cpp"))
    return str(tmp_path / "pkgs")


@pytest.fixture
def run(tmp_path, pkgs):
    r = Run(tmp_path, pkgs)
    try:
        r.before = r.ready(BASE_NAMES)
        yield r
    finally:
        r.close()


def changed(before: dict[str, int], after: dict[str, int]) -> set[str]:
    """The nodes whose pid is not what it was (new ones included)."""
    return {name for name, pid in after.items() if before.get(name) != pid}


def test_a_changed_private_param_restarts_only_its_owner_and_the_master_holds_it(run):
    run.edit('<param name="rate" value="1"/>', '<param name="rate" value="2"/>')
    dry = run.reload("--dry-run")
    assert dry["ok"] and not dry["applied"]
    assert dry["difference"]["set"] == {"/a/rate": 2} and list(dry["difference"]["restart"]) == ["/a"]
    assert run.pids() == run.before  # (a dry run changes nothing)
    # it needs the run's token, as `launcher stop` does
    (run.tmp / "wrong-token").write_text("0" * 64 + "\n")
    refused = run.tool("reload", "--token-file", str(run.tmp / "wrong-token"))
    assert refused.returncode == 4 and "reload needs this run's token" in refused.stderr, refused.stderr
    answer = run.reload()
    assert answer["ok"] and answer["applied"] and answer["difference"] == dry["difference"]
    after = run.ready(BASE_NAMES)
    assert changed(run.before, after) == {"a"}  # exactly what the dry run listed
    assert not pid_alive(run.before["a"])
    assert run.params()["/a/rate"] == 2
    run.assert_params_are_the_files()


def test_a_changed_global_param_is_set_and_nothing_restarts_and_run_time_params_survive(run):
    env = dict(run.env, PATH=ROS_PATH + ":" + run.env.get("PATH", ""))
    subprocess.run(["rosparam", "set", "/set_at_run_time", "7"], env=env, check=True, timeout=60)
    run.edit('<param name="g" value="1"/>', '<param name="g" value="2"/><param name="h" value="new"/>')
    answer = run.reload()
    assert answer["ok"] and answer["difference"]["restart"] == {} and answer["difference"]["set"] == {"/g": 2, "/h": "new"}
    assert run.pids() == run.before
    params = run.params()
    assert (params["/g"], params["/h"], params["/set_at_run_time"]) == (2, "new", 7)
    run.assert_params_are_the_files(runtime=("/set_at_run_time",))
    # what the launch keeps for `launcher report` is the reloaded files' parameters (not the run-time one)
    kept = os.path.join(run.env["ROS_LOG_DIR"], "latest", "launcher-params.yaml")
    until(lambda: (yaml.safe_load(open(kept)) or {}).get("/h") == "new", 10, what="the kept parameters reloaded")
    assert yaml.safe_load(open(kept))["/g"] == 2 and "/set_at_run_time" not in yaml.safe_load(open(kept))


def test_a_yaml_edit_restarts_only_the_node_it_loads_into(run):
    run.edit("i: 2", "i: 3", file="cpp.yaml")
    run.edit("one", "two", file="shared.yaml")
    cpp_file = run.tmp / "cpp.txt"
    until(cpp_file.exists, 30, what="the roscpp node read its parameters")
    cpp_file.unlink()  # (the node started anew writes it again)
    answer = run.reload()
    assert answer["ok"] and list(answer["difference"]["restart"]) == ["/cpp"]
    after = run.ready(BASE_NAMES)
    assert changed(run.before, after) == {"cpp"}
    until(cpp_file.exists, 30, what="the restarted roscpp node read its parameters")
    params = run.params()
    assert (params["/cpp/gains/i"], params["/shared/value"]) == (3, "two")
    assert "global=two" in cpp_file.read_text()  # the roscpp node started anew saw the new global too
    run.assert_params_are_the_files()


def test_an_added_and_a_removed_node(run):
    run.edit('<node pkg="rl_tests" type="spinner" name="b" args="--x 1"/>',
             '<node pkg="rl_tests" type="spinner" name="c"><param name="p" value="3"/></node>')
    answer = run.reload()
    assert answer["ok"]
    assert list(answer["difference"]["stop"]) == ["/b"] and list(answer["difference"]["start"]) == ["/c"]
    after = run.ready(BASE_NAMES - {"b"} | {"c"})
    assert changed(run.before, after) == {"c"} and not pid_alive(run.before["b"])
    status = json.loads(run.tool("status", "--json").stdout)
    assert "/b" not in {n["name"] for n in status["nodes"]}
    assert run.params()["/c/p"] == 3
    run.assert_params_are_the_files()
    # the events file has the reload's line
    events = [json.loads(line) for line in open(os.path.join(status["events_file"]))]
    reloads = [e for e in events if e.get("event") == "reload"]
    assert len(reloads) == 1 and reloads[0]["started"] == ["/c"] and reloads[0]["stopped"] == ["/b"]


def test_a_changed_args_restarts_that_node_only(run):
    run.edit('args="--x 1"', 'args="--x 2"')
    answer = run.reload()
    assert answer["ok"] and list(answer["difference"]["restart"]) == ["/b"]
    assert "args" in answer["difference"]["restart"]["/b"]
    after = run.ready(BASE_NAMES)
    assert changed(run.before, after) == {"b"}
    with open("/proc/%d/cmdline" % after["b"], "rb") as f:
        assert b"--x\x002\x00" in f.read()
    run.assert_params_are_the_files()


def test_a_changed_respawn_max_retries_restarts_nothing(run):
    run.edit('respawn_max_retries="3"', 'respawn_max_retries="5"')
    answer = run.reload()
    assert answer["ok"] and list(answer["difference"]["supervise"]) == ["/r"]
    assert answer["difference"]["restart"] == {} and answer["lines"] == ["supervise /r: respawn_max_retries 3 -> 5"]
    assert run.pids() == run.before
    run.assert_params_are_the_files()


def test_nothing_changed_restarts_nothing_and_sets_nothing(run):
    env = dict(run.env, PATH=ROS_PATH + ":" + run.env.get("PATH", ""))
    # a parameter the launch set, changed at run time: a reload with no change leaves it alone
    subprocess.run(["rosparam", "set", "/g", "99"], env=env, check=True, timeout=60)
    r = run.tool("reload")
    assert r.returncode == 0 and r.stdout == "nothing changed\n", r.stderr
    assert run.pids() == run.before  # the anonymous node kept its name and its pid
    assert run.params()["/g"] == 99


def test_an_xml_error_changes_nothing_and_names_file_and_line(run):
    run.edit('<param name="rate" value="1"/>', '<param name="rate" value="2"/>')
    run.edit('<node pkg="rl_tests" type="spinner" name="r"', '<node pkg="rl_tests" type="spinner" name="r" <')
    r = run.tool("reload")
    assert r.returncode == 1
    line = [n for n, text in enumerate(BASE.splitlines(), 1) if 'name="r"' in text][0]
    assert "r.launch:%d: Invalid roslaunch XML syntax" % line in r.stderr, r.stderr
    assert "nothing changed" in r.stderr
    assert run.pids() == run.before and run.params()["/a/rate"] == 1
    # a missing executable is refused the same way
    run.launch.write_text(BASE.replace('type="spinner" name="sim"', 'type="no_such_exe" name="sim"'))
    r = run.tool("reload")
    assert r.returncode == 1 and "no_such_exe" in r.stderr and "r.launch" in r.stderr, r.stderr
    assert run.pids() == run.before


def test_an_arg_given_on_the_reload_switches_an_if_branch(run):
    dry = run.reload("--dry-run", "sim:=false")
    assert list(dry["difference"]["stop"]) == ["/sim"] and list(dry["difference"]["start"]) == ["/real"]
    answer = run.reload("sim:=false")
    assert answer["ok"]
    after = run.ready(BASE_NAMES - {"sim"} | {"real"})
    assert changed(run.before, after) == {"real"}
    run.assert_params_are_the_files("sim:=false")
    # the run's args are now these: a reload without args keeps sim:=false
    assert run.reload()["lines"] == []


def test_an_operator_stopped_node_stays_stopped_unless_it_changed(run):
    for name in ("/a", "/b"):
        r = run.tool("stop", name)
        assert r.returncode == 0, r.stderr
    until(lambda: not {"a", "b"} & set(run.pids()), 30, what="a and b stopped")
    run.edit('args="--x 1"', 'args="--x 2"')  # b changes, a does not
    answer = run.reload()
    assert answer["ok"] and list(answer["difference"]["restart"]) == ["/b"]
    after = run.ready(BASE_NAMES - {"a"})  # b started as new; a stays stopped
    assert changed(run.before, after) == {"b"}
    states = {n["name"]: n["state"] for n in json.loads(run.tool("status", "--json").stdout)["nodes"]}
    assert states["/a"] == "stopped" and states["/b"] == "running"


def test_a_fatal_node_stays_fatal_unless_it_changed(run):
    def states() -> dict:
        return {n["name"]: n for n in json.loads(run.tool("status", "--json").stdout)["nodes"]}
    run.edit("</launch>", '<node pkg="rl_tests" type="crasher" name="crash" respawn="true" respawn_max_retries="1" '
                          'respawn_delay="0.1"/>\n</launch>')
    assert list(run.reload()["difference"]["start"]) == ["/crash"]
    until(lambda: states()["/crash"]["state"] == "fatal", 30, 0.2, what="/crash FATAL")
    runs = states()["/crash"]["restarts"]
    run.edit('<param name="g" value="1"/>', '<param name="g" value="2"/>')  # another change: it stays FATAL
    assert run.reload()["ok"]
    assert states()["/crash"]["state"] == "fatal" and states()["/crash"]["restarts"] == runs
    run.edit('type="crasher" name="crash"', 'type="crasher" name="crash" args="again"')  # changed: started anew
    assert list(run.reload()["difference"]["restart"]) == ["/crash"]
    until(lambda: states()["/crash"]["restarts"] > runs, 30, 0.2, what="/crash started anew")
    until(lambda: states()["/crash"]["state"] == "fatal", 30, 0.2, what="/crash FATAL again (it failed again)")
    assert run.pids() == run.before  # (the others kept their pids throughout)


def test_a_bind_to_added_by_a_reload_binds_the_node_from_then_on(run):
    """The relations are the plan's: a reload gives the fleet the new plan's, so a `bind_to` it adds holds at once
    (an operator's stop of the partner stops the node bound to it first, and its start starts it again)."""
    run.edit('name="b" args="--x 1"', 'name="b" args="--x 1" bind_to="a"')
    answer = run.reload()
    assert answer["ok"] and list(answer["difference"]["supervise"]) == ["/b"], answer
    assert run.pids() == run.before
    r = run.tool("stop", "/a")
    assert r.returncode == 0, r.stderr
    until(lambda: not {"a", "b"} & set(run.pids()), 30, what="a and the node bound to it stopped")
    nodes = {n["name"]: n for n in json.loads(run.tool("status", "--json").stdout)["nodes"]}
    assert nodes["/a"]["state"] == "stopped" and nodes["/b"]["phase"] == "detached", nodes["/b"]
    assert run.tool("start", "/a").returncode == 0
    after = run.ready(BASE_NAMES)
    assert changed(run.before, after) == {"a", "b"}
