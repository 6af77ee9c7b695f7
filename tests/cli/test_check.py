"""`launcher check`: findings on every if/unless branch with file:line, clean files clean, the compat corpus."""

from __future__ import annotations

import os
import json
import re
import subprocess
import sys
import tempfile

import pytest

from launcher.cli import check
from launcher.model.errors import LaunchError
from launcher.workspace.packages import PackageIndex
from launcher.xml import resolve_launch_arguments

from helpers import COMPAT, ROS_PYTHON

PACKAGE_XML = ('<?xml version="1.0"?>\n<package format="2"><name>%s</name><version>0.0.1</version>'
               '<description>d</description><maintainer email="m@example.com">m</maintainer>'
               '<license>BSD</license></package>\n')


@pytest.fixture
def ws(tmp_path):
    pkg = tmp_path / "src" / "robot"
    (pkg / "config").mkdir(parents=True)
    (pkg / "package.xml").write_text(PACKAGE_XML % "robot")
    (pkg / "config" / "ok.yaml").write_text("gain: 2\n")
    (pkg / "config" / "bad.yaml").write_text("gain: [1, 2\n")
    node = pkg / "driver.py"
    node.write_text("#!/bin/sh\n")
    node.chmod(0o755)
    env = {k: v for k, v in os.environ.items() if not k.startswith("ROS_")}
    env.update(ROS_PACKAGE_PATH=str(tmp_path / "src"), ROS_HOME=str(tmp_path / "home"))
    return tmp_path, env


def write(tmp, name, body):
    path = tmp / name
    path.write_text('<?xml version="1.0"?>\n<launch>\n%s\n</launch>\n' % body)
    return str(path)


def run_check(env, *args):
    return subprocess.run([sys.executable, "-m", "launcher.cli.tool", "check", *args], env=env, capture_output=True,
                          text=True, timeout=60)


def findings(env, path, *argv):
    return check.check([path], list(argv), environ=env, packages=PackageIndex(env))


def test_error_behind_if_arg_is_found_with_its_line_and_branch(ws):
    tmp, env = ws
    path = write(tmp, "robot.launch", '<arg name="sim" default="false"/>\n'   # line 3
                 '<node name="driver" pkg="robot" type="driver.py"/>\n'           # line 4
                 '<group if="$(arg sim)">\n'                                      # line 5
                 '  <node name="fake" pkg="robot" type="no_such_sim.py"/>\n'      # line 6
                 '</group>')
    p = run_check(env, path)
    assert p.returncode == 1, p.stdout + p.stderr
    assert "robot.launch:6: <node> [/fake]" in p.stdout and "no_such_sim.py" in p.stdout
    assert "on the branch sim:=true" in p.stdout
    # roslaunch's own load (the default branch) has nothing to say
    assert not [f for f in findings(env, path, "sim:=false") if f.severity == "error" and not f.branch
                and "no_such_sim" in f.message]


def test_condition_in_an_included_file_decided_by_a_top_level_arg(ws):
    tmp, env = ws
    inner = write(tmp, "inner.launch", '<arg name="sim"/>\n'
                  '<node if="$(arg sim)" name="fake" pkg="robot" type="no_such_sim.py"/>')   # line 4
    path = write(tmp, "outer.launch", '<arg name="use_sim" default="false"/>\n'
                 '<include file="%s"><arg name="sim" value="$(arg use_sim)"/></include>' % inner)  # line 4
    fs = [f for f in findings(env, path) if f.severity == "error"]
    assert len(fs) == 1 and fs[0].branch == ("use_sim:=true",), fs
    assert "inner.launch:4:" in fs[0].message and "included from %s:4" % path in fs[0].message


def test_unless_branch_yaml_and_undefined_arg(ws):
    tmp, env = ws
    path = write(tmp, "robot.launch", '<arg name="real" default="true"/>\n'
                 '<rosparam unless="$(arg real)" file="$(find robot)/config/bad.yaml"/>\n'   # line 4
                 '<param name="x" value="$(arg not_declared)"/>')                           # line 5
    fs = findings(env, path)
    errors = {(f.line, f.branch) for f in fs if f.severity == "error"}
    assert any("bad.yaml" in f.message and f.branch == ("real:=false",) for f in fs), fs
    assert (5, ()) in errors, fs
    assert any("not_declared" in f.message for f in fs)


