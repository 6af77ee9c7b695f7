"""ROS YAML: rosparam's dialect of YAML (angles, binary) for loading and dumping parameters.

rosparam extends PyYAML's safe loader with `deg(...)`/`rad(...)` plain scalars and the
`!degrees`/`!radians` tags, and wraps `!!binary` data (here: plain bytes). We do the same
on private loader classes (never on PyYAML's global ones) and evaluate angle expressions
with a small arithmetic evaluator instead of Python's `eval`.

There is one reading path, through PyYAML's public API only: libyaml (PyYAML's CSafeLoader)
composes the node graph, whose plain nodes (strings, numbers, bools, lists, maps) are built
directly and the rest by PyYAML's SafeConstructor; a text libyaml refuses or reads
differently goes to PyYAML's pure-Python loader, roslaunch's own, which also words errors.
Equality with rosparam is checked by differential fuzzing and on real parameter files
(tests/params/corpus). Dumping is launcher.params.dump.

Limits of the interpreter that a document can reach are errors with the document's line:
collections nested more than MAX_DEPTH deep (roslaunch gives up at Python's recursion limit,
~480 levels, and cannot dump lists ~320 deep; libyaml's composer recurses in C and would
crash the process some 30,000 levels down, so a document that may nest deeper than
_C_SAFE_DEPTH is measured by libyaml's parser before it is composed), and integers longer
than Python converts to text (`sys.get_int_max_str_digits()`, 4300 digits: roslaunch fails
on them the same way; an `0x` integer or a base-60 one is checked before it is computed,
as computing a base-60 one of a million parts takes hours), and aliases that make a document
hold more than MAX_VALUES values (a kilobyte of `&a {p: *b, q: *b}` doubling 30 times: each
becomes a parameter, which roslaunch too takes hours to make).
"""

from __future__ import annotations

import ast
import math
import operator
import re
import sys
from typing import Any

import yaml

from launcher.model.errors import LaunchError, shorten


class RosYamlError(LaunchError, ValueError):
    """Invalid ROS YAML; `line` is the line in the YAML file (or launch file, for inline YAML)."""

    def __init__(self, message: str, filename: str | None = None, line: int | None = None):
        super().__init__(message, filename, line)


class _ValueRefused(Exception):
    """A value rosparam would refuse, found while constructing (raised inside PyYAML, mapped later)."""

    def __init__(self, message: str, line: int):
        super().__init__(message)
        self.line = line


class _Refused(_ValueRefused):
    """A document refused for what it is, whichever loader reads it (too deep, an integer too long)."""


MAX_DEPTH = 256  # collections nested in one document
MAX_VALUES = 1_000_000  # values in one document with its aliases followed (each a parameter or an item sent)
_C_SAFE_DEPTH = 5000  # libyaml's composer is known safe this deep (it recurses in C)
_LONG_LINE = re.compile(r"(?m)^[^\n]{1000}")
_INT_MAX_DIGITS = getattr(sys, "get_int_max_str_digits", lambda: 0)()  # (0: no limit, or an older Python)


def _nesting_bound(text: str) -> int:
    """How deep `text`'s collections may nest at most, from two counts (no parse).

    Each level takes a character at least. A flow collection opens with a '[' or '{'; a block
    collection is indented further than its parent, but for a sequence right under a mapping
    key: block nesting is at most twice the longest line (below 1000 characters, unless a line
    is longer).
    """
    if len(text) <= MAX_DEPTH:
        return len(text)
    line = min(len(text), 999)
    if line == 999 and _LONG_LINE.search(text) is not None:
        return len(text)
    return min(len(text), text.count("[") + text.count("{") + 2 * (line + 2))


def _nesting_refused(text: str, loader_cls: type) -> int | None:
    """The line (0-based) where `text` nests deeper than MAX_DEPTH, by libyaml's parser (which keeps
    its own stack: no recursion), or None."""
    loader = loader_cls(text)
    depth = 0
    try:
        while loader.check_event():
            event = loader.get_event()
            kind = type(event)
            if kind is yaml.SequenceStartEvent or kind is yaml.MappingStartEvent:
                depth += 1
                if depth > MAX_DEPTH:
                    return event.start_mark.line
            elif kind is yaml.SequenceEndEvent or kind is yaml.MappingEndEvent:
                depth -= 1
    except yaml.YAMLError:
        pass  # (composing stops at the same error, no deeper than here)
    finally:
        loader.dispose()
    return None


