"""A run's Prometheus metrics: what `launcher status` shows of every node, its watched topics, the master's calls and
the launcher's own process, read at scrape time; `launch --metrics [ADDR:]PORT` serves them at /metrics.

A scrape never blocks the launch's loop. The loop only copies what it has into
a `Snapshot` (columns of values made with map(): a quarter of a millisecond for 500 nodes); the text is made
in the scraping thread by the official client library, `prometheus_client`
(its metric families and its `generate_latest`, fed by us: nothing is
registered or updated on the loop), and a family whose values did not change
since the last scrape is not formatted again (`Formatter`). The `--metrics`
server is the standard library's WSGI server, in a thread; the loop is asked
for a snapshot with `call_soon_threadsafe`, and a loop that does not answer
within SNAPSHOT_WAIT_S gets the last one served (with the process metrics,
read in the thread: what a stuck launch looks like is still scraped). The text
is Prometheus's format 0.0.4, whatever a scraper prefers (OpenMetrics costs the
library twice the time, and Prometheus reads both). The
launch's XML-RPC server answers `launcher_metrics` the same way (the snapshot
on the loop, the text in a worker thread): the web page's server serves it at
its own /metrics.

The values are the fleet's, the same `launcher status` reads: the node's public
state, restarts, exit code, CPU and RSS (sampled by health/resources.py; the
CPU counter adds each sample's use, so it never goes down across respawns).
prometheus_client is imported when the first scrape comes (~45 ms: a launch
that is never scraped does not pay for it).
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import operator
import socket
import sys
import threading
from typing import TYPE_CHECKING, Any, Callable, NamedTuple

from launcher import __version__
from launcher.fleet import lifecycle
from launcher.fleet.state import LOCAL_HOST, STATES
from launcher.master.callstats import BUCKETS, MethodStats
from launcher.model.errors import LaunchError
from launcher.output import console

if TYPE_CHECKING:  # (annotations only)
    from launcher.services.service import MasterLink, RunNodes

SNAPSHOT_WAIT_S = 2.0  # a scrape waits this long for the loop's snapshot, then serves the last one
RUNNING_PHASES = frozenset((lifecycle.RUNNING, lifecycle.HUNG, lifecycle.STALLED, lifecycle.STOPPING))  # a process runs
NODE_LABELS = ["node", "host"]


NODE_COLUMNS = ("state", "running", "registered", "restarts", "last_exit_code", "cpu_seconds", "rss")


class TopicSample(NamedTuple):
    node: str
    host: str
    topic: str
    rate: float  # messages a second over the watch window
    since_last: float | None  # seconds since its last message (None: none yet)


class Snapshot(NamedTuple):
    """The run's values at one scrape. The nodes' are columns: `nodes` their (name, host), `columns` each of
    NODE_COLUMNS, a value a node in the same order: made with map() on the loop, compared whole in the thread."""

    run_id: str
    nodes: tuple[tuple[str, str], ...] = ()
    # state: its public state (fleet.state.STATES); running: its process runs; registered: with the master; restarts;
    # last_exit_code (None: none yet); cpu_seconds (None: not sampled here, another machine's); rss
    columns: dict[str, tuple] = {}
    topics: tuple[TopicSample, ...] = ()
    calls: dict[str, MethodStats] | None = None  # the master's calls by method (None: not our master)
    graph: tuple[int, int, int] | None = None  # registered nodes, topics, services (None: not our master)


_get = operator.attrgetter


def node_columns(records: tuple, statuses: tuple) -> dict[str, tuple]:
    """The nodes' records (fleet.lifecycle.Record) and statuses (fleet.state.NodeStatus) as a scrape's columns: the
    values `launcher status` shows (registered: the record's, told by health/registration; last_exit_code: kept
    while the node runs again)."""
    cpu = tuple(map(_get("cpu_seconds"), statuses))
    hosts = tuple(map(_get("host"), records))
    if any(h != LOCAL_HOST for h in hosts):  # (another machine's nodes are not sampled here)
        cpu = tuple(c if h == LOCAL_HOST else None for c, h in zip(cpu, hosts))
    return {"state": tuple(map(_get("state"), statuses)),
            "running": tuple(map(RUNNING_PHASES.__contains__, map(_get("state"), records))),
            "registered": tuple(map(_get("registered"), records)), "restarts": tuple(map(_get("restarts"), records)),
            "last_exit_code": tuple(map(_get("last_exit_code"), statuses)), "cpu_seconds": cpu,
            "rss": tuple(map(_get("rss"), statuses))}


class Exporter:
    """What a run's metrics are read from: its master session and its nodes (the fleet, the stall watch)."""

    def __init__(self, master: MasterLink, nodes: RunNodes, run_id: Callable[[], str]):
        self.master = master
        self.nodes = nodes
        self.run_id = run_id
        self.formatter = Formatter()  # (what each family's text was at the last scrape, for both servers)

    def snapshot(self) -> Snapshot:
        """The run's values now: on the loop (it reads the fleet), and cheap (no text is made here)."""
        ours = self.master.master  # our master, None when one was found running
        api = ours.api if ours is not None else None
        registry = api.registry if api is not None else None
        fleet = self.nodes.fleet
        nodes: tuple[tuple[str, str], ...] = ()
        columns: dict[str, tuple] = {}
        if fleet is not None:
            statuses = tuple(fleet.nodes.values())
            records = tuple(map(fleet.records.__getitem__, fleet.nodes))
            nodes = tuple(map(_get("name", "host"), records))
            columns = node_columns(records, statuses)
        topics = []
        stall = self.nodes.stall
        if stall is not None:
            now = asyncio.get_running_loop().time()
            for node, watches in stall.watches.items():
                for topic, watch in watches.items():
                    topics.append(TopicSample(node, LOCAL_HOST, topic, watch.rate(now),
                                              None if watch.last is None else now - watch.last))
        graph = None
        if registry is not None:
            graph = (len(registry.nodes), len(set(registry.publishers.map) | set(registry.subscribers.map)),
                     len(registry.services.map))
        return Snapshot(self.run_id(), nodes, columns, tuple(topics), ours.calls.copy() if ours is not None else None,
                        graph)

    async def text(self) -> str:
        """The exposition (Prometheus's text format) of the run now: the snapshot on the loop, the text made in a
        worker thread (what `launcher_metrics` answers)."""
        snap = self.snapshot()
        data = await asyncio.get_running_loop().run_in_executor(None, self.formatter.render, snap)
        return data.decode("utf-8")


