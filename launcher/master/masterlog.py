"""master.log: what rosmaster logs (registrations, parameter changes, callbacks to nodes), in its words and format.

rosmaster writes it through Python's logging with `/etc/ros/python_logging.conf`'s
format, `[rosmaster.master][INFO] 2026-11-24 06:07:47,937: +PUB [/t] /a http://...`.
A master answers thousands of calls a second, and a third of them are logged: the
logging module (a record, a formatter, a lock and a flush per line, ~10 us) would
cost it several percent of its throughput, so this writer formats the same line
itself (~3 us), with the date part made once per second. Until `open` it writes
nothing.
"""

from __future__ import annotations

import time
from typing import Any, TextIO


class MasterLog:
    __slots__ = ("_file", "_second", "_stamp")

    def __init__(self) -> None:
        self._file: TextIO | None = None
        self._second = -1
        self._stamp = ""

    @property
    def enabled(self) -> bool:
        return self._file is not None

    def open(self, path: str) -> bool:
        """Append to `path` from now on; False (and nothing written) if it cannot be opened."""
        try:
            self._file = open(path, "a", buffering=1, encoding="utf-8")  # (a line at a time: a crash loses none)
        except OSError:
            return False
        return True

    def close(self) -> None:
        f, self._file = self._file, None
        if f is not None:
            try:
                f.close()
            except OSError:
                pass

    def info(self, msg: str, *args: Any, logger: str = "rosmaster.master") -> None:
        if self._file is None:
            return
        now = time.time()
        second = int(now)
        if second != self._second:
            self._second = second
            self._stamp = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(second))
        try:
            self._file.write("[%s][INFO] %s,%03d: %s\n" % (logger, self._stamp, int(now * 1000) % 1000,
                                                            msg % args if args else msg))
        except OSError:  # a full disk: the master goes on without its log
            self.close()


# the one master log of this process (a process runs one master)
mlog = MasterLog()
