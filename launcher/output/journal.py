"""Node output for the journal: when the launch's stdout is journald's stream, each relayed line says its node and priority.

Where journald's native socket is there (a service under systemd), each line
is one journal entry of its own (`NativeStream`) with fields: PRIORITY, the
node's process name as SYSLOG_IDENTIFIER (`journalctl -u NAME -t talker-1`)
and its ROS name as ROS_NODE (`journalctl -u NAME ROS_NODE=/talker`). Without
the socket, the line goes to the stream with a `<N>` at its start, which
journald reads as the line's syslog priority (SyslogLevelPrefix=, on by
default), and the node's name after it (`talker-1: ...`, for `--grep`).
Either way `journalctl -u NAME -p err` finds the errors. The priority is the
ROS level of a rospy/roscpp console line (`[ERROR] [...]: ...`), else that of
the stream (stderr: err; stdout: info). A line split over reads is framed once
whole (`LineFramer`).
"""

from __future__ import annotations

import os
import re
import socket
import struct

from launcher.output import console

EMERG, ALERT, CRIT, ERR, WARNING, NOTICE, INFO, DEBUG = range(8)
LEVELS = {b"FATAL": CRIT, b"ERROR": ERR, b"WARN": WARNING, b"INFO": INFO, b"DEBUG": DEBUG}
# rospy: "[INFO] [1700000000.123456]: ...", roscpp: "[ INFO] [1700000000.123456789]: ..." (perhaps coloured)
LEVEL = re.compile(rb"^(?:\x1b\[[0-9;]*m)?\[\s*(FATAL|ERROR|WARN|INFO|DEBUG)\]")
NATIVE_SOCKET = "/run/systemd/journal/socket"
# journald takes a datagram up to its socket's buffer; a longer line (rare in node output) goes to the stream
MAX_ENTRY = 48 * 1024


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


def native_socket(path: str = NATIVE_SOCKET) -> socket.socket | None:
    """A datagram socket connected to journald's native socket, if there is one."""
    if not os.path.exists(path):
        return None
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
    try:
        sock.connect(path)
    except OSError:
        sock.close()
        return None
    return sock


_shared: list[socket.socket | None] = []


def shared_socket() -> socket.socket | None:
    """The launch's one connection to journald's native socket (made at the first node that needs it)."""
    if not _shared:
        _shared.append(native_socket())
    return _shared[0]


def entry(fields: list[tuple[str, bytes]]) -> bytes:
    """One journal entry in the native protocol: `KEY=value` lines, or a length-prefixed value that holds a newline."""
    out = []
    for key, value in fields:
        if b"\n" in value:
            out.append(b"%s\n%s%s\n" % (key.encode(), struct.pack("<Q", len(value)), value))
        else:
            out.append(b"%s=%s\n" % (key.encode(), value))
    return b"".join(out)


class NativeStream:
    """Where one node's framed lines (`<priority>line`) go when journald's socket is there: an entry each, with
    the node's fields. The console's thread writes to it as to a stream (`buffer.write`), so a full journal
    waits there, never on the loop; a line the socket refuses goes to `fallback` (the stream) instead."""

    def __init__(self, sock: socket.socket, process_name: str, node_name: str, fallback) -> None:
        self.buffer = self  # (what output/console.py writes node output to)
        self.sock = sock
        self.fields = [("SYSLOG_IDENTIFIER", process_name.encode()), ("ROS_NODE", node_name.encode())]
        self.prefix = process_name.encode() + b": "
        self.fallback = fallback

    def write(self, data: bytes | memoryview) -> int:
        for line in bytes(data).split(b"\n"):  # (console.write_all hands over a view)
            if not line:
                continue
            level, _, message = line[1:].partition(b">")
            try:
                if len(message) > MAX_ENTRY:
                    raise OSError("longer than an entry")
                self.sock.send(entry([("MESSAGE", message), ("PRIORITY", level)] + self.fields))
            except OSError:
                console.write_all(self.fallback, b"<%s>%s%s\n" % (level, self.prefix, message))
        return len(data)  # (all taken: console.write_all writes again what a stream did not take)

    def flush(self) -> None:
        pass


class LineFramer:
    """One node's stream: bytes in, whole lines out, each `<priority>node: line` (`node=""`: `<priority>line`)."""

    def __init__(self, node: str, stderr: bool):
        self.prefix = node.encode() + b": " if node else b""
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
