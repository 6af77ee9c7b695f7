"""roslaunch-style console messages (plain, bold, error lines), written by one thread that may block so nothing else does.

The launcher's stdout is often something it does not control: a terminal paused
with Ctrl-S, a pipe nobody reads, a slow SSH link. A `write` there blocks, and
if the event loop made it, the embedded master would stop answering and
respawns would stop. So the caller writes a line only when nothing is queued
before it, and only through a descriptor of its own that never blocks
(`_direct`: the terminal or pipe opened again with O_NONBLOCK, which leaves the
shared one as it is; a regular file as it is). The rest of a line the terminal
took only part of is queued, and the writer thread finishes that line before
anything else; a line it took none of is queued as any other. (A terminal that
select calls writable may have room for less than a line: a write to the
shared descriptor would wait there.) A stream without such a descriptor (a
socket, an in-memory one) is asked with `select`, and written to by the caller
only for a line of at most PIPE_BUF bytes, which then goes through whole.
Otherwise the line is handed to the console's writer thread through a bounded
queue and the caller goes on at once. When the queue is full the oldest lines
are dropped, and the writer says how many once output flows again. The extra
sinks (the launch's own log file) get every message in full, at once, from the
caller.

Node output relayed by the launcher (output/screen.py) goes through the same
queue, so that it keeps its order with the launcher's lines, but it is never
dropped: `relay` says when more than MAX_QUEUED_OUTPUT bytes of it wait, and
the relay then stops reading the node until `when_drained` calls it back. The
node then blocks in its own write, as it would on a blocked terminal. When
nothing waits, node output is written by the caller at once, whatever its size,
through the same descriptor, and what the terminal does not take at once is
queued in the same way. Every write, the caller's and the writer thread's,
writes again what a stream took only part of (`write_all`): with an unbuffered
stdout (PYTHONUNBUFFERED=1) a blocking write cut short by a signal returns a
count that the text layer ignores.
"""

from __future__ import annotations

import atexit
import collections
import os
import select
import stat
import sys
import threading

TYPE_CHECKING = False  # (typing.TYPE_CHECKING without importing typing: ~3 ms a start; the annotations are text)
if TYPE_CHECKING:
    from typing import Callable, TextIO

# Extra sinks (e.g. the launcher's own log file); each gets every message.
_handlers: list[Callable[[str], None]] = []

MAX_QUEUED_CHARS = 128 * 1024  # console text held while the terminal or pipe does not take it
MAX_QUEUED_OUTPUT = 256 * 1024  # node output held before the nodes' readers pause (never dropped)
PIPE_BUF = select.PIPE_BUF  # a write this small to a ready pipe or terminal is taken whole


def add_handler(fn: Callable[[str], None]) -> None:
    _handlers.append(fn)


def remove_handler(fn: Callable[[str], None]) -> None:
    if fn in _handlers:
        _handlers.remove(fn)


# Sinks that also want to know whether a message is an error (a roslaunch child tells its parent the level).
_level_handlers: list[Callable[[str, bool], None]] = []


def add_level_handler(fn: Callable[[str, bool], None]) -> None:
    _level_handlers.append(fn)


def remove_level_handler(fn: Callable[[str, bool], None]) -> None:
    if fn in _level_handlers:
        _level_handlers.remove(fn)


_is_terminal: dict[int, tuple[TextIO, bool]] = {}  # id(stream) -> (stream, isatty): one ioctl per stream


def _colours(stream: TextIO) -> bool:
    known = _is_terminal.get(id(stream))
    if known is None or known[0] is not stream:
        try:
            known = _is_terminal[id(stream)] = (stream, stream.isatty())
        except (OSError, ValueError):
            return False
    return known[1]


