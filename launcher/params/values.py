"""Typing of `<param>` values: roslaunch's `type=` attribute and its inference rules."""

from __future__ import annotations

TYPE_CHECKING = False  # (typing.TYPE_CHECKING without importing typing: ~3 ms a start; the annotations are text)
if TYPE_CHECKING:
    from typing import Any


PARAM_TYPES = ("auto", "str", "string", "int", "double", "bool", "boolean", "yaml")


def convert_value(text: str, ptype: str | None = "auto", *, filename: str | None = None,
                  first_line: int = 1, angles: bool = True) -> Any:
    """The value roslaunch gives `text` for `type=ptype` (case-insensitive; None or "" = auto).

    Does NOT strip `text`: roslaunch strips `value=` before typing it but types the
    contents of `textfile=`/`command=` as they are (`"7\\n"` is still the int 7, because
    `int()` ignores surrounding whitespace, but `"true\\n"` stays a string). `filename`,
    `first_line` and `angles` only matter for `yaml` (see `rosyaml.load_yaml`).
    Raises ValueError (RosYamlError for `yaml`) worded as roslaunch words it.
    """
    kind = (ptype or "auto").strip().lower()
    if kind == "auto":
        return auto_value(text)
    if kind == "str" or kind == "string":
        return text
    if kind == "int":
        return int(text)
    if kind == "double":
        return float(text)
    if kind == "bool" or kind == "boolean":
        return to_bool(text, kind)
    if kind == "yaml":
        from launcher.params.rosyaml import load_yaml  # lazy: keeps PyYAML off the plain path

        return load_yaml(text, filename=filename, first_line=first_line, angles=angles)
    raise ValueError("Unknown type '%s'" % kind)


def auto_value(text: str) -> Any:
    """`convert_value(text, "auto")`: roslaunch's inference for a `<param>` without `type=`."""
    # numbers first, as roslaunch: a '.' means float or nothing; no '_' for ints,
    # because Python 3 would accept `1_000` but roslaunch means a string there
    if "." in text:
        try:
            return float(text)
        except ValueError:
            pass
    elif "_" not in text and not text.isalpha():  # (letters only: int() would refuse it)
        try:
            return int(text)
        except ValueError:
            pass
    lowered = text.lower()
    if lowered == "true" or lowered == "false":
        return lowered == "true"
    return text


def to_bool(text: str, kind: str = "bool") -> bool:
    """roslaunch's bool conversion (also used for `if=`/`unless=`): true/1/false/0, any case."""
    value = text.lower().strip()
    if value == "true" or value == "1":
        return True
    if value == "false" or value == "0":
        return False
    raise ValueError("%s is not a '%s' type" % (value, kind))