def _shape(value: Any) -> tuple[int, int]:
    """(how deep lists and maps nest in `value`, how many values it holds with YAML's aliases followed
    wherever they are), each shared container measured once; a cycle, which only an alias makes, adds
    nothing (PyYAML writes it back as an alias, as roslaunch's --dump-params does). The count stops
    growing past MAX_VALUES and the walk stops past MAX_DEPTH."""
    if type(value) is not dict and type(value) is not list:
        return 0, 1
    done: dict[int, tuple[int, int]] = {}  # container id -> (depth, values), itself included
    on_path = {id(value)}
    stack = [[value, iter(_items(value)), 1, 1]]  # container, its items left, depth, values
    while stack:
        frame = stack[-1]
        for child in frame[1]:
            if type(child) is not dict and type(child) is not list:
                frame[3] += 1
                continue
            measured = done.get(id(child))
            if measured is None:
                if id(child) in on_path:
                    frame[3] += 1
                    continue
                if len(stack) >= MAX_DEPTH:
                    return MAX_DEPTH + 1, frame[3]
                on_path.add(id(child))
                stack.append([child, iter(_items(child)), 1, 1])
                break
            frame[2] = max(frame[2], measured[0] + 1)
            frame[3] = min(frame[3] + measured[1], MAX_VALUES + 1)
        else:
            stack.pop()
            on_path.discard(id(frame[0]))
            done[id(frame[0])] = (frame[2], frame[3])
            if stack:
                parent = stack[-1]
                parent[2] = max(parent[2], frame[2] + 1)
                parent[3] = min(parent[3] + frame[3], MAX_VALUES + 1)
    return done[id(value)]


def _items(container: Any) -> Any:
    return container.values() if type(container) is dict else container


def _too_many_digits(text: str, line: int) -> _Refused:
    return _Refused("invalid YAML: the integer [%s] has more than %d digits, the most Python converts to text"
                    % (shorten(text), _INT_MAX_DIGITS), line)


def _construct_int(loader: Any, node: yaml.Node) -> int:
    """SafeConstructor's int, refusing one that Python could not print (as roslaunch fails on it), and
    before computing it where that takes long."""
    text = loader.construct_scalar(node)
    if _INT_MAX_DIGITS:
        digits = text.replace("_", "").lstrip("+-")
        # base 60: the value is at least 60**(parts - 1), which has 1.77 (parts - 1) digits
        if ":" in digits and (digits.count(":") * 1.77 > _INT_MAX_DIGITS):
            raise _too_many_digits(text, node.start_mark.line)
        if digits.isdigit() and len(digits) > _INT_MAX_DIGITS and digits != "0" and digits[0] != "0":
            raise _too_many_digits(text, node.start_mark.line)
    value = yaml.constructor.SafeConstructor.construct_yaml_int(loader, node)
    if _INT_MAX_DIGITS and value.bit_length() > 3 * _INT_MAX_DIGITS:  # (3.32 bits a digit: check nearer ones)
        try:
            str(value)
        except ValueError:
            raise _too_many_digits(text, node.start_mark.line) from None
    return value


# -- angle expressions -------------------------------------------------------------------

_BINOPS = {
    ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul, ast.Div: operator.truediv,
    ast.FloorDiv: operator.floordiv, ast.Mod: operator.mod, ast.Pow: operator.pow,
}
_UNARY = {ast.UAdd: operator.pos, ast.USub: operator.neg}
# rosparam evaluates with its module globals, where `math` is importable: `math.<name>` works.
# (minus the integer combinatorics, which can run for hours on a big argument)
_MATH_NAMES = {n: getattr(math, n) for n in dir(math)
               if not n.startswith("_") and n not in ("factorial", "comb", "perm", "prod", "lcm", "gcd", "isqrt")}


