"""Ready by output: a node's output file followed for the lines that `wait_for="output:NODE:PATTERN"` waits for.

Every node's output is in its `<name>-stdout.log`: a screen node's is copied
there by the launcher (`output/screen.py`), an output="log" node writes its
stdout there itself, so nothing tells the launcher when it writes. The
readiness poll (`health/readiness.py`), which runs only while some node is
held, asks each followed file for what it gained since: one stat when
nothing was written, a read of the new bytes when something was. A file that
shrank or was replaced (log rotation, a new run's truncation) is read again
from its start. `LineMatcher` is the pure part: bytes in, matched patterns out.
"""

from __future__ import annotations

import os
import re

# At most this much of a file is read per poll (the rest at the next): a chatty node cannot hold the loop.
READ_MAX = 1024 * 1024  # (7 ms of matching one pattern against 80-byte lines, measured)
# A line longer than this is matched in pieces of this size (a node that never ends its line holds no memory).
LINE_MAX = 64 * 1024


class LineMatcher:
    """The patterns waited for in one node's output, and which of them a line has matched so far."""

    def __init__(self) -> None:
        self.patterns: dict[str, re.Pattern] = {}
        self.matched: set[str] = set()
        self._tail = b""  # the line being written (no newline yet)

    def want(self, pattern: str) -> None:
        if pattern not in self.patterns:
            self.patterns[pattern] = re.compile(pattern)

    def restart(self) -> None:
        """The output starts again from nothing (what was matched stays matched)."""
        self._tail = b""

    def feed(self, data: bytes) -> None:
        complete, newline, tail = (self._tail + data).rpartition(b"\n")
        self._tail = tail
        if len(tail) > LINE_MAX:  # (matched as a line of its own)
            complete, newline, self._tail = complete + newline + tail, b"\n", b""
        pending = [(p, rx) for p, rx in self.patterns.items() if p not in self.matched]
        if not newline or not pending:
            return
        # one decode for the lot (a character cut by a read stays whole: only complete lines are decoded)
        for line in complete.decode("utf-8", "replace").split("\n"):
            line = line.rstrip("\r")
            for pattern, rx in pending:
                if pattern not in self.matched and rx.search(line):
                    self.matched.add(pattern)
            if len(self.matched) == len(self.patterns):
                return


class OutputFollower:
    """One output file, read as it grows."""

    def __init__(self, path: str):
        self.path = path
        self.matcher = LineMatcher()
        self._offset = 0
        self._inode: int | None = None

    def read(self) -> None:
        """Feed what the file gained since the last read (nothing if it does not exist yet)."""
        try:
            st = os.stat(self.path)
        except OSError:
            return
        if st.st_ino != self._inode or st.st_size < self._offset:
            self._inode, self._offset = st.st_ino, 0
            self.matcher.restart()
        if st.st_size == self._offset:
            return
        try:
            with open(self.path, "rb") as f:
                f.seek(self._offset)
                data = f.read(min(st.st_size - self._offset, READ_MAX))
        except OSError:
            return
        self._offset += len(data)
        self.matcher.feed(data)
