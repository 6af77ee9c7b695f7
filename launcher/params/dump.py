"""Writing parameters as YAML, byte for byte as PyYAML's safe dumper (roslaunch `--dump-params`, `rosparam dump`).

The common entries (simple keys, scalars, flat lists and maps of them) are written
here; anything else, and any string whose YAML type only PyYAML's resolver can tell,
goes to PyYAML, which is imported only then.
"""

from __future__ import annotations

import math
import re

TYPE_CHECKING = False  # (typing.TYPE_CHECKING without importing typing: ~3 ms a start; the annotations are text)
if TYPE_CHECKING:
    from typing import Any

# YAML 1.1's implicit bools and nulls among words (PyYAML's resolver): anything else made of
# [A-Za-z0-9_./-] that starts with a letter, '_' or '/' is a string to PyYAML
_BOOL_WORDS = ("yes", "true", "on", "no", "false", "off")
NON_STR_WORDS = frozenset(w for word in _BOOL_WORDS for w in (word, word.capitalize(), word.upper())) | frozenset(
    ("null", "Null", "NULL", "~"))
WORD_FIRST_CHARS = frozenset("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz_/")
_WORD_RE = re.compile(r"[A-Za-z_/][A-Za-z0-9_./-]*\Z")
# decimal ints (no '_', no leading 0: octal in YAML 1.1) and floats without exponent or '_'
_NUMBER_RE = re.compile(r"[-+]?(?:0|[1-9][0-9]*)\Z|[-+]?[0-9]+\.[0-9]+\Z")
_NUMBERISH_RE = re.compile(r"[A-Za-z0-9_./+-]+\Z")


def scalar_is_str(text: str) -> bool | None:
    """Whether PyYAML's resolver reads the plain scalar `text` as a string (True) or as
    another type (False); None when this function cannot tell without asking PyYAML."""
    if _WORD_RE.match(text):
        return text not in NON_STR_WORDS
    if _NUMBER_RE.match(text):
        return False
    if "/" in text and _NUMBERISH_RE.match(text):
        return True  # no YAML 1.1 type has a '/' in it (e.g. "10.0/2")
    return None

# A string PyYAML writes as a bare plain scalar or single-quoted, with nothing to escape or
# wrap: no spaces, quotes, indicators or non-ASCII, and no leading '-' or '.'.
_SIMPLE_STRING = re.compile(r"[A-Za-z0-9_/][A-Za-z0-9_./-]*\Z")
_SIMPLE_LINES = re.compile(r"(?:[A-Za-z0-9_/][A-Za-z0-9_./-]*\n)*[A-Za-z0-9_/][A-Za-z0-9_./-]*")  # of them, one a line
# Words of those characters with single spaces between them, starting with a letter, '_' or
# '/': PyYAML writes them plain too (inner spaces need no quoting), and no YAML 1.1 type
# starts that way with a space inside. PyYAML folds a plain scalar at a space past column 80.
_SPACED_STRING = re.compile(r"[A-Za-z_/][A-Za-z0-9_./-]*(?: [A-Za-z0-9_./-]+)+\Z")
_BEST_WIDTH = 80
_STR_TAG = "tag:yaml.org,2002:str"
_resolver = None


def _quoted_if_typed(value: str) -> str:
    """A simple string as PyYAML writes it: bare, or single-quoted if it would read back as
    another type (123, true, 1_000, null)."""
    known = scalar_is_str(value)
    if known is None:
        global _resolver
        import yaml
        if _resolver is None:
            _resolver = yaml.resolver.Resolver()
        known = _resolver.resolve(yaml.ScalarNode, value, (True, False)) == _STR_TAG
    return value if known else "'%s'" % value


_INF = math.inf
_NINF = -math.inf


def _plain_scalar(value: Any, column: int = _BEST_WIDTH, indent: int | None = None) -> str | None:
    """`value` as PyYAML's safe dumper writes it inline starting at `column` (a line it folds
    going on at `indent`), or None when it takes more care."""
    kind = type(value)
    if kind is str:
        if not value:
            return "''"
        if _SIMPLE_STRING.match(value):  # (of any length: with no space, there is nothing to fold)
            return _quoted_if_typed(value)
        if _SPACED_STRING.match(value) and column + len(value) <= _BEST_WIDTH:
            return value
        return _ascii_scalar(value, column, indent) if indent is not None else None
    if kind is bool:
        return "true" if value else "false"
    if kind is int:
        return str(value)
    if kind is float:
        if value != value:
            return ".nan"
        if value in (math.inf, -math.inf):
            return ".inf" if value > 0 else "-.inf"
        text = repr(value).lower()
        if "." not in text and "e" in text:
            text = text.replace("e", ".0e", 1)
        return text
    if value is None:
        return "null"
    return None


