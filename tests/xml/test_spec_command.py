"""`--args`: the node command line and environment changes, against roslaunch's own node_args.

Each case loads a small launch file and computes every node's command with
`launcher.plan.command.node_command`; roslaunch's answer comes from its setup_env +
create_local_process_args (what `roslaunch --args NODE` prints), run in-process by
Debian's python. The tables below are the expected `--args` lines (with @PKG@/@WS@ for the
temporary package and workspace), checked against both.
"""

from __future__ import annotations

import json
import os
import subprocess
from dataclasses import dataclass, field

import pytest

from launcher.model.errors import LaunchError

PKG = "spec_cmd_pkg"
DEFAULT_URI = "http://localhost:11311/"


@dataclass
class Cmd:
    id: str
    launch: str
    args: dict[str, str | None]                # node full name -> expected --args line (None: an error)
    argv: list[str] = field(default_factory=list)
    env: dict[str, str] = field(default_factory=dict)   # the caller's environment additions


CASES = [
    Cmd("plain", '<launch><node pkg="%s" type="talker" name="t"/></launch>' % PKG,
        {"/t": 'ROS_MASTER_URI="http://localhost:11311/" @PKG@/scripts/talker __name:=t'}),
    Cmd("args_prefix_remaps", '''<launch>
  <remap from="chatter" to="/global/chatter"/>
  <node pkg="%s" type="talker" name="t" launch-prefix="nice  -n 5"
        args="--rate  10 'two words' &quot;dq&quot;">
    <remap from="~in" to="out"/>
  </node>
</launch>''' % PKG,
        {"/t": 'ROS_MASTER_URI="http://localhost:11311/" nice -n 5 @PKG@/scripts/talker --rate 10 two words dq '
               'chatter:=/global/chatter ~in:=out __name:=t'}),
    Cmd("namespace_and_env", '''<launch>
  <group ns="robot">
    <env name="SPEC_CMD_B" value="b"/>
    <node pkg="%s" type="talker" name="t">
      <env name="SPEC_CMD_A" value="a"/>
    </node>
  </group>
</launch>''' % PKG,
        {"/robot/t": 'ROS_MASTER_URI="http://localhost:11311/" ROS_NAMESPACE="/robot" SPEC_CMD_B="b" '
                     'SPEC_CMD_A="a" @PKG@/scripts/talker __name:=t'}),
    Cmd("env_equal_to_current_is_not_printed", '''<launch>
  <node pkg="%s" type="talker" name="t">
    <env name="SPEC_CMD_SAME" value="same"/>
    <env name="SPEC_CMD_CHANGED" value="new"/>
  </node>
</launch>''' % PKG,
        {"/t": 'SPEC_CMD_CHANGED="new" ROS_MASTER_URI="http://localhost:11311/" @PKG@/scripts/talker __name:=t'},
        env={"SPEC_CMD_SAME": "same", "SPEC_CMD_CHANGED": "old"}),
    Cmd("master_uri_from_environment", '<launch><node pkg="%s" type="talker" name="t"/></launch>' % PKG,
        {"/t": '@PKG@/scripts/talker __name:=t'}, env={"ROS_MASTER_URI": "http://127.0.0.1:12345"}),
    Cmd("ros_namespace_environment", '''<launch>
  <node pkg="%s" type="talker" name="t"/>
</launch>''' % PKG,
        {"/envns/t": 'ROS_MASTER_URI="http://localhost:11311/" @PKG@/scripts/talker __name:=t'},
        env={"ROS_NAMESPACE": "/envns"}),
    Cmd("cli_ns", '<launch><node pkg="%s" type="talker" name="t" ns="sub"/></launch>' % PKG,
        {"/top/sub/t": 'ROS_MASTER_URI="http://localhost:11311/" ROS_NAMESPACE="/top/sub" @PKG@/scripts/talker '
                       '__name:=t'}, argv=["__ns:=/top"]),
    Cmd("workspace_lib_wins", '''<launch>
  <node pkg="%s" type="both" name="b"/>
  <node pkg="%s" type="deep" name="d"/>
</launch>''' % (PKG, PKG),
        {"/b": 'ROS_MASTER_URI="http://localhost:11311/" @WS@/lib/%s/both __name:=b' % PKG,
         "/d": 'ROS_MASTER_URI="http://localhost:11311/" @PKG@/nodes/sub/deep __name:=d'}),
    Cmd("args_with_substitutions", '''<launch>
  <arg name="rate" default="5"/>
  <node pkg="%s" type="talker" name="t" args="--data $(find %s)/cfg.yaml --rate $(arg rate)"/>
</launch>''' % (PKG, PKG),
        {"/t": 'ROS_MASTER_URI="http://localhost:11311/" @PKG@/scripts/talker --data @PKG@/cfg.yaml --rate 5 '
               '__name:=t'}),
    Cmd("test_tag", '<launch><test test-name="tt" pkg="%s" type="talker" args="-v"/></launch>' % PKG,
        {"/tt": 'ROS_MASTER_URI="http://localhost:11311/" @PKG@/scripts/talker -v __name:=tt'}),
    Cmd("missing_and_not_executable", '''<launch>
  <node pkg="%s" type="no_such_exe" name="missing"/>
  <node pkg="%s" type="not_exec" name="noexec"/>
  <node pkg="spec_cmd_no_pkg" type="x" name="nopkg"/>
</launch>''' % (PKG, PKG),
        {"/missing": None, "/noexec": None, "/nopkg": None}),
]


