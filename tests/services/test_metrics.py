"""services/metrics.py and master/callstats.py: a record's values as samples, the exposition parsed back with
prometheus_client's own parser, the histogram's buckets, and a scrape of `--metrics` while the loop is busy."""

from __future__ import annotations

import asyncio
import threading
import time
import urllib.request

from prometheus_client.parser import text_string_to_metric_families

from launcher.fleet import lifecycle
from launcher.fleet.lifecycle import Record
from launcher.fleet.state import NodeStatus, STATES
from launcher.master.callstats import BUCKETS, OTHER, CallStats
from launcher.services import metrics
from launcher.services.metrics import Snapshot, TopicSample

from helpers import free_port


def samples(text: str) -> dict:
    """{(name, sorted labels): value} of an exposition."""
    out = {}
    for family in text_string_to_metric_families(text):
        for s in family.samples:
            out[(s.name, tuple(sorted(s.labels.items())))] = s.value
    return out


def test_callstats_buckets_are_upper_bounds_and_unknown_methods_are_other():
    stats = CallStats(["getPid", "lookupNode"])
    stats.observe("getPid", BUCKETS[0])  # on the bound: in that bucket (le)
    stats.observe("getPid", BUCKETS[0] * 1.01)
    stats.observe("getPid", 100.0)  # above every bound
    for name in ("madeUp1", "madeUp2"):
        stats.observe(name, 0.0)
    got = stats.copy()
    assert set(got) == {"getPid", OTHER}
    assert got["getPid"].buckets[0] == 1 and got["getPid"].buckets[1] == 1 and got["getPid"].buckets[-1] == 1
    assert got["getPid"].count == 3 and abs(got["getPid"].total - (BUCKETS[0] * 2.01 + 100.0)) < 1e-9
    assert got[OTHER].count == 2


def _status(record: Record, state: str, cpu_seconds: float = 0.0, rss: int | None = None) -> NodeStatus:
    status = NodeStatus(record.name, record.process, record.host)
    status.state, status.cpu_seconds, status.rss = state, cpu_seconds, rss
    return status


def test_node_columns_are_what_launcher_status_shows():
    r = Record("/a", "a-1", "localhost", lifecycle.Rules(), state=lifecycle.RUNNING, restarts=4, registered=True)
    b = Record("/b", "b-1", "localhost", lifecycle.Rules(), state=lifecycle.STOPPING)
    c = Record("/c", "c-1", "arm.local", lifecycle.Rules(), state=lifecycle.RESPAWNING, exit_code=3)
    statuses = (_status(r, "running", 1.5), _status(b, "running", 2.0, 1000), _status(c, "respawning"))
    statuses[0].last_exit_code = 3  # (kept while it runs again)
    statuses[2].last_exit_code = 3
    assert metrics.node_columns((r, b, c), statuses) == {
        "state": ("running", "running", "respawning"), "running": (True, True, False),
        "registered": (True, False, False), "restarts": (4, 0, 0), "last_exit_code": (3, None, 3),
        "cpu_seconds": (1.5, 2.0, None), "rss": (None, 1000, None)}  # (another machine's CPU is not sampled here)


def snapshot(rows: list, **kw) -> Snapshot:
    """A snapshot of nodes given as dicts of NODE_COLUMNS (and name, host)."""
    return Snapshot("run-1", tuple((r["name"], r["host"]) for r in rows),
                    {c: tuple(r[c] for r in rows) for c in metrics.NODE_COLUMNS}, **kw)


def node(name: str, state: str, running: bool, registered, restarts: int, last_exit_code, cpu_seconds, rss) -> dict:
    return dict(name=name, host="localhost", state=state, running=running, registered=registered, restarts=restarts,
                last_exit_code=last_exit_code, cpu_seconds=cpu_seconds, rss=rss)