# ---- in the scraping thread ----------------------------------------------------------------------------
#
# Each family is a key (its values, from the snapshot: tuples compared in microseconds) and a builder of the
# library's family from that key. A scrape formats again only the families whose key changed since the last one:
# the library formats ~30 µs a sample, and a 500-node launch has ~6,600 (8 state series a node), most of which (the
# states, restarts, registration) change seldom; CPU and memory, which move, are 1,000 of them.

CONTENT_TYPE = "text/plain; version=0.0.4; charset=utf-8"  # what prometheus_client's generate_latest writes


def _column(field: str) -> Callable[[Snapshot], tuple]:
    """A node family's key: the nodes' (name, host) and their column of `field`, as the loop made them."""
    return lambda snap: (snap.nodes, snap.columns.get(field, ()))


def _node_family(kind: str, name: str, doc: str, convert: Callable[[Any], float]) -> Callable[[tuple], Any]:
    def build(key: tuple) -> Any:
        from prometheus_client import core
        family = getattr(core, kind)(name, doc, labels=NODE_LABELS)
        for (node, host), value in zip(*key):
            if value is not None:
                family.add_metric([node, host], convert(value))  # (registered may be a URI: bool() of it)
        return family
    return build


def _states(key: tuple) -> Any:
    from prometheus_client.core import GaugeMetricFamily
    family = GaugeMetricFamily("launcher_node_state", "1 for the node's current state (README), 0 for the others",
                               labels=NODE_LABELS + ["state"])
    for (node, host), current in zip(*key):
        for s in STATES:
            family.add_metric([node, host, s], 1.0 if s == current else 0.0)
    return family


def _info(key: tuple) -> Any:
    from prometheus_client.core import GaugeMetricFamily
    family = GaugeMetricFamily("launcher_run_info", "The run this launch is (always 1)", labels=["run_id", "version"])
    family.add_metric([key[0], __version__], 1.0)
    return family


