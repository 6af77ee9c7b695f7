"""The live view as a web page: `launcher web [ADDR:]PORT` (a running launch) and `launch --web [ADDR:]PORT`: one
page, its live updates (server-sent events), the nodes' recent output, start/stop/restart with the run's token, and
the topics from the master's registry.

A process apart from the launch, as the terminal view (`operate/ui.py`): it reads
the launch through its server (the change stream, the samples, the output long
poll) and passes the operator's token on to it, so a browser never costs the
launch more than one more reader. It sends changes, not the table: a new page
gets the table once, then each change, each sample that moved, each new output.
Everything runs on one asyncio loop: the reads of the launch (`Hub`) and the
HTTP side (`operate/webserver.py`: bounded connections, deadlines, event
streams dropped when their client stops reading). Guards, on loopback too
(every local user shares it): a request whose `Host` is not this server by
address, by `localhost` or by this machine's name is refused (DNS rebinding),
and so is one whose `Origin` is another site's; a mutating request without the
run's token gets 403 saying where the token file is. The address printed to a
terminal carries the token in its fragment (`#token=...`, which no server log
or Referer ever sees); the page keeps it in the tab and takes it out of the
address bar. The page's files (operate/webpage/) ship in the package, no CDN.
`/metrics` is the launch's Prometheus metrics (`launcher_metrics`, services/metrics.py),
read-only as the page, so without the token.
"""

from __future__ import annotations

import argparse
import asyncio
import collections
import functools
import ipaddress
import json
import os
import signal
import socket
import sys
import time
from typing import Any, Awaitable, Callable, NamedTuple
from urllib.parse import parse_qs

from launcher.model import token as run_token
from launcher.net.http import Request
from launcher.net.open_files import raise_open_file_limit
from launcher.net.xmlrpc import Fault, XmlRpcError, call
from launcher.operate import client, columns
from launcher.operate.errors import slow
from launcher.operate import ui as reader  # (the launch's read calls; no prompt_toolkit is imported with it)
from launcher.operate.ui import OUTPUT_PERIOD_S, POLL_WAIT_S, RECENT_OUTPUT_BYTES, VIEW_OUTPUT_BYTES
from launcher.operate.view import ViewState
from launcher.operate.webserver import EventStream, PageServer, Reply, StreamReply

PAGE_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "webpage")
FILES = {"/": ("index.html", "text/html; charset=utf-8"), "/app.js": ("app.js", "text/javascript; charset=utf-8"),
         "/style.css": ("style.css", "text/css; charset=utf-8"), "/icon.svg": ("icon.svg", "image/svg+xml"),
         "/favicon.ico": ("icon.svg", "image/svg+xml")}  # (asked for by clients that do not read the page's link)
METRICS_TYPE = "text/plain; version=0.0.4; charset=utf-8"  # Prometheus's text format (launcher_metrics' answer)
SAMPLE_PERIOD_S = 1.0
HISTORY = 60  # samples a sparkline shows (a minute)
KEEPALIVE_S = 15.0  # an event stream's comment line while nothing happens (proxies close silent connections)
CONTROL_TIMEOUT_S = 600.0
READ_CALLS = 8  # the launch's or master's read calls made for pages at once (the rest wait their turn)
CONTROL_CALLS = 8  # start/stop/restart/reload calls at once (a stop may wait for its node's escalation)
# with every response: the page runs only its own files, no other site may frame it, nothing is cached
HEADERS = (b"Cache-Control: no-store\r\nContent-Security-Policy: default-src 'self'; frame-ancestors 'none'\r\n"
           b"X-Content-Type-Options: nosniff\r\n")
RETRY_S = 1.0  # a read that failed is made again after this long
ERRORS = (OSError, XmlRpcError, Fault, ValueError, TypeError, KeyError, asyncio.TimeoutError)


