"""`launcher logs NODE [-f] [-n LINES]`: a node's output, from the file the launch writes it to.

Every node's output is in `<name>-stdout.log` in the run's log directory: an
output="log" node writes its stdout there itself (and the launcher adds its
stderr, which also goes to the terminal); an output="screen" node's stdout and
stderr reach the terminal through the launcher, which keeps the same bytes
there (output/screen.py). `-f` follows the file as it grows, across the
node's restarts and the file's rotations, until Ctrl-C. Colours (the escape
sequences rosconsole writes) are kept only on a terminal, or with `--color`.
When no launch answers, the output the node left in the last run, after a line
on stderr saying how that run ended (operate/lastrun.py); `--run RUN_ID` reads
that run's.
"""

from __future__ import annotations

import argparse
import os
import re
import select
import sys
import time
from collections import deque
from typing import Callable

from launcher.operate import client

FOLLOW_PERIOD_S = 0.2


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="launcher logs", description=__doc__.split("\n")[0])
    p.add_argument("node", metavar="NODE", help="node name (/ns/name) or process name (ns/name-2)")
    p.add_argument("-f", "--follow", action="store_true", help="keep printing what the node writes")
    p.add_argument("-n", "--lines", type=int, default=10, metavar="LINES", help="print the last LINES lines "
                   "first (default 10; 0: none, -1: all)")
    p.add_argument("--color", "--colour", nargs="?", const="always", default="auto", choices=("auto", "always", "never"),
                   metavar="WHEN", help="keep the output's colours (escape sequences): auto (the default: when "
                   "writing to a terminal), always (--color alone) or never")
    client.add_launch_options(p)
    client.add_run_option(p)
    return p


def tail(path: str, lines: int) -> tuple[bytes, int]:
    """The last `lines` lines of a file (all for a negative count) and the offset after them."""
    with open(path, "rb") as f:
        if lines < 0:
            data = f.read()
            return data, f.tell()
        kept: deque[bytes] = deque(maxlen=max(lines, 0) or 1)
        for line in f:
            kept.append(line)
        end = f.tell()
    return (b"".join(kept) if lines > 0 else b""), end


def follow(path: str, offset: int, write: Callable[[bytes], None], keep_going: Callable[[], bool] = lambda: True,
           period: float = FOLLOW_PERIOD_S) -> None:
    """Write what is appended to `path` from `offset` on; a file truncated or replaced is read from its start."""
    inode = None
    while keep_going():
        try:
            st = os.stat(path)
        except FileNotFoundError:
            time.sleep(period)
            continue
        if inode is not None and st.st_ino != inode or st.st_size < offset:
            offset = 0  # rotated or truncated (a node restarted without respawn's append)
        inode = st.st_ino
        if st.st_size > offset:
            with open(path, "rb") as f:
                f.seek(offset)
                data = f.read()
            offset += len(data)
            write(data)
            continue
        time.sleep(period)


# Terminal escape sequences: CSI (colours: ESC [ 31 m), OSC (a title: ESC ] ... BEL or ST), the other two-byte ones.
ESCAPE = re.compile(rb"\x1b(?:\[[0-?]*[ -/]*[@-~]|\][^\x07\x1b]*(?:\x07|\x1b\\)|[@-Z\\^_])")
CUT_ESCAPE = re.compile(rb"\x1b(?:\[[0-?]*[ -/]*|\][^\x07\x1b]*)?\Z")  # one a chunk ends inside of
MAX_CUT = 256  # a longer "escape" at a chunk's end is no escape: it is written as it is


class Uncoloured:
    """Writes node output without its escape sequences (rosconsole colours every line, rospy at a terminal),
    for a reader that is no terminal; a sequence cut between two chunks is held until its end arrives."""

    def __init__(self, write: Callable[[bytes], None]):
        self._write = write
        self._held = b""

    def __call__(self, data: bytes) -> None:
        data = self._held + data
        cut = CUT_ESCAPE.search(data)
        if cut is not None and len(data) - cut.start() <= MAX_CUT:
            data, self._held = data[:cut.start()], data[cut.start():]
        else:
            self._held = b""
        if data:
            self._write(ESCAPE.sub(b"", data))


def _write(data: bytes) -> None:
    """All of `data` to stdout. Under `python -u` or PYTHONUNBUFFERED=1 its binary layer is the raw descriptor, and
    a write to a full terminal that a stop (Ctrl-Z, then fg) or a signal cuts short says so only by its count: the
    rest is written again (what output/console.write_all does for a launch's console)."""
    out = sys.stdout.buffer
    view = memoryview(data)
    while view:
        taken = out.write(view)
        if taken is None:  # (a raw descriptor someone made non-blocking, full: wait until it takes more)
            select.select((), (out.fileno(),), ())
        else:
            view = view[taken:]
    out.flush()


def _main(argv: list[str]) -> int:
    opts = parser().parse_args(argv)
    info, last = client.live_or_last(opts, client.status)
    if last is not None:
        path = last.stdout_log(opts.node)
        name = opts.node
        sys.stderr.write(last.ended_line() + "\n")
        sys.stderr.flush()
        opts.follow = False  # (nothing more will come)
    else:
        node = client.find_node(info, opts.node)
        path, name = node.get("stdout_log"), node["name"]
        if not path:
            raise client.ToolError("node [%s] has no output file on this machine (it runs elsewhere, or the "
                                   "launch has no log directory)" % name)
    colour = opts.color == "always" or opts.color == "auto" and sys.stdout.isatty()
    write = _write if colour else Uncoloured(_write)
    offset = 0
    try:
        data, offset = tail(path, opts.lines)
        write(data)
    except FileNotFoundError:
        if not opts.follow:
            raise client.ToolError("node [%s] has written no output yet (%s)" % (name, path)) from None
    if opts.follow:
        follow(path, offset, write)
    return client.EXIT_OK


def main(argv: list[str]) -> int:
    return client.run_tool(_main, argv)


# (offered by `launcher __complete` for this subcommand's node argument)
complete_node_names = client.complete_node_names