def _pow(a: Any, b: Any) -> Any:
    # integer powers whose result would be astronomically large are done in floats, so
    # `10**10**10` is an overflow error instead of a hang
    if isinstance(a, int) and isinstance(b, int) and b > 0 and a.bit_length() * b > 4096:
        return math.pow(a, b)
    return operator.pow(a, b)


def _evaluate(node: ast.AST) -> Any:
    if isinstance(node, ast.Expression):
        return _evaluate(node.body)
    if isinstance(node, ast.Constant) and isinstance(node.value, (int, float)):
        return node.value
    if isinstance(node, ast.BinOp) and type(node.op) in _BINOPS:
        left, right = _evaluate(node.left), _evaluate(node.right)
        if isinstance(node.op, ast.Pow):
            return _pow(left, right)
        return _BINOPS[type(node.op)](left, right)
    if isinstance(node, ast.UnaryOp) and type(node.op) in _UNARY:
        return _UNARY[type(node.op)](_evaluate(node.operand))
    if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id == "math"
            and node.attr in _MATH_NAMES and not callable(_MATH_NAMES[node.attr])):
        return _MATH_NAMES[node.attr]
    if (isinstance(node, ast.Call) and not node.keywords and isinstance(node.func, ast.Attribute)
            and isinstance(node.func.value, ast.Name) and node.func.value.id == "math"
            and callable(_MATH_NAMES.get(node.func.attr))):
        return _MATH_NAMES[node.func.attr](*[_evaluate(a) for a in node.args])
    raise ValueError("unsupported expression")


def radians_value(text: str) -> float:
    """rosparam's `rad(expr)` / `!radians expr`: `pi` is math.pi, arithmetic only."""
    value = text.strip()
    expr = value.replace("pi", "math.pi")  # rosparam's textual substitution, quirks included
    if expr.startswith("rad("):
        expr = expr[4:-1]
    try:
        return float(_evaluate(ast.parse(expr.strip(), mode="eval")))
    except (SyntaxError, ValueError, TypeError, ArithmeticError, RecursionError, MemoryError):
        raise ValueError("invalid radian expression: %s" % value) from None


def degrees_value(text: str) -> float:
    """rosparam's `deg(number)` / `!degrees number`, in radians."""
    expr = text
    if expr.startswith("deg("):
        expr = expr.strip()[4:-1]
    try:
        return float(expr) * math.pi / 180.0
    except ValueError:
        raise ValueError("invalid degree value: %s" % text) from None


def _construct_radians(loader: Any, node: yaml.Node) -> float:
    try:
        return radians_value(loader.construct_scalar(node))
    except ValueError as e:
        raise _ValueRefused(str(e), node.start_mark.line) from None


def _construct_degrees(loader: Any, node: yaml.Node) -> float:
    try:
        return degrees_value(loader.construct_scalar(node))
    except ValueError as e:
        raise _ValueRefused(str(e), node.start_mark.line) from None


def _construct_binary(loader: Any, node: yaml.Node) -> bytes:
    return loader.construct_yaml_binary(node)


# -- loader classes --------------------------------------------------------------------

_DEG = re.compile(r"^deg\([^\)]*\)$")
_RAD = re.compile(r"^rad\([^\)]*\)$")


def _construct_object(self: Any, node: yaml.Node, deep: bool = False) -> Any:
    # PyYAML's constructors let Python errors out for bad explicitly tagged scalars
    # (`!!int a`, `!!float`): turn them into a located error like any other bad YAML
    try:
        return yaml.constructor.BaseConstructor.construct_object(self, node, deep)
    except (_ValueRefused, yaml.YAMLError, RecursionError, MemoryError):
        raise
    except Exception as e:  # noqa: BLE001 - any failure here means the input is bad YAML
        raise _ValueRefused("invalid YAML: cannot construct %s: %s" % (node.tag, e), node.start_mark.line) from None


def _guarded(base: type) -> type:
    """`base` whose construction errors are located errors (PyYAML's own behaviour otherwise)."""
    return type("Guarded" + base.__name__, (base,), {"construct_object": _construct_object})