# A one-line string of printable ASCII that PyYAML's analysis would not write plain: an indicator
# first (or `---`, `...`), `: ` or a `:` at the end, ` #`, a space first or last.
# (compiled at first use, by re's cache: ~0.3 ms at every start, for long or unusual strings only)
_PRINTABLE_LINE = r"[\x20-\x7e]*\Z"
_NOT_PLAIN = r"""^(?:[#,\[\]{}&*!|>'"%@`]|[?:-](?: |\Z)|---|\.\.\.| )|: |:\Z| #| \Z"""


def _ascii_scalar(value: str, column: int, indent: int) -> str | None:
    """A one-line string of printable ASCII with no two spaces in a row, as PyYAML writes it from
    `column`: plain when its analysis and resolver allow, else single-quoted; folded at a space past
    column 80 (a long one costs no PyYAML emitter, ~1 s a megabyte). None for anything else."""
    if "  " in value or not re.match(_PRINTABLE_LINE, value):
        return None
    if not re.search(_NOT_PLAIN, value) and _quoted_if_typed(value) is value:
        return _folded(value, column, indent)
    # PyYAML's write_single_quoted: a quote doubled; no fold at a space that starts or ends the text
    words = value.replace("'", "''").split(" ")
    out = ["'", words[0]]
    column += 1 + len(words[0])
    fold = "\n" + " " * indent
    last = len(words) - 1
    for i in range(1, last + 1):
        word = words[i]
        if column > _BEST_WIDTH and (i > 1 or words[0]) and (i < last or word):
            out.append(fold)
            column = indent
        else:
            out.append(" ")
            column += 1
        out.append(word)
        column += len(word)
    out.append("'")
    return "".join(out)


def _folded(value: str, column: int, indent: int) -> str:
    """A string of simple words with single spaces between them as PyYAML writes it plain from
    `column`: at a space past column 80 it breaks the line, and the next word starts at `indent`
    (so a long one costs no PyYAML emitter, ~1 s a megabyte)."""
    words = value.split(" ")
    out = [words[0]]
    column += len(words[0])
    fold = "\n" + " " * indent
    for word in words[1:]:
        if column > _BEST_WIDTH:
            out.append(fold)
            column = indent
        else:
            out.append(" ")
            column += 1
        out.append(word)
        column += len(word)
    return "".join(out)


def _float_text(value: float) -> str:
    """A float as PyYAML writes it."""
    if value != value:
        return ".nan"
    if value == _INF or value == _NINF:
        return ".inf" if value > 0 else "-.inf"
    text = repr(value)  # (a finite float's repr is already lower case)
    if "." not in text and "e" in text:
        text = text.replace("e", ".0e", 1)
    return text


def _items_text(value: list, column: int) -> list[str] | None:
    """The items (starting at `column`) of a list of plain scalars as PyYAML writes them, or None."""
    out = []
    for x in value:
        kind = type(x)
        if kind is float:
            out.append(_float_text(x))
        elif kind is int:
            out.append(str(x))
        else:
            text = _plain_scalar(x, column, column)
            if text is None:
                return None
            out.append(text)
    return out


def _entry(key: Any, value: Any, indent: int = 0) -> str | None:
    """One `key: value` entry of a block mapping at `indent`, for values made of plain
    scalars, lists of them and string-keyed mappings of those; None for anything else."""
    # (an empty key is no simple key for PyYAML: it writes "? ''")
    if type(key) is not str or not key or len(key) > 100 or not _SIMPLE_STRING.match(key):
        return None
    k = key if (key[0] in WORD_FIRST_CHARS and key not in NON_STR_WORDS) else _quoted_if_typed(key)
    pad = " " * indent if indent else ""
    kind = type(value)
    if kind is list:
        if not value:
            return "%s%s: []\n" % (pad, k)
        items = _items_text(value, indent + 2)
        if items is None:
            return None
        # PyYAML writes a sequence inside a mapping "indentless": dashes under the key
        dash = pad + "- "
        return "%s%s:\n%s%s\n" % (pad, k, dash, ("\n" + dash).join(items))
    if kind is dict:
        if not value:
            return "%s%s: {}\n" % (pad, k)
        if not all(type(x) is str for x in value):
            return None
        out = ["%s%s:\n" % (pad, k)]
        for sub in sorted(value):
            text = _entry(sub, value[sub], indent + 2)
            if text is None:
                return None
            out.append(text)
        return "".join(out)
    v = _float_text(value) if kind is float else _plain_scalar(value, indent + len(k) + 2, indent + 2)
    if v is not None:
        return "%s%s: %s\n" % (pad, k, v)
    return None


