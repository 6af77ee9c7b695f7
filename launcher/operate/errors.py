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

    def __init__(self, message: str):
        super().__init__(message, EXIT_NO_LAUNCH)
