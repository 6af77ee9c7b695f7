"""roslaunch's XML-RPC API, served by a running launch: what `launcher` and roslaunch's own tools read and steer.

Read calls answer as Debian's roslaunch does (checked side by side):
`list_processes`, `process_info`, `get_pid`, `get_node_names`. The URI is
registered on the master as `/roslaunch/uris/host_<host>__<port>`, which is
how `roslaunch.netapi` and `launcher` find running launches. `launch --core`
serves it too, as roscore (a roslaunch run) does: its processes are the
master and rosout-1.

Added calls: `launcher_status` (the run and every node's state as one JSON
text: a 500-node status must cost the launcher little), `launcher_changes`
(the fleet's changes after a sequence number, waiting for one: a long poll), and
`launcher_samples` (each running node's CPU and RSS, what a live view redraws
every second; or the last minute of them, what a view attaching late starts its
sparklines with), `launcher_output` (the nodes' output from their
`-stdout.log` files after the offsets a reader has, and for output="log" nodes
their WARN/ERROR/FATAL lines from /rosout: a long poll too, so a view on
another machine shows output from files it cannot read), `launcher_metrics`
(the run's Prometheus metrics as text, services/metrics.py: the web page's
server serves them at /metrics), and
`start_nodes`/`stop_nodes`/`restart_nodes(token, pattern)` and
`launcher_reload(token, args, dry_run)` (the launch's files read again and the
difference applied, run/reload.py), which are refused with a fault unless
`token` is the run's (`launcher.model.token`).
The pattern selects among local and remote nodes alike (a remote node is
steered by `launcher.remote.parent`); the answer is [1, text, names], or
[0, the refusals, the names that were steered] when some node could not be.
"""

from __future__ import annotations

import asyncio
import json
import os
import time
from typing import TYPE_CHECKING, Any, Protocol

from launcher import compat
from launcher.compat import orig_argv
from launcher.net.hostname import advertised_host, listen_address
from launcher.net.xmlrpc_codec import Fault, encode_value
from launcher.model import patterns, token as run_token
from launcher.fleet import processes
from launcher.fleet.state import EVENTS_FILE, LOCAL_HOST

if TYPE_CHECKING:  # (annotations only)
    from launcher.fleet.state import Fleet
    from launcher.services.service import RunNodes

OUTPUT_CHECK_S = 0.5  # how often a waiting launcher_output looks at the files' sizes (a node writes its own file)
ROSOUT_KEY = "@rosout"  # in launcher_output's offsets: the /rosout warnings' number (no node name has an "@")
MOST_KEY = "@most"  # in launcher_output's offsets: the most bytes of a node's output one answer gives a view
OUTPUT_MAX_BYTES = 64 * 1024  # of one node's output in one answer (a reader asks again for the rest)
CHANGES_WAIT_MAX_S = 60.0  # a long poll's longest wait (the client's call timeout must be longer)
STATUS_MAX_AGE_S = 0.5  # a status may be this old (uptimes), unless a node changed state meanwhile
REFUSED_TEXT = ("refused: %s needs this run's token (the file %s, readable only by the user who started "
                "the launch); `launcher %s` reads it for you")


def rosname_of_host(host: str) -> str:
    """roslaunch's `_hostname_to_rosname`: `host_` and the host lowercased, other characters as `_`."""
    return "host_" + "".join(c if "a" <= c <= "z" or "0" <= c <= "9" else "_" for c in host.lower())


class RunView(Protocol):
    """What the server sees of its run (`launcher.services.servers.RunView`): its nodes, its identity, its core."""

    nodes: RunNodes  # the fleet and node control: fleet, spec, package_of, remote_names, control, parent_call(s)
    fleet: Fleet | None  # every node's state, None before the nodes are started
    starting: bool  # a launch whose nodes are not made yet (its master, parameters and rosout come first)
    run_id: str
    master_uri: str
    log_dir: str
    launch_files: list[str]

    def core_processes(self) -> list[list]: ...

    def unresponsive(self) -> list[dict]: ...


