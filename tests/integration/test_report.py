"""`launcher report` of a run with a crashing node whose console printed the token-bearing address, and a password
parameter: the archive holds what a bug report needs, and neither secret anywhere in its bytes; made while the launch
runs too."""

from __future__ import annotations

import gzip
import io
import json
import os
import subprocess
import sys
import tarfile

import pytest

from helpers import ROS_PYTHON, free_port, until
from running import Launcher, make_package, write_launch
from running import ros_env as env_of

pytestmark = pytest.mark.integration

Sleeper = """#!%s
import rospy
rospy.init_node("sleeper")
rospy.loginfo("db is %%s", rospy.get_param("/db/password"))
rospy.spin()
""" % ROS_PYTHON
# what issue 34's `launch --web` prints to a terminal: the page's address with the run's token in its fragment
Crasher = """#!/bin/sh
echo "the page: http://127.0.0.1:8765/#token=$(cat "$ROS_LOG_DIR/latest/launcher-token")"
echo "crasher: giving up" >&2
exit 3
"""
PASSWORD = "correct-horse-battery"


def report(env: dict, cwd: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "launcher.cli.tool", "report"] + list(args), env=env, cwd=cwd,
                          capture_output=True, text=True, timeout=120)


def members(path: str) -> dict[str, bytes]:
    with tarfile.open(path, "r:gz") as tar:
        return {m.name.split("/", 1)[1]: tar.extractfile(m).read() for m in tar.getmembers() if m.isfile()}


def test_report_of_a_run_holds_what_a_bug_report_needs_and_no_secret(tmp_path, ros_env):
    make_package(str(tmp_path / "pkgs"), "report_tests", {"sleeper": Sleeper, "crasher": Crasher})
    with open(tmp_path / "db.yaml", "w") as f:
        f.write("password: %s\nhost: db.local\n" % PASSWORD)
    port = free_port()
    env = env_of(str(tmp_path), port, str(tmp_path / "pkgs"))
    env["ROS_API_KEY"] = "s3cr3t-env-value"
    path = write_launch(str(tmp_path), """
      <rosparam ns="db" file="%s"/>
      <param name="speed" value="2.5"/>
      <node pkg="report_tests" type="sleeper" name="sleeper" output="screen"/>
      <node pkg="report_tests" type="crasher" name="crasher" respawn="true" respawn_delay="0.3"/>""" % (tmp_path / "db.yaml"))
    lp = Launcher(["-p", str(port), path], env, str(tmp_path))
    try:
        lp.wait_output(r"db is %s" % PASSWORD)  # (the sleeper's console line holds the password too)
        run_dir = os.path.realpath(os.path.join(env["ROS_LOG_DIR"], "latest"))
        with open(os.path.join(run_dir, "launcher-token")) as f:
            token = f.read().strip()
        until(lambda: open(os.path.join(run_dir, "crasher-3-stdout.log")).read().count("#token=" + token) >= 2, 30,
              what="the crasher printed the token twice")
        running = report(env, str(tmp_path), "-o", str(tmp_path / "running.tar.gz"))
        assert running.returncode == 0, running.stderr
        assert "log/launcher-events.jsonl" in members(str(tmp_path / "running.tar.gz"))
    finally:
        lp.close()

    done = report(env, str(tmp_path))
    assert done.returncode == 0, done.stderr
    out = tmp_path / ("launcher-report-%s.tar.gz" % os.path.basename(run_dir))
    assert str(out.name) in done.stdout
    files = members(str(out))
    manifest = json.loads(files["manifest.json"])
    assert manifest["run_id"] == os.path.basename(run_dir)
    assert {"log/launcher-events.jsonl", "params.yaml", "log/sleeper-2-stdout.log", "log/crasher-3-stdout.log",
            "environment.json", "versions.json", "files" + path, "files" + str(tmp_path / "db.yaml")} <= set(files)
    assert any(n.startswith("log/roslaunch-") and n.endswith(".log") for n in files)
    assert b"launch_ended" in files["log/launcher-events.jsonl"]
    assert b"exit_code\":3" in files["log/launcher-events.jsonl"]
    # the parameters the launch set, from its own record: the master is gone
    import yaml
    params = yaml.safe_load(files["params.yaml"])
    assert params["/speed"] == 2.5 and params["/db/host"] == "db.local"
    assert params["/db/password"] == "[removed by launcher report]"
    assert json.loads(files["environment.json"])["ROS_API_KEY"] != "s3cr3t-env-value"
    assert set(manifest["secrets_removed"]["names"]) >= {"/db/password", "ROS_API_KEY"}
    assert manifest["secrets_removed"]["token"] is True
    assert manifest["limits"] == {"bytes_per_file": 10 * 1000 * 1000, "bytes_in_all": 200 * 1000 * 1000,
                                  "per_file": manifest["limits"]["per_file"]}
    assert json.loads(files["versions.json"])["packages"]["report_tests"]["version"] == "0.0.1"
    assert b"#token=" in files["log/crasher-3-stdout.log"]  # the line is kept, its secret is not
    # no secret anywhere in the archive's bytes (its members' names and contents, and the compressed file)
    with open(out, "rb") as f:
        raw = f.read()
    for data in (gzip.decompress(raw), raw, gzip.decompress(open(tmp_path / "running.tar.gz", "rb").read())):
        for secret in (token, PASSWORD, "s3cr3t-env-value"):
            assert secret.encode() not in data, secret
    assert "launcher-token" not in files and not any("launcher-token" in n for n in files)


