"""The live view's state, without a terminal: the nodes, the selection, the filter, muted nodes, the output pane and
its scrolling, and the rows as text (`operate/ui.py` draws them with prompt_toolkit; tested in tests/operate).

It is fed what the launch's server sends: `launcher_status` once (`load`), then
the change stream (`changes`, the events file's lines), the resource samples
(`samples`) and the nodes' output (`output`). Every function of time takes
`now` (wall-clock seconds), so the rows are a function of what was fed and a
clock.
"""

from __future__ import annotations

import collections
from typing import Any, Iterable

from launcher.fleet.lastexit import keep_last_exit
from launcher.model.units import format_size
from launcher.operate import columns

OUTPUT_KEPT = 5000  # lines of the output pane kept for scrolling back
STATE_STYLE = {"running": "green", "waiting": "yellow", "respawning": "yellow", "hung": "red", "fatal": "red",
               "exited": "grey", "stopped": "grey"}
LEVEL_STYLE = {"WARN": "warn", "ERROR": "error", "FATAL": "fatal"}  # a /rosout line's colour (operate/ui.py)
NODE_OUTPUT = "node"  # the pane shows the selected node's recent output (its log), not every node's
ALL_OUTPUT = "all"
HISTORY = 60  # CPU samples kept per node for its sparkline (a minute at the 1 s refresh)
SPARK = "\u2581\u2582\u2583\u2584\u2585\u2586\u2587\u2588"
SPARK_MIN_TOP = 0.05  # cores: the sparkline's top at least this, so an idle node's noise stays flat
HELP = "\u2191\u2193 s/t/r stop/start/restart  S/T all  R reload  / filter  m mute  o log  q quit"


class Line:
    """One line of the output pane."""

    __slots__ = ("node", "text", "kind")

    def __init__(self, node: str, text: str, kind: str = "output"):
        self.node = node
        self.text = text
        # "output" (the node's), "state" (a change the view saw), or a /rosout line's level (WARN, ERROR, FATAL)
        self.kind = kind


