"""Node output for the journal: when the launch's stdout is journald's stream, each relayed line says its node and priority.

journald reads a `<N>` at the start of a line of a service's stream as the
line's syslog priority (SyslogLevelPrefix=, on by default), so `journalctl -u
NAME -p err` finds the errors; the node's name follows (`/talker: ...`), so
`journalctl -u NAME --grep '^/talker:'` finds one node's lines. The priority
is the ROS level of a rospy/roscpp console line (`[ERROR] [...]: ...`), else
that of the stream (stderr: err; stdout: info). A line split over reads is
framed once whole (`LineFramer`).
"""

from __future__ import annotations

import os
import re

EMERG, ALERT, CRIT, ERR, WARNING, NOTICE, INFO, DEBUG = range(8)
LEVELS = {b"FATAL": CRIT, b"ERROR": ERR, b"WARN": WARNING, b"INFO": INFO, b"DEBUG": DEBUG}
# rospy: "[INFO] [1700000000.123456]: ...", roscpp: "[ INFO] [1700000000.123456789]: ..." (perhaps coloured)
LEVEL = re.compile(rb"^(?:\x1b\[[0-9;]*m)?\[\s*(FATAL|ERROR|WARN|INFO|DEBUG)\]")


def is_journal(environ: dict[str, str], fd: int = 1) -> bool:
    """Is `fd` the journal's stream (systemd sets JOURNAL_STREAM=device:inode of it)?"""
    dev, _, ino = environ.get("JOURNAL_STREAM", "").partition(":")
    try:
        st = os.fstat(fd)
    except OSError:
        return False
    return dev.isdigit() and ino.isdigit() and (st.st_dev, st.st_ino) == (int(dev), int(ino))


def priority(line: bytes, stderr: bool) -> int:
    m = LEVEL.match(line)
    if m:
        return LEVELS[m.group(1)]
    return ERR if stderr else INFO


class LineFramer:
    """One node's stream: bytes in, whole lines out, each `<priority>node: line`."""

    def __init__(self, node: str, stderr: bool):
        self.prefix = node.encode() + b": "
        self.stderr = stderr
        self.partial = b""

    def feed(self, data: bytes) -> bytes:
        lines = (self.partial + data).split(b"\n")
        self.partial = lines.pop()
        return b"".join(self._frame(line) for line in lines)

    def end(self) -> bytes:
        """What is left of a last line without a newline (the node has closed the stream)."""
        line, self.partial = self.partial, b""
        return self._frame(line) if line else b""

    def _frame(self, line: bytes) -> bytes:
        line = line.rstrip(b"\r")
        return b"<%d>%s%s\n" % (priority(line, self.stderr), self.prefix, line)
