"""What the operator's commands end with: their exit statuses and the error that carries one (client, lastrun and
every subcommand share them; lastrun reads a finished run without the client's calls)."""

from __future__ import annotations

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_NO_LAUNCH, EXIT_REFUSED = 0, 1, 2, 3, 4


class ToolError(Exception):
    """A message for the user and the exit status that goes with it."""

    def __init__(self, message: str, status: int = EXIT_FAILED):
        super().__init__(message)
        self.status = status


class NotOurs(ToolError):
    """The run asked about is roslaunch's or roscore's (operate/lastrun.py): no events file, no states to tell."""

    def __init__(self, message: str, run_id: str = "", run_dir: str = ""):
        super().__init__(message, EXIT_NO_LAUNCH)
        self.run_id = run_id
        self.run_dir = run_dir


class NoAnswer(ToolError):
    """The launch did not answer in time: it may be busy (a loaded robot computer) or its machine out of reach for a
    while, not gone. A command that asks once ends with it (as with a launch that is gone); one that follows the
    launch (`events -f`, `status --watch`, the views) asks again."""

    def __init__(self, message: str):
        super().__init__(message, EXIT_NO_LAUNCH)


def slow(e: BaseException) -> bool:
    """Whether a failed call timed out (the launch is slow to answer) rather than found no launch (refused: nothing
    listens at its address; cut: its server closed as it ended)."""
    import asyncio
    import socket
    return isinstance(e, (socket.timeout, TimeoutError, asyncio.TimeoutError, NoAnswer))
