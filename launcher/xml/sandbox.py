"""`$(eval ...)`: a Python expression evaluated by walking its syntax tree, never by `eval()`.

roslaunch hands the text to Python's `eval()` behind a check for `__`, so any launch file
can run code (a generator's frame reaches the module's globals without a single `__`).
A launch file is input, and static tools (`--nodes`, `--dump-params`, a checker in a CI
job on a pull request) must never run what it says. So nothing here executes: the text
is parsed with `ast`, and only the node kinds in `Evaluator._EVAL` are interpreted, over
values of plain types (numbers, strings, lists, tuples, dicts, sets, ranges). Names come
from an explicit table (roslaunch's functions, its `true`/`false` and math names, the
file's args, a few pure builtins); the only attribute access is a call of a method
listed in `_METHODS`. Frames, classes and globals are out of reach by construction, not
by a list of forbidden words.

A launch tree evaluates the same texts again and again (an include's nodes, each with its
own args), so each distinct text is parsed once and made once into nested closures
(`compiled`), one per syntax node, that do what the walk's handler for that node does
without looking the handler up at every node of every evaluation. The node kinds a real
launch file uses are made so; any other node (comprehensions, subscripts, f-strings, ...)
and any refusal are left to the walk, at evaluation, as before.

The work is bounded too: every comprehension step counts against `MAX_STEPS` (without
them, the work is bounded by the length of the text), and every value made is weighed (its length, the weights of what it holds,
shared parts counted each time, as `str()` would print them) against `MAX_SIZE` before
or as it is made, so `9**9**9`, `'x' * 10**10` or `list(range(10**8))` are clean errors,
not a hang or a MemoryError.
"""

from __future__ import annotations

# The node classes and the parser's flag are the C module's own: `ast`, the Python module around it,
# adds only helpers this module does not use and costs ~1 ms to import (a --nodes run with $(eval)).
import _ast as ast
import math
import operator
import re

TYPE_CHECKING = False  # (typing.TYPE_CHECKING without importing typing: ~3 ms a start; the annotations are text)
if TYPE_CHECKING:
    from typing import Any, Callable, Iterator

    Lookup = Callable[[str], Any]
    """A name's value, in roslaunch's order (its functions and constants, then the file's args,
    auto-typed); NOT_FOUND when it has none. The builtins table is searched after it."""
    Code = Callable[["Evaluator"], Any]
    """A syntax node made a closure (`compiled`): its value in the evaluation it is given."""

MAX_STEPS = 100_000  # comprehension iterations (a real launch file uses a few)
MAX_SIZE = 1_000_000  # the weight of any one value: characters, items
MAX_INT_BITS = 14_000  # ~4,200 decimal digits (Python's str() refuses ints above 4,300)
MAX_SOURCE = 20_000  # characters of expression text


class EvalError(Exception):
    """The expression is refused or failed; the message says why (the loader adds file and line)."""


NOT_FOUND = object()  # what a Lookup gives for a name it has no value of (an exception costs ~1 us a name)


def evaluate(expr: str, lookup: Lookup) -> Any:
    """The value of `expr`; EvalError (with Python's words for the user's own mistakes) otherwise."""
    return Evaluator(lookup).run(compiled(expr))


_PARSED: dict[str, ast.expr] = {}


def parse(expr: str) -> ast.expr:
    """The expression's tree (parsed once per distinct text)."""
    tree = _PARSED.get(expr)
    if tree is None:
        if len(expr) > MAX_SOURCE:
            raise EvalError("expression longer than %d characters" % MAX_SOURCE)
        try:
            tree = compile(expr.strip(), "<unknown>", "eval", ast.PyCF_ONLY_AST).body  # (ast.parse)
        except SyntaxError as e:
            raise EvalError("invalid expression: %s" % e.msg) from None
        except (RecursionError, MemoryError):
            raise EvalError("expression nested too deeply") from None
        if len(_PARSED) < 4096:
            _PARSED[expr] = tree
    return tree


# -- what a value may be, and what it weighs --------------------------------------------

_SCALARS = (type(None), bool, int, float, complex)
_CONTAINERS = (list, tuple, set, frozenset, dict, type({}.keys()), type({}.values()), type({}.items()))