def test_duplicate_names_and_unknown_machine_on_a_branch(ws):
    tmp, env = ws
    path = write(tmp, "robot.launch", '<arg name="two" default="false"/>\n'
                 '<node name="driver" pkg="robot" type="driver.py"/>\n'
                 '<node if="$(arg two)" name="driver" pkg="robot" type="driver.py"/>\n'          # line 5
                 '<node name="remote" pkg="robot" type="driver.py" machine="nowhere"/>')        # line 6
    fs = findings(env, path)
    assert any(f.line == 5 and f.branch == ("two:=true",) and "multiple nodes named" in f.message for f in fs), fs
    assert any(f.line == 6 and f.branch == () and "machine [nowhere]" in f.message for f in fs), fs


def test_a_parameter_xmlrpc_cannot_send_is_an_error_at_its_line(ws):
    """A YAML date or an integer beyond 32 bits loads (roslaunch's --dump-params prints them) but fails the
    launch as it sets them (test_compat_corpus proves such a finding against roslaunch's own marshalling;
    tests/run/test_apart.py shows our launch's refusal)."""
    tmp, env = ws
    path = write(tmp, "robot.launch", '<rosparam>\n'                                           # line 3
                 '  when: 2024-01-02\n'
                 '  fine: "2024-01-02"\n'
                 '</rosparam>\n'
                 '<param name="big" type="int" value="4294967296"/>\n'                           # line 7
                 '<param name="small" type="int" value="2147483647"/>')
    fs = [f for f in findings(env, path) if f.severity == "error"]
    assert [(f.line, f.kind) for f in fs] == [(3, "run"), (7, "run")], fs
    assert "parameter [/when] cannot be set: a value of type date" in fs[0].message and "quote it" in fs[0].message
    assert "parameter [/big] cannot be set: the integer 4294967296" in fs[1].message
    assert fs[0].message.startswith(path + ":3: ")
    done = run_check(env, path)
    assert done.returncode == 1 and "/when" in done.stdout + done.stderr, (done.stdout, done.stderr)


def test_args_compared_with_literals_in_eval_are_varied_over_those_literals(ws):
    tmp, env = ws
    path = write(tmp, "robot.launch", '<arg name="mode" default="real"/>\n'
                 '<arg name="level" default="1"/>\n'
                 '<node if="$(eval arg(\'mode\') == \'sim\')" name="fake" pkg="robot" type="no_sim.py"/>\n'  # 5
                 '<group if="$(eval mode in [\'replay\', \'bag\'])">\n'
                 '  <node name="player" pkg="robot" type="no_player.py"/>\n'                                   # 7
                 '</group>\n'
                 '<node unless="$(eval \'hw\' != mode)" name="hw" pkg="robot" type="no_hw.py"/>\n'              # 9
                 '<node if="$(eval int(arg(\'level\')) == 3 and mode == \'real\')" name="deep" pkg="robot" '
                 'type="no_deep.py"/>')                                                                          # 10
    fs = findings(env, path)
    branches = {f.line: f.branch for f in fs if f.severity == "error"}
    assert branches.get(5) == ("mode:=sim",), fs
    assert branches.get(7) == ("mode:=replay",), fs
    assert branches.get(9) == ("mode:=hw",), fs
    assert 10 in branches and "level:=3" in branches[10], fs
    p = run_check(env, path)
    assert p.returncode == 1 and "on the branch mode:=sim" in p.stdout, p.stdout


def test_literals_of_an_included_files_condition_vary_the_top_arg_passed_to_it(ws):
    tmp, env = ws
    inner = write(tmp, "inner.launch", '<arg name="mode"/>\n'
                  '<node if="$(eval mode == \'sim\')" name="fake" pkg="robot" type="no_sim.py"/>')   # line 4
    path = write(tmp, "outer.launch", '<arg name="robot_mode" default="real"/>\n'
                 '<include file="%s"><arg name="mode" value="$(arg robot_mode)"/></include>' % inner)
    fs = [f for f in findings(env, path) if f.severity == "error"]
    assert [(f.line, f.branch) for f in fs] == [(4, ("robot_mode:=sim",))], fs


def test_a_condition_too_deep_to_parse_is_an_error_not_a_traceback(ws):
    tmp, env = ws
    deep = "1+" * 15000 + "1"
    path = write(tmp, "robot.launch", '<arg name="mode" default="a"/>\n'
                 '<node if="$(eval mode == \'b\' or %s == 2)" name="x" pkg="robot" type="driver.py"/>' % deep)
    p = run_check(env, "-q", path)
    assert p.returncode == 1 and "Traceback" not in p.stderr, p.stderr[-2000:]
    assert "robot.launch:4:" in p.stdout