def _topics(key: tuple) -> list:
    from prometheus_client.core import GaugeMetricFamily
    labels = NODE_LABELS + ["topic"]
    rate = GaugeMetricFamily("launcher_topic_rate_hertz", "Messages a second of a watched topic (watch_topic), over "
                             "its watch window", labels=labels)
    silence = GaugeMetricFamily("launcher_topic_seconds_since_message", "Seconds since a watched topic's last "
                                "message", labels=labels)
    for t in key:
        rate.add_metric([t.node, t.host, t.topic], t.rate)
        if t.since_last is not None:
            silence.add_metric([t.node, t.host, t.topic], t.since_last)
    return [rate, silence]


def _calls(key: tuple) -> Any:
    from prometheus_client.core import HistogramMetricFamily
    from prometheus_client.utils import floatToGoString
    family = HistogramMetricFamily("launcher_master_call_duration_seconds", "Master API calls by method: the time "
                                   "from a complete request to its reply written", labels=["method"])
    bounds = [floatToGoString(b) for b in BUCKETS] + ["+Inf"]
    for method, stats in key:
        cumulative, buckets = 0, []
        for bound, count in zip(bounds, stats.buckets):
            cumulative += count
            buckets.append((bound, cumulative))
        family.add_metric([method], buckets, stats.total)
    return family


def _graph(key: tuple) -> list:
    from prometheus_client.core import GaugeMetricFamily
    out = []
    for name, doc, value in zip(("launcher_master_registered_nodes", "launcher_master_topics",
                                 "launcher_master_services"),
                                ("Nodes registered with the master", "Topics with a publisher or a subscriber",
                                 "Services registered with the master"), key):
        g = GaugeMetricFamily(name, doc)
        g.add_metric([], value)
        out.append(g)
    return out


# (name, key of a snapshot (None: the family is left out), builder of the family or families from the key)
FAMILIES: list[tuple[str, Callable[[Snapshot], Any], Callable[[Any], Any]]] = [
    ("info", lambda snap: (snap.run_id,), _info),
    ("running", _column("running"),
     _node_family("GaugeMetricFamily", "launcher_node_running", "1 while the node's process runs", float)),
    ("registered", _column("registered"),
     _node_family("GaugeMetricFamily", "launcher_node_registered", "1 while the node is registered with the master",
                  lambda v: float(bool(v)))),
    ("restarts", _column("restarts"),
     _node_family("CounterMetricFamily", "launcher_node_restarts", "Starts of the node after its first", float)),
    ("last_exit_code", _column("last_exit_code"),
     _node_family("GaugeMetricFamily", "launcher_node_last_exit_code", "The exit code of the node's last run that "
                  "exited", float)),
    ("cpu", _column("cpu_seconds"),
     _node_family("CounterMetricFamily", "launcher_node_cpu_seconds", "CPU time used by the node's process group, "
                  "all its runs", float)),
    ("rss", _column("rss"),
     _node_family("GaugeMetricFamily", "launcher_node_resident_memory_bytes", "Resident memory of the node's "
                  "process group", float)),
    ("state", _column("state"), _states),
    ("topics", lambda snap: snap.topics, _topics),
    ("calls", lambda snap: None if snap.calls is None else tuple(sorted(snap.calls.items())), _calls),
    ("graph", lambda snap: snap.graph, _graph),
]


class _Families:
    """What generate_latest reads: an object with collect()."""

    def __init__(self, families: Any):
        self.families = families if isinstance(families, list) else [families]

    def collect(self) -> list:
        return self.families


class Formatter:
    """The text of snapshots, each family formatted by prometheus_client and kept until its values change."""

    def __init__(self) -> None:
        self._lock = threading.Lock()  # (two scrapes at once: one formats, the other waits, then reuses)
        self._kept: dict[str, tuple[Any, bytes]] = {}
        self._process: Any = None

    def render(self, snap: Snapshot | None) -> bytes:
        from prometheus_client import generate_latest
        parts = []
        with self._lock:
            if snap is not None:
                for name, key_of, build in FAMILIES:
                    key = key_of(snap)
                    if key is None:
                        continue
                    kept = self._kept.get(name)
                    if kept is None or kept[0] != key:
                        kept = self._kept[name] = (key, generate_latest(_Families(build(key))))
                    parts.append(kept[1])
            if self._process is None:
                from prometheus_client import CollectorRegistry, ProcessCollector
                self._process = CollectorRegistry(auto_describe=False)
                ProcessCollector(registry=self._process)
            parts.append(generate_latest(self._process))  # (the launcher's own process: read now)
        return b"".join(parts)