def _too_big(what: str) -> EvalError:
    return EvalError("%s: values are limited to %d items or characters" % (what, MAX_SIZE))


def check_int(value: int) -> int:
    if value.bit_length() > MAX_INT_BITS:
        raise EvalError("integer too large (more than %d bits)" % MAX_INT_BITS)
    return value


# -- the functions of the table that need a bound before they run -----------------------

def _range(*args: Any) -> range:
    r = range(*args)
    if len(r) > MAX_SIZE:
        raise _too_big("range of %d items" % len(r))
    return r


def _pow(base: Any, exp: Any, mod: Any = None) -> Any:
    if mod is not None:
        return pow(base, exp, mod)  # (modular: the result is smaller than mod)
    return _power(base, exp)


def _power(base: Any, exp: Any) -> Any:
    if type(base) in (int, bool) and type(exp) in (int, bool) and exp > 0 and abs(base) > 1:
        if (abs(base).bit_length() - 1) * exp > MAX_INT_BITS:
            raise EvalError("integer too large (more than %d bits)" % MAX_INT_BITS)
    return base ** exp


def _sum(values: Any, start: Any = 0) -> Any:
    # numbers only: sum() of lists copies quadratically
    if not isinstance(start, (int, float, complex)):
        raise EvalError("sum() adds numbers only")
    total = start
    for v in values:
        if not isinstance(v, (int, float, complex)):
            raise EvalError("sum() adds numbers only")
        total = total + v
        if type(total) is int:
            check_int(total)
    return total


def _prod(values: Any, start: Any = 1) -> Any:
    total = start
    for v in values:
        total = _multiply(total, v)
    return total


def _small_int_args(name: str, f: Callable[..., Any], limit: int) -> Callable[..., Any]:
    def bounded(*args: Any) -> Any:
        if any(isinstance(a, int) and a > limit for a in args):
            raise EvalError("%s() of numbers above %d is refused" % (name, limit))
        return f(*args)
    bounded.__name__ = name
    return bounded


def _eager(f: Callable[..., Any]) -> Callable[..., list]:
    """map/filter/zip/enumerate/reversed made lists at once (nothing lazy outlives a step)."""
    def made(*args: Any, **kwargs: Any) -> list:
        return list(f(*args, **kwargs))
    made.__name__ = f.__name__
    return made


# Names every expression can use after roslaunch's own and the args: pure builtins only
# (no getattr, type, vars, open, eval, ...). The types themselves are values so that
# `isinstance(x, str)` works; a type has no callable method here (see _METHODS).
BUILTINS: dict[str, Any] = {
    "abs": abs, "all": all, "any": any, "bin": bin, "bool": bool, "chr": chr, "dict": dict,
    "divmod": divmod, "float": float, "frozenset": frozenset, "hex": hex, "int": int,
    "isinstance": isinstance, "len": len, "list": list, "max": max, "min": min, "oct": oct, "ord": ord,
    "repr": repr, "round": round, "set": set, "sorted": sorted, "str": str, "tuple": tuple,
    "range": _range, "pow": _pow, "sum": _sum,
    "map": _eager(map), "filter": _eager(filter), "zip": _eager(zip), "enumerate": _eager(enumerate),
    "reversed": _eager(reversed),
}

# roslaunch defines every name of the math module; the few that can run long are bounded.
MATH: dict[str, Any] = {k: v for k, v in vars(math).items() if not k.startswith("_")}
MATH.update(factorial=_small_int_args("factorial", math.factorial, 1500),
            comb=_small_int_args("comb", math.comb, 5000), perm=_small_int_args("perm", math.perm, 1500),
            prod=_prod)


# -- methods: the only attribute access there is --------------------------------------

def _checked_format(fmt: str, *args: Any, **kwargs: Any) -> str:
    _check_format_fields(fmt)
    return fmt.format(*args, **kwargs)


# (the format checks' patterns are compiled at their first use, by re's cache: few $(eval)s format text)
_FIELD_NAME = r"^\w*$"
_SPEC_NUMBER = r"\d+"


def _check_spec(spec: str) -> None:
    """A format spec's width and precision are bounded (`{:>999999999}` would be a gigabyte)."""
    for n in re.findall(_SPEC_NUMBER, spec):
        if int(n) > MAX_SIZE:
            raise _too_big("format width %s" % n)


