"""Sizes in bytes: the one rule for reading them (options, launch attributes) and for printing them.

The rule (README, "Units"): a number of bytes with an optional unit, case-insensitive;
`k`/`kB`, `M`/`MB`, `G`/`GB`, `T`/`TB` are powers of 1000 (as rosmon), `Ki`/`KiB`,
`Mi`/`MiB`, `Gi`/`GiB`, `Ti`/`TiB` powers of 1024, `B` or none bytes; the number may
have a fraction (`500MB`, `1.5GiB`, `200k`, `4096`). So `--log-max-size 100MB` and
`log_max_size="100MB"` are both 100,000,000 bytes, and roslaunch's log-check threshold,
which it calls "1GB" but is 2**30 bytes, is `1GiB` here.
"""

from __future__ import annotations

import re

# roslaunch's log-check threshold: the log directory's size it warns about ("1GB" in its words)
LOG_CHECK_THRESHOLD = 1 << 30
# What a size looks like, for error messages.
SIZE_EXPECTED = "a size such as 500MB, 1.5GiB, 200k or a number of bytes"

_SIZE = re.compile(r"\s*(\d+(?:\.\d*)?|\.\d+)\s*([A-Za-z]*)\s*\Z")
_PREFIXES = ("k", "M", "G", "T")
# (bytes, unit) as printed, largest first: TiB, TB, GiB, GB, ..., KiB, kB
_UNITS = sorted([(1000 ** power, prefix + "B") for power, prefix in enumerate(_PREFIXES, 1)]
                + [(1024 ** power, prefix.upper() + "iB") for power, prefix in enumerate(_PREFIXES, 1)], reverse=True)
# unit as read (any case, the B optional) -> bytes
_SCALES = {"": 1, "b": 1, **{u.lower(): s for s, u in _UNITS}, **{u.lower()[:-1]: s for s, u in _UNITS}}


def parse_size(text: str) -> int:
    """`500MB`, `1.5GiB`, `200k`, `4096` -> bytes (rounded down); ValueError naming the text otherwise."""
    m = _SIZE.match(text)
    scale = _SCALES.get(m.group(2).lower()) if m else None
    if scale is None:
        raise ValueError("invalid size [%s]: expected %s" % (text, SIZE_EXPECTED))
    whole, _, fraction = m.group(1).partition(".")  # integers: "0.3GB" is exact, and 2**60 bytes too
    return int(whole or 0) * scale + int(fraction or 0) * scale // 10 ** len(fraction)


def format_size(n: float, measured: bool = False) -> str:
    """Bytes for people, in units `parse_size` reads back: exactly in the largest unit that gives the size to a tenth
    (100000000 -> 100MB, 2**30 -> 1GiB, 1.5 * 2**30 -> 1.5GiB), else to a tenth of a decimal unit (612345678 ->
    612.3MB). A `measured` size (a process's RSS, free space) is only ever the latter: memory comes in 4 KiB pages,
    and 33624064 is more readable as 33.6MB than as the exact 32836KiB."""
    n = int(n)
    for scale, unit in () if measured else _UNITS:
        if n >= scale and n * 10 % scale == 0:
            return _tenths(n * 10 // scale) + unit
    for scale, unit in _UNITS:
        if n >= scale and not unit.endswith("iB"):
            return _tenths(round(n * 10 / scale)) + unit
    return "%dB" % n


def _tenths(t: int) -> str:
    return "%d" % (t // 10) if t % 10 == 0 else "%d.%d" % divmod(t, 10)