def test_report_of_a_run_that_is_not_there_says_so(tmp_path):
    env = dict(os.environ, ROS_LOG_DIR=str(tmp_path / "log"))
    os.makedirs(tmp_path / "log")
    r = report(env, str(tmp_path), "--run", "no-such-run")
    assert r.returncode != 0 and "no run [no-such-run]" in r.stderr and "Traceback" not in r.stderr
    assert not list(tmp_path.glob("*.tar.gz"))


def test_a_long_output_is_cut_to_its_last_10_mb_from_a_line_start(tmp_path, monkeypatch):
    from launcher.operate import report as rep
    run = tmp_path / "run1"
    run.mkdir()
    (run / "launcher-token").write_text("T0KEN-T0KEN\n")
    lines = b"".join(b"line %07d T0KEN-T0KEN\n" % i for i in range(200))
    (run / "node-1-stdout.log").write_bytes(lines)
    monkeypatch.setattr(rep, "MAX_FILE_BYTES", 1000)
    manifest = rep.make(str(run), str(tmp_path / "r.tar.gz"), {}, latest=False)
    got = members(str(tmp_path / "r.tar.gz"))["log/node-1-stdout.log"]
    # 25 bytes a line: the last 40 lines, whole, with the token removed from each
    assert got.startswith(b"line 0000160 ") and got.endswith(b"line 0000199 [removed by launcher report]\n")
    assert got.count(b"\n") == 40 and b"T0KEN" not in got
    entry = next(f for f in manifest["files"] if f["name"] == "log/node-1-stdout.log")
    assert entry["truncated"] == "the last 1000 of %d bytes" % len(lines)
    assert "params_missing" in manifest and "record_missing" in manifest


Aborter = "#!%s\nimport os, time\ntime.sleep(0.5)\nos.abort()\n" % ROS_PYTHON


def test_a_core_dump_is_in_the_report_as_its_backtrace_not_the_core(tmp_path, ros_env):
    """With cores written as files and gdb here (CI installs it), gdb's backtrace; a core piped to a handler
    (systemd-coredump, apport) gets what that handler tells, or where the core is."""
    import resource
    import shutil
    if resource.getrlimit(resource.RLIMIT_CORE)[1] == 0:
        pytest.skip("the hard core limit is 0 here: no process may dump core (as tests/process/test_coredumps.py)")
    piped = open("/proc/sys/kernel/core_pattern").read().startswith("|")
    make_package(str(tmp_path / "pkgs"), "report_tests", {"aborter": Aborter})
    port = free_port()
    env = env_of(str(tmp_path), port, str(tmp_path / "pkgs"))
    path = write_launch(str(tmp_path), '<node pkg="report_tests" type="aborter" name="aborter" required="true" '
                        'enable_coredumps="true" cwd="node"/>')
    lp = Launcher(["-p", str(port), path], env, str(tmp_path))
    try:
        lp.wait_output("dumped core", stream="stderr")
        lp.wait(30)
    finally:
        lp.close()
    done = report(env, str(tmp_path), "-o", str(tmp_path / "r.tar.gz"))
    assert done.returncode == 0, done.stderr
    files = members(str(tmp_path / "r.tar.gz"))
    (trace,) = [data for name, data in files.items() if name.startswith("backtraces/")]
    assert b"aborter-2: signal 6, " in trace
    if not piped:
        assert b"core dumped to " in trace
        if shutil.which("gdb") is not None:
            assert b"#0 " in trace and b"abort" in trace
        else:
            assert b"gdb is not installed" in trace
    assert not any(os.path.basename(n).startswith("core") for n in files)
