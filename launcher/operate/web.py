"""The live view as a web page: `launcher web [ADDR:]PORT` (a running launch) and `launch --web [ADDR:]PORT`: one
page, its live updates (server-sent events), the nodes' recent output, start/stop/restart with the run's token, and
the topics from the master's registry.

A process apart from the launch, as the terminal view (`operate/ui.py`): it reads
the launch through its server (the change stream, the samples, the output long
poll) and passes the operator's token on to it, so a browser never costs the
launch more than one more reader. It sends changes, not the table: a new page
gets the table once, then each change, each sample that moved, each new output.
The HTTP side is the standard library's threading server (a handful of
browsers, each held by its event stream). Guards, on loopback too (every local
user shares it): a request whose `Host` is not this server by address, by
`localhost` or by this machine's name is refused (DNS rebinding), and so is one
whose `Origin` is another site's; a mutating request without the run's token
gets 403. The page's files (operate/webpage/) ship in the package, no CDN.
`/metrics` is the launch's Prometheus metrics (`launcher_metrics`, services/metrics.py),
read-only as the page, so without the token.
"""

from __future__ import annotations

import argparse
import collections
import http.server
import ipaddress
import json
import os
import queue
import socket
import sys
import threading
import time
from typing import Any

from launcher.net.xmlrpc import Fault, XmlRpcError, call_blocking
from launcher.operate import client
from launcher.model import token as run_token
from launcher.operate import ui as reader  # (the launch's read calls; no prompt_toolkit is imported with it)
from launcher.operate.ui import POLL_WAIT_S
from launcher.operate.view import ViewState

PAGE_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "webpage")
FILES = {"/": ("index.html", "text/html; charset=utf-8"), "/app.js": ("app.js", "text/javascript; charset=utf-8"),
         "/style.css": ("style.css", "text/css; charset=utf-8")}
METRICS_TYPE = "text/plain; version=0.0.4; charset=utf-8"  # Prometheus's text format (launcher_metrics' answer)
SAMPLE_PERIOD_S = 1.0
HISTORY = 60  # samples a sparkline shows (a minute)
KEEPALIVE_S = 15.0  # an event stream's comment line while nothing happens (proxies close silent connections)
CONTROL_TIMEOUT_S = 600.0
CLIENT_QUEUE = 1000  # events a slow browser may lag behind before it is dropped (it reconnects and starts over)


