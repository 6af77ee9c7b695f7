"""`launch --metrics` scraped every second by Debian's real Prometheus (its own storage in a temporary directory), and
read back through Prometheus's HTTP query API; the web page's server serves the same metrics without the token."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import urllib.parse
import urllib.request

import pytest

from conftest import skip_unless_ros_required
from readme import section
from helpers import ROS_PYTHON, free_port, until
from running import Launcher, RospyTalker, make_package, ros_env, write_launch

pytestmark = pytest.mark.integration

Sleeper = """#!%s
import rospy
rospy.init_node("sleeper")
rospy.spin()
""" % ROS_PYTHON
Crasher = "#!/bin/sh\necho 'crasher: giving up'\nexit 3\n"

PROMETHEUS_CONFIG = """
global:
  scrape_interval: 1s
  scrape_timeout: 1s
scrape_configs:
  - job_name: launch
    static_configs:
      - targets: ['127.0.0.1:%d']
"""


def tool(env: dict, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "launcher.cli.tool"] + list(args), env=env, capture_output=True,
                          text=True, timeout=60)


def get(url: str) -> bytes:
    with urllib.request.urlopen(url, timeout=10) as answer:
        return answer.read()


class Prometheus:
    """Debian's prometheus scraping one target every second, its storage in `tmp`."""

    def __init__(self, tmp: str, target_port: int):
        exe = shutil.which("prometheus") or shutil.which("prometheus", path="/usr/bin:/usr/sbin")
        if exe is None:
            skip_unless_ros_required("Debian's prometheus is not installed (apt-get install prometheus)")
        config = os.path.join(tmp, "prometheus.yml")
        with open(config, "w") as f:
            f.write(PROMETHEUS_CONFIG % target_port)
        self.port = free_port()
        self.log = open(os.path.join(tmp, "prometheus.log"), "wb")
        self.proc = subprocess.Popen([exe, "--config.file=" + config, "--storage.tsdb.path=" + os.path.join(tmp, "tsdb"),
                                      "--web.listen-address=127.0.0.1:%d" % self.port], stdout=self.log,
                                     stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, start_new_session=True)

    def query(self, promql: str) -> list[dict]:
        """The instant vector of `promql` now: [{"metric": labels, "value": [time, "text"]}, ...]."""
        answer = json.loads(get("http://127.0.0.1:%d/api/v1/query?%s"
                                % (self.port, urllib.parse.urlencode({"query": promql}))))
        assert answer["status"] == "success", answer
        return answer["data"]["result"]

    def value(self, promql: str) -> float | None:
        """The one value of `promql` (None: no series)."""
        result = self.query(promql)
        assert len(result) <= 1, result
        return float(result[0]["value"][1]) if result else None

    def close(self) -> None:
        self.proc.terminate()
        try:
            self.proc.wait(20)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self.log.close()