def _with_ros_syntax(cls: type) -> type:
    cls.add_constructor("tag:yaml.org,2002:binary", _construct_binary)
    cls.add_constructor("!radians", _construct_radians)
    cls.add_constructor("!degrees", _construct_degrees)
    cls.add_implicit_resolver("!degrees", _DEG, list("deg("))
    cls.add_implicit_resolver("!radians", _RAD, list("rad("))
    return cls


def _ros_flavour(base: type) -> type:
    return _with_ros_syntax(type("Ros" + base.__name__, (base,), {}))


def _checked_ints(cls: type) -> type:
    cls.add_constructor("tag:yaml.org,2002:int", _construct_int)
    return cls


_PY_ROS = _checked_ints(_ros_flavour(_guarded(yaml.SafeLoader)))
_PY_PLAIN = _checked_ints(_guarded(yaml.SafeLoader))
# libyaml's loader: no construction guard, since any error on it makes load_yaml retry with
# the guarded pure-Python loader, which decides and words it
_C_ROS = _checked_ints(_ros_flavour(yaml.CSafeLoader)) if hasattr(yaml, "CSafeLoader") else None
_C_PLAIN = _checked_ints(type("PlainCSafeLoader", (yaml.CSafeLoader,), {})) if hasattr(yaml, "CSafeLoader") else None


# Texts on which libyaml and PyYAML's pure-Python loader (roslaunch's) disagree, found by
# differential fuzzing: tabs (PyYAML refuses them inside plain scalars and after ':'), byte
# order marks and Unicode line breaks, the bare non-specific tag `!`, and a comment right
# after a block scalar indicator. Such texts go to PyYAML directly. So does a '?' where a flow
# collection may be ('[a?]', '{url: http://x?y}'): inside `[]` and `{}` PyYAML ends a plain
# scalar at '?' and reads it as a key's mark, where libyaml keeps it in the scalar.
_LIBYAML_DIVERGES = re.compile("[\t\ufeff\x85\u2028\u2029]|!(?:\\s|\\Z)|[|>][-+0-9]*#")


def _loaders(angles: bool, text: str) -> tuple[type, ...]:
    """Loaders to try in order: libyaml first (fast), then PyYAML's (the reference's) to decide
    any input libyaml refuses and to word the error as rosparam would."""
    c_loader, py_loader = (_C_ROS, _PY_ROS) if angles else (_C_PLAIN, _PY_PLAIN)
    if c_loader is None or _LIBYAML_DIVERGES.search(text) or ("?" in text and ("[" in text or "{" in text)):
        return (py_loader,)
    return (c_loader, py_loader)


def load_yaml(text: str, *, filename: str | None = None, first_line: int = 1, angles: bool = True) -> Any:
    """Parse one YAML document the way rosparam does.

    `first_line` is the line of `filename` where `text` starts (inline YAML in a launch file),
    so error lines point into that file. `angles=False` is PyYAML's plain safe loader, which
    is what roslaunch uses for `type="yaml"` params before any `<rosparam>` was processed.
    Raises RosYamlError.
    """
    return parse_yaml(text, filename=filename, first_line=first_line, angles=angles)[0]


def parse_yaml(text: str, *, filename: str | None = None, first_line: int = 1,
               angles: bool = True) -> tuple[Any, bool]:
    """(load_yaml's value, whether it is a plain tree: str/int/float/bool/None, lists and maps, no aliases)."""
    key = (text, angles)
    memo = _parsed.get(key)
    if memo is not None:
        value, plain_tree = memo
        return (_copy_tree(value) if plain_tree else _fresh_copy(value)), plain_tree
    loaders = _loaders(angles, text)
    bound = _nesting_bound(text)
    deep = bound > MAX_DEPTH
    if bound > _C_SAFE_DEPTH and loaders[0] in (_C_ROS, _C_PLAIN):
        line = _nesting_refused(text, loaders[0])
        if line is not None:
            raise _yaml_error(_Refused(_NESTED, line), text, filename, first_line)
    for i, loader in enumerate(loaders):
        try:
            if loader is _C_ROS or loader is _C_PLAIN:
                value, plain_tree = _load_c_tree(text, loader)
            else:
                value, plain_tree = yaml.load(text, Loader=loader), False
            if not plain_tree and (deep or "*" in text):  # (_plain measures a plain tree as it builds it)
                depth, values = _shape(value)
                if depth > MAX_DEPTH:
                    raise _Refused(_NESTED, 0)
                if values > MAX_VALUES:
                    raise _Refused("invalid YAML: its aliases make more than %d values, the limit" % MAX_VALUES, 0)
        except _Refused as e:
            raise _yaml_error(e, text, filename, first_line) from None
        except Exception as e:  # noqa: BLE001 - whatever PyYAML raises, the text is not valid ROS YAML
            if i + 1 < len(loaders):
                continue
            raise _yaml_error(e, text, filename, first_line) from None
        global _memo_chars
        if len(text) <= _MEMO_TEXT_MAX and _memo_chars + len(text) <= _MEMO_CHARS:
            _memo_chars += len(text)
            _parsed[key] = (value, plain_tree)
            return (_copy_tree(value) if plain_tree else _fresh_copy(value)), plain_tree
        return value, plain_tree
    raise AssertionError("unreachable")