def test_the_exposition_holds_every_family_with_its_labels():
    snap = snapshot([node("/sleeper", "running", True, True, 0, None, 1.25, 4096),
                     node("/crasher", "respawning", False, None, 5, 3, 0.5, None)],
                    topics=(TopicSample("/sleeper", "localhost", "/chatter", 9.5, 0.25),),
                    calls={"getPid": metrics.MethodStats((1, 2) + (0,) * (len(BUCKETS) - 1), 0.5)}, graph=(3, 4, 5))
    got = samples(metrics.exposition(snap).decode())
    sleeper = (("host", "localhost"), ("node", "/sleeper"))
    crasher = (("host", "localhost"), ("node", "/crasher"))
    assert got[("launcher_node_running", sleeper)] == 1 and got[("launcher_node_running", crasher)] == 0
    assert got[("launcher_node_registered", sleeper)] == 1 and ("launcher_node_registered", crasher) not in got
    assert got[("launcher_node_restarts_total", crasher)] == 5
    assert got[("launcher_node_last_exit_code", crasher)] == 3 and ("launcher_node_last_exit_code", sleeper) not in got
    assert got[("launcher_node_cpu_seconds_total", sleeper)] == 1.25
    assert got[("launcher_node_resident_memory_bytes", sleeper)] == 4096
    for n, current in ((sleeper, "running"), (crasher, "respawning")):
        assert {st: got[("launcher_node_state", tuple(sorted(n + (("state", st),))))] for st in STATES} == \
            {st: 1.0 if st == current else 0.0 for st in STATES}
    topic = tuple(sorted(sleeper + (("topic", "/chatter"),)))
    assert got[("launcher_topic_rate_hertz", topic)] == 9.5
    assert got[("launcher_topic_seconds_since_message", topic)] == 0.25
    assert got[("launcher_master_call_duration_seconds_bucket", (("le", "0.0001"), ("method", "getPid")))] == 1
    assert got[("launcher_master_call_duration_seconds_bucket", (("le", "0.00025"), ("method", "getPid")))] == 3
    assert got[("launcher_master_call_duration_seconds_bucket", (("le", "+Inf"), ("method", "getPid")))] == 3
    assert got[("launcher_master_call_duration_seconds_count", (("method", "getPid"),))] == 3
    assert got[("launcher_master_call_duration_seconds_sum", (("method", "getPid"),))] == 0.5
    assert (got[("launcher_master_registered_nodes", ())], got[("launcher_master_topics", ())],
            got[("launcher_master_services", ())]) == (3, 4, 5)
    assert got[("process_resident_memory_bytes", ())] > 0


def test_a_family_is_formatted_again_only_when_its_values_change(monkeypatch):
    a = node("/a", "running", True, True, 0, None, 1.0, 4096)
    formatter = metrics.Formatter()
    built = []

    def counted(name, build):
        def counting(key):
            built.append(name)
            return build(key)
        return counting
    monkeypatch.setattr(metrics, "FAMILIES", [(name, key_of, counted(name, build))
                                              for name, key_of, build in metrics.FAMILIES])
    first = samples(formatter.render(snapshot([a])).decode())
    assert first[("launcher_node_cpu_seconds_total", (("host", "localhost"), ("node", "/a")))] == 1.0
    built.clear()
    later = samples(formatter.render(snapshot([dict(a, cpu_seconds=2.5, state="hung")])).decode())
    assert sorted(built) == ["cpu", "state"]
    assert later[("launcher_node_cpu_seconds_total", (("host", "localhost"), ("node", "/a")))] == 2.5
    assert later[("launcher_node_state", (("host", "localhost"), ("node", "/a"), ("state", "hung")))] == 1.0
    assert later[("launcher_node_running", (("host", "localhost"), ("node", "/a")))] == 1.0  # (kept)


def test_a_scrape_while_the_loop_is_busy_gets_the_last_snapshot_and_the_loop_is_never_waited_on(monkeypatch):
    """The scrape's thread asks the loop for a snapshot; a loop busy for longer than SNAPSHOT_WAIT_S gets the
    last one served, with the process metrics read in the thread."""
    monkeypatch.setattr(metrics, "SNAPSHOT_WAIT_S", 0.3)
    calls = []

    class Exporter:
        formatter = metrics.Formatter()

        def snapshot(self):
            calls.append(threading.current_thread())
            return Snapshot("run-%d" % len(calls), ())

    async def main():
        server = metrics.MetricsServer(Exporter(), "127.0.0.1:%d" % free_port())
        await server.start()
        url = server.url
        loop = asyncio.get_running_loop()
        try:
            first = await loop.run_in_executor(None, lambda: urllib.request.urlopen(url, timeout=5).read())
            assert b'run_id="run-1"' in first
            answers = []
            scrape = threading.Thread(target=lambda: answers.append(
                (urllib.request.urlopen(url, timeout=5).read(), time.monotonic())))
            started = time.monotonic()
            scrape.start()
            time.sleep(1.5)  # the loop blocked: the scrape cannot get a new snapshot
            scrape.join(5)
            text, answered = answers[0]
            assert answered - started < 1.0, "the scrape waited for the busy loop"
            assert b'run_id="run-1"' in text and b"process_cpu_seconds_total" in text
        finally:
            await server.stop()
        return calls

    calls = asyncio.run(main())
    assert all(t is threading.main_thread() for t in calls)  # (snapshots only ever taken on the loop)
