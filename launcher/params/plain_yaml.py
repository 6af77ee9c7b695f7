"""The plain subset of YAML most parameter files are written in, read and typed without PyYAML.

Importing PyYAML costs ~12 ms and its node objects ~1 us a scalar, while parameter
files are mostly block mappings of simple keys to numbers, words, quoted strings and
one-line flow lists and maps. This module reads exactly that subset and gives the
values rosparam's loader (PyYAML's safe loader) gives; for any text outside the subset,
or any scalar whose YAML 1.1 type it is not certain of, it answers NOT_PLAIN and the
caller uses PyYAML (launcher.params.rosyaml), which also words the errors.
tests/params/test_plain_yaml.py checks the answers against PyYAML.
"""

from __future__ import annotations

import re
from typing import Any

NOT_PLAIN = object()

# YAML 1.1's implicit bools and nulls among words (PyYAML's resolver): anything else made of
# these characters and starting with a letter, '_' or '/' is a string
_BOOLS = {w: v for words, v in ((("yes", "true", "on"), True), (("no", "false", "off"), False))
          for word in words for w in (word, word.capitalize(), word.upper())}
_NULLS = frozenset(("null", "Null", "NULL", "~"))
NON_STR_WORDS = frozenset(_BOOLS) | _NULLS
WORD_FIRST_CHARS = frozenset("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz_/")
_WORD = r"[A-Za-z_/][A-Za-z0-9_./-]*"
_INT = r"[-+]?(?:0|[1-9][0-9]*)"  # decimal, no '_' and no leading 0 (octal in YAML 1.1)
_FLOAT = r"[-+]?[0-9]+\.[0-9]+"  # no exponent (YAML 1.1 wants a sign in it), no '_'
_NUMBER_RE = re.compile(r"(?:(%s)|%s)\Z" % (_INT, _FLOAT))
_WORD_RE = re.compile(_WORD + r"\Z")
_NUMBERISH_RE = re.compile(r"[A-Za-z0-9_./+-]+\Z")
# printable ASCII and newlines only: tabs, control characters, non-ASCII, BOMs take PyYAML
_UNUSUAL = re.compile(r"[^\n -~]")
_BLOCK_LINE = re.compile(r"( *)(%s):(?: +(.*?))? *\Z" % _WORD)
_SCALAR_TOKEN = re.compile(r"'[^'\n]*'|\"[^\"\\\n]*\"|[A-Za-z0-9_./+-]+")
_FLOW_SPACE = re.compile(r" *")

_memo: dict[str, Any] = {}
_MEMO_MAX = 4096
_MEMO_TEXT_MAX = 512


def scalar_is_str(text: str) -> bool | None:
    """Whether PyYAML reads the plain scalar `text` as a string (True) or as another type
    (False); None when this module cannot tell."""
    if _WORD_RE.match(text):
        return text not in _BOOLS and text not in _NULLS
    if _NUMBER_RE.match(text):
        return False
    if "/" in text and _NUMBERISH_RE.match(text):
        return True  # no YAML 1.1 type but str has a '/' in it (e.g. "10.0/2")
    return None


def _scalar(token: str) -> Any:
    """The value of one scalar token (as matched by _SCALAR_TOKEN), or NOT_PLAIN."""
    first = token[0]
    if first == "'" or first == '"':
        return token[1:-1]
    if _WORD_RE.match(token):
        if token in _BOOLS:
            return _BOOLS[token]
        if token in _NULLS:
            return None
        return token
    m = _NUMBER_RE.match(token)
    if m is None:
        return token if "/" in token else NOT_PLAIN  # (see scalar_is_str)
    return int(token) if m.group(1) else float(token)


def _key(token: str) -> Any:
    # (PyYAML refuses implicit keys longer than 1024 characters)
    if len(token) <= 1000 and _WORD_RE.match(token) and token not in _BOOLS and token not in _NULLS:
        return token
    return NOT_PLAIN


def _flow(text: str, pos: int) -> tuple[Any, int]:
    """One flow node of `text` at `pos` (a one-line `[...]`, `{...}` or scalar): (value, end)."""
    pos = _FLOW_SPACE.match(text, pos).end()  # type: ignore[union-attr]
    if pos >= len(text):
        return NOT_PLAIN, pos
    c = text[pos]
    if c == "[":
        out: list[Any] = []
        pos = _FLOW_SPACE.match(text, pos + 1).end()  # type: ignore[union-attr]
        if text.startswith("]", pos):
            return out, pos + 1
        while True:
            value, pos = _flow(text, pos)
            if value is NOT_PLAIN:
                return NOT_PLAIN, pos
            out.append(value)
            pos = _FLOW_SPACE.match(text, pos).end()  # type: ignore[union-attr]
            if text.startswith("]", pos):
                return out, pos + 1
            if not text.startswith(", ", pos) or text.startswith(("]", "}", ","), pos + 2):
                return NOT_PLAIN, pos  # (also refuses a trailing comma)
            pos += 2
    if c == "{":
        mapping: dict[Any, Any] = {}
        pos = _FLOW_SPACE.match(text, pos + 1).end()  # type: ignore[union-attr]
        if text.startswith("}", pos):
            return mapping, pos + 1
        while True:
            m = _SCALAR_TOKEN.match(text, pos)
            if m is None:
                return NOT_PLAIN, pos
            key = _key(m.group())
            pos = m.end()
            if key is NOT_PLAIN or not text.startswith(": ", pos):
                return NOT_PLAIN, pos
            value, pos = _flow(text, pos + 2)
            if value is NOT_PLAIN:
                return NOT_PLAIN, pos
            mapping[key] = value
            pos = _FLOW_SPACE.match(text, pos).end()  # type: ignore[union-attr]
            if text.startswith("}", pos):
                return mapping, pos + 1
            if not text.startswith(", ", pos) or text.startswith(("]", "}", ","), pos + 2):
                return NOT_PLAIN, pos
            pos += 2
    m = _SCALAR_TOKEN.match(text, pos)
    if m is None:
        return NOT_PLAIN, pos
    end = m.end()
    if end < len(text) and text[end] not in " ,]}":
        return NOT_PLAIN, pos
    return _scalar(m.group()), end