# -- constructing libyaml's node graph -----------------------------------------------------------
# PyYAML's SafeConstructor builds values through generators and per-tag method lookups (~1 us a
# node). Parameter files hold plain strings, numbers, booleans, lists and maps; those are built
# here directly, with the SafeConstructor's results. Any other tag (timestamps, merge keys, binary,
# angles, sets, ...), an unhashable key or a recursive alias hands the document back to PyYAML.

_STR = "tag:yaml.org,2002:str"
_INT = "tag:yaml.org,2002:int"
_FLOAT = "tag:yaml.org,2002:float"
_BOOL = "tag:yaml.org,2002:bool"
_NULL = "tag:yaml.org,2002:null"
_SEQ = "tag:yaml.org,2002:seq"
_MAP = "tag:yaml.org,2002:map"


class _NotPlain(Exception):
    """The document needs PyYAML's constructor."""


def _load_c(text: str, loader_cls: type) -> Any:
    """yaml.load(text, Loader=loader_cls) for a libyaml loader, plain documents built by _plain()."""
    return _load_c_tree(text, loader_cls)[0]


def _load_c_tree(text: str, loader_cls: type) -> tuple[Any, bool]:
    """(_load_c's value, whether it is a plain tree: built by _plain() with no aliases)."""
    loader = loader_cls(text)
    try:
        node = loader.get_single_node()
        if node is None:
            return None, True
        built: dict[Any, Any] = {_DEPTH: 0}
        try:
            value = _plain(node, built)
            return value, _ALIASED not in built
        except (_NotPlain, ValueError, KeyError, TypeError, RecursionError):
            return loader.construct_document(node), False
    finally:
        loader.dispose()


def _plain(node: Any, built: dict[int, Any]) -> Any:
    """The value of `node` as SafeConstructor makes it; `built` shares aliased nodes' values."""
    tag = node.tag
    value = node.value
    if type(value) is str:  # a scalar
        if tag == _STR:
            return value
        if tag == _INT:
            # SafeConstructor.construct_yaml_int, for plain decimals
            digits = value[1:] if value[:1] in ("-", "+") else value
            if digits.isdigit() and (digits[0] != "0" or digits == "0"):
                return int(value)
            raise _NotPlain
        if tag == _FLOAT:
            # SafeConstructor.construct_yaml_float, without '_', ':' (base 60), .inf and .nan
            if "_" in value or ":" in value or "n" in value or "N" in value:
                raise _NotPlain
            return float(value)
        if tag == _BOOL:
            return yaml.constructor.SafeConstructor.bool_values[value.lower()]
        if tag == _NULL:
            return None
        raise _NotPlain
    key = id(node)
    if key in built:
        done = built[key]
        if done is _BUILDING:
            raise _NotPlain  # a recursive structure
        built[_ALIASED] = True
        return done
    built[key] = _BUILDING
    depth = built[_DEPTH] = built[_DEPTH] + 1
    if depth > MAX_DEPTH:
        raise _Refused(_NESTED, node.start_mark.line)
    if tag == _SEQ:
        out: Any = [_plain(item, built) for item in value]
    elif tag == _MAP:
        out = {}
        for key_node, value_node in value:
            if key_node.tag not in _SCALAR_KEY_TAGS:
                raise _NotPlain  # merge keys, '=', collections as keys
            out[_plain(key_node, built)] = _plain(value_node, built)
    else:
        raise _NotPlain
    built[_DEPTH] = depth - 1
    built[key] = out
    return out


