"""roslaunch-style console messages: plain, bold and error lines, flushed at once."""

from __future__ import annotations

import sys
from typing import Callable, TextIO

# Extra sinks (e.g. the launcher's own log file); each gets every message.
_handlers: list[Callable[[str], None]] = []


def add_handler(fn: Callable[[str], None]) -> None:
    _handlers.append(fn)


def remove_handler(fn: Callable[[str], None]) -> None:
    if fn in _handlers:
        _handlers.remove(fn)


_is_terminal: dict[int, tuple[TextIO, bool]] = {}  # id(stream) -> (stream, isatty): one ioctl per stream


def _colours(stream: TextIO) -> bool:
    known = _is_terminal.get(id(stream))
    if known is None or known[0] is not stream:
        try:
            known = _is_terminal[id(stream)] = (stream, stream.isatty())
        except (OSError, ValueError):
            return False
    return known[1]


def _emit(stream: TextIO, msg: str, style: str | None) -> None:
    for h in _handlers:
        try:
            h(msg)
        except Exception:  # a broken log sink must never stop the launch
            pass
    try:
        # Colours only on a terminal: roslaunch always writes escapes, which
        # litter redirected output; the words are the same either way.
        if style and _colours(stream):
            stream.write("\033[%sm%s\033[0m\n" % (style, msg))
        else:
            stream.write(msg + "\n")
        # Flushed per line: node output shares the same terminal/pipe.
        stream.flush()
    except (OSError, ValueError):
        pass


def printlog(msg: str) -> None:
    """A plain line on stdout."""
    _emit(sys.stdout, msg, None)


def printlog_bold(msg: str) -> None:
    """A bold line on stdout (roslaunch's `printlog_bold`)."""
    _emit(sys.stdout, msg, "1")


def printerrlog(msg: str) -> None:
    """A red line on stderr (roslaunch's `printerrlog`)."""
    _emit(sys.stderr, msg, "31")