def test_prometheus_scrapes_a_launch_every_second(tmp_path, ros_env):
    talker = RospyTalker.replace("#!/usr/bin/env python3", "#!" + ROS_PYTHON)  # (20 Hz on chatter)
    make_package(str(tmp_path / "pkgs"), "metrics_tests", {"sleeper": Sleeper, "crasher": Crasher, "talker": talker})
    master_port, metrics_port, web_port = free_port(), free_port(), free_port()
    env = ros_env_of(tmp_path, master_port)
    path = write_launch(str(tmp_path), """
      <node pkg="metrics_tests" type="sleeper" name="sleeper"/>
      <node pkg="metrics_tests" type="crasher" name="crasher" respawn="true" respawn_delay="2"/>
      <node pkg="metrics_tests" type="talker" name="talker" watch_topic="chatter" watch_window="2"/>""")
    lp = Launcher(["-p", str(master_port), "--metrics", str(metrics_port), "--web", str(web_port), path], env,
                  str(tmp_path))
    prom = None
    try:
        lp.wait_output(r"metrics at http://127\.0\.0\.1:%d/metrics" % metrics_port)
        prom = Prometheus(str(tmp_path), metrics_port)
        q = prom.value
        ok = (OSError, ValueError)
        until(lambda: prom.query('up{job="launch"} == 1'), 60, 0.5, "Prometheus scraping the launch", ok)

        until(lambda: q('launcher_node_running{node="/sleeper"}') == 1, 30, 0.5, "the sleeper running", ok)
        until(lambda: q('launcher_node_registered{node="/sleeper",host="localhost"}') == 1, 30, 0.5,
              "the rospy sleeper registered", ok)
        until(lambda: (q('launcher_node_resident_memory_bytes{node="/sleeper"}') or 0) > 0, 30, 0.5,
              "the sleeper's resident memory", ok)
        assert q('launcher_node_cpu_seconds_total{node="/sleeper"}') is not None

        until(lambda: (q('launcher_node_restarts_total{node="/crasher"}') or 0) >= 2, 60, 0.5,
              "two restarts of the crasher", ok)
        scraped = q('launcher_node_restarts_total{node="/crasher"}')
        r = tool(env, "status", "--json")
        assert r.returncode == 0, r.stderr
        shown = {n["name"]: n for n in json.loads(r.stdout)["nodes"]}["/crasher"]["restarts"]
        assert abs(scraped - shown) <= 1, (scraped, shown)
        until(lambda: q('launcher_node_last_exit_code{node="/crasher"}') == 3, 30, 0.5, "the crasher's exit code 3",
              ok)

        # the watched topic's rate (over its 2 s window) and silence
        until(lambda: 10 <= (q('launcher_topic_rate_hertz{node="/talker",topic="/chatter"}') or 0) <= 30, 30, 0.5,
              "the talker's 20 Hz", ok)
        assert q('launcher_topic_seconds_since_message{node="/talker",topic="/chatter"}') < 1.5

        # each node's state series: one per public state, and they sum to 1
        states = prom.query('launcher_node_state{node=~"/sleeper|/crasher"}')
        assert {(s["metric"]["node"], s["metric"]["state"]) for s in states} == {
            (n, st) for n in ("/sleeper", "/crasher")
            for st in ("waiting", "running", "respawning", "exited", "fatal", "hung", "stalled", "stopped")}
        sums = {s["metric"]["node"]: float(s["value"][1]) for s in prom.query("sum by (node) (launcher_node_state)")}
        assert sums == {"/sleeper": 1.0, "/crasher": 1.0, "/talker": 1.0}

        # the master's latency histogram (the sleeper registered through it) and the launcher's own process
        buckets = prom.query('launcher_master_call_duration_seconds_bucket{method="registerPublisher"}')
        assert {b["metric"]["le"] for b in buckets} >= {"0.001", "+Inf"}
        assert q('launcher_master_call_duration_seconds_count{method="registerPublisher"}') >= 1
        until(lambda: prom.query("histogram_quantile(0.99, sum by (le) (rate("
                                 "launcher_master_call_duration_seconds_bucket[1m])))"), 30, 0.5, "the p99", ok)
        assert q('launcher_master_registered_nodes') >= 2  # (the sleeper and rosout)
        assert q('process_resident_memory_bytes{job="launch"}') > 0
        assert q('process_cpu_seconds_total{job="launch"}') is not None
        assert int(q('process_open_fds{job="launch"}')) > 0

        # the README's query of each family: Prometheus takes each, and the node families' give an answer here
        rows = [line.split("|") for line in section("Metrics for Prometheus").splitlines() if line.startswith("| `")]
        queries = [re.search(r"`([^`]+)`", row[2]).group(1) for row in rows]
        assert len(queries) >= 12
        for promql in queries:
            prom.query(promql)  # (asserts Prometheus's "success")
        assert prom.query("sum by (state) (launcher_node_state)")

        # the web page's server: the same metrics, read-only, with no token
        text = until(lambda: get("http://127.0.0.1:%d/metrics" % web_port).decode(), 30, 0.5, "the page's /metrics",
                     ok)
        assert 'launcher_node_running{host="localhost",node="/sleeper"} 1.0' in text
    finally:
        if prom is not None:
            prom.close()
        lp.close()


def ros_env_of(tmp_path, port: int) -> dict:
    return ros_env(str(tmp_path), port, str(tmp_path / "pkgs"))