def _check_format_fields(fmt: str) -> None:
    """str.format may name arguments (`{}`, `{0}`, `{name}`) but not walk into them (`{0.x}`, `{0[k]}`)."""
    import string  # (only a str.format call needs it)
    try:
        fields = list(string.Formatter().parse(fmt))
    except ValueError as e:
        raise EvalError("bad format string: %s" % e) from None
    for _, field, spec, _ in fields:
        if field is None:
            continue
        if not re.match(_FIELD_NAME, field):
            raise EvalError("format field {%s} is refused: only plain names and positions" % field)
        if spec:
            if "{" in spec:
                raise EvalError("nested format fields are not supported in $(eval)")
            _check_spec(spec)


_PERCENT = r"%(?:\([^)]*\))?[#0\- +]*(\*|\d+)?(?:\.(\*|\d+))?"


def _check_percent(fmt: str) -> None:
    for width, precision in re.findall(_PERCENT, fmt):
        for n in (width, precision):
            if n == "*":
                raise EvalError("'*' widths are not supported in $(eval)")
            if n and int(n) > MAX_SIZE:
                raise _too_big("format width %s" % n)


def _pad(name: str) -> Callable[..., str]:
    method = getattr(str, name)

    def pad(s: str, width: int, *fill: Any) -> str:
        if isinstance(width, int) and width > MAX_SIZE:
            raise _too_big("%s(%d)" % (name, width))
        return method(s, width, *fill)
    return pad


def _replace(s: str, old: str, new: str, count: int = -1) -> str:
    if isinstance(old, str) and isinstance(new, str):
        hits = s.count(old) if old else len(s) + 1
        if count >= 0:
            hits = min(hits, count)
        if len(s) + hits * len(new) > MAX_SIZE:
            raise _too_big("replace()")
    return s.replace(old, new, count)


def _join(sep: str, items: Any) -> str:
    items = list(items)
    if isinstance(sep, str) and len(sep) * max(len(items) - 1, 0) + sum(
            len(i) for i in items if isinstance(i, str)) > MAX_SIZE:
        raise _too_big("join()")
    return sep.join(items)


def _plain(cls: type, *names: str) -> dict[str, Callable[..., Any]]:
    # The methods this interpreter has: roslaunch's $(eval) offers those of the Python it runs on
    # (removeprefix and removesuffix came with 3.9; Noetic's roslaunch on Ubuntu 20.04 has neither).
    return {n: getattr(cls, n) for n in names if hasattr(cls, n)}


_METHODS: dict[type, dict[str, Callable[..., Any]]] = {
    str: {
        **_plain(str, "capitalize", "casefold", "count", "endswith", "find", "index", "isalnum", "isalpha",
                 "isdecimal", "isdigit", "isidentifier", "islower", "isnumeric", "isspace", "istitle",
                 "isupper", "lower", "lstrip", "partition", "removeprefix", "removesuffix", "rfind",
                 "rindex", "rpartition", "rsplit", "rstrip", "split", "splitlines", "startswith", "strip",
                 "swapcase", "title", "upper"),
        "center": _pad("center"), "ljust": _pad("ljust"), "rjust": _pad("rjust"), "zfill": _pad("zfill"),
        "replace": _replace, "join": _join, "format": _checked_format,
    },
    list: _plain(list, "count", "index", "copy"),
    tuple: _plain(tuple, "count", "index"),
    dict: _plain(dict, "get", "keys", "values", "items", "copy"),
    int: _plain(int, "bit_length"),
    bool: _plain(int, "bit_length"),
    float: _plain(float, "is_integer"),
}


# -- operators, each checked before it can make something huge ---------------------------

def _multiply(a: Any, b: Any) -> Any:
    ta, tb = type(a), type(b)
    if ta in (int, bool) and tb in (int, bool):
        if a.bit_length() + b.bit_length() > MAX_INT_BITS + 1:
            raise EvalError("integer too large (more than %d bits)" % MAX_INT_BITS)
    elif ta in (str, list, tuple) and tb in (int, bool) and len(a) * b > MAX_SIZE:
        raise _too_big("repetition of %d items %d times" % (len(a), b))
    elif tb in (str, list, tuple) and ta in (int, bool) and len(b) * a > MAX_SIZE:
        raise _too_big("repetition of %d items %d times" % (len(b), a))
    return a * b


