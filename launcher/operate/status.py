"""`launcher status [--json] [--watch]`: every node of a running launch, one line each.

Columns: node, state, whether its run is registered with the master (REG: a
process runs, "running", and a ROS node is up once it is registered too), pid,
uptime, restarts, last exit (code or signal),
CPU (cores), RSS, host, and while a node is over one of its limits, which
(memory_limit, cpu_limit) and what it uses now. `--json` prints the run and
its nodes as one JSON object (fields as in launcher-events.jsonl); `--watch`
redraws at each change of the launch's stream (`launcher_changes`, a long poll)
and every second between them (uptimes, CPU), and once the launch has ended
shows that run as its files tell it. When no launch answers, the last run's end and each
node's state then (operate/lastrun.py; exit status 3: nothing runs); `--run
RUN_ID` shows that run's. A run of roslaunch's has no states to tell: that is
said where the status would be, with `--json` as an object of its `run_id`,
`log_dir` and the `error` in words (exit status 3).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from typing import Any

from launcher.operate import client
from launcher.fleet.state import over_limit_text
from launcher.operate.columns import HEADER, STARTING, row


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="launcher status", description=__doc__.split("\n")[0])
    p.add_argument("--json", action="store_true", help="print the status as JSON")
    p.add_argument("--watch", action="store_true", help="redraw at every change and every second (Ctrl-C ends)")
    client.add_launch_options(p)
    client.add_run_option(p)
    return p


def table(info: dict[str, Any]) -> str:
    title = "launch %s (pid %s, run_id %s)" % (info.get("uri", "?"), info.get("pid", "?"), info.get("run_id", "?"))
    if info.get("starting"):  # (no node is made yet)
        text = title + "\n" + STARTING
    else:
        text = title + "\n" + node_table(info["nodes"])
    for u in info.get("unresponsive") or ():  # (the master's own view: callbacks to these go unanswered)
        text += ("\nWARNING: the master cannot reach %s (%s): %d failed callback(s) over %.0f s, the last: %s; "
                 "%d waiting" % (" ".join(u["names"]) or "?", u["api"], u["failures"], u["failing_s"],
                                 u["last_error"], u["queued"]))
    return text


def node_table(nodes: list[dict[str, Any]]) -> str:
    """One line per node (fields as in launcher_status or the events file), under a header."""
    if not nodes:
        return "no nodes"  # (`launch --core`, or a launch of no node)
    rows = [HEADER] + [row(n) for n in nodes]
    if any(n.get("over_limit") for n in nodes):  # (a column only while some node is over a limit)
        rows = [rows[0] + ("OVER LIMIT",)] + [
            row + (over_limit_text(n["over_limit"], n.get("cpu"), n.get("rss")) if n.get("over_limit") else "-",)
            for row, n in zip(rows[1:], nodes)]
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    return "\n".join("  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in rows)


def _main(argv: list[str]) -> int:
    opts = parser().parse_args(argv)
    # --json passes the launch's own JSON through: a 500-node status is not decoded to be encoded again
    def snapshot(uri: str) -> str:
        return client.status_text(uri) if opts.json else table(client.status(uri))

    try:
        first, last = client.live_or_last(opts, lambda uri: (uri, snapshot(uri)))
    except client.NotOurs as e:  # (a status to read, though not one of ours: said where the status would be)
        if opts.json:  # (as an object, so that a script reading the status gets JSON whatever the run)
            sys.stdout.write(json.dumps({"run_id": e.run_id, "log_dir": e.run_dir, "error": str(e)}) + "\n")
        else:
            sys.stdout.write("%s\n" % e)
        return e.status
    if last is not None:
        show_last(last, opts.json)
        # (the run's end was asked for by --run; otherwise the launch asked about does not run)
        return client.EXIT_OK if opts.run else client.EXIT_NO_LAUNCH
    uri, text = first
    # clear and redraw from the top; a pipe gets one snapshot after another
    prefix = "\x1b[H\x1b[2J" if opts.watch and sys.stdout.isatty() else ""
    sys.stdout.write(prefix + text + "\n")
    if not opts.watch:
        return client.EXIT_OK
    sys.stdout.flush()

    def redraw(_answer: dict[str, Any]) -> None:
        try:
            text = snapshot(uri)
        except client.ToolError as e:
            if e.status != client.EXIT_NO_LAUNCH:
                raise
            return  # (gone between the stream's answer and this: the stream says so next)
        sys.stdout.write(prefix + text + "\n")
        sys.stdout.flush()

    run_id = json.loads(client.status_text(uri)).get("run_id") or None
    since = client.changes(uri, client.LAST_SEQ, 0.0)["seq"]
    client.follow_changes(uri, since, redraw)  # (an answer at each change, or after a second without one)
    # the launch has ended: the run as its files tell it (how it ended, each node's last state)
    from launcher.operate import lastrun
    try:
        ended = lastrun.read(lastrun.find_run(os.environ, run_id), latest=False)
    except client.ToolError as e:
        raise client.ToolError("the launch at %s has ended (%s)" % (uri, e), client.EXIT_NO_LAUNCH) from None
    show_last(ended, opts.json, prefix)
    return client.EXIT_NO_LAUNCH


def show_last(last: Any, as_json: bool, prefix: str = "") -> None:
    """A run that has ended (operate/lastrun.py), as its files tell it."""
    if as_json:
        sys.stdout.write(prefix + json.dumps(last.as_dict(), separators=(",", ":")) + "\n")
    else:
        sys.stdout.write("%s%s\n%s\n" % (prefix, last.headline(), node_table(last.nodes())))
    sys.stdout.flush()


def main(argv: list[str]) -> int:
    return client.run_tool(_main, argv)
