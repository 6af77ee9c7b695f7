"""Terminal-bound node output relayed by the launcher: a pty or pipe per stream, read on the loop, copied to the console and to the node's output file.

roslaunch lets an output="screen" node (and the stderr of an output="log"
node) write straight to its own terminal, so nothing keeps that output and
`launcher logs` could not show it. Here the launcher sits in the data path:

- The node gets, per stream, a **pty when the launcher's own stream is a
  terminal** (the node still sees a tty: rospy colours its log lines only when
  `isatty()`, C stdio line-buffers only a tty) and a **pipe otherwise** (the
  buffering a redirected roslaunch gave it). When stdout and stderr are the same
  terminal, one pty carries both, so their order is kept. The pty gets the
  terminal's window size, and output processing off (OPOST): the real terminal
  turns "\\n" into "\\r\\n" once, when the launcher writes there. It is not made
  the node's controlling terminal (the node runs in its own session and only
  inherits the descriptor; it never opens the pty). When the terminal is
  resized (SIGWINCH to the launcher), every such pty gets the new size: a node
  that asks for its terminal's size sees it, as one writing to the terminal
  itself does under roslaunch (neither gets a SIGWINCH of its own).
- The loop reads each descriptor when it is readable, as much as it holds (up
  to READ_MAX: a pty gives at most 4 KiB a read, so a flood is read in a few
  reads per wake), and passes on the **whole lines** of it as one slice: one
  write appends them to the node's `<proc>-stdout.log` (the file roslaunch
  writes for output="log"; kept under --log-max-size by output/logrotate.py),
  one hand-over gives them to the console. What follows the last newline waits
  for the rest of its line, so two nodes' lines never mix mid-line on the
  shared terminal; a line still without its end after PARTIAL_S (a prompt, a
  progress bar redrawn with "\r") or longer than LINE_MAX is passed on as it
  is. Nothing here looks at single lines or decodes: a view's output pane
  (services/server.py's `launcher_output`) and an output readiness pattern
  (health/outputwatch.py) read the log file. Only the journal's per-line fields
  (under systemd, output/journal.py) take the lines one by one; `counts` says
  how many bytes went each way (the launch log's last note). The kernel cannot
  do this copy for us while keeping lines whole: splice(2)/tee(2) move bytes
  without telling where a line ends, and a pty (what a node on a terminal
  gets) is read through the tty layer either way (benchmarks/screen_flood.py's
  C floor: the kernel's part of a pty relay, which ours is close to). The
  console never drops node output: past its bound, reading stops until it
  drains, and the node blocks in its write as on a blocked terminal.
- When the node exits, what it wrote is read out (`drain`) before the
  supervisor prints the exit line, so the console shows it in roslaunch's order.
  A descriptor still held by a process the node left behind stays watched until
  its end of file.
- A node that dies at once of `ModuleNotFoundError` for a module the system's
  python has (rospy, run by a venv's or pyenv's `python3` first on PATH) gets
  one line saying so at its exit, once per interpreter (launcher/workspace/nodepython.py).
"""

from __future__ import annotations

import asyncio
import fcntl
import os
import signal
import sys
import termios
import weakref
from typing import TextIO

from launcher.workspace import nodepython
from launcher.output import console, journal

CHUNK = 65536  # one read: a pipe's default capacity (and no larger: a bigger buffer is an mmap per read)
# Per readable event, reads go on until the descriptor is empty or this much was read: a flooding pty (4 KiB a
# read) costs a few reads per wake instead of a wake per read, and the loop is not held for long.
READ_MAX = 256 * 1024
SHORT_READ = 2048  # a read shorter than this emptied the descriptor (a pipe, or a pty's trickle): no read more
LINE_MAX = 64 * 1024  # a line longer than this is passed on in pieces (a node that never ends its line)
# A line without its end yet is passed on after this (a prompt, a progress bar): long enough for a node
# held back by a busy machine between two writes of one line, short enough for a person.
PARTIAL_S = 0.2
# At a node's exit at most this much is read at once per stream: more than any pipe or pty buffers
# (fs.pipe-max-size is 1 MiB), and a bound when a process the node left behind keeps writing.
DRAIN_MAX = 1 << 20


def _is_terminal(fd: int) -> bool:
    try:
        return os.isatty(fd)
    except OSError:
        return False