def _lshift(a: Any, b: Any) -> Any:
    if type(a) in (int, bool) and type(b) in (int, bool) and b > 0 and a.bit_length() + b > MAX_INT_BITS:
        raise EvalError("integer too large (more than %d bits)" % MAX_INT_BITS)
    return a << b


def _modulo(a: Any, b: Any) -> Any:
    if type(a) is str:
        _check_percent(a)
    return a % b


# (operator's C functions where the operation needs no check: one Python frame less per operation)
_BINARY: dict[type, Callable[[Any, Any], Any]] = {
    ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: _multiply, ast.Div: operator.truediv,
    ast.FloorDiv: operator.floordiv, ast.Mod: _modulo, ast.Pow: _power, ast.LShift: _lshift,
    ast.RShift: operator.rshift, ast.BitAnd: operator.and_, ast.BitOr: operator.or_, ast.BitXor: operator.xor,
}
_UNARY: dict[type, Callable[[Any], Any]] = {
    ast.UAdd: operator.pos, ast.USub: operator.neg, ast.Not: operator.not_, ast.Invert: operator.invert,
}
_COMPARE: dict[type, Callable[[Any, Any], bool]] = {
    ast.Eq: operator.eq, ast.NotEq: operator.ne, ast.Lt: operator.lt, ast.LtE: operator.le, ast.Gt: operator.gt,
    ast.GtE: operator.ge, ast.Is: operator.is_, ast.IsNot: operator.is_not,
    ast.In: lambda a, b: a in b, ast.NotIn: lambda a, b: a not in b,
}


# The errors of the user's own mistakes (1/0, int('x'), a missing key), said as EvalErrors in Python's words
# (an EvalError, of none of these classes, passes as it is)
_USER_ERRORS = (ArithmeticError, ValueError, TypeError, LookupError, AttributeError)


def _user_error(e: Exception) -> EvalError:
    return EvalError("%s: %s" % (type(e).__name__, e))


