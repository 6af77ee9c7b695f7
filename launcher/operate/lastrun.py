"""A run whose launch has ended, read from its log directory: how it ended, each node's state at the end, its files.

`launcher status`, `events` and `logs` read the running launch; when none
answers (the master is gone, or no launch of ours is on it) they read the last
run instead (client.live_or_last): `$ROS_LOG_DIR/latest` (default `$ROS_HOME/log/latest`), or the
run `--run RUN_ID` names. Each node's state at the end is its last event in
`launcher-events.jsonl` (fleet.state.Fleet writes one line per change).
How the launch ended is told by an event `{"event": "launch_ended", "time":
..., "reason": ...}` when the events file has one, else by its launch log
(runlog.RunLog, `roslaunch-<host>-<pid>.log`): a launch that stopped by itself
writes `done` last; one that was killed (`kill -9`, a crash of the machine)
ends without a word after its last event. A roslaunch or roscore run has no
events file and a launch log of roslaunch's own lines: it is said to be one.
"""

from __future__ import annotations

import json
import os
import re
import socket
import time
from typing import Any, Mapping, NamedTuple

from launcher.fleet.lastexit import keep_last_exit
from launcher.operate import errors
from launcher.fleet.state import EVENTS_FILE, LAUNCH_ENDED
from launcher.workspace.roshome import log_root
from launcher.model.suggest import did_you_mean

LAUNCH_LOG = re.compile(r"roslaunch-(?P<host>.+)-(?P<pid>\d+)\.log")
# a line of our launch log: "[2024-05-01 12:00:03.123] text" (roslaunch's read "[roslaunch][INFO] 2024-...")
OUR_LINE = re.compile(r"\[(\d{4}-\d\d-\d\d \d\d:\d\d:\d\d)\.(\d{3})\] ?(.*)")
DONE = "done"  # the last line of the launch log of a launch that stopped by itself (runtime's teardown)
STDOUT_LOG = re.compile(r"(?P<name>.+)-(?P<number>\d+)-stdout\.log")  # (runtime.node_specs names them so)
TAIL_BYTES = 4096  # enough of a launch log's end for its last line
DOWN_STATES = ("exited", "fatal", "stopped")  # a node in these was down before its launch was killed
KILLED_REASON = "the launch was killed"


