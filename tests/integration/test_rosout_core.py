"""`launch --core`'s built-in rosout beside Debian's `roscore`: same rosnode info, same log lines."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import xmlrpc.client

import pytest

pytestmark = pytest.mark.integration

sys.path.insert(0, os.path.dirname(__file__))
from helpers import Procs, free_port, until  # noqa: E402
from test_rosout_nodes import PY_LOGGER  # noqa: E402


def _core(procs: Procs, argv: list[str], env: dict[str, str]) -> xmlrpc.client.ServerProxy:
    procs.start(argv)
    master = xmlrpc.client.ServerProxy(env["ROS_MASTER_URI"])

    def rosout_up() -> bool:
        try:
            return any(s[0] == "/rosout/set_logger_level" for s in master.getSystemState("/t")[2][2])
        except OSError:
            return False
    until(rosout_up, timeout=60, what="%s with /rosout" % argv[0])
    return master


def _rosout_log(env: dict[str, str], master: xmlrpc.client.ServerProxy) -> str:
    run_id = master.getParam("/t", "/run_id")[2]
    return os.path.join(env["ROS_LOG_DIR"], run_id, "rosout.log")


def _demo_lines(path: str) -> list[str]:
    try:
        text = open(path, encoding="utf-8").read()
    except FileNotFoundError:
        return []
    lines = [l for l in text.splitlines() if " /py_logger " in l and not l.endswith("] waiting")]
    return lines if any(l.endswith("] done") for l in lines) else []


def _waiting_seen(path: str) -> bool:
    try:
        text = open(path, encoding="utf-8").read()
    except FileNotFoundError:
        return False
    return any(" /py_logger " in l and l.endswith("] waiting") for l in text.splitlines())


def test_launch_core_rosout_looks_like_roscore_rosout(ros_env, tmp_path):
    script = tmp_path / "py_logger.py"
    script.write_text(PY_LOGGER)
    base = {k: v for k, v in os.environ.items() if not k.startswith("ROS_")}
    base.update(PATH=ros_env["path"], ROS_HOSTNAME="127.0.0.1", PYTHONUNBUFFERED="1")
    results = {}
    for kind in ("roscore", "launch"):
        port = free_port()
        env = dict(base, ROS_MASTER_URI="http://127.0.0.1:%d/" % port,
                   ROS_LOG_DIR=str(tmp_path / kind / "log"), ROS_HOME=str(tmp_path / kind))
        if kind == "launch":
            # Our command, from the same python that runs the tests, ROS tools still reachable.
            env["PATH"] = os.path.dirname(sys.executable) + ":" + ros_env["path"]
            argv = [sys.executable, "-m", "launcher", "--core", "-p", str(port)]
        else:
            argv = ["roscore", "-p", str(port)]
        procs = Procs(env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            master = _core(procs, argv, env)
            info = procs.output(["rosnode", "info", "/rosout"])
            procs.start([ros_env["python"], str(script), "__name:=py_logger"])
            path = _rosout_log(env, master)
            # registered is not connected: lines logged before rosout's subscription is up are lost
            # (by roscore's rosout too), so "go" only once a "waiting" line has come through
            until(lambda: _waiting_seen(path), 20, what="py_logger connected to rosout")
            master.setParam("/t", "/rosout_test/go", True)
            lines = until(lambda: _demo_lines(path), 20, what="demo lines in %s" % path)
            results[kind] = (info, lines, open(path).read().splitlines()[:3])
        finally:
            procs.stop_all()

    def norm_info(text: str) -> str:
        return re.sub(r"Pid: \d+", "Pid: N", re.sub(r"http://[\d.]+:\d+/", "URI", text))

    def norm_line(line: str) -> str:
        line = re.sub(r"^\d+\.\d{9} ", "STAMP ", line)
        # rospy lists its publications in no fixed order.
        return re.sub(r"\[topics: ([^\]]*)\]",
                      lambda m: "[topics: %s]" % ", ".join(sorted(m.group(1).split(", "))), line)

    ref_info, ref_lines, ref_head = results["roscore"]
    our_info, our_lines, our_head = results["launch"]
    assert norm_info(our_info) == norm_info(ref_info)
    assert [norm_line(l) for l in our_lines] == [norm_line(l) for l in ref_lines]
    assert len(our_lines) == 5  # info, warn, error, fatal, done
    assert [re.sub(r"^\d+\.\d{9}", "T", l) for l in our_head] == [
        re.sub(r"^\d+\.\d{9}", "T", l) for l in ref_head] == ["", "", "T  Node Startup"]