_BUILDING = object()
_ALIASED = "aliased"  # key in _plain's `built` (whose other keys are ints) once an alias was met
_DEPTH = "depth"  # key in _plain's `built`: how many collections deep the node being built is
_NESTED = "invalid YAML: collections are nested more than %d deep, the limit" % MAX_DEPTH
_SCALAR_KEY_TAGS = frozenset((_STR, _INT, _FLOAT, _BOOL, _NULL))


# Big launch trees repeat the same small YAML (inline <rosparam>, type="yaml" values, files
# included many times): parse each text once per run. Callers get their own copy, so
# nobody can alter what another caller received.
_MEMO_TEXT_MAX = 64 * 1024
_MEMO_CHARS = 8 * 1024 * 1024  # bounds the memo's memory to a few times this
_memo_chars = 0
_parsed: dict[tuple[str, bool], tuple[Any, bool]] = {}  # -> (value, plain tree: no aliases)


def _copy_tree(value: Any) -> Any:
    """Deep copy of a plain parsed tree (dicts, lists, scalars; no container occurs twice)."""
    kind = type(value)
    if kind is dict:
        return {k: (v if type(v) is not dict and type(v) is not list else _copy_tree(v)) for k, v in value.items()}
    if kind is list:
        return [v if type(v) is not dict and type(v) is not list else _copy_tree(v) for v in value]
    return value


def _fresh_copy(value: Any, memo: dict[int, Any] | None = None) -> Any:
    """Deep copy of parsed YAML (dicts, lists, scalars); objects shared through YAML
    aliases stay shared in the copy, as they were in the parse."""
    kind = type(value)
    if kind is not dict and kind is not list:
        return value  # scalars (str, int, float, bool, None, bytes, date) are immutable
    if memo is None:
        memo = {}
    found = memo.get(id(value))
    if found is not None:
        return found
    if kind is dict:
        copy: Any = {}
        memo[id(value)] = copy
        for k, v in value.items():
            copy[k] = _fresh_copy(v, memo)
    else:
        copy = []
        memo[id(value)] = copy
        copy.extend(_fresh_copy(v, memo) for v in value)
    return copy


def _yaml_error(e: BaseException, text: str, filename: str | None, first_line: int) -> RosYamlError:
    offset = first_line - 1
    if isinstance(e, _ValueRefused):
        return RosYamlError(str(e), filename, e.line + 1 + offset)
    if isinstance(e, yaml.MarkedYAMLError):
        parts = []
        if e.context:
            where = ""
            if e.context_mark is not None:
                where = " (line %d, column %d)" % (e.context_mark.line + 1 + offset, e.context_mark.column + 1)
            parts.append(e.context + where)
        problem = e.problem or "invalid YAML"
        line = None
        if e.problem_mark is not None:
            line = e.problem_mark.line + 1 + offset
            problem += " (line %d, column %d)" % (line, e.problem_mark.column + 1)
        parts.append(problem)
        if e.note:
            parts.append(e.note)
        return RosYamlError("invalid YAML: " + ": ".join(parts), filename, line)
    if isinstance(e, yaml.reader.ReaderError):
        line = text.count("\n", 0, max(e.position, 0)) + 1 + offset
        what = e.reason
        if isinstance(e.character, int):
            what = "unacceptable character #x%04x: %s" % (e.character, e.reason)
        return RosYamlError("invalid YAML: %s" % what, filename, line)
    if isinstance(e, (RecursionError, MemoryError)):
        return RosYamlError("invalid YAML: nested too deeply", filename, first_line)
    return RosYamlError("invalid YAML: %s" % e, filename, first_line)


# -- dumping: launcher.params.dump (which needs PyYAML only for what it cannot write itself) ----------

from launcher.params.dump import _pyyaml_dump, dump_yaml  # noqa: E402,F401 - re-exported