class LastRun(NamedTuple):
    run_id: str
    run_dir: str
    latest: bool  # read as the last run (not named by --run)
    events: list[dict[str, Any]]  # every line of the events file
    ended_at: float | None  # when the launch said it ended (a launch_ended event, or its log's `done`)
    end_reason: str  # the launch_ended event's reason, if it gave one
    pid: int | None  # the launch's (its launch log's name)
    still_running: bool  # that launch still runs (it cannot be reached, yet it has not ended)
    last_line_at: float | None  # the time of the launch log's last line

    def killed(self) -> bool:
        """The launch ended without a word (`kill -9`, a crash of the machine): its nodes' last events may say
        they run, yet they went with it (the launch's watchdog kills them)."""
        return self.ended_at is None and not self.still_running

    def nodes(self) -> list[dict[str, Any]]:
        """Each node's last state change, with `name` and `last_exit_*` as in launcher_status (for the status
        table); a node of a killed launch that was not down by then is `stopped`, "the launch was killed"."""
        nodes = node_states(self.events)
        if self.killed():
            for node in nodes:
                if node.get("state") not in DOWN_STATES:
                    node.update(state="stopped", phase="stopped", reason=KILLED_REASON, next_start=None)
        return nodes

    def last_event_at(self) -> float | None:
        times = [e["time"] for e in self.events if isinstance(e.get("time"), (int, float))]
        return max(times) if times else None

    def headline(self) -> str:
        """How the run ended, in one sentence, and where its logs are."""
        which = "the last run" if self.latest else "the run"
        if self.still_running:
            text = "%s, %s, has not ended: its launch (pid %s) still runs, but cannot be reached" % (
                which, self.run_id, self.pid)
        elif self.ended_at is not None:
            text = "%s, %s, ended at %s" % (which, self.run_id, when(self.ended_at))
            if self.end_reason:
                text += " (%s)" % self.end_reason
        else:
            last = self.last_event_at()
            text = "%s, %s, ended without a word after its last %s at %s: its launch%s was killed" % (
                which, self.run_id, "event" if last is not None else "line of its launch log",
                when(last if last is not None else self.last_line_at), "" if self.pid is None else " (pid %d)" % self.pid)
        return "%s\nits logs: %s" % (text, self.run_dir)

    def ended_line(self) -> str:
        """How the run ended, in one line (what `launcher events` and `logs` say on stderr before it)."""
        return self.headline().split("\n", 1)[0]

    def events_file(self) -> str:
        return os.path.join(self.run_dir, EVENTS_FILE)

    def as_dict(self) -> dict[str, Any]:
        return {"run_id": self.run_id, "log_dir": self.run_dir, "pid": self.pid, "running": self.still_running,
                "ended_at": self.ended_at, "end_reason": self.end_reason, "last_event_at": self.last_event_at(),
                "events_file": self.events_file(), "nodes": self.nodes()}

    def stdout_log(self, name: str) -> str:
        """The output file of node `name` (node name, leading / optional, or process name ns/name-2)."""
        files = {}
        try:
            for f in os.listdir(self.run_dir):
                m = STDOUT_LOG.fullmatch(f)
                if m:
                    files[f] = "/" + m.group("name").replace("-", "/")  # (a ROS name has no '-')
        except OSError:
            pass
        process_file = name.strip("/").replace("/", "-") + "-stdout.log"
        if process_file in files:
            return os.path.join(self.run_dir, process_file)
        wanted = name if name.startswith("/") else "/" + name
        found = [f for f, node in files.items() if node == wanted]
        if not found:
            names = set(final_states(self.events)) | set(files.values())
            hint = did_you_mean(wanted, sorted(names))
            raise errors.ToolError("unknown node [%s]: it has no output file in %s%s"
                                   % (name, self.run_dir, "; " + hint if hint else ""))
        # (several launches on one master share a run's directory: the newest file is the last launch's)
        return max((os.path.join(self.run_dir, f) for f in found), key=_mtime)


def read_events(path: str) -> list[dict[str, Any]]:
    """The lines of an events file (OSError when it cannot be read)."""
    events = []
    with open(path, "rb") as f:
        for line in f:
            try:
                event = json.loads(line)
            except ValueError:
                continue  # (a line being written, or cut by the launch's end)
            if isinstance(event, dict):
                events.append(event)
    return events


def node_states(events: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Each node's last state change, with `name`, and how its last run that ended did end (`last_exit_*`,
    which the events file does not write: fleet.lastexit.keep_last_exit follows its lines)."""
    nodes: dict[str, dict[str, Any]] = {}
    for event in events:
        name = event.get("node")
        if isinstance(name, str) and "state" in event:
            node = nodes.setdefault(name, {"name": name, "last_exit_code": None, "last_exit_signal": None,
                                           "last_exit_at": None})
            keep_last_exit(node, event)
            node.update(event)
    return list(nodes.values())


def final_states(events: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Each node's last state change (lines of other kinds, such as launch_ended, have no node)."""
    nodes: dict[str, dict[str, Any]] = {}
    for event in events:
        if isinstance(event.get("node"), str) and "state" in event:
            nodes[event["node"]] = event
    return nodes


def when(t: float | None) -> str:
    return "?" if t is None else time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(t))


def _mtime(path: str) -> float:
    try:
        return os.stat(path).st_mtime
    except OSError:
        return 0.0