class LaunchServer:
    """The API of one run, read from its `RunView` (never the run itself)."""

    def __init__(self, run: RunView, environ: dict[str, str]):
        self.run = run
        self.host = advertised_host(environ)  # (rosgraph's choice for roslaunch's server, as for the master)
        self.uri = ""
        self.param_key = ""
        self.token = ""
        self.token_path = ""
        self._server: Any = None
        self._status: Any = None  # the last launcher_status text, XML-encoded
        self._status_at = 0.0
        self._status_fleet: Fleet | None = None  # the fleet the cached status was read from (None: before it)

    async def start(self) -> None:
        from launcher.net.xmlrpc_server import XmlRpcServer
        run_dir = self.run.log_dir
        if run_dir:
            try:
                self.token, self.token_path = run_token.create(run_dir)
            except OSError as e:  # control stays closed; reading still works
                from launcher.output import console
                console.printerrlog("WARNING: cannot write the run's token in [%s]: %s; start/stop/restart "
                                    "are refused" % (run_dir, e.strerror))
        # (system.multicall as roslaunch's server has it: our remote children send their reports in batches)
        self._server = XmlRpcServer(self._dispatch, listen_address(self.host), 0, multicall=True, max_connections=64)
        await self._server.start()
        host = "[%s]" % self.host if ":" in self.host else self.host
        self.uri = "http://%s:%d/" % (host, self._server.port)
        self.param_key = "/roslaunch/uris/%s__%d" % (rosname_of_host(self.host), self._server.port)

    async def stop(self) -> None:
        if self._server is not None:
            await self._server.stop()
            self._server = None

    # ---- dispatch ----------------------------------------------------------------------------------

    def _dispatch(self, method: str, params: list) -> Any:
        handler = self._API.get(method)
        nodes = self.run.nodes
        if handler is None and method in nodes.parent_calls():
            return nodes.parent_call(method, params)  # a child on another machine calling its parent
        if handler is None:
            # the words of roslaunch's server (Python's SimpleXMLRPCServer)
            raise Fault(1, "<class 'Exception'>:method \"%s\" is not supported" % method)
        try:
            return handler(self, *params)
        except TypeError as e:
            raise Fault(1, "<class 'TypeError'>:%s" % e) from None

    # ---- what runs ---------------------------------------------------------------------------------

    def _local(self) -> list[Any]:
        """This machine's nodes, as the fleet shows them (in start order)."""
        fleet = self.run.fleet
        return [s for s in fleet if s.host == LOCAL_HOST] if fleet is not None else []

    def _spec(self, node_name: str) -> Any:
        return self.run.nodes.spec(node_name)

    def _core(self) -> list[list]:
        return self.run.core_processes()

    def _core_info(self, process_name: str) -> dict[str, Any]:
        """process_info of the master or rosout, with the fields Debian's roslaunch gives its rosout-1.

        Both run inside the launcher, so the honest pid and command line are the launcher's own: that
        process answers at the master URI and publishes /rosout_agg, and a tool watching the pid sees
        them alive exactly as long as they are. Neither is ever restarted apart from the launch
        (respawn False, where roscore's rosout has respawn="true"); the package, `required` and
        `log_output` are what roslaunch reports. (Debian's roslaunch answers process_info("master")
        with a fault: it hands os.environ, not a dict, to the XML-RPC marshaller.)
        """
        master = process_name == "master"
        return {"spawn_count": 1, "args": orig_argv(), "env": dict(os.environ),
                "package": "rosmaster" if master else "rosout", "name": process_name, "alive": True,
                "respawn": False, "respawn_delay": 0.0, "required": master, "pid": os.getpid(),
                "run_id": self.run.run_id, "log_output": not master}

    def list_processes(self) -> list:
        return processes.list_processes(self._local(), self._core())

    def process_info(self, process_name: str) -> list:
        if any(name == process_name for name, _ in self._core()):
            return [1, "process info", self._core_info(process_name)]
        return processes.process_info(self._local(), process_name, self._details)

    def _details(self, status: Any) -> dict[str, Any]:
        """What roslaunch's process_info tells beyond the state: the process's command line and settings."""
        spec = self._spec(status.name)
        if spec is None:
            return {}
        env = spec.command.env if spec.command.env is not None else os.environ
        info = {"args": list(spec.argv), "env": dict(env), "package": self.run.nodes.package_of(spec.name),
                "respawn": spec.respawn, "respawn_delay": float(spec.respawn_delay), "required": spec.required,
                "run_id": self.run.run_id, "log_output": spec.output == "log"}
        return info

    def get_pid(self) -> list:
        pid = os.getpid()
        return [1, str(pid), pid]

    def get_node_names(self) -> list:
        return processes.node_names(self._local(), [name for name, _ in self._core()])

    # ---- launcher's additions ----------------------------------------------------------------------

    def launcher_status(self) -> list:
        # Built at most once per STATUS_MAX_AGE_S, and again after any state change: ten operators
        # polling a 500-node launch every second would otherwise cost it several % of a core.
        now = time.monotonic()
        fleet = self.run.fleet
        if fleet is not self._status_fleet:  # (the nodes were made since: a status read before has none of them)
            if fleet is not None:
                fleet.listeners.append(self._state_changed)
            self._status_fleet, self._status = fleet, None
        if self._status is None or now - self._status_at > STATUS_MAX_AGE_S:
            self._status = encode_value(self._build_status())
            self._status_at = now
        return [1, "status", self._status]

    def _state_changed(self, _status: Any) -> None:
        self._status = None

    def _build_status(self) -> str:
        run = self.run
        fleet = run.fleet
        nodes = []
        if fleet is not None:
            for status in fleet:
                d = status.as_dict()
                spec = self._spec(status.name)
                if spec is not None and spec.log_dir:
                    # where `launcher logs` finds the node's output (output="screen" too: the launcher keeps
                    # a copy, output/screen.py), and the node's own log file (__log:=)
                    d["stdout_log"] = spec.stdout_path or ""
                    d["node_log"] = os.path.join(spec.log_dir, spec.log_name + ".log")
                nodes.append(d)
        log_dir = run.log_dir
        info = {"pid": os.getpid(), "uri": self.uri, "run_id": run.run_id, "master_uri": run.master_uri,
                "log_dir": log_dir, "token_file": self.token_path,
                "events_file": os.path.join(log_dir, EVENTS_FILE) if log_dir else "",
                "launch_files": list(run.launch_files), "nodes": nodes, "starting": run.starting,
                # the nodes our master cannot reach (its callbacks time out or are refused)
                "unresponsive": run.unresponsive()}
        # default=str: a field a later state model adds that JSON cannot hold shows as text, not a fault
        return json.dumps(info, separators=(",", ":"), default=str)

    def launcher_changes(self, since: Any, timeout: Any = 0.0) -> Any:
        """The node changes after sequence number `since` (0: all that are kept), waiting up to `timeout`
        seconds (at most CHANGES_WAIT_MAX_S) when there are none yet: a long poll, what a live view, `launcher
        status --watch` and `launcher events -f` read instead of tailing the events file. The run's own lines
        (a reload, the master restarted, the launch's end) are in the stream too, with no "node". [1, text, JSON
        {"seq": the last one, "complete": false when older changes were dropped (read the status again),
        "starting": true while the launch has made no node yet (once false, read the status again: it may have
        none to tell of), "changes": [as in the events file; the steps it leaves out marked "internal": true]}]."""
        if not isinstance(since, int) or not isinstance(timeout, (int, float)) or timeout < 0:
            raise Fault(1, "launcher_changes(since: int, timeout: seconds)")

        async def changes() -> list:
            wait = min(float(timeout), CHANGES_WAIT_MAX_S)
            fleet = self.run.fleet
            if fleet is None:  # (asked while the launch sets up: the answer comes once it has made its nodes, at
                # once, with their first changes or none: a launch of no node has no change to tell it by)
                try:
                    await compat.wait_for(self.run.nodes.made.wait(), wait)
                except asyncio.TimeoutError:
                    return [1, "changes", json.dumps({"seq": 0, "complete": True, "starting": self.run.starting,
                                                      "changes": []})]
                fleet, wait = self.run.fleet, 0.0
            await fleet.wait_change(since, wait)
            lines, complete = fleet.changes_json(since)  # (the lines as the fleet keeps them: JSON already)
            return [1, "changes", '{"seq":%d,"complete":%s,"starting":false,"changes":%s}'
                    % (fleet.seq, "true" if complete else "false", lines)]
        return changes()

    def launcher_samples(self, history: Any = False) -> list:
        """[1, text, JSON {node: [cpu (cores), rss (bytes)]}] of the running nodes with a sample: the columns
        that change without a state change, a few bytes a node rather than the whole status. With `history`
        true, the samples the fleet keeps of each node (its last HISTORY, a minute at the default period),
        JSON {node: [[time, cpu, rss], ...]}: a view that attaches late draws its sparklines at once."""
        fleet = self.run.fleet
        if fleet is None:
            return [1, "samples", "{}"]
        if history:
            kept = {s.name: [[round(t, 2), cpu, rss] for t, cpu, rss in s.history] for s in fleet if s.history}
            return [1, "samples", json.dumps(kept, separators=(",", ":"))]
        samples = {s.name: [s.cpu, s.rss] for s in fleet if s.cpu is not None}
        return [1, "samples", json.dumps(samples, separators=(",", ":"))]

    def _output_paths(self) -> dict[str, tuple[str, bool]]:
        """node -> (its -stdout.log, whether its output goes to that file only: output="log")."""
        paths = {}
        for status in self._local():
            spec = self._spec(status.name)
            if spec is not None and spec.stdout_path:
                paths[status.name] = (spec.stdout_path, spec.output != "screen")
        return paths

    def _warnings_of(self) -> Any:
        """Whose /rosout warnings a view gets: this machine's output="log" nodes, and the other machines'
        nodes (their output files are there; /rosout is the one way their warnings reach the view)."""
        remote = set(self.run.nodes.remote_names())

        def shown(name: str) -> bool:
            spec = self._spec(name)
            return spec.output != "screen" if spec is not None else name in remote
        return shown

    def launcher_output(self, offsets: Any, timeout: Any = 0.0) -> Any:
        """The nodes' new output: `offsets` is JSON {node: offset in its -stdout.log}; a node left out is
        read from its end (only what comes next), a negative offset -N gives its last N bytes first.
        Nodes with output="log" are the exception, as under roslaunch (their file is their log): left out,
        they are not followed, and their WARN, ERROR and FATAL lines from /rosout come instead (those of
        the other machines' nodes too), after the
        number given as "@rosout" (left out: from now). Waits up to `timeout` seconds (at most
        CHANGES_WAIT_MAX_S) while there is none. [1, text, JSON {"offsets": {node: the next offset, "@rosout":
        the next number}, "output": {node: text}, "log": [[node, level, text], ...]}] (the offsets of every
        node followed, the output of those that wrote; a file shorter than its offset was rotated and is
        read from its start). Without our rosout (a master found running), every node's file is followed.
        "@most": N > 0 among the offsets (a view, which shows a flood as a screen refreshes): of a node further
        behind than N bytes, only the newest N come, from the first line that begins in them (if one does),
        and "skipped": {node: bytes passed over} says so (`launcher logs` reads every byte; a launch that
        does not know "@most" gives every byte)."""
        try:
            asked = json.loads(offsets) if isinstance(offsets, str) else None
        except ValueError:
            asked = None
        most = asked.pop(MOST_KEY, 0) if isinstance(asked, dict) else 0
        if not isinstance(asked, dict) or not isinstance(timeout, (int, float)) or timeout < 0 \
                or type(most) is not int or most < 0:
            raise Fault(1, "launcher_output(offsets: JSON {node: offset}, timeout: seconds)")
        tail = getattr(self.run, "warnings", None)
        if tail is not None and not isinstance(asked.get(ROSOUT_KEY), int):
            asked[ROSOUT_KEY] = tail.seq

        def read() -> tuple[dict, dict, list, dict]:
            nexts, output, skipped = {}, {}, {}
            for name, (path, log_only) in self._output_paths().items():
                at = asked.get(name)
                if log_only and tail is not None and not isinstance(at, int):
                    continue  # (its warnings come from /rosout)
                try:
                    size = os.stat(path).st_size
                except OSError:
                    nexts[name] = 0
                    continue
                if not isinstance(at, int):
                    at = size
                elif at < 0:
                    at = max(0, size + at)
                elif at > size:  # (rotated: logrotate moved it away and a new file began)
                    at = 0
                if at < size:
                    start = size - most if most and size - at > most else at
                    with open(path, "rb") as f:
                        f.seek(start)
                        data = f.read(min(size - start, OUTPUT_MAX_BYTES))
                    if start > at:  # (the line cut in two is passed over too, unless no other begins after it)
                        cut = data.find(b"\n") + 1
                        cut = cut if cut < len(data) else 0
                        skipped[name] = start + cut - at
                        at, data = start + cut, data[cut:]
                    at += len(data)
                    if data:
                        output[name] = data.decode("utf-8", "replace")
                nexts[name] = at
            log: list = []
            if tail is not None:
                lines = tail.since(asked[ROSOUT_KEY])
                if lines:
                    shown = self._warnings_of()
                    log = [list(line) for line in lines if shown(line[0])]
                nexts[ROSOUT_KEY] = tail.seq
            return nexts, output, log, skipped

        async def wait() -> list:
            # (the files are written by the nodes themselves: their sizes are looked at, a stat a node
            # every OUTPUT_CHECK_S, only while a reader waits)
            deadline = time.monotonic() + min(float(timeout), CHANGES_WAIT_MAX_S)
            nexts, output, log, skipped = read()
            while not output and not log and not skipped and time.monotonic() < deadline:
                asked.update(nexts)  # (a node first read from its end is read on from there)
                await asyncio.sleep(min(OUTPUT_CHECK_S, max(0.0, deadline - time.monotonic())))
                nexts, output, log, skipped = read()
            answer = {"offsets": nexts, "output": output}
            if tail is not None:
                answer["log"] = log
            if skipped:
                answer["skipped"] = skipped
            return [1, "output", json.dumps(answer, separators=(",", ":"))]
        return wait()

    def _check_token(self, verb: str, given_token: Any) -> None:
        if not run_token.matches(self.token, given_token):
            raise Fault(run_token.REFUSED, REFUSED_TEXT % (verb, self.token_path or "launcher-token in the run's log "
                                                 "directory", verb))

    def _control(self, verb: str, given_token: Any, pattern: Any) -> Any:
        self._check_token(verb, given_token)
        if not isinstance(pattern, str):
            raise Fault(1, "%s: the pattern must be a string" % verb)
        nodes = self.run.nodes
        local = [s.name for s in self._local()]
        # the nodes of other machines too (launcher.remote.parent steers them): one pattern, one answer
        remote_names = nodes.remote_names()
        names = patterns.match(pattern, local + remote_names)
        if not names:
            return [-1, "no node matches [%s]" % pattern, []]
        return self._apply(verb, names, set(remote_names))

    async def _apply(self, verb: str, names: list[str], remote_names: set[str]) -> list:
        """Each node steered at once; [1, what, names], or [0, the refusals, the names that were steered]."""
        nodes = self.run.nodes
        refusals = await asyncio.gather(*(nodes.control(verb, n, n in remote_names) for n in names))
        done = [n for n, why in zip(names, refusals) if not why]
        if any(refusals):
            return [0, "\n".join(why for why in refusals if why), done]
        past = {"start": "started", "stop": "stopped", "restart": "restarted"}[verb]
        return [1, "%s %d node(s)" % (past, len(names)), names]

    def start_nodes(self, token: Any, pattern: Any) -> Any:
        return self._control("start", token, pattern)

    def stop_nodes(self, token: Any, pattern: Any) -> Any:
        return self._control("stop", token, pattern)

    def restart_nodes(self, token: Any, pattern: Any) -> Any:
        return self._control("restart", token, pattern)

    def launcher_reload(self, token: Any, args: Any, dry_run: Any = False) -> Any:
        """Read the launch's files again and apply the difference (run/reload.py); `args`: name:=value that
        replace the run's; `dry_run`: only say what would change (it needs the token too: it reads the files
        as the launch's user). [1, text, JSON answer] or [-1, the error (file:line), JSON answer]."""
        self._check_token("reload", token)
        reload = getattr(self.run, "reload", None)
        if reload is None:
            raise Fault(1, "this launch cannot be reloaded (a core, or a test run)")
        if not isinstance(args, list) or not all(isinstance(a, str) for a in args):
            raise Fault(1, "launcher_reload(token, args: list of name:=value, dry_run: bool)")

        async def reloaded() -> list:
            answer = await reload(list(args), bool(dry_run))
            text = json.dumps(answer, separators=(",", ":"), default=str)
            return [1, "reload", text] if answer["ok"] else [-1, answer["error"], text]
        return reloaded()

    def launcher_metrics(self) -> Any:
        """[1, text, the run's metrics in Prometheus's text format] (services/metrics.py: the values copied on the
        loop, the text made in a worker thread): what the web page's server serves at /metrics."""
        metrics = getattr(self.run, "metrics", None)
        if metrics is None:
            raise Fault(1, "this run has no metrics")

        async def text() -> list:
            return [1, "metrics", await metrics.text()]
        return text()

    _API: dict[str, Any] = {}


LaunchServer._API = {name: getattr(LaunchServer, name) for name in (
    "list_processes", "process_info", "get_pid", "get_node_names", "launcher_status", "launcher_changes",
    "launcher_samples", "launcher_output", "start_nodes", "stop_nodes", "restart_nodes", "launcher_reload",
    "launcher_metrics")}