def round_sample(cpu: float | None, rss: int | None) -> list:
    """A sample as the page gets it: CPU to a tenth of a percent, RSS to 100 kB (finer moves are noise, and
    a sample that did not move is not sent)."""
    return [None if cpu is None else round(cpu, 3), None if rss is None else int(rss) // 100000 * 100000]


class Hub:
    """The launch as the page sees it: a ViewState kept current from the launch's server, and every change
    handed to each connected page."""

    def __init__(self, uri: str):
        self.uri = uri
        self.state = ViewState()
        self.state.load(client.status(uri))
        self.lock = threading.Lock()
        self.clients: list[queue.Queue] = []
        self.sent: dict[str, list] = {}  # the samples the pages have
        # each node's samples over the last minute, as a new page's sparklines start (then it keeps its own)
        self.history: dict[str, collections.deque] = {
            name: collections.deque((round_sample(cpu, rss) for _t, cpu, rss in kept), maxlen=HISTORY)
            for name, kept in reader.past_samples(uri).items()}  # (what the launch kept: full from the start)
        self.gone = threading.Event()

    def start(self) -> None:
        for target in (self._changes, self._samples, self._output):
            threading.Thread(target=target, daemon=True).start()

    def _call(self, method: str, *params: Any, timeout: float = 10.0) -> Any:
        return reader.call(self.uri, method, *params, timeout=timeout)

    def _loop(self, body: Any) -> None:
        failures = 0
        while not self.gone.is_set():
            try:
                body()
                failures = 0
            except (OSError, XmlRpcError, Fault, ValueError):
                failures += 1
                if failures >= 3:  # (the launch has ended: so does its page server)
                    self.gone.set()
                    self.broadcast({"type": "gone"})
                self.gone.wait(1.0)

    def broadcast(self, event: dict) -> None:
        data = ("data: %s\n\n" % json.dumps(event, separators=(",", ":"))).encode()
        with self.lock:
            for q in list(self.clients):
                try:
                    q.put_nowait(data)
                except queue.Full:  # (a page that cannot keep up starts over: it is told to reconnect)
                    self.clients.remove(q)
                    with q.mutex:
                        q.queue.clear()
                    q.put_nowait(None)

    def subscribe(self) -> tuple[queue.Queue, bytes]:
        """A page's queue, and its first event: the table as it is now."""
        q: queue.Queue = queue.Queue(CLIENT_QUEUE)
        with self.lock:
            nodes = [dict(n) for n in self.state.nodes.values()]
            snapshot = {"type": "snapshot", "nodes": nodes, "uri": self.state.info.get("uri"),
                        "history": {name: list(h) for name, h in self.history.items()},
                        "run_id": self.state.info.get("run_id"), "seq": self.state.seq}
            self.clients.append(q)
        return q, ("data: %s\n\n" % json.dumps(snapshot, separators=(",", ":"), default=str)).encode()

    def unsubscribe(self, q: queue.Queue) -> None:
        with self.lock:
            if q in self.clients:
                self.clients.remove(q)

    def _changes(self) -> None:
        def body() -> None:
            answer = json.loads(self._call("launcher_changes", self.state.seq, POLL_WAIT_S, timeout=POLL_WAIT_S + 10))
            with self.lock:
                if not answer["complete"]:
                    self.state.load(json.loads(self._call("launcher_status")))
                self.state.changes(answer["changes"])
                self.state.seq = max(self.state.seq, answer["seq"])
            if answer["changes"]:
                self.broadcast({"type": "changes", "changes": answer["changes"]})
        self._loop(body)

    def _samples(self) -> None:
        def body() -> None:
            samples = json.loads(self._call("launcher_samples"))
            with self.lock:
                self.state.samples(samples)
                now = {name: round_sample(*samples.get(name, (None, None))) for name in self.state.nodes}
                moved = {name: s for name, s in now.items() if self.sent.get(name) != s}
                self.sent = now
                for name, sample in now.items():
                    self.history.setdefault(name, collections.deque(maxlen=HISTORY)).append(sample)
            if moved:
                self.broadcast({"type": "samples", "time": round(time.time(), 1), "samples": moved})
            self.gone.wait(SAMPLE_PERIOD_S)
        self._loop(body)

    def _output(self) -> None:
        offsets: dict[str, int] = {}

        def body() -> None:
            output, log = reader.new_output(self.uri, offsets)
            if output or log:
                self.broadcast({"type": "output", "output": output, "log": log})
        self._loop(body)

    def recent_output(self, node: str) -> str:
        return reader.recent_output(self.uri, node)

    def topics(self) -> list[dict]:
        """Each topic of the master's registry: its type, publishers and subscribers."""
        master = self.state.info.get("master_uri")
        code, _msg, (pubs, subs, _srvs) = call_blocking(master, "getSystemState", "/launcher_web", timeout=10)
        code2, _msg2, types = call_blocking(master, "getTopicTypes", "/launcher_web", timeout=10)
        type_of = dict(types) if code2 == 1 else {}
        topics: dict[str, dict] = {}
        for topic, nodes in pubs:
            topics.setdefault(topic, {"topic": topic, "publishers": [], "subscribers": []})["publishers"] = nodes
        for topic, nodes in subs:
            topics.setdefault(topic, {"topic": topic, "publishers": [], "subscribers": []})["subscribers"] = nodes
        for t in topics.values():
            t["type"] = type_of.get(t["topic"], "")
        return sorted(topics.values(), key=lambda t: t["topic"])


def allowed_host(host: str, port: int, bound: str) -> bool:
    """Whether a request's Host header names this server: by an address literal, `localhost` or this machine's
    name, with our port. A name that merely resolves here (DNS rebinding) does not."""
    name, sep, p = host.rpartition(":")
    if not sep or p != str(port) or not name:
        return False
    name = name.strip("[]").lower()
    if name in ("localhost", socket.gethostname().lower(), socket.getfqdn().lower()):
        return True
    try:
        ipaddress.ip_address(name)
    except ValueError:
        return False
    return True


def make_handler(hub: Hub, port_box: list, bound: str) -> type:
    class Handler(http.server.BaseHTTPRequestHandler):
        protocol_version = "HTTP/1.1"
        server_version = "launcher-web"

        def log_message(self, format: str, *args: Any) -> None:  # (quiet: the launch's terminal is not ours)
            pass

        def _send(self, status: int, body: bytes, ctype: str = "text/plain; charset=utf-8") -> None:
            self.send_response(status)
            self.send_header("Content-Type", ctype)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "no-store")
            # the page runs only its own files, and no other site may frame it
            self.send_header("Content-Security-Policy", "default-src 'self'; frame-ancestors 'none'")
            self.send_header("X-Content-Type-Options", "nosniff")
            self.end_headers()
            self.wfile.write(body)

        def _json(self, value: Any, status: int = 200) -> None:
            self._send(status, json.dumps(value, default=str).encode(), "application/json")

        def _guard(self) -> bool:
            host = self.headers.get("Host", "")
            if not allowed_host(host, port_box[0], bound):
                self._send(403, b"refused: the Host header does not name this server\n")
                return False
            origin = self.headers.get("Origin")
            if origin is not None and origin != "http://" + host:
                self._send(403, b"refused: a request from another site\n")
                return False
            return True

        def do_GET(self) -> None:
            if not self._guard():
                return
            path, _, query = self.path.partition("?")
            if path in FILES:
                name, ctype = FILES[path]
                with open(os.path.join(PAGE_DIR, name), "rb") as f:
                    body = f.read()
                if name == "index.html":
                    body = body.replace(b"{{BOUND}}", ("%s:%d" % (bound, port_box[0])).encode())
                self._send(200, body, ctype)
            elif path == "/events":
                self._events()
            elif path == "/api/output":
                node = dict(p.partition("=")[::2] for p in query.split("&")).get("node", "")
                from urllib.parse import unquote
                try:
                    self._json({"node": unquote(node), "output": hub.recent_output(unquote(node))})
                except (OSError, XmlRpcError, Fault, ValueError) as e:
                    self._json({"error": str(e)}, 502)
            elif path == "/metrics":  # Prometheus's scrape: read-only, as the page, so without the token
                try:
                    self._send(200, reader.call(hub.uri, "launcher_metrics", timeout=10.0).encode(), METRICS_TYPE)
                except (OSError, XmlRpcError, Fault, ValueError) as e:
                    self._send(502, ("the launch does not answer: %s\n" % e).encode())
            elif path == "/api/topics":
                try:
                    self._json(hub.topics())
                except (OSError, XmlRpcError, Fault, ValueError, TypeError) as e:
                    self._json({"error": str(e)}, 502)
            else:
                self._send(404, b"not found\n")

        def do_POST(self) -> None:
            if not self._guard():
                return
            length = int(self.headers.get("Content-Length") or 0)
            body = self.rfile.read(min(length, 65536)) if length else b""
            verb = self.path.rpartition("/")[2]
            if not self.path.startswith("/api/") or verb not in ("start", "stop", "restart", "reload"):
                self._send(404, b"not found\n")
                return
            token = self.headers.get("X-Launcher-Token", "")
            if not token:
                self._send(403, b"refused: start, stop, restart and reload need the run's token\n")
                return
            if verb == "reload":
                self._reload(token)
                return
            try:
                pattern = json.loads(body or b"{}").get("node", "")
            except (ValueError, AttributeError):
                self._send(400, b"the body is JSON {\"node\": PATTERN}\n")
                return
            try:
                code, msg, names = call_blocking(hub.uri, "%s_nodes" % verb, token, pattern, timeout=CONTROL_TIMEOUT_S)
            except Fault as e:
                self._send(403 if e.faultCode == run_token.REFUSED else 400, (e.faultString + "\n").encode())
                return
            except (OSError, XmlRpcError) as e:
                self._send(502, ("the launch does not answer: %s\n" % e).encode())
                return
            self._json({"ok": code == 1, "message": msg, "nodes": names}, 200 if code == 1 else 400)

        def _reload(self, token: str) -> None:
            """The reload button: the launch reads its files again and applies the difference (`launcher reload`)."""
            try:
                code, msg, text = call_blocking(hub.uri, "launcher_reload", token, [], False, timeout=CONTROL_TIMEOUT_S)
            except Fault as e:
                self._send(403 if e.faultCode == run_token.REFUSED else 400, (e.faultString + "\n").encode())
                return
            except (OSError, XmlRpcError) as e:
                self._send(502, ("the launch does not answer: %s\n" % e).encode())
                return
            lines = json.loads(text).get("lines", [])
            message = ("reloaded: " + "; ".join(lines) if lines else "reload: nothing changed") if code == 1 \
                else "reload refused, nothing changed: " + msg
            self._json({"ok": code == 1, "message": message, "lines": lines}, 200 if code == 1 else 400)

        def _events(self) -> None:
            q, first = hub.subscribe()
            try:
                self.send_response(200)
                self.send_header("Content-Type", "text/event-stream")
                self.send_header("Cache-Control", "no-store")
                self.end_headers()
                self.wfile.write(first)
                self.wfile.flush()
                while not hub.gone.is_set():
                    try:
                        data = q.get(timeout=KEEPALIVE_S)
                    except queue.Empty:
                        data = b": -\n\n"
                    if data is None:
                        break
                    self.wfile.write(data)
                    self.wfile.flush()
            except OSError:
                pass
            finally:
                hub.unsubscribe(q)
                self.close_connection = True

    return Handler