def _same_terminal(a: int, b: int) -> bool:
    try:
        return os.path.samestat(os.fstat(a), os.fstat(b))
    except OSError:
        return False


def _open_pty(terminal_fd: int) -> tuple[int, int] | None:
    """(launcher's end, node's end) of a new pty sized like `terminal_fd`; None when no pty can be had."""
    try:
        parent, child = os.openpty()
    except OSError:
        return None  # (ptys exhausted: kernel.pty.max) a pipe still carries the output
    try:
        attrs = termios.tcgetattr(child)
        attrs[1] &= ~termios.OPOST
        termios.tcsetattr(child, termios.TCSANOW, attrs)
        fcntl.ioctl(child, termios.TIOCSWINSZ, fcntl.ioctl(terminal_fd, termios.TIOCGWINSZ, b"\0" * 8))
    except OSError:
        pass  # a terminal without a size: the node sees 0x0, as under `script`
    return parent, child


# The relayed ptys (launcher's end -> the terminal descriptor whose size they copy), and the loops that
# pass a resize on to them.
_sized_ptys: dict[int, int] = {}
_resize_loops: weakref.WeakSet[asyncio.AbstractEventLoop] = weakref.WeakSet()


def _copy_size(pty_fd: int, terminal_fd: int) -> None:
    try:
        fcntl.ioctl(pty_fd, termios.TIOCSWINSZ, fcntl.ioctl(terminal_fd, termios.TIOCGWINSZ, b"\0" * 8))
    except OSError:
        pass  # the terminal is gone or has no size: the pty keeps the one it has


def _terminal_resized() -> None:
    for pty_fd, terminal_fd in _sized_ptys.items():
        _copy_size(pty_fd, terminal_fd)


def _follow_resizes(loop: asyncio.AbstractEventLoop, pty_fd: int, terminal_fd: int) -> None:
    _sized_ptys[pty_fd] = terminal_fd
    if loop not in _resize_loops:
        try:
            loop.add_signal_handler(signal.SIGWINCH, _terminal_resized)
        except (RuntimeError, ValueError):  # not the main thread's loop: the ptys keep their first size
            return
        _resize_loops.add(loop)


# Bytes relayed since the launch started, by the way they went: "as_read", whole lines passed on as they were
# read (no per-line work), and "by_line", taken line by line in Python (the journal's fields).
counts = {"as_read": 0, "by_line": 0}


def relay_note() -> str | None:
    """The launch log's words on how the screen output went (None: there was none)."""
    if not counts["as_read"] and not counts["by_line"]:
        return None
    return ("screen relay: %d bytes relayed in whole lines as read (no per-line work), %d line by line "
            "(the journal's fields)" % (counts["as_read"], counts["by_line"]))


# The interpreters an import hint was given for: once per launch is enough (every node of a package fails alike).
_hinted: set[str] = set()


def _open_pipe() -> tuple[int, int]:
    read_end, write_end = os.pipe2(os.O_CLOEXEC)
    return read_end, write_end


class Channels:
    """The descriptors of one run's relayed streams: the node's ends (for Popen) and the launcher's."""

    __slots__ = ("stdout", "stderr", "sources", "_child_ends")

    def __init__(self) -> None:
        self.stdout: int | None = None  # the node's stdout (None: spawn decides, a file or inherited)
        self.stderr: int | None = None
        self.sources: list[tuple[int, TextIO]] = []  # (launcher's end, console stream it goes to)
        self._child_ends: list[int] = []

    def _add(self, launcher_stream: TextIO, terminal_fd: int) -> int:
        ends = _open_pty(terminal_fd) if _is_terminal(terminal_fd) else None
        parent, child = ends if ends is not None else _open_pipe()
        os.set_blocking(parent, False)
        self.sources.append((parent, launcher_stream))
        self._child_ends.append(child)
        return child

    def close_child_ends(self) -> None:
        """After the spawn: only the node holds them now (so that its exit ends the stream)."""
        for fd in self._child_ends:
            os.close(fd)
        self._child_ends.clear()

    def close(self) -> None:
        """The spawn failed: nothing will read these."""
        self.close_child_ends()
        for fd, _ in self.sources:
            os.close(fd)
        self.sources.clear()