def _value(text: str) -> Any:
    """A block mapping value or a whole one-line document: scalar or flow collection, nothing after it."""
    value, end = _flow(text, 0)
    if value is NOT_PLAIN or end != len(text):
        return NOT_PLAIN
    return value


# One line of a block mapping, or a blank or comment line (no key). The common values are
# told apart by the regex itself (which group matched); flow collections go to _value.
_LINE = re.compile(r"""
    (?: [ ]* (?:\#.*)?                             # blank or comment line
      | ([ ]*)(%(word)s):                            # 1 indent, 2 key
        (?: [ ]+ (?: '([^'\n]*)'                     # 3 single-quoted
                   | "([^"\\\n]*)"                 # 4 double-quoted
                   | (%(int)s)                       # 5 int
                   | (%(float)s)                     # 6 float
                   | (%(word)s)                      # 7 word: a string, a bool or null
                   | ([A-Za-z0-9_.+-]*/[A-Za-z0-9_./+-]*)  # 8 with a '/': a string
                   | ([\[{].*?)                      # 9 flow collection
                   ) )? [ ]*
    )\Z""" % {"word": _WORD, "int": _INT, "float": _FLOAT}, re.X)
_FLOW_NUMBERS = re.compile(r"\[((?:%(n)s)(?:, (?:%(n)s))*)\]\Z" % {"n": "%s|%s" % (_FLOAT, _INT)})


def _parse(text: str) -> Any:
    if _UNUSUAL.search(text):
        return NOT_PLAIN
    lines = text.split("\n")
    first = next((ln for ln in lines if ln.strip() and not ln.lstrip().startswith("#")), None)
    if first is None:
        return None  # an empty document
    if first.lstrip()[:1] in ("[", "{") or _BLOCK_LINE.match(first) is None:
        # a one-line document: a flow collection or a scalar
        if sum(1 for ln in lines if ln.strip() and not ln.lstrip().startswith("#")) != 1:
            return NOT_PLAIN
        return _value(first.strip())
    root: dict[Any, Any] = {}
    stack: list[tuple[int, dict[Any, Any]]] = []
    pending: tuple[int, dict[Any, Any], str] | None = None  # a `key:` whose value may be a nested block
    line_match = _LINE.match
    bools = _BOOLS
    nulls = _NULLS
    for line in lines:
        m = line_match(line)
        if m is None:
            return NOT_PLAIN
        key = m.group(2)
        if key is None:
            continue  # blank or comment
        if key in bools or key in nulls or len(key) > 1000:
            return NOT_PLAIN  # (a bool or null key; PyYAML refuses implicit keys over 1024 characters)
        indent = len(m.group(1))
        if not stack:
            stack.append((indent, root))
        elif pending is not None and indent > pending[0]:
            nested: dict[Any, Any] = {}
            pending[1][pending[2]] = nested
            stack.append((indent, nested))
        else:
            while stack and indent < stack[-1][0]:
                stack.pop()
            if not stack or indent != stack[-1][0]:
                return NOT_PLAIN  # inconsistent indentation: PyYAML says what is wrong
        pending = None
        mapping = stack[-1][1]
        kind = m.lastindex
        if kind == 2:  # `key:` alone
            mapping[key] = None
            pending = (indent, mapping, key)
        elif kind == 7:
            word = m.group(7)
            mapping[key] = bools[word] if word in bools else None if word in nulls else word
        elif kind == 5:
            mapping[key] = int(m.group(5))
        elif kind == 6:
            mapping[key] = float(m.group(6))
        elif kind == 9:
            flow = m.group(9)
            numbers = _FLOW_NUMBERS.match(flow)
            if numbers is not None:
                value: Any = [float(x) if "." in x else int(x) for x in numbers.group(1).split(", ")]
            else:
                value = _value(flow)
                if value is NOT_PLAIN:
                    return NOT_PLAIN
            mapping[key] = value
        else:  # 3, 4, 8: strings
            mapping[key] = m.group(kind)
    return root


def load_plain(text: str) -> Any:
    """The value rosparam's YAML loader gives `text`, if `text` is in the plain subset; else NOT_PLAIN.

    Each call returns new containers (the parse of a text is remembered, its result copied).
    """
    value = _memo.get(text, NOT_PLAIN)
    if value is NOT_PLAIN:
        try:
            value = _parse(text)
        except RecursionError:  # absurdly nested flow collections: PyYAML words the error
            return NOT_PLAIN
        if value is NOT_PLAIN:
            return NOT_PLAIN
        # short texts (inline YAML, type="yaml" values) tend to repeat: remember those
        if len(text) > _MEMO_TEXT_MAX or len(_memo) >= _MEMO_MAX:
            return value
        _memo[text] = value
    return copy_tree(value)


def copy_tree(value: Any) -> Any:
    """Deep copy of a parsed YAML tree that shares no container (no aliases)."""
    kind = type(value)
    if kind is dict:
        return {k: (v if type(v) is not dict and type(v) is not list else copy_tree(v)) for k, v in value.items()}
    if kind is list:
        return [v if type(v) is not dict and type(v) is not list else copy_tree(v) for v in value]
    return value