class _Writer:
    """The one thread that writes console lines, in the order they were emitted, to their streams."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        # (stream, text) for a launcher line, (stream, bytes) for a chunk of a node's output
        self._queue: collections.deque[tuple[TextIO, str | bytes]] = collections.deque()
        self._queued_chars = 0  # launcher lines only: they are what may be dropped
        self._queued_output = 0  # node output bytes
        self._drained: list[Callable[[], None]] = []  # relays waiting for the node output to drain
        self._dropped: dict[TextIO, int] = {}  # lines dropped, by the stream they were for
        self._writing = False
        self._thread: threading.Thread | None = None

    def put(self, stream: TextIO, text: str) -> None:
        with self._cond:
            if not self._queue and not self._writing and not self._dropped:
                # the common case: at once, in order, from the caller
                fd = _direct(stream)
                if fd is not None:
                    data = _encoded(stream, text)
                    written = _write_some(stream, fd, data) if data else 0
                    if written == len(data):
                        return
                    if written:  # the rest of a line begun: the writer thread's first, never dropped
                        self._queue.append((stream, data[written:]))
                        self._queued_output += len(data) - written
                        self._wake()
                        return
                    # (none of it taken: queued as a line, below)
                else:  # (a stream without a descriptor of its own: asked)
                    size = len(text) if text.isascii() else len(text.encode(errors="replace"))
                    if size <= PIPE_BUF and _ready(stream):
                        _write(stream, text)
                        return
            self._queue.append((stream, text))
            self._queued_chars += len(text)
            while self._queued_chars > MAX_QUEUED_CHARS and self._drop_oldest_line():
                pass
            self._wake()

    def put_output(self, stream: TextIO, data: bytes) -> bool:
        """Write or queue a chunk of node output (never dropped); False when the nodes should wait."""
        with self._cond:
            if not self._queue and not self._writing:
                fd = _direct(stream)
                if fd is not None:
                    written = _write_some(stream, fd, data)
                    if written == len(data):
                        return True
                    data = data[written:]  # (the rest of the line goes first, from the writer thread)
                elif len(data) <= PIPE_BUF and _ready(stream):
                    _write_output(stream, data)
                    return True
            self._queue.append((stream, data))
            self._queued_output += len(data)
            self._wake()
            return self._queued_output <= MAX_QUEUED_OUTPUT

    def when_drained(self, callback: Callable[[], None]) -> None:
        """Call `callback` (from the writer thread) once the node output queued is down to half its bound."""
        with self._cond:
            if self._queued_output > MAX_QUEUED_OUTPUT // 2:
                self._drained.append(callback)
                return
        callback()

    def _drop_oldest_line(self) -> bool:
        """Drop the oldest launcher line but the newest one (node output is never dropped)."""
        for i in range(len(self._queue) - 1):
            lost_stream, lost = self._queue[i]
            if isinstance(lost, str):
                del self._queue[i]
                self._queued_chars -= len(lost)
                self._dropped[lost_stream] = self._dropped.get(lost_stream, 0) + 1
                return True
        return False

    def _wake(self) -> None:
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name="console", daemon=True)
            self._thread.start()
            atexit.register(self.flush, 2.0)  # (an os._exit path calls flush() itself)
        self._cond.notify()

    def flush(self, timeout: float) -> bool:
        """Wait until every queued line is written (False if the output stayed blocked for `timeout`)."""
        with self._cond:
            return self._cond.wait_for(lambda: not self._queue and not self._writing, timeout)

    def _run(self) -> None:
        drained: list[Callable[[], None]] = []
        while True:
            for callback in drained:  # (outside the lock: a callback hands over to the event loop)
                try:
                    callback()
                except Exception:  # noqa: BLE001 - a closed loop at exit: nothing left to resume
                    pass
            with self._cond:
                self._writing = False
                self._cond.notify_all()
                self._cond.wait_for(lambda: self._queue)
                stream, item = self._queue.popleft()
                if isinstance(item, str):
                    self._queued_chars -= len(item)
                else:
                    self._queued_output -= len(item)
                drained = []
                if self._drained and self._queued_output <= MAX_QUEUED_OUTPUT // 2:
                    drained, self._drained = self._drained, []
                dropped: dict[TextIO, int] = {}
                if isinstance(item, str):  # (said among the launcher's lines, not inside a node's output)
                    dropped, self._dropped = self._dropped, {}
                self._writing = True
            for lost_stream, count in dropped.items():  # said where the lines would have gone
                _write(lost_stream, "[launch] %d console line%s dropped while the output was blocked\n"
                       % (count, "" if count == 1 else "s"))
            if isinstance(item, str):
                _write(stream, item)
            else:
                _write_output(stream, item)


def _ready(stream: TextIO) -> bool:
    """Would a short write to `stream` go through without blocking?"""
    try:
        fd = stream.fileno()
    except (OSError, ValueError, AttributeError):
        return True  # an in-memory stream (a test's capture) never blocks
    try:
        return bool(select.select((), (fd,), (), 0)[1])
    except (OSError, ValueError):
        return False


# stream -> a descriptor writing to it that never blocks (None: there is none, the stream is asked with select)
_directs: dict[TextIO, int | None] = {}


def _direct(stream: TextIO) -> int | None:
    """A descriptor of the stream's terminal, pipe or file that a write never blocks on, made once per stream: a
    terminal or a pipe opened again (/proc/self/fd) with O_NONBLOCK, so the descriptor the launcher shares with
    its shell and its nodes stays blocking; a regular file or /dev/null, which never block, as they are."""
    if stream in _directs:
        return _directs[stream]
    fd = None
    try:
        own = stream.fileno()
        stream.buffer  # type: ignore[attr-defined]  # (bytes go to the descriptor: a text-only stream is not one)
        mode = os.fstat(own).st_mode
        if stat.S_ISREG(mode) or (stat.S_ISCHR(mode) and not os.isatty(own)):
            fd = own
        elif stat.S_ISFIFO(mode) or stat.S_ISCHR(mode):
            fd = os.open("/proc/self/fd/%d" % own, os.O_WRONLY | os.O_NONBLOCK | os.O_NOCTTY | os.O_CLOEXEC)
    except (OSError, ValueError, AttributeError):
        fd = None  # (no /proc, a socket, an in-memory stream: the way with select)
    _directs[stream] = fd
    return fd


def forget(stream: TextIO) -> None:
    """Close the descriptor kept for writing node output to `stream` (a stream that is closed: while that
    descriptor is open, the pipe's reader never sees its end)."""
    fd = _directs.pop(stream, None)
    if fd is not None and fd != _fileno(stream):
        os.close(fd)


def _fileno(stream: TextIO) -> int | None:
    try:
        return stream.fileno()
    except (OSError, ValueError):
        return None


def _write_some(stream: TextIO, fd: int, data: bytes) -> int:
    """As much of `data` as `fd` takes now: how many bytes (a stream that is gone takes all: they are lost)."""
    try:
        stream.flush()  # (text someone printed without flushing goes first)
        return os.write(fd, data)
    except BlockingIOError:
        return 0
    except (OSError, ValueError):
        return len(data)


def _encoded(stream: TextIO, text: str) -> bytes:
    """A launcher line as the bytes the stream's text layer would write (b"": a character its encoding has not,
    the line is not shown)."""
    try:
        return text.encode(stream.encoding or "utf-8", stream.errors or "strict")
    except (ValueError, LookupError):
        return b""


def _write(stream: TextIO, text: str) -> None:
    if getattr(stream, "buffer", None) is None:  # (a capture: text only)
        try:
            stream.write(text)
            stream.flush()
        except (OSError, ValueError):  # (a closed stream)
            pass
        return
    # as bytes, all of them: the text layer ignores what a raw stream (below) did not take
    data = _encoded(stream, text)
    if data:
        _write_output(stream, data)  # Flushed per line: node output shares the same terminal/pipe.


def _write_output(stream: TextIO, data: bytes) -> None:
    """Node output as the node wrote it: bytes, to the stream's binary buffer (text only for a capture)."""
    if getattr(stream, "buffer", None) is None:
        _write(stream, data.decode(errors="replace"))
        return
    try:
        stream.flush()  # (text someone printed without flushing goes first)
        write_all(stream, data)
    except (OSError, ValueError):
        pass


def write_all(stream: TextIO, data: bytes) -> None:
    """All of `data` to the stream's binary layer, in order, waiting while it is full.

    Under `python -u` or PYTHONUNBUFFERED=1 (the unit `launcher install` writes sets it, as do many container
    images) that layer is the raw descriptor, and one write takes what the kernel took at once: less than all
    when a signal (Ctrl-Z and fg, a profiler attaching, one the launch handles) comes in the middle of a blocking
    write to a full terminal or pipe, or nothing when someone made the descriptor non-blocking. The rest is ours to
    write again: the text layer and print() do not (the tail of such a write was lost on the terminal, issue 36).
    A buffered layer takes all, or says how much it took (BlockingIOError)."""
    buffer = stream.buffer  # type: ignore[attr-defined]
    view = memoryview(data)
    while True:
        try:
            while view:
                taken = buffer.write(view)
                if taken is None:  # (a raw non-blocking descriptor, full: it took nothing)
                    select.select((), (stream.fileno(),), ())  # (this thread may wait: see the module's words)
                else:
                    view = view[taken:]
            buffer.flush()
            return
        except BlockingIOError as e:  # (a buffered layer over a non-blocking descriptor)
            view = view[e.characters_written:]
            select.select((), (stream.fileno(),), ())


_writer = _Writer()


def flush(timeout: float = 2.0) -> bool:
    """Write out what is queued before the process exits; give up after `timeout` if the output is blocked."""
    return _writer.flush(timeout)


def relay(stream: TextIO, data: bytes) -> bool:
    """A chunk of a node's output for `stream`, in order with the launcher's lines and never dropped.

    False when more node output waits than the console's bound: the caller stops reading the node
    and asks `when_drained` to be told when to go on.
    """
    return _writer.put_output(stream, data)


def when_drained(callback: Callable[[], None]) -> None:
    """Call `callback` once the node output waiting is down to half the bound (perhaps at once, perhaps
    from the console's thread)."""
    _writer.when_drained(callback)


def _emit(stream: TextIO, msg: str, style: str | None) -> None:
    for h in _handlers:
        try:
            h(msg)
        except Exception:  # a broken log sink must never stop the launch
            pass
    for lh in _level_handlers:
        try:
            lh(msg, stream is sys.stderr)
        except Exception:
            pass
    # Colours only on a terminal: roslaunch always writes escapes, which
    # litter redirected output; the words are the same either way.
    if style and _colours(stream):
        _writer.put(stream, "\033[%sm%s\033[0m\n" % (style, msg))
    else:
        _writer.put(stream, msg + "\n")


def printlog(msg: str) -> None:
    """A plain line on stdout."""
    _emit(sys.stdout, msg, None)


def printlog_bold(msg: str) -> None:
    """A bold line on stdout (roslaunch's `printlog_bold`)."""
    _emit(sys.stdout, msg, "1")


def printerrlog(msg: str) -> None:
    """A red line on stderr (roslaunch's `printerrlog`)."""
    _emit(sys.stderr, msg, "31")


def printfatal(msg: str) -> None:
    """The error that ends the launch: bold red on stderr, so it stands out from the (red) warnings before it."""
    _emit(sys.stderr, msg, "1;31")