def exposition(snap: Snapshot) -> bytes:
    """A snapshot in Prometheus's text format, with the process metrics read now (nothing kept)."""
    return Formatter().render(snap)


# ---- launch --metrics ----------------------------------------------------------------------------------


def parse_address(text: str) -> tuple[str, int]:
    """[ADDR:]PORT: loopback unless an address is given."""
    host, sep, port = text.rpartition(":")
    if not port.isdigit() or int(port) > 65535:
        raise LaunchError("--metrics: the address is [ADDR:]PORT, not [%s]" % text)
    return (host.strip("[]") if sep and host else "127.0.0.1"), int(port)


class MetricsServer:
    """`launch --metrics [ADDR:]PORT`: /metrics served by the standard library's WSGI server in a thread (a thread
    per scrape), the text made there by prometheus_client."""

    def __init__(self, exporter: Exporter, address: str):
        self.exporter = exporter
        self.host, self.port = parse_address(address)
        self.url = ""
        self._loop: asyncio.AbstractEventLoop | None = None
        self._httpd: Any = None
        self._last: Snapshot | None = None

    async def start(self) -> None:
        self._loop = asyncio.get_running_loop()
        try:
            # (the library's import and the bind off the loop: the nodes are starting meanwhile)
            self._httpd = await self._loop.run_in_executor(None, self._serve)
        except OSError as e:  # the launch runs on without it, as without any server that cannot start
            console.printerrlog("could not serve the metrics at %s:%d: %s" % (self.host, self.port, e.strerror or e))
            return
        except ImportError as e:
            console.printerrlog("could not serve the metrics: this Python (%s) lacks %s (pip install "
                                "prometheus_client)" % (sys.executable, e.name))
            return
        host = "[%s]" % self.host if ":" in self.host else self.host
        self.url = "http://%s:%d/metrics" % (host, self._httpd.server_address[1])
        console.printlog("metrics at %s" % self.url)

    def _serve(self) -> Any:
        # (imported here, off the loop and only with --metrics: http.server costs a launch ~45 ms; and the first
        # scrape does not wait for prometheus_client)
        import prometheus_client  # noqa: F401
        import socketserver
        from wsgiref.simple_server import WSGIRequestHandler, WSGIServer, make_server

        class Server(socketserver.ThreadingMixIn, WSGIServer):
            address_family = socket.AF_INET6 if ":" in self.host else socket.AF_INET
            daemon_threads = True  # (a scrape under way never holds the launch's exit)

        class QuietHandler(WSGIRequestHandler):
            def log_message(self, format: str, *args: Any) -> None:  # (no line per scrape on the launch's stderr)
                pass
        httpd = make_server(self.host, self.port, self._app, Server, handler_class=QuietHandler)
        threading.Thread(target=httpd.serve_forever, name="launcher-metrics", daemon=True).start()
        return httpd

    def _app(self, environ: dict, start_response: Any) -> list:
        if environ.get("PATH_INFO") not in ("/metrics", "/"):
            start_response("404 Not Found", [("Content-Type", "text/plain")])
            return [b"not found: the metrics are at /metrics\n"]
        body = self.exporter.formatter.render(self._take())
        start_response("200 OK", [("Content-Type", CONTENT_TYPE), ("Content-Length", str(len(body)))])
        return [body]

    def _take(self) -> Snapshot | None:
        """The loop's snapshot (in a scrape's thread), or the last one if the loop does not answer in time."""
        loop = self._loop
        done: concurrent.futures.Future = concurrent.futures.Future()

        def take() -> None:
            if done.set_running_or_notify_cancel():
                try:
                    done.set_result(self.exporter.snapshot())
                except Exception as e:  # noqa: BLE001 - said to the scrape, never to the loop
                    done.set_exception(e)
        try:
            loop.call_soon_threadsafe(take)
            self._last = done.result(SNAPSHOT_WAIT_S)
        except concurrent.futures.TimeoutError:
            done.cancel()
        except Exception:  # noqa: BLE001 - the loop has closed, or the snapshot failed: the last one is served
            pass
        return self._last

    async def stop(self) -> None:
        httpd, self._httpd = self._httpd, None
        if httpd is not None:
            # (shutdown waits for serve_forever's poll, up to half a second: off the loop)
            await asyncio.get_running_loop().run_in_executor(None, _close, httpd)


def _close(httpd: Any) -> None:
    httpd.shutdown()
    httpd.server_close()

