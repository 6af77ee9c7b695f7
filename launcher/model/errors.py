"""The project's error type: bad input a user can fix, reported without a traceback."""

from __future__ import annotations


class LaunchError(Exception):
    """A problem with launch input (a file, an argument, the environment).

    `str()` is the whole message a user sees: `file:line: what is wrong`,
    followed by the include chain when the problem is inside an included file.
    """

    def __init__(self, message: str, filename: str | None = None, line: int | None = None,
                 include_chain: tuple[tuple[str, int], ...] = ()):
        self.message = message
        self.filename = filename
        self.line = line
        self.include_chain = include_chain
        super().__init__(self.format())

    def format(self) -> str:
        if self.filename and self.line:
            text = "%s:%d: %s" % (self.filename, self.line, self.message)
        elif self.filename:
            text = "%s: %s" % (self.filename, self.message)
        else:
            text = self.message
        for fname, line in self.include_chain:
            text += "\n  included from %s:%d" % (fname, line)
        return text


class UsageError(LaunchError):
    """A command line roslaunch's option parser refuses: said with the usage, exit status 2."""


SHOWN_CHARS = 300  # of a user's text quoted in a message


def shorten(text: str) -> str:
    """A user's text as a message quotes it: whole, or, past SHOWN_CHARS, its start and end around
    the number of characters left out (a 5 MB attribute makes no readable error)."""
    if len(text) <= SHOWN_CHARS:
        return text
    return "%s[... %d characters ...]%s" % (text[:200], len(text) - 260, text[-60:])