class ViewState:
    """What the view shows. Nodes are the status's dicts (fields as in `launcher_status`), kept up to date."""

    def __init__(self) -> None:
        self.info: dict[str, Any] = {}
        self.nodes: dict[str, dict[str, Any]] = {}  # in the launch's order
        self.selected = ""  # a node name ('' before any)
        self.filter = ""
        self.muted: set[str] = set()
        self.lines: collections.deque[Line] = collections.deque(maxlen=OUTPUT_KEPT)
        self._partial: dict[str, str] = {}  # a node's output line not ended yet
        self.scroll = 0  # output lines scrolled back from the newest (0: follows the output)
        self.table_top = 0  # the first visible row of the node table
        self.mode = ALL_OUTPUT
        self.node_output: list[str] = []  # the selected node's recent output, in NODE_OUTPUT mode
        self.message = ""  # the answer to the operator's last action
        self.seq = 0  # the last change of the stream applied
        self.history: dict[str, collections.deque] = {}  # node -> its CPU samples (cores; None: not running)
        self.header: list[str] = list(columns.HEADER)  # the table's header as the last rows were fitted
        self.sep = "  "

    # ---- fed by the launch ---------------------------------------------------------------------------

    def load(self, info: dict[str, Any]) -> None:
        """The whole status (`launcher_status`): at start, and when the change stream lost changes."""
        self.info = info
        self.nodes = {n["name"]: dict(n) for n in info.get("nodes") or ()}
        if self.selected not in self.nodes:
            shown = self.visible()
            self.selected = shown[0] if shown else ""

    @property
    def starting(self) -> bool:
        """A launch still setting up, as its status said: no node is made yet (its master, its parameters first)."""
        return bool(self.info.get("starting")) and not self.nodes

    def stale(self, answer: dict[str, Any]) -> bool:
        """Whether an answer of the change stream (`launcher_changes`) means the status must be read again: changes
        were dropped; or the launch has made its nodes since the status was read (a change names a node this state
        lacks, or the launch no longer says it is starting: a launch of no node has no change to say it by)."""
        return (not answer["complete"] or self.unknown(answer["changes"])
                or (self.starting and not answer.get("starting", False)))

    def unknown(self, lines: Iterable[dict[str, Any]]) -> bool:
        """Whether a change names a node this state does not have (the status was read before the launch had made
        its nodes): its reader reads the status again, which has it."""
        return any(isinstance(c.get("node"), str) and c["node"] not in self.nodes for c in lines)

    def changes(self, lines: Iterable[dict[str, Any]]) -> None:
        """Changes of the stream (as the events file writes them): each node's row, and a line in the pane."""
        for c in lines:
            self.seq = max(self.seq, c.get("seq", 0))
            node = self.nodes.get(c.get("node", ""))
            if node is None:
                continue
            was_running, old_pid = node.get("state") == "running", node.get("pid")
            keep_last_exit(node, c)
            for key in ("state", "pid", "exit_code", "exit_signal", "restarts", "failures", "next_start",
                        "over_limit", "reason", "phase", "registered", "uri"):
                if key in c:
                    node[key] = c[key]
            if node["state"] == "running" and (not was_running or node.get("pid") != old_pid):
                node["started_at"] = c.get("time")
            if node["state"] != "running":
                node["started_at"] = None
                node["cpu"] = node["rss"] = None
            if not c.get("internal"):  # (one line per change of the events file, in its words)
                self.lines.append(Line(node["name"], change_text(c), "state"))

    def samples(self, samples: dict[str, list]) -> None:
        """CPU (cores) and RSS (bytes) of the running nodes (`launcher_samples`); each node's CPU history too."""
        for name, node in self.nodes.items():
            cpu_rss = samples.get(name)
            node["cpu"], node["rss"] = cpu_rss if cpu_rss else (None, None)
            self.history.setdefault(name, collections.deque(maxlen=HISTORY)).append(node["cpu"])

    def past_samples(self, history: dict[str, list]) -> None:
        """The samples the launch kept before the view attached (`launcher_samples(true)`: [time, cpu, rss]
        lists), put before any the view took itself."""
        for name, kept in history.items():
            if name in self.nodes:
                mine = self.history.get(name, ())
                self.history[name] = collections.deque([s[1] for s in kept] + list(mine), maxlen=HISTORY)

    def spark(self, name: str, width: int) -> str:
        """A node's CPU over its last `width` samples as block characters (a space where it did not run)."""
        values = list(self.history.get(name, ()))[-width:] if width > 0 else []
        top = max([SPARK_MIN_TOP] + [v for v in values if v is not None])
        return "".join(" " if v is None else SPARK[min(len(SPARK) - 1, int(v / top * (len(SPARK) - 1) + 0.5))]
                       for v in values)

    def output(self, node: str, text: str) -> None:
        """A piece of a node's output: whole lines go to the pane, a line's start waits for its end."""
        text = self._partial.pop(node, "") + text
        *done, rest = text.split("\n")
        if rest:
            self._partial[node] = rest
        for line in done:
            self.lines.append(Line(node, line.rstrip("\r")))
        if self.scroll:  # (the operator reads back: what they read stays in place)
            self.scroll = min(self.scroll + len(done), max(0, len(self.lines) - 1))

    def skipped(self, node: str, size: int) -> None:
        """Output of a node passed over (a flood, more than a view shows): said in its place; the line it was
        in is passed over with it."""
        self._partial.pop(node, None)
        self.lines.append(Line(node, "... %s of output passed over (`launcher logs %s` has every line)"
                               % (format_size(size, measured=True), node), "state"))
        if self.scroll:
            self.scroll = min(self.scroll + 1, max(0, len(self.lines) - 1))

    def warning(self, node: str, level: str, text: str) -> None:
        """A WARN, ERROR or FATAL line of an output="log" node, from /rosout: tagged with its level."""
        for line in text.split("\n"):
            self.lines.append(Line(node, "%s %s" % (level, line), level))
        if self.scroll:
            self.scroll = min(self.scroll + 1, max(0, len(self.lines) - 1))

    # ---- the operator's keys -----------------------------------------------------------------------------

    def visible(self) -> list[str]:
        """The nodes the filter lets through (a part of the name, any case)."""
        f = self.filter.lower()
        return [name for name in self.nodes if f in name.lower()]

    def move(self, delta: int) -> None:
        shown = self.visible()
        if not shown:
            self.selected = ""
            return
        i = shown.index(self.selected) if self.selected in shown else 0
        self.selected = shown[max(0, min(len(shown) - 1, i + delta))]

    def set_filter(self, text: str) -> None:
        self.filter = text
        shown = self.visible()
        if self.selected not in shown:
            self.selected = shown[0] if shown else ""
        self.table_top = 0

    def toggle_mute(self) -> None:
        if not self.selected:
            return
        if self.selected in self.muted:
            self.muted.discard(self.selected)
            self.message = "%s unmuted" % self.selected
        else:
            self.muted.add(self.selected)
            self.message = "%s muted: its output is not shown" % self.selected
        self.scroll = 0

    def scroll_output(self, delta: int) -> None:
        """Back (positive) or forward through the pane's lines; 0 is the newest (following)."""
        self.scroll = max(0, min(self.scroll + delta, max(0, len(self.shown_lines()) - 1)))

    def show_node_output(self, text: str | None) -> None:
        """The selected node's recent output (None: back to every node's output)."""
        if text is None:
            self.mode, self.node_output = ALL_OUTPUT, []
        else:
            self.mode, self.node_output = NODE_OUTPUT, text.split("\n")
        self.scroll = 0

    # ---- what is drawn -------------------------------------------------------------------------------------

    def shown_lines(self) -> list[str]:
        return [text for text, _ in self.shown_entries()]

    def shown_entries(self) -> list[tuple[str, str]]:
        """The pane's lines with their style (a /rosout line's level's, else '')."""
        if self.mode == NODE_OUTPUT:
            return [(text, "") for text in self.node_output]
        f = self.filter.lower()
        return [("[%s] %s" % (line.node, line.text), LEVEL_STYLE.get(line.kind, "")) for line in self.lines
                if line.node not in self.muted and f in line.node.lower()]

    def output_rows(self, height: int) -> list[str]:
        """The pane's lines, `height` of them at most, ending `scroll` lines before the newest."""
        return [text for text, _ in self.output_entries(height)]

    def output_entries(self, height: int) -> list[tuple[str, str]]:
        """output_rows with each line's style."""
        lines = self.shown_entries()
        end = len(lines) - self.scroll
        return lines[max(0, end - height):end]

    def table_rows(self, height: int, now: float, width: int = 0) -> list[tuple[str, str, bool]]:
        """(row text, the state's style, selected) of the visible nodes, `height` rows at most, scrolled so that
        the selection shows. The columns are `launcher status`'s (operate/columns.row); in `width` columns
        (0: no limit) they are fitted as `fit_columns` does, every column kept."""
        shown = self.visible()
        if height <= 0 or not shown:
            return []
        if self.selected in shown:
            i = shown.index(self.selected)
            if i < self.table_top:
                self.table_top = i
            elif i >= self.table_top + height:
                self.table_top = i - height + 1
        self.table_top = max(0, min(self.table_top, len(shown) - height))
        window = shown[self.table_top:self.table_top + height]
        rows = [columns.row(self._with_uptime(self.nodes[name], now)) for name in window]
        self.header, rows, sep = fit_columns(columns.HEADER, rows, width - len(MARK) if width else 0)
        self.sep = sep
        out = []
        for name, r in zip(window, rows):
            node = self.nodes[name]
            # ("> ": the selection shows without colours too)
            text = ("> " if name == self.selected else MARK) + sep.join(r).rstrip()
            if node.get("over_limit"):
                text += " OVER " + ",".join(sorted(node["over_limit"]))
            if name in self.muted:
                text += " (muted)"
            out.append((text[:width] if width else text,
                        "red" if node.get("over_limit") else STATE_STYLE.get(node["state"], ""), name == self.selected))
        return out

    def table_header(self, now: float) -> str:
        """The column names in the widths of the rows under them (table_rows first)."""
        return MARK + self.sep.join(self.header).rstrip()

    def title(self, width: int = 0) -> str:
        """The launch, its run id, how many nodes run (and the filter); in `width` columns (0: no limit) the
        run id goes first (a uuid: the counts matter more at a glance)."""
        shown, total = len(self.visible()), len(self.nodes)
        running = sum(1 for n in self.nodes.values() if n["state"] == "running")
        counts = "%d/%d running" % (running, total)
        if self.filter:
            counts += "  filter [%s]: %d shown" % (self.filter, shown)
        text = "launch %s  run %s  %s" % (self.info.get("uri", "?"), self.info.get("run_id", "?"), counts)
        if width and len(text) > width:
            text = "launch %s  %s" % (self.info.get("uri", "?"), counts)
        return text

    @staticmethod
    def _with_uptime(node: dict[str, Any], now: float) -> dict[str, Any]:
        if node.get("state") == "running" and node.get("started_at"):
            return dict(node, uptime=max(0.0, now - node["started_at"]))
        return dict(node, uptime=None)