@pytest.fixture
def tree(tmp_path):
    pkg = tmp_path / "pkgs" / PKG
    for rel, mode in (("scripts/talker", 0o755), ("nodes/sub/deep", 0o755), ("scripts/not_exec", 0o644),
                      ("scripts/both", 0o755)):
        path = pkg / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text("#!/bin/sh\nexit 0\n")
        path.chmod(mode)
    (pkg / "package.xml").write_text("<package><name>%s</name></package>" % PKG)
    ws = tmp_path / "ws"
    (ws / "lib" / PKG).mkdir(parents=True)
    (ws / ".catkin").write_text("")
    (ws / "lib" / PKG / "both").write_text("#!/bin/sh\n")
    (ws / "lib" / PKG / "both").chmod(0o755)
    env = {k: v for k, v in os.environ.items()
           if not k.startswith("ROS_") and not k.startswith("SPEC_") and k != "CMAKE_PREFIX_PATH"}
    env.update(ROS_PACKAGE_PATH=str(tmp_path / "pkgs"), CMAKE_PREFIX_PATH=str(ws), ROS_HOME=str(tmp_path / "home"))
    return tmp_path, str(pkg), str(ws), env


def _expected(line: str | None, pkg: str, ws: str) -> str | None:
    return None if line is None else line.replace("@PKG@", pkg).replace("@WS@", ws)


def _ours(launch_file: str, case: Cmd, env: dict[str, str]) -> dict[str, str | None]:
    from launcher.plan.command import node_command
    from launcher.workspace.packages import PackageIndex
    from launcher.xml import load

    packages = PackageIndex(env)
    config = load([launch_file], case.argv, environ=env, packages=packages)
    out: dict[str, str | None] = {}
    master_uri = env.get("ROS_MASTER_URI") or DEFAULT_URI
    for node in list(config.nodes) + list(config.tests):
        try:
            cmd = node_command(node, master_uri=master_uri, environ=env, packages=packages)
        except LaunchError:
            out[node.full_name] = None
            continue
        out[node.full_name] = " ".join(['%s="%s"' % kv for kv in cmd.env_changes] + cmd.argv)
    return out


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_node_command(tree, case):
    root, pkg, ws, env = tree
    launch_file = root / ("%s.launch" % case.id)
    launch_file.write_text(case.launch)
    got = _ours(str(launch_file), case, dict(env, **case.env))
    expected = {name: _expected(line, pkg, ws) for name, line in case.args.items()}
    for name in expected:
        assert name in got, "node %s not loaded: %s" % (name, sorted(got))
        assert got[name] == expected[name], name


REFERENCE_RUNNER = r"""
import json, os, sys
import rosgraph
import roslaunch.config, roslaunch.core, roslaunch.node_args, roslaunch.substitution_args, roslaunch.xmlloader
out = []
for path, env, argv in json.loads(sys.stdin.read()):
    os.environ.clear(); os.environ.update(env)
    sys.argv = ["roslaunch", path] + argv
    roslaunch.substitution_args._rospack = None
    roslaunch.node_args._rospack = None
    config = roslaunch.config.ROSLaunchConfig()
    roslaunch.xmlloader.XmlLoader(resolve_anon=False).load(path, config, verbose=False)
    result = {}
    for node in list(config.nodes) + list(config.tests):
        name = rosgraph.names.ns_join(node.namespace, node.name)
        machine = roslaunch.core.local_machine()
        penv = roslaunch.core.setup_env(node, machine, rosgraph.get_master_uri())
        penv = {k: v for k, v in penv.items() if v != os.environ.get(k)}
        try:
            args = roslaunch.node_args.create_local_process_args(node, machine)
            result[name] = " ".join(['%s="%s"' % kv for kv in penv.items()] + args)
        except Exception:
            result[name] = None
    out.append(result)
print(json.dumps(out))
"""