class Evaluator:
    """One evaluation: where names are found, the local variables of comprehensions, the work done so far."""

    def __init__(self, lookup: Lookup):
        self.lookup = lookup
        self.local: list[dict[str, Any]] = []  # comprehension scopes, innermost last
        self.steps = 0
        # Weights of the containers made so far, by id; the containers are kept alive in
        # `made` while this evaluation runs, so an id is never reused for another one.
        self.weights: dict[int, int] = {}
        self.made: list[Any] = []

    def run(self, code: Code) -> Any:
        """The value of a compiled expression (`compiled`) in this evaluation."""
        try:
            return code(self)
        except RecursionError:
            raise EvalError("expression nested too deeply") from None
        except MemoryError:
            raise EvalError("out of memory") from None

    def eval(self, node: ast.AST) -> Any:
        handler = self._EVAL.get(type(node))
        if handler is None:
            raise EvalError("%s is not allowed in $(eval)" % _describe(node))
        return handler(self, node)

    # -- weighing ----------------------------------------------------------------------

    def weigh(self, value: Any) -> Any:
        """`value`, once its weight is known to be within MAX_SIZE."""
        t = type(value)
        if t is float or t is bool or (t is str and len(value) <= MAX_SIZE):
            return value  # (the common values, weighed without a call)
        if self.weight(value) > MAX_SIZE:
            raise _too_big("a value of weight %d" % self.weight(value))
        return value

    def weight(self, value: Any) -> int:
        t = type(value)
        if t is str:
            return len(value)
        if t is int:
            check_int(value)
            return 1 + value.bit_length() // 64
        if t in _SCALARS or t is range:
            return 1
        if t in _CONTAINERS:
            known = self.weights.get(id(value))
            if known is None:
                known = 1
                items = value.items() if t is dict else value
                for item in items:
                    known += self.weight(item)
                    if known > MAX_SIZE:
                        break
                self.weights[id(value)] = known
                self.made.append(value)
            return known
        return 1  # a function of the tables

    # -- the node kinds ----------------------------------------------------------------

    def _constant(self, node: ast.Constant) -> Any:
        if type(node.value) not in (str, int, float, complex, bool, type(None)):
            raise EvalError("%r literals are not allowed in $(eval)" % type(node.value).__name__)
        return node.value

    def _name(self, node: ast.Name) -> Any:
        return self.resolve(node.id)

    def resolve(self, name: str) -> Any:
        """A name's value: a comprehension's variable, else an arg or substitution, else a builtin (the walk and
        the compiled closures both ask here)."""
        if self.local:
            for scope in reversed(self.local):
                if name in scope:
                    return scope[name]
        value = self.lookup(name)
        if value is not NOT_FOUND:
            return value
        if name in BUILTINS:
            return BUILTINS[name]
        raise EvalError("name '%s' is not defined" % name)

    def _binop(self, node: ast.BinOp) -> Any:
        op = _BINARY.get(type(node.op))
        if op is None:
            raise EvalError("the operator %s is not allowed in $(eval)" % type(node.op).__name__)
        return self.weigh(self._apply(op, self.eval(node.left), self.eval(node.right)))

    def _unaryop(self, node: ast.UnaryOp) -> Any:
        return self._apply(_UNARY[type(node.op)], self.eval(node.operand))

    def _boolop(self, node: ast.BoolOp) -> Any:
        is_and = isinstance(node.op, ast.And)
        value = None
        for operand in node.values:
            value = self.eval(operand)
            if bool(value) != is_and:
                return value
        return value

    def _compare(self, node: ast.Compare) -> Any:
        left = self.eval(node.left)
        for op, right_node in zip(node.ops, node.comparators):
            right = self.eval(right_node)
            if not self._apply(_COMPARE[type(op)], left, right):
                return False
            left = right
        return True

    def _ifexp(self, node: ast.IfExp) -> Any:
        return self.eval(node.body) if self.eval(node.test) else self.eval(node.orelse)

    def _subscript(self, node: ast.Subscript) -> Any:
        value = self.eval(node.value)
        key = node.slice
        if type(key).__name__ == "Index":  # (Python 3.8's parser wraps a subscript's key in ast.Index)
            key = key.value  # type: ignore[attr-defined]
        if isinstance(value, (str, list, tuple, dict, range)):
            return self.weigh(self._apply(lambda v, k: v[k], value, self.eval(key)))
        raise EvalError("'%s' object is not subscriptable" % type(value).__name__)

    def _slice(self, node: ast.Slice) -> slice:
        return slice(*(None if part is None else self.eval(part) for part in (node.lower, node.upper, node.step)))

    def _list(self, node: ast.List) -> list:
        return self.weigh(self._items(node.elts))

    def _tuple(self, node: ast.Tuple) -> tuple:
        return self.weigh(tuple(self._items(node.elts)))

    def _set(self, node: ast.Set) -> set:
        return self.weigh(self._apply(set, self._items(node.elts)))

    def _dict(self, node: ast.Dict) -> dict:
        out: dict[Any, Any] = {}
        for key, value in zip(node.keys, node.values):
            if key is None:  # {**other}
                self._apply(out.update, self.eval(value))
            else:
                k = self.eval(key)
                self._apply(out.__setitem__, k, self.eval(value))
        return self.weigh(out)

    def _items(self, nodes: list[ast.expr]) -> list:
        out: list[Any] = []
        for n in nodes:
            if isinstance(n, ast.Starred):
                out.extend(self._apply(list, self.eval(n.value)))
            else:
                out.append(self.eval(n))
        return out

    def _joinedstr(self, node: ast.JoinedStr) -> str:
        parts = []
        for part in node.values:
            if isinstance(part, ast.Constant):
                parts.append(part.value)
                continue
            value = self.eval(part.value)
            if part.conversion == ord("r"):
                value = repr(value)
            elif part.conversion == ord("a"):
                value = ascii(value)
            elif part.conversion == ord("s"):
                value = str(value)
            spec = self._joinedstr(part.format_spec) if part.format_spec is not None else ""
            _check_spec(spec)
            parts.append(self._apply(format, value, spec))
        return self.weigh("".join(parts))

    def _call(self, node: ast.Call) -> Any:
        func = node.func
        if isinstance(func, ast.Attribute):
            target = self.eval(func.value)
            method = _METHODS.get(type(target), {}).get(func.attr)
            if method is None:
                raise EvalError("'%s.%s' is not allowed in $(eval)" % (type(target).__name__, func.attr))
            args = [target]
        else:
            method = self.eval(func)
            if not callable(method):
                raise EvalError("'%s' object is not callable" % type(method).__name__)
            args = []
        args += self._items(node.args)
        kwargs: dict[str, Any] = {}
        for kw in node.keywords:
            if kw.arg is None:
                more = self.eval(kw.value)
                if not isinstance(more, dict):
                    raise EvalError("argument after ** must be a dict")
                kwargs.update(more)
            else:
                kwargs[kw.arg] = self.eval(kw.value)
        return self.weigh(self._apply(method, *args, **kwargs))

    def _comprehension(self, node: Any, make: Callable[[], Any], add: Callable[[Any, Any], None]) -> Any:
        out = make()
        weight = [1]
        scope: dict[str, Any] = {}
        self.local.append(scope)
        try:
            self._generate(node.generators, 0, scope, lambda: add(out, weight))
        finally:
            self.local.pop()
        return out

    def _generate(self, generators: list[ast.comprehension], i: int, scope: dict[str, Any],
                  emit: Callable[[], None]) -> None:
        gen = generators[i]
        if gen.is_async:
            raise EvalError("async comprehensions are not allowed in $(eval)")
        iterable = self.eval(gen.iter)
        if not isinstance(iterable, (str, list, tuple, dict, set, frozenset, range) + _CONTAINERS):
            raise EvalError("'%s' object is not iterable" % type(iterable).__name__)
        for item in iterable:
            self.steps += 1
            if self.steps > MAX_STEPS:
                raise EvalError("expression takes more than %d steps" % MAX_STEPS)
            self._bind(gen.target, item, scope)
            if all(self.eval(cond) for cond in gen.ifs):
                if i + 1 < len(generators):
                    self._generate(generators, i + 1, scope, emit)
                else:
                    emit()

    def _bind(self, target: ast.expr, value: Any, scope: dict[str, Any]) -> None:
        if isinstance(target, ast.Name):
            scope[target.id] = value
        elif isinstance(target, (ast.Tuple, ast.List)):
            values = self._apply(list, value)
            if len(values) != len(target.elts):
                raise EvalError("cannot unpack %d values into %d names" % (len(values), len(target.elts)))
            for t, v in zip(target.elts, values):
                self._bind(t, v, scope)
        else:
            raise EvalError("%s is not allowed as a comprehension target in $(eval)" % _describe(target))

    def _grow(self, weight: list[int], value: Any) -> None:
        weight[0] += self.weight(value)
        if weight[0] > MAX_SIZE:
            raise _too_big("a comprehension")

    def _listcomp(self, node: ast.ListComp) -> list:
        def add(out: list, weight: list[int]) -> None:
            value = self.eval(node.elt)
            self._grow(weight, value)
            out.append(value)
        return self.weigh(self._comprehension(node, list, add))

    def _setcomp(self, node: ast.SetComp) -> set:
        def add(out: set, weight: list[int]) -> None:
            value = self.eval(node.elt)
            self._grow(weight, value)
            self._apply(out.add, value)
        return self.weigh(self._comprehension(node, set, add))

    def _dictcomp(self, node: ast.DictComp) -> dict:
        def add(out: dict, weight: list[int]) -> None:
            key, value = self.eval(node.key), self.eval(node.value)
            self._grow(weight, key)
            self._grow(weight, value)
            self._apply(out.__setitem__, key, value)
        return self.weigh(self._comprehension(node, dict, add))

    # A generator expression is made a list: it is consumed at once by the call around it
    # (sum, any, join, ...), and nothing lazy may outlive the step that made it.
    _generatorexp = _listcomp

    def _apply(self, f: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
        """f(*args): the user's own mistakes (1/0, int('x'), a missing key) become EvalErrors in Python's words."""
        try:
            return f(*args, **kwargs)
        except _USER_ERRORS as e:
            raise _user_error(e) from None

    _EVAL: dict[type, Callable[[Evaluator, Any], Any]] = {
        ast.Constant: _constant, ast.Name: _name, ast.BinOp: _binop, ast.UnaryOp: _unaryop,
        ast.BoolOp: _boolop, ast.Compare: _compare, ast.IfExp: _ifexp, ast.Subscript: _subscript,
        ast.Slice: _slice, ast.List: _list, ast.Tuple: _tuple, ast.Set: _set, ast.Dict: _dict,
        ast.JoinedStr: _joinedstr, ast.Call: _call, ast.ListComp: _listcomp, ast.SetComp: _setcomp,
        ast.DictComp: _dictcomp, ast.GeneratorExp: _generatorexp,
    }


def _describe(node: ast.AST) -> str:
    what = {ast.Lambda: "lambda", ast.Attribute: "attribute access", ast.NamedExpr: "':='",
            ast.Starred: "'*' here", ast.Await: "await", ast.Yield: "yield", ast.YieldFrom: "yield"}
    return what.get(type(node), type(node).__name__)


# -- compiled: each text's tree made once into closures -----------------------------------
#
# Each function below makes one kind of node into a closure of the evaluation that does what
# the walk's handler does, in the same order, with the same checks and errors, calling its
# children's closures instead of dispatching on their kinds. A node of another kind, or one
# the walk refuses (an operator or a literal it does not allow), is left to the walk
# (`Evaluator.eval`), whose refusal then comes when, and only if, that node is evaluated.

_COMPILED: dict[str, Code] = {}


def compiled(expr: str) -> Code:
    """The closure that evaluates `expr` (made once per distinct text, as `parse` parses it)."""
    code = _COMPILED.get(expr)
    if code is None:
        tree = parse(expr)
        try:
            code = _compile(tree)
        except RecursionError:  # (deeper than Python's stack: the walk meets the same limit, with its error)
            code = _walked(tree)
        if len(_COMPILED) < 4096:
            _COMPILED[expr] = code
    return code


def names_read(expr: str, function: str) -> tuple[tuple[str, ...], tuple[str, ...]] | None:
    """What an evaluation of `expr` can ask its Lookup for, from its text alone: (every name in it, the
    literal text of each call of `function`, `arg('rate')`: 'rate'); None when `function` is used in any
    other way (given no literal string, passed as a value, a comprehension's variable)."""
    names: dict[str, None] = {}
    literals: dict[str, None] = {}
    called = set()  # the Name nodes that are `function(literal)`'s function
    for node in _walk(parse(expr)):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == function:
            arg = node.args[0] if len(node.args) == 1 and not node.keywords else None
            if not (isinstance(arg, ast.Constant) and type(arg.value) is str):
                return None
            literals[arg.value] = None
            called.add(id(node.func))
        elif isinstance(node, ast.Name):
            if node.id == function and id(node) not in called:
                return None
            names[node.id] = None
    return tuple(names), tuple(literals)


def _walk(tree: ast.AST) -> Iterator[ast.AST]:
    """The tree's nodes, each before its children (ast.walk, without importing `ast`)."""
    stack = [tree]
    while stack:
        node = stack.pop()
        yield node
        for field in node._fields:
            value = getattr(node, field, None)
            if isinstance(value, ast.AST):
                stack.append(value)
            elif isinstance(value, list):
                stack.extend(v for v in reversed(value) if isinstance(v, ast.AST))


def _walked(node: ast.AST) -> Code:
    return lambda ev: ev.eval(node)


def _compile(node: ast.AST) -> Code:
    make = _COMPILE.get(type(node))
    code = make(node) if make is not None else None
    return code if code is not None else _walked(node)


def _compile_constant(node: ast.Constant) -> Code | None:
    value = node.value
    if type(value) not in (str, int, float, complex, bool, type(None)):
        return None
    return lambda ev: value


def _compile_name(node: ast.Name) -> Code:
    name = node.id

    def load(ev: Evaluator) -> Any:
        return ev.resolve(name)
    return load


def _compile_binop(node: ast.BinOp) -> Code | None:
    op = _BINARY.get(type(node.op))
    if op is None:
        return None
    left, right = _compile(node.left), _compile(node.right)

    def binop(ev: Evaluator) -> Any:
        a = left(ev)
        b = right(ev)
        try:  # (Evaluator._apply, inline: the commonest step of an evaluation)
            value = op(a, b)
        except _USER_ERRORS as e:
            raise _user_error(e) from None
        return ev.weigh(value)
    return binop


def _compile_unaryop(node: ast.UnaryOp) -> Code:
    op = _UNARY[type(node.op)]
    operand = _compile(node.operand)
    return lambda ev: ev._apply(op, operand(ev))


def _compile_boolop(node: ast.BoolOp) -> Code:
    is_and = isinstance(node.op, ast.And)
    operands = [_compile(v) for v in node.values]

    def boolop(ev: Evaluator) -> Any:
        value = None
        for operand in operands:
            value = operand(ev)
            if bool(value) != is_and:
                return value
        return value
    return boolop


def _compile_compare(node: ast.Compare) -> Code:
    first = _compile(node.left)
    steps = [(_COMPARE[type(op)], _compile(right)) for op, right in zip(node.ops, node.comparators)]

    def compare(ev: Evaluator) -> Any:
        left = first(ev)
        for op, right_code in steps:
            right = right_code(ev)
            if not ev._apply(op, left, right):
                return False
            left = right
        return True
    return compare


def _compile_ifexp(node: ast.IfExp) -> Code:
    test, body, orelse = _compile(node.test), _compile(node.body), _compile(node.orelse)
    return lambda ev: body(ev) if test(ev) else orelse(ev)


def _compile_items(nodes: list[ast.expr]) -> Callable[[Evaluator], list]:
    """The closure of `Evaluator._items`: the values of `nodes`, a starred one's items spread."""
    if not any(isinstance(n, ast.Starred) for n in nodes):
        codes = [_compile(n) for n in nodes]
        if len(codes) == 1:  # (a call's one argument: no comprehension to run)
            only = codes[0]
            return lambda ev: [only(ev)]
        return lambda ev: [code(ev) for code in codes]
    parts = [(True, _compile(n.value)) if isinstance(n, ast.Starred) else (False, _compile(n)) for n in nodes]

    def items(ev: Evaluator) -> list:
        out: list[Any] = []
        for starred, code in parts:
            if starred:
                out.extend(ev._apply(list, code(ev)))
            else:
                out.append(code(ev))
        return out
    return items


def _compile_list(node: ast.List) -> Code:
    items = _compile_items(node.elts)
    return lambda ev: ev.weigh(items(ev))


def _compile_tuple(node: ast.Tuple) -> Code:
    items = _compile_items(node.elts)
    return lambda ev: ev.weigh(tuple(items(ev)))


def _compile_call(node: ast.Call) -> Code:
    func = node.func
    items = _compile_items(node.args)
    keywords = [(kw.arg, _compile(kw.value)) for kw in node.keywords]

    def kwargs_of(ev: Evaluator) -> dict[str, Any]:
        kwargs: dict[str, Any] = {}
        for name, code in keywords:
            if name is None:
                more = code(ev)
                if not isinstance(more, dict):
                    raise EvalError("argument after ** must be a dict")
                kwargs.update(more)
            else:
                kwargs[name] = code(ev)
        return kwargs

    if isinstance(func, ast.Attribute):
        target_code, attr = _compile(func.value), func.attr

        def call_method(ev: Evaluator) -> Any:
            target = target_code(ev)
            method = _METHODS.get(type(target), {}).get(attr)
            if method is None:
                raise EvalError("'%s.%s' is not allowed in $(eval)" % (type(target).__name__, attr))
            args = [target]
            args += items(ev)
            return ev.weigh(ev._apply(method, *args, **kwargs_of(ev)) if keywords else ev._apply(method, *args))
        return call_method
    func_code = _compile(func)

    def call(ev: Evaluator) -> Any:
        method = func_code(ev)
        if not callable(method):
            raise EvalError("'%s' object is not callable" % type(method).__name__)
        args = items(ev)
        if keywords:
            return ev.weigh(ev._apply(method, *args, **kwargs_of(ev)))
        try:  # (Evaluator._apply, inline)
            value = method(*args)
        except _USER_ERRORS as e:
            raise _user_error(e) from None
        return ev.weigh(value)
    return call


_COMPILE: dict[type, Callable[[Any], Code | None]] = {
    ast.Constant: _compile_constant, ast.Name: _compile_name, ast.BinOp: _compile_binop,
    ast.UnaryOp: _compile_unaryop, ast.BoolOp: _compile_boolop, ast.Compare: _compile_compare,
    ast.IfExp: _compile_ifexp, ast.List: _compile_list, ast.Tuple: _compile_tuple, ast.Call: _compile_call,
}