def _shares_containers(value: Any) -> bool:
    """Whether a list/dict object occurs twice: PyYAML would write anchors and aliases."""
    seen: set[int] = set()
    # only containers can be shared: skip the (many) scalar values of a flat dict at once
    stack = [v for v in value.values() if isinstance(v, (list, dict))] if type(value) is dict else [value]
    while stack:
        v = stack.pop()
        if isinstance(v, (list, dict)):
            if id(v) in seen:
                return True
            seen.add(id(v))
            stack.extend(v.values() if isinstance(v, dict) else v)
    return False


def _pyyaml_dump(value: Any) -> str:
    import yaml
    return yaml.dump(value, Dumper=yaml.SafeDumper, default_flow_style=False)


def dump_yaml(value: Any) -> str:
    """YAML text of `value` as roslaunch `--dump-params` and `rosparam dump` print it
    (PyYAML's safe block style; bytes become `!!binary`).

    PyYAML's pure-Python emitter is the reference, but it costs ~50 us per scalar (a
    quarter of a second for a big launch), and libyaml's emitter differs in places. So
    the entries of a top-level mapping that are plain scalars or flat lists of them are
    written here, exactly as PyYAML writes them; every other entry goes through PyYAML.
    """
    if type(value) is dict and not value:
        return "{}\n"  # (as PyYAML writes it: a launch without parameters imports no PyYAML)
    if type(value) is not dict or _shares_containers(value):
        return _pyyaml_dump(value)
    try:
        keys = sorted(value)  # safe_dump's sort_keys=True
    except TypeError:
        return _pyyaml_dump(value)
    # parameter names are nearly always simple strings: check them all in one regex pass
    all_simple = (all(type(k) is str for k in keys) and _SIMPLE_LINES.fullmatch("\n".join(keys)) is not None
                  and max(map(len, keys)) <= 100)
    # the common entries (a simple key and a scalar) are written inline; anything else by _entry
    # or PyYAML. ~1 us per entry instead of ~3: a big launch has thousands of them. A simple
    # string that starts with a letter, '_' or '/' is a string to YAML unless it is one of the
    # words YAML 1.1 reads as a bool or null (see scalar_is_str): no need to ask further.
    first_chars = WORD_FIRST_CHARS
    non_str = NON_STR_WORDS
    match = _SIMPLE_STRING.match
    spaced = _SPACED_STRING.match
    out = []
    append = out.append
    for key in keys:
        v = value[key]
        if all_simple or (type(key) is str and key and len(key) <= 100 and match(key)):
            k = key if (key[0] in first_chars and key not in non_str) else _quoted_if_typed(key)
            kind = type(v)
            if kind is str:
                if not v:
                    append(k + ": ''\n")
                    continue
                if match(v):
                    append(k + ": " + (v if (v[0] in first_chars and v not in non_str) else _quoted_if_typed(v)) + "\n")
                    continue
                if len(k) + 2 + len(v) <= _BEST_WIDTH and spaced(v):
                    append(k + ": " + v + "\n")
                    continue
                text = _ascii_scalar(v, len(k) + 2, 2)
                if text is not None:
                    append(k + ": " + text + "\n")
                    continue
            elif kind is bool:
                append(k + (": true\n" if v else ": false\n"))
                continue
            elif kind is int:
                append(k + ": " + str(v) + "\n")
                continue
            elif kind is float:
                if v == v and v != _INF and v != _NINF:
                    # (a finite float's repr is already lower case)
                    text = repr(v)
                    if "." not in text and "e" in text:
                        text = text.replace("e", ".0e", 1)
                    append(k + ": " + text + "\n")
                else:
                    append(k + ": " + _plain_scalar(v) + "\n")  # type: ignore[operator]
                continue
        long_key = type(key) is str and len(key) >= _SIMPLE_KEY_MAX
        text = _long_key_entry(key, v) if long_key else _entry(key, v)
        append(text if text is not None else _pyyaml_dump({key: v}))
    return "".join(out)


# PyYAML writes a key as a simple key while it and its tag (`!!str`) are shorter than 128 characters;
# a longer one as an explicit `? key` with `: value` on the next line
_SIMPLE_KEY_MAX = 128 - len("!!str")


_LONG_KEY_STANDIN = "_" * _SIMPLE_KEY_MAX


def _long_key_entry(key: Any, value: Any) -> str | None:
    """A top-level entry with a long key (a parameter name of a megabyte), as PyYAML writes it: the
    key written here, the value after it by PyYAML if need be, under a stand-in key as long (its
    lines do not depend on the key's, and PyYAML's analysis of a long key costs ~1 s a megabyte);
    None if the key is no one-line text."""
    k = _plain_scalar(key, 2, 2) if type(key) is str else None
    if k is None:
        return None
    v = _float_text(value) if type(value) is float else _plain_scalar(value, 2, 2)
    if v is not None:
        return "? %s\n: %s\n" % (k, v)
    return "? " + k + _pyyaml_dump({_LONG_KEY_STANDIN: value})[2 + len(_LONG_KEY_STANDIN):]