def test_expectations_are_roslaunchs(ros_env, tree):
    root, pkg, ws, env = tree
    jobs = []
    for case in CASES:
        launch_file = root / ("%s.launch" % case.id)
        launch_file.write_text(case.launch)
        jobs.append([str(launch_file), dict(env, PATH=ros_env["path"], **case.env), case.argv])
    proc = subprocess.run([ros_env["python"], "-c", REFERENCE_RUNNER], input=json.dumps(jobs), text=True,
                          capture_output=True, timeout=300, env=dict(os.environ, PATH=ros_env["path"]))
    assert proc.returncode == 0, proc.stderr
    failures = []
    for case, got in zip(CASES, json.loads(proc.stdout)):
        for name, line in case.args.items():
            expected = _expected(line, pkg, ws)
            if got.get(name, "<node missing>") != expected:
                failures.append("%s %s:\n  roslaunch: %s\n  expected:  %s" % (case.id, name, got.get(name), expected))
    assert not failures, "\n".join(failures)


# -- many random nodes in one file: every --args line must be roslaunch's ---------------------

def _random_launch(seed: int = 5, n: int = 150) -> str:
    import random
    rng = random.Random(seed)

    def esc(v: str) -> str:
        return v.replace("&", "&amp;").replace('"', "&quot;").replace("<", "&lt;")

    body = []
    for i in range(n):
        attrs = {"pkg": PKG, "type": rng.choice(["talker", "deep", "both"]), "name": "r%d" % i}
        if rng.random() < 0.4:
            attrs["ns"] = rng.choice(["a", "/b", "c/d", "/e/f/"])
        if rng.random() < 0.5:
            attrs["args"] = rng.choice(["--x 1", "'a  b' c", '"q r"  s', "$(arg v) --v", "-a=1 -b='2 3'", " lead trail "])
        if rng.random() < 0.3:
            attrs["launch-prefix"] = rng.choice(["nice -n 5", "env A=1", "valgrind  --tool=memcheck"])
        children = []
        for _ in range(rng.randint(0, 3)):
            if rng.random() < 0.5:
                children.append('<remap from="%s" to="%s"/>' % (rng.choice(["in", "~p", "/abs", "x/y"]),
                                                                rng.choice(["o", "/g/o", "~q"])))
            else:
                children.append('<env name="%s" value="%s"/>' % (rng.choice(["SPEC_CMD_R1", "SPEC_CMD_R2", "HOME"]),
                                                                 esc(rng.choice(["1", "two words", "$(arg v)", ""]))))
        wrap_ns = rng.choice([None, None, "grp", "/top"])
        node = "<node%s>%s</node>" % ("".join(' %s="%s"' % (k, esc(v)) for k, v in attrs.items()), "".join(children))
        body.append('<group ns="%s">%s</group>' % (wrap_ns, node) if wrap_ns else node)
    return '<launch><arg name="v" default="7"/><remap from="glob" to="/remapped"/>%s</launch>' % "".join(body)


def test_random_nodes_command_lines_are_roslaunchs(ros_env, tree):
    root, pkg, ws, env = tree
    launch_file = root / "random.launch"
    launch_file.write_text(_random_launch())
    case = Cmd("random", "", {})
    ours = _ours(str(launch_file), case, env)
    assert len(ours) == 150
    jobs = [[str(launch_file), dict(env, PATH=ros_env["path"]), []]]
    proc = subprocess.run([ros_env["python"], "-c", REFERENCE_RUNNER], input=json.dumps(jobs), text=True,
                          capture_output=True, timeout=300, env=dict(os.environ, PATH=ros_env["path"]))
    assert proc.returncode == 0, proc.stderr
    ref = json.loads(proc.stdout)[0]
    assert sorted(ref) == sorted(ours)
    different = ["%s:\n  roslaunch: %s\n  ours:      %s" % (n, ref[n], ours[n]) for n in sorted(ref) if ref[n] != ours[n]]
    assert not different, "\n".join(different[:10])