def find_run(environ: Mapping[str, str], run_id: str | None = None) -> str:
    """The log directory of run `run_id`, or of the last run (`latest`); ToolError when there is none."""
    root = log_root(environ)
    path = os.path.join(root, run_id or "latest")
    if os.path.isdir(path):
        return os.path.realpath(path)
    if not run_id:
        raise errors.ToolError("no run has logged in %s (no %s)" % (root, path), errors.EXIT_NO_LAUNCH)
    try:
        hint = did_you_mean(run_id, os.listdir(root))
    except OSError:
        hint = ""
    raise errors.ToolError("no run [%s] in %s%s" % (run_id, root, "; " + hint if hint else ""))


def read(run_dir: str, latest: bool = True) -> LastRun:
    """The run in `run_dir`; ToolError when it is not one of `launch` (roslaunch's or roscore's)."""
    run_id = os.path.basename(run_dir)
    events: list[dict[str, Any]] = []
    has_events = True
    try:
        events = read_events(os.path.join(run_dir, EVENTS_FILE))
    except FileNotFoundError:
        has_events = False
    except OSError as e:
        raise errors.ToolError("cannot read %s: %s" % (os.path.join(run_dir, EVENTS_FILE), e.strerror)) from None
    ours = _our_launch_logs(run_dir)
    if not has_events and not ours:
        raise errors.NotOurs("%s, %s, is roslaunch's (or roscore's), not a run of `launch`: it has no %s, and "
                               "`launcher` cannot tell its nodes' states; its logs are in %s"
                               % ("the last run" if latest else "the run", run_id, EVENTS_FILE, run_dir),
                             run_id, run_dir)
    pid, host, (line_at, line) = None, "", (None, "")
    if ours:
        path = max(ours, key=_mtime)  # (the last launch, when several shared the run: see stdout_log)
        m = LAUNCH_LOG.fullmatch(os.path.basename(path))
        pid, host = int(m.group("pid")), m.group("host")
        line_at, line = _last_line(path)
    ended_at, reason = None, ""
    ended = [e for e in events if e.get("event") == LAUNCH_ENDED]
    if ended:
        at = ended[-1].get("time")
        ended_at = at if isinstance(at, (int, float)) else line_at if line_at is not None else _mtime(run_dir)
        reason = str(ended[-1].get("reason") or "")
    elif line == DONE:
        ended_at = line_at
    still_running = ended_at is None and pid is not None and host == socket.gethostname() and _is_launch(pid)
    return LastRun(run_id, run_dir, latest, events, ended_at, reason, pid, still_running, line_at)


def _our_launch_logs(run_dir: str) -> list[str]:
    """The launch logs in `run_dir` that `launch` wrote (roscore's and roslaunch's share the name pattern)."""
    found = []
    try:
        names = os.listdir(run_dir)
    except OSError:
        return []
    for name in names:
        if LAUNCH_LOG.fullmatch(name):
            path = os.path.join(run_dir, name)
            try:
                with open(path, encoding="utf-8", errors="replace") as f:
                    first = f.readline()
            except OSError:
                continue
            if OUR_LINE.match(first):
                found.append(path)
    return found


def _last_line(path: str) -> tuple[float | None, str]:
    """The time and text of the launch log's last line (None, "" for an empty or unreadable log)."""
    try:
        with open(path, "rb") as f:
            f.seek(max(0, os.fstat(f.fileno()).st_size - TAIL_BYTES))
            tail = f.read().decode("utf-8", "replace")
    except OSError:
        return None, ""
    lines = [line for line in tail.splitlines() if line.strip()]
    if not lines:
        return None, ""
    m = OUR_LINE.match(lines[-1])
    if not m:
        return None, lines[-1].strip()
    at = time.mktime(time.strptime(m.group(1), "%Y-%m-%d %H:%M:%S")) + int(m.group(2)) / 1000
    return at, m.group(3).strip()


def _is_launch(pid: int) -> bool:
    """Process `pid` runs and is a launch (not another process that got its pid since)."""
    try:
        with open("/proc/%d/cmdline" % pid, "rb") as f:
            return b"launch" in f.read()
    except OSError:
        return False