def test_args_of_every_top_file_are_varied(ws):
    tmp, env = ws
    first = write(tmp, "first.launch", '<arg name="sim" default="false"/>\n'
                  '<node if="$(arg sim)" name="fake" pkg="robot" type="no_such_sim.py"/>')     # line 4
    second = write(tmp, "second.launch", '<arg name="other" default="1"/>')
    fs = check.check([first, second], [], environ=env, packages=PackageIndex(env))
    assert [(f.line, f.branch) for f in fs if f.severity == "error"] == [(4, ("sim:=true",))], fs


def test_errors_in_group_machine_remap_and_env_do_not_end_the_load(ws):
    tmp, env = ws
    path = write(tmp, "robot.launch", '<group ns="$(arg nope1)"><node name="a" pkg="robot" type="driver.py"/>'
                 '</group>\n'                                                                       # line 3
                 '<machine name="m" address="$(arg nope2)"/>\n'                                   # line 4
                 '<remap from="$(arg nope3)" to="b"/>\n'                                          # line 5
                 '<env name="X" value="$(arg nope4)"/>\n'                                         # line 6
                 '<group><group ns="$(arg nope5)"/><node name="b" pkg="robot" type="b_missing.py"/></group>\n'  # 7
                 '<node name="d" pkg="robot" type="missing.py"/>')                                 # line 8
    errors = [f for f in findings(env, path) if f.severity == "error"]
    assert {3, 4, 5, 6, 7, 8} <= {f.line for f in errors}, errors
    # (the inner group alone is skipped: the node after it in the outer group is checked)
    assert any("b_missing.py" in f.message for f in errors), errors


def test_errors_in_include_and_arg_do_not_end_the_load(ws):
    tmp, env = ws
    inner = write(tmp, "inner.launch", '<arg name="x" default="1" value="2"/>\n'             # line 3
                  '<node name="inner_d" pkg="robot" type="inner_missing.py"/>')             # line 4
    path = write(tmp, "robot.launch", '<include file="$(dirname)/nowhere.launch"/>\n'     # line 3
                 '<arg name="both" default="1" value="2"/>\n'                             # line 4
                 '<include file="%s"/>\n'                                                 # line 5
                 '<include file="%s"><arg name="unused" value="1"/></include>\n'          # line 6
                 '<node name="d" pkg="robot" type="missing.py"/>' % (inner, inner))        # line 7
    errors = {(os.path.basename(f.filename), f.line) for f in findings(env, path) if f.severity == "error"}
    assert {("robot.launch", 3), ("robot.launch", 4), ("inner.launch", 3), ("inner.launch", 4),
            ("robot.launch", 6), ("robot.launch", 7)} <= errors, errors


def test_include_chain_and_missing_find_path(ws):
    tmp, env = ws
    inner = write(tmp, "inner.launch", '<rosparam file="$(find robot)/config/none.yaml"/>')
    path = write(tmp, "outer.launch", '<include file="%s"/>' % inner)
    p = run_check(env, path)
    assert p.returncode == 1
    assert "inner.launch:3:" in p.stdout and "included from %s:3" % path in p.stdout, p.stdout


def test_clean_file_gives_no_error_and_junit_says_so(ws):
    tmp, env = ws
    path = write(tmp, "robot.launch", '<arg name="sim" default="false"/>\n'
                 '<node name="driver" pkg="robot" type="driver.py">\n'
                 '  <rosparam file="$(find robot)/config/ok.yaml"/>\n</node>\n'
                 '<node if="$(arg sim)" name="sim_driver" pkg="robot" type="driver.py"/>')
    out = str(tmp / "junit" / "check.xml")
    p = run_check(env, path, "--junit-xml", out)
    assert p.returncode == 0, p.stdout + p.stderr
    with open(out) as f:
        text = f.read()
    assert 'tests="1" failures="0"' in text and 'classname="roslaunch.RoslaunchCheck"' in text


def test_junit_lists_the_errors(ws):
    tmp, env = ws
    path = write(tmp, "robot.launch", '<node name="d" pkg="robot" type="missing.py"/>')
    out = str(tmp / "check.xml")
    p = run_check(env, path, "--junit-xml", out)
    assert p.returncode == 1
    with open(out) as f:
        text = f.read()
    assert 'failures="1"' in text and "roslaunch check [%s] failed" % path in text and "missing.py" in text