def round_sample(cpu: float | None, rss: int | None) -> list:
    """A sample as the page gets it: CPU to a tenth of a percent, RSS to 100 kB (finer moves are noise, and
    a sample that did not move is not sent)."""
    return [None if cpu is None else round(cpu, 3), None if rss is None else int(rss) // 100000 * 100000]


def event_bytes(event: dict) -> bytes:
    return ("data: %s\n\n" % json.dumps(event, separators=(",", ":"), default=str)).encode()


async def read(uri: str, method: str, *params: Any, timeout: float = 10.0) -> Any:
    """A read call of the launch's server: its value (a failed answer is an XmlRpcError)."""
    code, msg, value = await call(uri, method, *params, timeout=timeout)
    if code != 1:
        raise XmlRpcError("%s: %s" % (method, msg))
    return value


class Hub:
    """The launch as the page sees it: a ViewState kept current from the launch's server by three readers on the
    loop (changes, samples, output), and every change handed to each event stream."""

    def __init__(self, uri: str, info: dict[str, Any], past: dict[str, list]):
        self.uri = uri
        self.state = ViewState()
        self.state.load(info)
        self.streams: set[EventStream] = set()
        self.sent: dict[str, list] = {}  # the samples the pages have
        # each node's samples over the last minute, as a new page's sparklines start (then it keeps its own)
        self.history: dict[str, collections.deque] = {
            name: collections.deque((round_sample(cpu, rss) for _t, cpu, rss in kept), maxlen=HISTORY)
            for name, kept in past.items()}  # (what the launch kept: full from the start)
        self.gone: asyncio.Event | None = None
        self.reads: asyncio.Semaphore | None = None
        self.controls: asyncio.Semaphore | None = None

    @property
    def token_file(self) -> str:
        return self.state.info.get("token_file") or ""

    async def run(self) -> None:
        """Read the launch until it stops answering."""
        self.gone = asyncio.Event()
        self.reads, self.controls = asyncio.Semaphore(READ_CALLS), asyncio.Semaphore(CONTROL_CALLS)
        readers = [asyncio.ensure_future(self._loop(body)) for body in (self._changes, self._samples,
                                                                           self._output(), self._keepalive)]
        try:
            await self.gone.wait()
        finally:
            for task in readers:
                task.cancel()

    async def _loop(self, body: Callable[[], Awaitable[None]]) -> None:
        failures = 0
        while not self.gone.is_set():
            try:
                await body()
                failures = 0
            except ERRORS as e:
                # (a call that timed out: the launch is busy, or out of reach a while; asked again, never the end)
                failures += 0 if slow(e) else 1
                if failures >= 3:  # (the launch has ended: so does its page server)
                    self.broadcast({"type": "gone"})
                    self.gone.set()
                    return
                await asyncio.sleep(RETRY_S)

    def broadcast(self, event: dict) -> None:
        self.send(event_bytes(event))

    def send(self, data: bytes) -> None:
        for stream in list(self.streams):
            if not stream.send(data):  # (a page that does not read is dropped: it reconnects and starts over)
                self.streams.discard(stream)

    def subscribe(self) -> StreamReply:
        """A page's event stream: its first event is the table as it is now (with what it says in place of its
        rows while the launch sets up, "starting": a "started" event follows once it has made its nodes)."""
        snapshot = {"type": "snapshot", "nodes": list(self.state.nodes.values()), "uri": self.state.info.get("uri"),
                    "history": {name: list(h) for name, h in self.history.items()},
                    "run_id": self.state.info.get("run_id"), "seq": self.state.seq,
                    "starting": columns.STARTING if self.state.starting else ""}
        return StreamReply(event_bytes(snapshot), self.streams.add, self.streams.discard)

    async def _changes(self) -> None:
        answer = json.loads(await read(self.uri, "launcher_changes", self.state.seq, POLL_WAIT_S,
                                       timeout=POLL_WAIT_S + 10))
        if self.state.stale(answer):  # (as the terminal view: ui.Feed)
            starting = self.state.starting
            self.state.load(json.loads(await read(self.uri, "launcher_status")))
            if starting and not self.state.starting:
                self.broadcast({"type": "started"})
        self.state.changes(answer["changes"])
        self.state.seq = max(self.state.seq, answer["seq"])
        if answer["changes"]:
            self.broadcast({"type": "changes", "changes": answer["changes"]})

    async def _samples(self) -> None:
        samples = json.loads(await read(self.uri, "launcher_samples"))
        self.state.samples(samples)
        now = {name: round_sample(*samples.get(name, (None, None))) for name in self.state.nodes}
        moved = {name: s for name, s in now.items() if self.sent.get(name) != s}
        self.sent = now
        for name, sample in now.items():
            self.history.setdefault(name, collections.deque(maxlen=HISTORY)).append(sample)
        if moved:
            self.broadcast({"type": "samples", "time": round(time.time(), 1), "samples": moved})
        await asyncio.sleep(SAMPLE_PERIOD_S)

    def _output(self) -> Callable[[], Awaitable[None]]:
        offsets: dict[str, int] = {}

        async def body() -> None:
            asked = json.dumps(dict(offsets, **{"@most": VIEW_OUTPUT_BYTES}))  # (as the terminal view: ui.new_output)
            answer = json.loads(await read(self.uri, "launcher_output", asked, POLL_WAIT_S, timeout=POLL_WAIT_S + 10))
            offsets.update(answer["offsets"])
            if answer["output"] or answer.get("log") or answer.get("skipped"):
                self.broadcast({"type": "output", "output": answer["output"], "log": answer.get("log") or [],
                                "skipped": answer.get("skipped") or {}})
                await asyncio.sleep(OUTPUT_PERIOD_S)
        return body

    async def _keepalive(self) -> None:
        await asyncio.sleep(KEEPALIVE_S)
        self.send(b": -\n\n")

    async def recent_output(self, node: str) -> str:
        """The end of a node's output (its -stdout.log), as the launch's server reads it."""
        async with self.reads:  # type: ignore[union-attr]
            answer = json.loads(await read(self.uri, "launcher_output", json.dumps({node: -RECENT_OUTPUT_BYTES}), 0))
        return answer["output"].get(node, "")

    async def topics(self) -> list[dict]:
        """Each topic of the master's registry: its type, publishers and subscribers."""
        master = self.state.info.get("master_uri")
        async with self.reads:  # type: ignore[union-attr]
            (code, _msg, (pubs, subs, _srvs)), (code2, _msg2, types) = await asyncio.gather(
                call(master, "getSystemState", "/launcher_web"), call(master, "getTopicTypes", "/launcher_web"))
        type_of = dict(types) if code2 == 1 else {}
        topics: dict[str, dict] = {}
        for topic, nodes in pubs:
            topics.setdefault(topic, {"topic": topic, "publishers": [], "subscribers": []})["publishers"] = nodes
        for topic, nodes in subs:
            topics.setdefault(topic, {"topic": topic, "publishers": [], "subscribers": []})["subscribers"] = nodes
        for t in topics.values():
            t["type"] = type_of.get(t["topic"], "")
        return sorted(topics.values(), key=lambda t: t["topic"])

    async def metrics(self) -> str:
        """The launch's Prometheus metrics, as its server makes them (launcher_metrics)."""
        async with self.reads:  # type: ignore[union-attr]
            return await read(self.uri, "launcher_metrics")

    async def control(self, method: str, *params: Any) -> Any:
        """A start/stop/restart/reload call with the operator's token: (code, message, value)."""
        async with self.controls:  # type: ignore[union-attr]
            return await call(self.uri, method, *params, timeout=CONTROL_TIMEOUT_S)


@functools.lru_cache(maxsize=None)
def own_names() -> tuple:
    """This machine's names, looked up once (getfqdn asks the resolver: never on each request)."""
    return ("localhost", socket.gethostname().lower(), socket.getfqdn().lower())


def allowed_host(host: str, port: int, bound: str) -> bool:
    """Whether a request's Host header names this server: by an address literal, `localhost` or this machine's
    name, with our port. A name that merely resolves here (DNS rebinding) does not."""
    name, sep, p = host.rpartition(":")
    if not sep or p != str(port) or not name:
        return False
    name = name.strip("[]").lower()
    try:
        ipaddress.ip_address(name)
    except ValueError:
        return name in own_names()
    return True


class Route(NamedTuple):
    """What answers a path: `answer(request)` gives a Reply, an awaitable of one, or an event stream.
    `token`: a mutating request, refused without the run's token."""

    answer: Callable[[Request], Any]
    token: bool = False


def json_reply(value: Any, status: int = 200) -> Reply:
    return Reply(status, json.dumps(value, default=str).encode(), "application/json")


def text_reply(status: int, text: str) -> Reply:
    return Reply(status, (text + "\n").encode())


class Page:
    """The page's routes and guards, on top of a Hub. Every route is here: the page's files, its reads
    (read-only: GET, no token) and its controls (POST, the run's token); a further read-only route
    (a metrics page) is one more entry in `get`."""

    def __init__(self, hub: Hub, bound: str, port_box: list):
        self.hub = hub
        self.bound = bound
        self.port_box = port_box  # (the port is known once the server listens)
        self.files: dict[str, bytes] = {}
        self.get: dict[bytes, Route] = {path.encode(): Route(self._file) for path in FILES}
        self.get[b"/events"] = Route(lambda request: self.hub.subscribe())
        self.get[b"/api/output"] = Route(self._output)
        self.get[b"/api/topics"] = Route(self._topics)
        self.get[b"/metrics"] = Route(self._metrics)  # (Prometheus's scrape: read-only, as the page)
        self.post: dict[bytes, Route] = {b"/api/" + verb: Route(self._control, token=True)
                                         for verb in (b"start", b"stop", b"restart", b"reload")}

    def handle(self, request: Request) -> Any:
        refusal = self._guard(request)
        if refusal is not None:
            return refusal
        route = (self.get if request.method == b"GET" else self.post).get(request.target)
        if route is None:
            return text_reply(404, "not found")
        if route.token and not request.field(b"x-launcher-token"):
            where = self.hub.token_file or "launcher-token in the run's log directory"
            return text_reply(403, "refused: start, stop, restart and reload need the run's token, in the file %s "
                              "(readable only by the user who started the launch); open the address `launcher web` "
                              "printed on its terminal, or add #token= and the file's content to the page's address"
                              % where)
        return route.answer(request)

    def _guard(self, request: Request) -> Reply | None:
        """Refuse a request whose Host is not this server (DNS rebinding) or that comes from another site."""
        host = (request.field(b"host") or b"").decode("latin-1")
        if not allowed_host(host, self.port_box[0], self.bound):
            return text_reply(403, "refused: the Host header does not name this server")
        origin = request.field(b"origin")
        if origin is not None and origin.decode("latin-1") != "http://" + host:
            return text_reply(403, "refused: a request from another site")
        return None

    def _file(self, request: Request) -> Reply:
        name, ctype = FILES[request.target.decode()]
        body = self.files.get(name)
        if body is None:
            with open(os.path.join(PAGE_DIR, name), "rb") as f:
                body = f.read()
            if name == "index.html":
                body = body.replace(b"{{BOUND}}", ("%s:%d" % (self.bound, self.port_box[0])).encode())
            self.files[name] = body  # (read once: a few kB)
        return Reply(200, body, ctype)

    async def _output(self, request: Request) -> Reply:
        node = (parse_qs(request.query.decode("utf-8", "replace")).get("node") or [""])[0]
        try:
            return json_reply({"node": node, "output": await self.hub.recent_output(node)})
        except ERRORS as e:
            return json_reply({"error": str(e)}, 502)

    async def _topics(self, request: Request) -> Reply:
        try:
            return json_reply(await self.hub.topics())
        except ERRORS as e:
            return json_reply({"error": str(e)}, 502)

    async def _metrics(self, request: Request) -> Reply:
        try:
            return Reply(200, (await self.hub.metrics()).encode(), METRICS_TYPE)
        except ERRORS as e:
            return text_reply(502, "the launch does not answer: %s" % (str(e) or type(e).__name__))

    async def _control(self, request: Request) -> Reply:
        verb = request.target.rpartition(b"/")[2].decode()
        token = (request.field(b"x-launcher-token") or b"").decode("latin-1")
        if verb == "reload":
            params: tuple = ("launcher_reload", token, [], False)
        else:
            try:
                pattern = json.loads(request.body or b"{}").get("node", "")
            except (ValueError, AttributeError):
                return text_reply(400, 'the body is JSON {"node": PATTERN}')
            params = ("%s_nodes" % verb, token, pattern)
        try:
            code, msg, value = await self.hub.control(*params)
        except Fault as e:
            return text_reply(403 if e.faultCode == run_token.REFUSED else 400, e.faultString)
        except (OSError, XmlRpcError, asyncio.TimeoutError) as e:
            return text_reply(502, "the launch does not answer: %s" % (str(e) or type(e).__name__))
        if verb != "reload":
            return json_reply({"ok": code == 1, "message": msg, "nodes": value}, 200 if code == 1 else 400)
        # the reload button: the launch read its files again and applied the difference (`launcher reload`)
        lines = json.loads(value).get("lines", []) if code == 1 else []
        message = ("reloaded: " + "; ".join(lines) if lines else "reload: nothing changed") if code == 1 \
            else "reload refused, nothing changed: " + msg
        return json_reply({"ok": code == 1, "message": message, "lines": lines}, 200 if code == 1 else 400)


def parse_address(text: str) -> tuple[str, int]:
    """[ADDR:]PORT: loopback unless an address is given."""
    host, sep, port = text.rpartition(":")
    if not port.isdigit():
        raise client.ToolError("the web address is [ADDR:]PORT, not [%s]" % text, client.EXIT_USAGE)
    return (host.strip("[]") if sep and host else "127.0.0.1"), int(port)


def address_line(uri: str, url: str, token_file: str, terminal: bool) -> str:
    """What `launcher web` says once it listens. To a terminal, the page's address with the run's token in its
    fragment (opened as it is, the page's buttons work at once); anywhere else (a file, the journal, `launch
    --ui`'s console), where a token would stay, the plain address and where the token file is."""
    if terminal and token_file:
        try:
            return "launcher web: the live view of %s at %s#token=%s\n" % (uri, url, run_token.read(token_file))
        except OSError:
            pass
    return ("launcher web: the live view of %s at %s (its buttons need the run's token: the file %s)\n"
            % (uri, url, token_file or "launcher-token in the run's log directory"))


async def _serve(hub: Hub, host: str, port: int, parent: int | None) -> None:
    port_box = [port]
    page = Page(hub, host, port_box)
    server = PageServer(page.handle, host, port, headers=HEADERS)
    await server.start()
    port_box[0] = server.port
    shown = "[%s]" % host if ":" in host else host
    sys.stderr.write(address_line(hub.uri, "http://%s:%d/" % (shown, server.port), hub.token_file,
                                  sys.stderr.isatty()))
    sys.stderr.flush()
    loop = asyncio.get_running_loop()
    running = asyncio.ensure_future(hub.run())
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, running.cancel)

    def watch_parent() -> None:
        if parent is not None and os.getppid() != parent:  # (the launch that started us is gone)
            running.cancel()
        else:
            loop.call_later(1.0, watch_parent)
    watch_parent()
    try:
        await running
    except asyncio.CancelledError:
        pass
    finally:
        await server.stop()


def serve(uri: str, address: str, parent: int | None = None) -> int:
    host, port = parse_address(address)
    raise_open_file_limit()  # (each client is a file: the connection cap follows the limit)
    hub = Hub(uri, client.status(uri), reader.past_samples(uri))
    own_names()  # (before the loop runs: the resolver is never asked on it)
    try:
        asyncio.run(_serve(hub, host, port, parent))
    except OSError as e:
        raise client.ToolError("cannot serve the page at %s:%d: %s" % (host, port, e.strerror or e)) from None
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
