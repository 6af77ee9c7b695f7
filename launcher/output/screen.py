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
- The loop reads each descriptor when it is readable (one read and one write
  per chunk, no per-byte work), appends the chunk to the node's
  `<proc>-stdout.log` (the file roslaunch writes for output="log"; kept under
  --log-max-size by output/logrotate.py) and hands it to the console. The
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

CHUNK = 65536  # one read per readable event: a pipe's default capacity
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

    def _read(self, fd: int) -> int:
        """One read of `fd`, relayed: how many bytes (0 when there is nothing more now, or ever: closed)."""
        try:
            data = os.read(fd, CHUNK)
        except BlockingIOError:
            return 0
        except OSError:  # EIO: a pty whose node ends are all closed
            data = b""
        if not data:
            self._close(fd)
            return 0
        if self.log_fd is not None:
            try:
                os.write(self.log_fd, data)
            except OSError as e:  # a full disk: the terminal keeps the output, the file stops here
                console.printerrlog("[%s] stopped writing its output to its log file: %s"
                                         % (self.name, e.strerror))
                os.close(self.log_fd)
                self.log_fd = None
        framer = self.framers.get(fd)
        target = self.targets.get(fd, self.sources[fd])
        if not console.relay(target, framer.feed(data) if framer else data) and not self.paused:
            self._pause()
        if (b"No module named" in data and self.missing_module is None
                and self.loop.time() - self.started < nodepython.AT_ONCE_S):
            self.missing_module = nodepython.missing_module(data)
        return len(data)

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
                n = self._read(fd)
                if not n:
                    break
                relayed += n
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