# Debian's roslaunch, through its own code, on one corpus case: for each branch (the args added to the case's),
# what `roslaunch --nodes` (the load), `roslaunch --args NODE` (each node's command line: a missing package or
# executable fails there) and a launch (roslaunch assigns machines before it starts anything: an undeclared
# machine fails there, "unknown machine [x]"; it sets the parameters: a value XML-RPC cannot send fails there)
# say. It runs in one process per case, under Debian's python.
REFERENCE = r'''
import json, sys, xmlrpc.client
import roslaunch.config, roslaunch.node_args, roslaunch.xmlloader
from roslaunch.core import local_machine

job = json.load(sys.stdin)
out = []
for branch in job["branches"]:
    sys.argv = ["roslaunch"] + job["args"] + branch  # (the loader reads name:=value from sys.argv)
    res = {"load": None, "args": {}, "launch": None}
    try:
        config = roslaunch.config.load_config_default(job["files"], None, loader=roslaunch.xmlloader.XmlLoader(),
                                                      verbose=False, assign_machines=False)
    except Exception as e:
        res["load"] = "%s: %s" % (type(e).__name__, e)
        out.append(res)
        continue
    for node in config.nodes + config.tests:
        name = roslaunch.node_args._resolved_name(node)
        try:
            roslaunch.node_args.create_local_process_args(node, local_machine())
            res["args"][name] = None
        except Exception as e:
            res["args"][name] = "%s: %s" % (type(e).__name__, e)
    try:
        config.assign_machines()
    except Exception as e:
        res["launch"] = "%s: %s" % (type(e).__name__, e)
    res["params"] = {}  # (a launch sets each parameter through xmlrpclib's marshaller, as this one: its refusals)
    for key, param in config.params.items():
        try:
            xmlrpc.client.dumps((param.value,))
        except Exception as e:
            res["params"][key] = "%s: %s" % (type(e).__name__, e)
    out.append(res)
json.dump(out, sys.stdout)
'''


def _corpus_cases():
    if not os.path.isdir(COMPAT):
        return []
    sys.path.insert(0, COMPAT)
    try:
        import compatlib
    finally:
        sys.path.remove(COMPAT)
    return [(compatlib, c) for c in compatlib.build_cases()]


def _check_case(compatlib, case, home):
    env = compatlib.case_env(case, home)
    packages = PackageIndex(env)
    files, args = resolve_launch_arguments([compatlib.expand(a) for a in case["argv"]], packages)
    return files, args, check.check(files, args, environ=env, packages=packages)


def _reference(compatlib, case, home, files, args, branches):
    """Debian's roslaunch on each branch of a case: [{"load": error, "args": {node: error}, "launch": error}]."""
    env = compatlib.case_env(case, home, {"PYTHONPATH": ""})
    proc = subprocess.run([ROS_PYTHON, "-c", REFERENCE], input=json.dumps(
        {"files": files, "args": args, "branches": [list(b) for b in branches]}), capture_output=True, text=True,
        env=env, cwd=compatlib.COMPAT, timeout=120)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout)


def _golden_clean(golden):
    """The goldens of a case show no error anywhere: every option and every node's --args ran clean."""
    return (not golden["error"] and all(r["rc"] == 0 for r in golden["results"].values())
            and all(n["--args"]["rc"] == 0 for n in golden["nodes"].values() if n["source"] == "nodes"))