def parse_address(text: str) -> tuple[str, int]:
    """[ADDR:]PORT: loopback unless an address is given."""
    host, sep, port = text.rpartition(":")
    if not port.isdigit():
        raise client.ToolError("the web address is [ADDR:]PORT, not [%s]" % text, client.EXIT_USAGE)
    return (host.strip("[]") if sep and host else "127.0.0.1"), int(port)


def serve(uri: str, address: str, parent: int | None = None) -> int:
    host, port = parse_address(address)
    hub = Hub(uri)
    port_box = [port]
    server = http.server.ThreadingHTTPServer((host, port), make_handler(hub, port_box, host))
    server.daemon_threads = True
    port_box[0] = server.server_address[1]
    shown = "[%s]" % host if ":" in host else host
    sys.stderr.write("launcher web: the live view of %s at http://%s:%d/\n" % (uri, shown, port_box[0]))
    sys.stderr.flush()
    hub.start()
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        while not hub.gone.wait(1.0):
            if parent is not None and os.getppid() != parent:  # (the launch that started us is gone)
                break
    except KeyboardInterrupt:
        pass
    server.shutdown()
    return client.EXIT_OK


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="launcher web", description="the live view of a running launch as a web "
                                "page (loopback unless an address is given)")
    p.add_argument("address", metavar="[ADDR:]PORT")
    p.add_argument("--parent", type=int, help=argparse.SUPPRESS)  # (launch --web: end with that launch)
    client.add_launch_options(p)
    return p


def _main(argv: list[str]) -> int:
    opts = parser().parse_args(argv)
    if opts.parent:  # launch --web: its launch registers on the master soon after
        deadline = time.monotonic() + 120
        while True:
            try:
                uri = client.find_launch(opts)
                break
            except client.ToolError:
                if time.monotonic() > deadline or os.getppid() != opts.parent:
                    return client.EXIT_NO_LAUNCH
                time.sleep(0.2)
    else:
        uri = client.find_launch(opts)
    return serve(uri, opts.address, opts.parent)


def main(argv: list[str]) -> int:
    return client.run_tool(_main, argv)
