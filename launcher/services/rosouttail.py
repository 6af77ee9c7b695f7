"""The recent WARN, ERROR and FATAL lines of /rosout, numbered: what the live views show of the nodes whose
output goes to their log file (output="log", roslaunch's default), through the server's `launcher_output`.

The built-in rosout (net/rosout.py) hands every such message here; a reader
asks for the lines after the last number it has, as it asks for a file's
bytes after an offset. Only the newest KEPT are kept, and of their text
KEPT_CHARS at most (a node logging megabytes a message must not make the
tail hold a gigabyte): a reader that fell further behind gets the oldest kept
on (the pane is a glance, not a record: rosout.log is that).
"""

from __future__ import annotations

import collections

KEPT = 1000
KEPT_CHARS = 1000000  # (a thousand lines of a kilobyte: the newest line is always kept, whole)
LEVEL_NAMES = {4: "WARN", 8: "ERROR", 16: "FATAL"}


class RosoutTail:
    """The last KEPT warnings: (number, node, level name, text)."""

    def __init__(self, kept: int = KEPT, kept_chars: int = KEPT_CHARS):
        self.lines: collections.deque[tuple[int, str, str, str]] = collections.deque()
        self.kept, self.kept_chars = kept, kept_chars
        self.chars = 0  # the kept lines' text
        self.seq = 0  # the number of the newest line (0: none yet)

    def add(self, level: int, node: str, text: str) -> None:
        self.seq += 1
        self.lines.append((self.seq, node, LEVEL_NAMES.get(level, "FATAL" if level > 16 else "WARN"), text))
        self.chars += len(text)
        while len(self.lines) > self.kept or (self.chars > self.kept_chars and len(self.lines) > 1):
            self.chars -= len(self.lines.popleft()[3])

    def since(self, seq: int) -> list[tuple[str, str, str]]:
        """(node, level, text) of the lines numbered after `seq`, oldest first."""
        if seq >= self.seq:
            return []
        start = max(0, len(self.lines) - (self.seq - seq))
        return [line[1:] for line in list(self.lines)[start:]]
