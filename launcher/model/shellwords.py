"""Splitting a command line into words as `shlex.split` does (POSIX mode), in time linear in its length.

roslaunch splits a node's `args` and `launch-prefix` and a `<param command>` with
shlex.split, and so do we; but shlex adds a word up one character at a time
(`token = token + c`), which is quadratic in the length of one word: a 1 MB word
took minutes. The rules are shlex's with `whitespace_split` and no comments: words
end at a space, tab, CR or LF; a backslash takes the next character as it is;
'single quotes' take everything up to the next one; "double quotes" too, where a
backslash only escapes a double quote or a backslash; an empty quoted word is a word.
The tests check equality with shlex.split on generated text.
"""

from __future__ import annotations

import re

# (patterns compiled at the first split, by re's cache: ~0.4 ms that a `launch --nodes` need not pay)
_PART = r"""[^ \t\r\n'"\\]+|\\(.)|'([^']*)'|"((?:[^"\\]|\\.)*)"|[ \t\r\n]+"""
_QUOTED_ESCAPE = r"""\\([\\"])"""


def split(text: str) -> list[str]:
    """shlex.split(text); ValueError ("No closing quotation", "No escaped character") as it raises."""
    words: list[str] = []
    word: list[str] | None = None  # the parts of the word being read
    pos, end = 0, len(text)
    match = re.compile(_PART, re.S).match
    while pos < end:
        m = match(text, pos)
        if m is None:  # a quote that does not close, or a backslash at the end
            if text[pos] == "\\" and pos + 1 == end:
                raise ValueError("No escaped character")
            if text[pos] == '"' and text.endswith("\\") and _odd_backslashes_at_end(text, pos + 1):
                raise ValueError("No escaped character")
            raise ValueError("No closing quotation")
        pos = m.end()
        first = text[m.start()]
        if first in " \t\r\n":
            if word is not None:
                words.append("".join(word))
                word = None
            continue
        if word is None:
            word = []
        if first == "\\":
            word.append(m.group(1))
        elif first == "'":
            word.append(m.group(2))
        elif first == '"':
            inner = m.group(3)
            word.append(re.sub(_QUOTED_ESCAPE, r"\1", inner) if "\\" in inner else inner)
        else:
            word.append(m.group(0))
    if word is not None:
        words.append("".join(word))
    return words


def _odd_backslashes_at_end(text: str, start: int) -> bool:
    """Whether an unclosed double-quoted text ends in a backslash that escapes nothing (shlex then
    says "No escaped character" rather than "No closing quotation")."""
    n = len(text) - len(text.rstrip("\\"))
    return n % 2 == 1 and len(text) - n >= start