def open_channels(output: str) -> Channels:
    """The relayed streams for a node: both for output="screen", stderr alone for output="log"."""
    ch = Channels()
    if output == "screen":
        if _is_terminal(1) and _is_terminal(2) and _same_terminal(1, 2):
            ch.stdout = ch.stderr = ch._add(sys.stdout, 1)  # one pty: stdout and stderr keep their order
        else:
            ch.stdout = ch._add(sys.stdout, 1)
            ch.stderr = ch._add(sys.stderr, 2)
    else:
        ch.stderr = ch._add(sys.stderr, 2)
    return ch


class ScreenOutput:
    """One run's relayed output: readers on the loop, the copy in the node's output file, backpressure."""

    def __init__(self, loop: asyncio.AbstractEventLoop, name: str, sources: list[tuple[int, TextIO]],
                 log_path: str | None, truncate: bool, node_name: str | None = None) -> None:
        self.loop = loop
        self.name = name
        self.sources = dict(sources)  # launcher's end -> console stream, while open
        self.paused = False
        self.started = loop.time()
        self.missing_module: str | None = None  # what an import error at the start named (workspace/nodepython.py)
        self.log_fd: int | None = None
        # under systemd, stdout is the journal: each line goes with its priority and node (output/journal.py),
        # as an entry with the node's fields where journald's socket is there, else framed on the stream
        self.framers: dict[int, journal.LineFramer] = {}
        self.targets: dict[int, object] = {}  # launcher's end -> where its framed lines go, if not the stream
        # launcher's end -> (the start of a line not ended yet, when that line began)
        self.partial: dict[int, tuple[bytes, float]] = {}
        self._partial_timer: asyncio.TimerHandle | None = None
        if journal.is_journal(os.environ):
            sock = journal.shared_socket()
            for fd, stream in self.sources.items():
                self.framers[fd] = journal.LineFramer("" if sock else name, stream is sys.stderr)
                if sock:
                    self.targets[fd] = journal.NativeStream(sock, name, node_name or "/" + name, stream)
        if log_path:
            flags = os.O_WRONLY | os.O_CREAT | os.O_CLOEXEC | os.O_APPEND | (os.O_TRUNC if truncate else 0)
            try:
                self.log_fd = os.open(log_path, flags, 0o666)
            except OSError as e:  # the output still reaches the terminal; say why the file will miss it
                console.printerrlog("[%s] cannot write its output to %s: %s" % (name, log_path, e.strerror))
        for fd, stream in self.sources.items():
            loop.add_reader(fd, self._readable, fd)
            if _is_terminal(fd):  # a pty (Channels._add makes one only for a terminal stream)
                try:
                    _follow_resizes(loop, fd, stream.fileno())
                except (OSError, ValueError):  # a stream without a descriptor: nothing to follow
                    pass

    @property
    def closed(self) -> bool:
        return not self.sources

    def _read(self, fd: int, limit: int = READ_MAX) -> int:
        """Read what `fd` holds (about `limit` at most) and relay its whole lines: how many bytes (0 when there
        is nothing more now, or ever: closed)."""
        chunks = []
        got = 0
        ended = False
        while got < limit:
            try:
                data = os.read(fd, CHUNK)
            except BlockingIOError:
                break
            except OSError:  # EIO: a pty whose node ends are all closed
                data = b""
            if not data:
                ended = True
                break
            chunks.append(data)
            got += len(data)
            if len(data) < SHORT_READ:
                break
        if chunks:
            self._lines(fd, chunks[0] if len(chunks) == 1 else b"".join(chunks))
        if ended:
            self._close(fd)
        return got

    def _lines(self, fd: int, data: bytes) -> None:
        """Pass on the whole lines of what was read; keep the start of a line not ended yet."""
        kept = self.partial.pop(fd, None)
        if kept is not None:
            data = kept[0] + data
        end = data.rfind(b"\n") + 1
        if end < len(data) and len(data) - end <= LINE_MAX:
            began = kept[1] if kept is not None and end == 0 else self.loop.time()
            self.partial[fd] = (data[end:], began)
            if self._partial_timer is None:
                self._partial_timer = self.loop.call_later(PARTIAL_S, self._partial_due)
            if not end:
                return
            data = data[:end]
        self._relay(fd, data)

    def _partial_due(self) -> None:
        """Lines left without their end for PARTIAL_S are passed on as they are (what the node wrote since is
        read first: its end may be there); the others are looked at again. Not while the console is full: the
        ends wait unread in the kernel then."""
        self._partial_timer = None
        if not self.paused:
            now = self.loop.time()
            for fd, (_, began) in list(self.partial.items()):
                if now - began >= PARTIAL_S and fd in self.sources:
                    self._read(fd)
                    if self.paused:
                        break
                    kept = self.partial.get(fd)
                    if kept is not None and kept[1] == began:
                        self._flush_partial(fd)
        if self.partial:
            first = min(began for _, began in self.partial.values())
            self._partial_timer = self.loop.call_later(max(0.0, first + PARTIAL_S - self.loop.time()),
                                                       self._partial_due)

    def _flush_partial(self, fd: int) -> None:
        kept = self.partial.pop(fd, None)
        if kept is not None:
            self._relay(fd, kept[0])

    def _relay(self, fd: int, data: bytes) -> None:
        """Lines (the last one perhaps not ended) to the node's output file and the console, each one call."""
        if self.log_fd is not None:
            try:
                os.write(self.log_fd, data)
            except OSError as e:  # a full disk: the terminal keeps the output, the file stops here
                console.printerrlog("[%s] stopped writing its output to its log file: %s"
                                         % (self.name, e.strerror))
                os.close(self.log_fd)
                self.log_fd = None
        framer = self.framers.get(fd)
        if framer is None:
            counts["as_read"] += len(data)
            relayed = console.relay(self.sources[fd], data)
        else:
            counts["by_line"] += len(data)
            relayed = console.relay(self.targets.get(fd, self.sources[fd]), framer.feed(data))
        if not relayed and not self.paused:
            self._pause()
        if (self.missing_module is None and self.loop.time() - self.started < nodepython.AT_ONCE_S
                and b"No module named" in data):
            self.missing_module = nodepython.missing_module(data)

    def _readable(self, fd: int) -> None:
        if fd in self.sources and not self.paused:
            self._read(fd)

    def _pause(self) -> None:
        self.paused = True
        for fd in self.sources:
            self.loop.remove_reader(fd)
        console.when_drained(self._drained)

    def _drained(self) -> None:
        try:
            self.loop.call_soon_threadsafe(self._resume)
        except RuntimeError:  # the loop is closed: the launch is over
            pass

    def _resume(self) -> None:
        if not self.paused:
            return
        self.paused = False
        for fd in self.sources:
            self.loop.add_reader(fd, self._readable, fd)

    def drain(self) -> None:
        """Relay the output the node has written so far (it exited): what the kernel holds, up to DRAIN_MAX per
        stream. Backpressure waits for no one here: that much is bounded."""
        for fd in list(self.sources):
            relayed = 0
            while fd in self.sources and relayed < DRAIN_MAX:
                n = self._read(fd, min(READ_MAX, DRAIN_MAX - relayed))
                if not n:
                    break
                relayed += n
            if fd in self.sources:
                self._flush_partial(fd)  # (its last line, even without its end, comes before the exit line)
        if self.missing_module is not None:
            self._import_hint(self.missing_module)
            self.missing_module = None

    def _import_hint(self, module: str) -> None:
        """The node died of an import error at its start: say so if it is the PATH trap (once per interpreter)."""
        hint = nodepython.import_hint(self.name, module, os.environ)
        if hint is not None and hint[0] not in _hinted:
            _hinted.add(hint[0])
            console.printerrlog(hint[1])

    def _close(self, fd: int) -> None:
        self._flush_partial(fd)
        if not self.partial and self._partial_timer is not None:
            self._partial_timer.cancel()
            self._partial_timer = None
        framer = self.framers.pop(fd, None)
        if framer is not None and fd in self.sources:
            console.relay(self.targets.pop(fd, self.sources[fd]), framer.end())
        self.sources.pop(fd, None)
        _sized_ptys.pop(fd, None)
        if not self.paused:
            self.loop.remove_reader(fd)
        os.close(fd)
        if not self.sources and self.log_fd is not None:
            os.close(self.log_fd)
            self.log_fd = None

    def close(self) -> None:
        """The launch ends: relay what is there and let go of the descriptors."""
        self.drain()
        for fd in list(self.sources):
            self._close(fd)