def test_compat_corpus(ros_env, ros_part_missing, monkeypatch):
    """No false positive: every error `check` reports on a corpus file that roslaunch loads, Debian's roslaunch
    itself refuses too, on the same branch; every case roslaunch refuses gives an error.

    The decision: `check` is right to report, on files roslaunch loads cleanly,
    - nodes whose package or executable is missing (ros_comm's example files run rospy's talker.py, which
      Debian does not ship; exec_resolution.launch): `roslaunch --args NODE` fails on them, and so does the
      launch;
    - a node on a `machine=` no `<machine>` declares: roslaunch loads the file, then refuses to launch it
      ("unknown machine [x]", from assign_machines, before anything starts);
    - a parameter XML-RPC cannot send (param_types.launch's YAML null): roslaunch loads the file, then its
      launch fails as it sets that parameter (xmlrpclib's "cannot marshal None");
    - errors on another branch (if_unless.launch includes a missing file when `off:=true`; ros_comm's
      example.launch runs a node of a missing package when `commandline_true_arg:=false`): roslaunch given
      those args refuses too.
    So this test proves each such error against roslaunch's own code (REFERENCE: the load `--nodes` does,
    `--args`' command line per node, the machine assignment of a launch), on the case's args plus the branch's.
    And the converse: on the default branch of a case whose goldens show no error anywhere (file level and
    every node's --args), `check` reports no error but the launch-time ones roslaunch is shown to make.
    """
    cases = _corpus_cases()
    if not cases:
        pytest.skip("../shared/compat is not beside this checkout")
    if subprocess.run([ROS_PYTHON, "-c", "import roslaunch.config"], capture_output=True).returncode:
        ros_part_missing("roslaunch (Debian's python3-roslaunch) not importable")
    monkeypatch.chdir(cases[0][0].COMPAT)  # (the corpus' relative paths are relative to its root)
    clean = refused = proven = quiet = 0
    proven_kinds: set[str] = set()
    for compatlib, case in cases:
        golden = compatlib.load_golden(case["id"])
        with tempfile.TemporaryDirectory() as home:
            try:
                files, args, fs = _check_case(compatlib, case, home)
            except LaunchError as e:  # from the arguments themselves: roslaunch refuses those too
                assert golden["error"], (case["id"], e)
                refused += 1
                continue
            errors = [f for f in fs if f.severity == "error"]
            if golden["error"]:
                assert errors, case["id"]
                refused += 1
                continue
            clean += 1
            if not errors:
                quiet += 1
                continue
            branches = sorted({f.branch for f in errors} | {()})
            ref = dict(zip(branches, _reference(compatlib, case, home, files, args, branches)))
        norm = compatlib.Normalizer(home)
        default = ref[()]
        # the reference is the recorded CLI: on the case's own args, the same nodes fail `--args`
        assert default["load"] is None, (case["id"], default["load"])
        recorded = {norm.text(n) for n, r in golden["nodes"].items() if r["source"] == "nodes" and r["--args"]["rc"]}
        assert {norm.text(n) for n, e in default["args"].items() if e} == recorded, case["id"]
        for f in errors:
            r = ref[f.branch]
            where = (case["id"], f.format())
            if r["load"] is not None:
                kind = "load"
            else:
                assert f.kind == "run", ("roslaunch loads this branch", where)
                unsendable = re.search(r"parameter \[([^]]*)\] cannot be set", f.message)
                if "which no <machine> tag declares" in f.message:
                    assert r["launch"] and "unknown machine" in r["launch"], ("roslaunch launches it", where)
                    kind = "launch"
                elif unsendable:
                    assert unsendable.group(1) in r["params"], ("roslaunch sets it", where)
                    kind = "launch"
                else:
                    assert f.node, ("roslaunch loads this branch", where)
                    failing = {norm.text(n) for n, e in r["args"].items() if e}
                    assert norm.text(f.node) in failing, ("roslaunch --args runs it", where)
                    kind = "args"
            if not f.branch and _golden_clean(golden):
                assert kind == "launch", ("the goldens show no error", where)
            proven_kinds.add(kind if not f.branch else "branch " + kind)
            proven += 1
    # (the corpus holds each kind; if it stops to, this test proves less than it says)
    assert proven_kinds >= {"args", "launch", "branch load", "branch args"}, proven_kinds
    assert clean > 100 and refused > 100 and quiet > 80, (clean, refused, quiet)


def test_nodes_that_do_not_register_are_named(ws):
    tmp, env = ws
    path = write(tmp, "robot.launch", '<node name="driver" pkg="robot" type="driver.py"/>\n'   # line 3
                 '<group registers="false">\n'                                                 # line 4
                 '  <node name="helper" pkg="robot" type="driver.py"/>\n'                      # line 5
                 '</group>\n'
                 '<node name="pump" pkg="robot" type="driver.py" registers="false"/>')        # line 7
    p = run_check(env, path)
    assert p.returncode == 0, p.stdout + p.stderr
    notes = [line for line in p.stdout.splitlines() if line.startswith("note: ")]
    assert notes == ['note: %s:5: <node> [/helper] has registers="false": not a ROS node, up once its process runs '
                     '(no registration with the master is awaited)' % path,
                     'note: %s:7: <node> [/pump] has registers="false": not a ROS node, up once its process runs '
                     '(no registration with the master is awaited)' % path], p.stdout
    assert p.stdout.rstrip().endswith("0 error(s), 0 warning(s), 2 note(s)")
    bad = write(tmp, "bad.launch", '<node name="x" pkg="robot" type="driver.py" registers="maybe"/>')
    p = run_check(env, bad)
    assert p.returncode == 1 and "bad.launch:3" in p.stdout and "registers" in p.stdout, p.stdout
