"""Which nodes an operator's PATTERN names: an exact node name, else a glob, else a regular expression.

As rosmon's start_stop: `/robot/driver`, `driver` (a relative name is taken
from the root), `/robot/*`, `/robot/(left|right)_.*`. The forms are tried in
that order and the first that names any node wins, so that a regular
expression such as `/cam.*` is not read as a glob that matches nothing.
"""

from __future__ import annotations

import fnmatch
import re
from typing import Iterable

GLOB_CHARS = frozenset("*?[")


def _absolute(pattern: str) -> str:
    return pattern if pattern.startswith("/") else "/" + pattern


def match(pattern: str, names: Iterable[str]) -> list[str]:
    """The names `pattern` selects, in the given order; [] if none (a bad regex selects none)."""
    names = list(names)
    if not pattern:
        return []
    exact = _absolute(pattern)
    if exact in names:
        return [exact]
    if GLOB_CHARS.intersection(pattern):
        selected = [n for n in names if fnmatch.fnmatchcase(n, exact)]
        if selected:
            return selected
    try:
        regex = re.compile(pattern)
    except re.error:
        return []
    return [n for n in names if regex.fullmatch(n) or regex.fullmatch(n[1:])]
