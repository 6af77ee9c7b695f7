"""Node output log files kept under a size: rotation by copy and truncate, which roslaunch never had (ros/ros_comm#79).

A node with `output="log"` writes its stdout straight into `<name>-stdout.log`
(the launcher does not sit in the path of that data); what goes to the terminal
(a screen node's output, a log node's stderr) is appended to the same file by
the launcher (output/screen.py), also with O_APPEND. Once a second the sizes
are looked at; a file past `max_size` is copied to `.1` (older copies shift to
`.2` ... up to `backups`) and truncated in place. Every descriptor on it is
opened with O_APPEND, so its next write lands at the new end and nothing needs
to be reopened; what it writes between the copy and the truncation (a few
milliseconds) is lost, as with logrotate's copytruncate. The copy runs in a
worker thread, so a large file never stalls the event loop.
"""

from __future__ import annotations

import asyncio
import os
from typing import Callable

CHECK_PERIOD_S = 1.0


class LogRotator:
    def __init__(self, max_size: int, backups: int, note: Callable[[str], None],
                 period: float = CHECK_PERIOD_S):
        self.max_size = max_size
        self.backups = max(1, backups)
        self.note = note  # told of each rotation (the launch log)
        self.period = period
        self.paths: dict[str, tuple[int, int]] = {}  # path -> (max size, backups)
        self._task: asyncio.Task | None = None

    def watch(self, path: str, max_size: int | None = None, backups: int | None = None) -> None:
        """Keep `path` under `max_size` (a node's log_max_size; the launch's when None)."""
        size = self.max_size if max_size is None else max_size
        if size > 0:
            self.paths[path] = (size, max(1, self.backups if backups is None else backups))

    def start(self) -> None:
        if self.paths and self._task is None:
            self._task = asyncio.get_running_loop().create_task(self._run())

    def close(self) -> None:
        if self._task is not None:
            self._task.cancel()
            self._task = None

    async def _run(self) -> None:
        loop = asyncio.get_running_loop()
        while True:
            await asyncio.sleep(self.period)
            for path, (max_size, backups) in self.paths.items():
                try:
                    size = os.stat(path).st_size
                except OSError:
                    continue
                if size > max_size:
                    try:
                        await loop.run_in_executor(None, self.rotate, path, backups)
                    except OSError as e:  # a full disk: say so, try again next time
                        self.note("cannot rotate %s: %s" % (path, e.strerror or e))
                    else:
                        self.note("rotated %s at %d bytes (keeping %d older copies)" % (path, size, backups))

    def rotate(self, path: str, backups: int) -> None:
        for i in range(backups - 1, 0, -1):
            older = "%s.%d" % (path, i)
            if os.path.exists(older):
                os.replace(older, "%s.%d" % (path, i + 1))
        import shutil  # here, at a rotation: it imports its compressors, ~0.3 MB a run without one would keep
        shutil.copyfile(path, path + ".1")  # (copy_file_range/sendfile in the kernel where it can)
        os.truncate(path, 0)