MARK = "  "  # before a row: "> " for the selected one
SHORT_HEADER = {"UPTIME": "UP", "RESTARTS": "RST", "LAST EXIT": "EXIT"}
NAME_MIN = 10  # the node column is shrunk no further (the columns after it are then cut at the edge)
HOST_MAX = 12  # a host's name is cut to this when the row would not fit otherwise


def fit_columns(header: tuple[str, ...], rows: list[tuple[str, ...]], width: int
                ) -> tuple[list[str], list[list[str]], str]:
    """(header, rows, separator): the cells padded to their column's width and, when the table is wider than
    `width` (0: no limit), fitted without dropping a column (80 columns hold them all): one space between
    columns, then short names for the wide headers, then a host cut to HOST_MAX, then the node names
    abbreviated from the left (`…` and their end, the part that tells nodes apart) down to NAME_MIN."""
    header, cells = list(header), [list(r) for r in rows]

    def widths() -> list[int]:
        return [max(len(h), *(len(r[i]) for r in cells)) for i, h in enumerate(header)]

    def total(sep: str) -> int:
        return sum(widths()) + len(sep) * (len(header) - 1)

    sep = "  "
    if width and total(sep) > width:
        sep = " "
        for step in ("headers", "host", "name"):
            if total(sep) <= width:
                break
            if step == "headers":
                header = [SHORT_HEADER.get(h, h) for h in header]
            elif step == "host":
                for r in cells:
                    r[-1] = cut_right(r[-1], HOST_MAX)
            else:
                room = max(NAME_MIN, width - (total(sep) - widths()[0]))
                for r in cells:
                    r[0] = cut_left(r[0], room)
    w = widths()
    return ([h.ljust(n) for h, n in zip(header, w)], [[c.ljust(n) for c, n in zip(r, w)] for r in cells], sep)


def cut_left(text: str, n: int) -> str:
    return text if len(text) <= n else "\u2026" + text[len(text) - n + 1:]


def cut_right(text: str, n: int) -> str:
    return text if len(text) <= n else text[:n - 1] + "\u2026"


def change_text(c: dict[str, Any]) -> str:
    """A change as one line of the pane: as `launcher events` says it (its time and node aside)."""
    return columns.words(c)
