"""Names a user almost got right: the close matches of a name among those that exist ("did you mean /r2/talker?")."""

from __future__ import annotations

import os

TYPE_CHECKING = False  # (typing.TYPE_CHECKING without importing typing: ~3 ms a start; the annotations are text)
if TYPE_CHECKING:
    from typing import Iterable

MAX_SUGGESTIONS = 3
CUTOFF = 0.6  # difflib's default: `robto` finds `robot`, `camra` finds `camera`, `a` finds nothing
SPREAD = 0.15  # a match this much worse than the best one is noise beside it (`sim.launch` for `bringup.lanch`)


def _base(name: str) -> str:
    return name.rstrip("/").rsplit("/", 1)[-1]


def close_matches(word: str, candidates: Iterable[str], n: int = MAX_SUGGESTIONS) -> list[str]:
    """The candidates `word` most likely meant, best first.

    A candidate scores difflib's similarity ratio, of the whole names or of their
    base names, whichever is higher; for graph names, one of the same base name
    scores as an exact match (`talker` for `/r2/talker`: the namespace is what
    a user leaves out).
    """
    # (difflib costs ~2.4 ms to import, measured with -X importtime: only an error pays for it)
    from difflib import SequenceMatcher

    if not word:
        return []
    base = _base(word)
    whole, bases = SequenceMatcher(), SequenceMatcher()
    whole.set_seq2(word)
    bases.set_seq2(base)
    scored = []
    for name in dict.fromkeys(candidates):
        if not name or name == word:
            continue
        name_base = _base(name)
        if name_base == base:
            score = 1.0
        else:
            score = 0.0
            for matcher, text in ((whole, name), (bases, name_base)):
                matcher.set_seq1(text)
                # (difflib's own order: the cheap upper bounds first)
                if matcher.real_quick_ratio() >= CUTOFF and matcher.quick_ratio() >= CUTOFF:
                    score = max(score, matcher.ratio())
        if score >= CUTOFF:
            scored.append((score, name))
    if not scored:
        return []
    scored.sort(key=lambda sn: -sn[0])  # (stable: equal scores keep the candidates' order)
    best = scored[0][0]
    return [name for score, name in scored if score >= best - SPREAD][:n]


def did_you_mean(word: str, candidates: Iterable[str], n: int = MAX_SUGGESTIONS) -> str:
    """"did you mean X?" (or "X or Y", "X, Y or Z"); "" when nothing is close."""
    found = close_matches(word, candidates, n)
    if not found:
        return ""
    return "did you mean %s?" % (found[0] if len(found) == 1 else "%s or %s" % (", ".join(found[:-1]), found[-1]))


def near_file(path: str) -> str:
    """did_you_mean for a missing file, among the files in its folder (a directory is no answer where a file is
    asked for: `cam.launch` does not get `launcher`); "" when there is none close, or no folder."""
    folder, name = os.path.split(path)
    try:
        with os.scandir(folder or os.curdir) as entries:
            files = [e.name for e in entries if _is_file(e)]
    except OSError:
        return ""
    return did_you_mean(name, sorted(files))


def _is_file(entry: os.DirEntry) -> bool:
    try:
        return entry.is_file()  # (a symbolic link to a file too)
    except OSError:
        return False
