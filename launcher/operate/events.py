"""`launcher events [-f] [--json]`: the run's node state changes, from its launcher-events.jsonl.

One line per change: time, node (and its host, when not this machine), state,
pid, exit, restarts, limits it is over, reason; `--json` prints the file's own
JSON lines. `-f` follows new events until Ctrl-C: while the launch runs, from its
change stream (`launcher_changes`, a long poll: each event as it happens), then,
once it has ended, what its file holds after them (its last line: the launch's
end). When no launch answers, the last run's events, after a line on stderr saying
how it ended (operate/lastrun.py); `--run RUN_ID` reads that run's.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

from launcher.operate import client
from launcher.operate.logs import tail
from launcher.operate.columns import words


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="launcher events", description=__doc__.split("\n")[0])
    p.add_argument("-f", "--follow", action="store_true", help="keep printing new events")
    p.add_argument("-n", "--lines", type=int, default=-1, metavar="N", help="only the last N events first")
    p.add_argument("--json", action="store_true", help="print the events as JSON lines")
    client.add_launch_options(p)
    client.add_run_option(p)
    return p


def describe(event: dict) -> str:
    when = time.strftime("%H:%M:%S", time.localtime(event.get("time", 0))) + ".%03d" % (event.get("time", 0) % 1 * 1000)
    if "node" not in event and event.get("event"):  # an event of the run, not a node's (launch_ended)
        return " ".join([when, str(event["event"]).replace("_", " ")] + (
            ["(%s)" % event["reason"]] if event.get("reason") else []))
    return "%s %s %s" % (when, event.get("node", "?"), words(event))


def _main(argv: list[str]) -> int:
    opts = parser().parse_args(argv)
    # (the launch's URI and, before its file is read, its stream's number: no event falls between the two)
    info, last = client.live_or_last(opts, lambda uri: (uri, client.changes(uri, client.LAST_SEQ, 0.0)["seq"],
                                                        client.status(uri)))
    if last is not None:
        sys.stderr.write(last.ended_line() + "\n")
        sys.stderr.flush()
        opts.follow = False  # (nothing more will come)
        path = last.events_file()
        uri, seq = "", 0
    else:
        uri, seq, info = info
        path = info.get("events_file")
    if not path:
        raise client.ToolError("the launch has no log directory, hence no events file")
    pending = b""
    printed = 0  # the last event's number printed (a line of the stream, or of the file)

    def show(events: list[tuple[str, dict | None]]) -> None:
        """(the line as the file has it, the event) each; an event after those printed is printed."""
        nonlocal printed
        out = []
        for text, event in events:
            number = event.get("seq") if isinstance(event, dict) else None
            if isinstance(number, int):
                if number <= printed:
                    continue  # (printed from the stream already)
                printed = number
            out.append(text if opts.json or event is None else describe(event))
        if out:
            sys.stdout.write("\n".join(out) + "\n")
            sys.stdout.flush()

    def write(data: bytes) -> None:
        nonlocal pending
        pending += data
        *lines, pending = pending.split(b"\n")  # a line still being written waits for its end
        events = []
        for line in lines:
            if not line.strip():
                continue
            text = line.decode("utf-8", "replace")
            try:
                events.append((text, json.loads(line)))
            except ValueError:
                events.append((text, None))
        show(events)

    offset = 0
    try:
        data, offset = tail(path, opts.lines)
        write(data)
    except FileNotFoundError:
        if not opts.follow:
            raise client.ToolError("no events yet (%s)" % path) from None
    if opts.follow:
        printed = max(printed, seq)  # (the file held every event up to `seq` when it was read)

        def follow(answer: dict) -> None:
            nonlocal offset
            if not answer["complete"]:  # (this reader fell behind the stream's backlog: the events it dropped
                try:  # are in the file, before the stream's; those printed already are skipped)
                    with open(path, "rb") as f:
                        f.seek(offset)
                        data = f.read()
                    offset += len(data)
                    write(data)
                except OSError:
                    pass
            show([(json.dumps(c, separators=(",", ":")), c) for c in answer["changes"]
                  if not c.get("internal")])  # (the steps the file leaves out: not shown)
        client.follow_changes(uri, printed, follow)
        try:  # the launch has ended: what its file has after the events the stream gave (its end)
            with open(path, "rb") as f:
                f.seek(offset)
                write(f.read() + b"\n")
        except OSError:
            pass
    return client.EXIT_OK


def main(argv: list[str]) -> int:
    return client.run_tool(_main, argv)
