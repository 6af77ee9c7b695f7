"""Nodelets, with Debian's nodelet tool and image_proc's nodelets: a loader is bound to its manager without a
word in the launch file. SIGKILL of the manager: it respawns, then its loaders start again (new pids, once
each, the one without respawn too) and the nodelets run in the new manager; at shutdown the loaders stop
before the manager."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys

from helpers import ROS_PATH, free_port, until
from running import Launcher, master_proxy, write_launch
from running import ros_env as run_env

NODELET = "/usr/lib/nodelet/nodelet"

BODY = """
  <node pkg="nodelet" type="nodelet" name="manager" args="manager" respawn="true"/>
  <node pkg="nodelet" type="nodelet" name="rectify" args="load image_proc/rectify manager"/>
  <node pkg="nodelet" type="nodelet" name="resize" args="load image_proc/resize manager" respawn="true"/>
"""
# what the two nodelets advertise (from the manager's process), and the manager's own service
NODELET_TOPICS = {"/image_rect", "/resize/image"}


def tool(env: dict, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "launcher.cli.tool"] + list(args), env=env, capture_output=True,
                          text=True, timeout=60)


def graph(port: int) -> tuple[dict[str, list[str]], set[str]]:
    """topic -> publishers, and the services, as the master has them."""
    code, _msg, (pubs, _subs, services) = master_proxy(port).getSystemState("/test")
    assert code == 1
    return {t: nodes for t, nodes in pubs}, {s for s, _nodes in services}


def nodelets_run(port: int) -> bool:
    pubs, services = graph(port)
    return "/manager/load_nodelet" in services and all(pubs.get(t) == ["/manager"] for t in NODELET_TOPICS)


def events(tmp_path) -> list[dict]:
    path = str(tmp_path / "log" / "latest" / "launcher-events.jsonl")
    with open(path) as f:
        return [json.loads(line) for line in f if line.strip()]


def phases(tmp_path) -> list[tuple[str, str]]:
    return [(e["node"], e["phase"]) for e in events(tmp_path) if "node" in e]


def test_a_killed_manager_respawns_and_then_its_loaders_start_again(tmp_path, ros_env, ros_part_missing):
    if not os.access(NODELET, os.X_OK) or not os.path.exists("/usr/share/image_proc/nodelet_plugins.xml"):
        ros_part_missing("Debian's nodelets are not installed (libnodeletlib-tools, libimage-proc-dev)")
    port = free_port()
    env = run_env(str(tmp_path), port, str(tmp_path))
    env.update(PATH=ROS_PATH)
    lp = Launcher([write_launch(str(tmp_path), BODY)], env, str(tmp_path))
    try:
        until(lambda: nodelets_run(port), 60, 0.1, what="the nodelets loaded into the manager", errors=(OSError,))
        first = lp.started_pids()
        assert set(first) == {"manager-2", "rectify-3", "resize-4"}, first
        os.kill(first["manager-2"], signal.SIGKILL)

        def restarted():
            pids = lp.started_pids()
            return all(pids[p] != first[p] for p in first) and pids
        again = until(restarted, 60, 0.1, what="the manager and both loaders started again")
        until(lambda: nodelets_run(port), 60, 0.1, what="the nodelets loaded into the new manager")
        # Debian's rosnode sees the three again (the loaders registered anew)
        listed = subprocess.run(["rosnode", "list"], env=env, capture_output=True, text=True, timeout=30).stdout
        assert {"/manager", "/rectify", "/resize"} <= set(listed.split()), listed
        # once each: the loader without respawn too, and the one with respawn not twice
        starts = [line for line in lp.stdout.splitlines() if "started with pid" in line]
        assert sorted(starts) == sorted("process[%s]: started with pid [%d]" % (p, pid)
                                        for pids in (first, again) for p, pid in pids.items()), starts
        after_kill = phases(tmp_path)
        after_kill = after_kill[after_kill.index(("/manager", "respawning")):]
        for loader in ("/rectify", "/resize"):
            # stopped while their manager was down, started after it ran again
            assert (loader, "detached") in after_kill, after_kill
            assert after_kill.index(("/manager", "running")) < after_kill.index((loader, "running")), after_kill
        # an operator's stop of the manager stops its loaders first; its start brings them back
        before = len(phases(tmp_path))
        r = tool(env, "stop", "/manager")
        assert r.returncode == 0, r.stderr
        stop = phases(tmp_path)[before:]
        assert stop[-1] == ("/manager", "stopped"), stop
        assert {("/rectify", "detached"), ("/resize", "detached")} <= set(stop), stop
        assert ("/rectify", "running") not in stop and ("/resize", "running") not in stop, stop
        assert tool(env, "start", "/manager").returncode == 0
        until(lambda: len(lp.started_pids()) == 3 and nodelets_run(port) and all(
            lp.started_pids()[p] != again[p] for p in again), 60, 0.1, what="the manager and its loaders back")
        lp.signal(signal.SIGINT)
        assert lp.wait(30) == 0
    finally:
        lp.close()
    stopped = [e for e in phases(tmp_path) if e[1] == "stopped"]
    assert stopped[-1] == ("/manager", "stopped"), stopped
    stop_lines = [line for line in lp.stdout.splitlines() if line.endswith("killing on exit")]
    for loader in ("rectify-3", "resize-4"):
        assert stop_lines.index("[%s] killing on exit" % loader) < stop_lines.index("[manager-2] killing on exit")
