"""Substitution args in launch attributes: `$(arg) $(env) $(optenv) $(anon) $(dirname) $(find) $(eval)`.

The algorithm is roslaunch's (substitution_args.py), because users depend on
its corner cases: `$(...)` commands are collected by the same little state
machine, the value of each replaces every copy of its text, `$(find)` runs in a
second pass over the already substituted string (so an arg whose value
contains `$(find pkg)` is expanded too), and `$(eval ...)` must be the whole
attribute. `$(eval)` is not Python's eval(): `xml/sandbox.py` walks the expression's
syntax tree over roslaunch's names, with an allowlist and a bound on the work.
"""

from __future__ import annotations

import os
import re
from typing import Any, Callable, Mapping

from launcher.names import anonymous_name
from launcher.params.values import auto_value

VALID_COMMANDS = ("find", "env", "optenv", "dirname", "anon", "arg")
_FIRST_PASS = ("env", "optenv", "dirname", "anon", "arg")


class SubstitutionError(Exception):
    """A `$(...)` that cannot be evaluated; the loader adds file and line."""


class ArgNotSet(SubstitutionError):
    """`$(arg name)` for an arg that has no value; `.name` is the arg."""

    def __init__(self, name: str):
        self.name = name
        super().__init__(name)


class SubstitutionScope:
    """What a substitution can see: the scope's args and anon names, the file, the environment, packages."""

    __slots__ = ("args", "anon", "filename", "environ", "find_package", "find_resource", "used_args")

    def __init__(self, args: Mapping[str, str], anon: dict[str, str], filename: str | None,
                 environ: Mapping[str, str], find_package: Callable[[str], str],
                 find_resource: Callable[[str, str], str], used_args: set[str] | None = None):
        self.args = args
        self.anon = anon
        self.filename = filename
        self.environ = environ
        self.find_package = find_package
        self.find_resource = find_resource
        # the names `$(arg)` (and `arg()` in `$(eval)`) have read: one set shared by a whole load,
        # so that the loader can tell a command-line arg nothing reads (a typo, usually)
        self.used_args = set() if used_args is None else used_args


_SIMPLE_COMMAND = re.compile(r"\$\(([^$()]+)\)")


def collect_commands(text: str) -> list[str]:
    """The bodies of the `$(...)` in `text`, in order (roslaunch's `_collect_args` state machine)."""
    # fast path: every '$' and every '(' opens a well-formed `$(...)`; the state machine
    # would collect exactly what the regex does
    n = text.count("$(")
    if n == text.count("$") == text.count("("):
        found = _SIMPLE_COMMAND.findall(text)
        if len(found) == n:
            return found
    out = []
    buf: list[str] = []
    state = 0  # 0 outside, 1 after '$', 2 after '$(', 3 inside
    for c in text:
        if c == "$":
            if state == 0:
                state = 1
            elif state == 1:
                pass
            else:
                raise SubstitutionError("Dollar signs '$' cannot be inside of substitution args [%s]" % text)
        elif c == "(":
            if state == 1:
                state = 2
            elif state != 0:
                raise SubstitutionError("Invalid left parenthesis '(' in substitution args [%s]" % text)
        elif c == ")":
            if state == 3:
                out.append("".join(buf))
                buf = []
            state = 0
        elif state == 1:
            state = 0
        elif state == 2:
            state = 3
        if state == 3:
            buf.append(c)
    return out


def resolve(text: str | None, scope: SubstitutionScope) -> str | None:
    """`text` with every substitution arg replaced; None stays None."""
    if not text or "$" not in text:
        return text
    if text.startswith("$(eval ") and text.endswith(")"):
        return evaluate(text[7:-1], scope)
    resolved = _first_pass_resolve(text, scope)
    if "$" in resolved:
        resolved = _find_pass_resolve(resolved, scope)
    return resolved


def _unknown(body: str) -> SubstitutionError:
    return SubstitutionError("Unknown substitution command [%s]. Valid commands are %s" % (body, list(VALID_COMMANDS)))


def _is_simple(text: str) -> bool:
    """Every '$' and every '(' of `text` opens a well-formed `$(...)`: then the `$(...)` texts in a
    string made by replacing some of them are exactly those left, as long as no value brings a '$'."""
    n = text.count("$(")
    return n == text.count("$") == text.count("(") and len(_SIMPLE_COMMAND.findall(text)) == n


# A launch tree repeats the same attribute texts many times (the same include's nodes and
# params, once per include): what a text asks for is worked out once per distinct text. The
# plans depend on the text alone; the values come from the scope at every use.
_PLAN_MAX = 16384
_FIRST_PLANS: dict[str, _FirstPlan] = {}
_FIND_PLANS: dict[str, _FindPlan] = {}


class _FirstPlan:
    """What the first pass does to one text.

    roslaunch replaces, for each `$(...)` in order, every copy of its text in the string as it
    stands; that is one scan of the whole string per `$(...)`, quadratic in a long attribute.
    `commands` are the distinct non-find commands (body, command, args) in order, up to an
    unknown one (command None), each evaluated once. For a simple text, `template` is a
    str.format template with a field for each copy of each command (a `$(find)` stays as it is,
    for the second pass): one format() call, in C, does all the replacing. `order` is every non-find body in order, for roslaunch's own way.
    """

    __slots__ = ("commands", "template", "order", "nothing")

    def __init__(self, text: str):
        commands: list[tuple[str, str | None, tuple[str, ...]]] = []
        order: list[str] = []
        index: dict[str, int] = {}  # body -> its value's position
        for body in collect_commands(text):  # (raises for a malformed text: nothing cached)
            words = body.split()
            if not words or words[0] not in VALID_COMMANDS:
                commands.append((body, None, ()))
                break
            if words[0] != "find":
                order.append(body)
                if body not in index:
                    index[body] = len(commands)
                    commands.append((body, words[0], tuple(words[1:])))
        self.commands = tuple(commands)
        self.order = tuple(order)
        self.nothing = not commands  # only $(find)s, for the second pass
        self.template: str | None = None
        if _is_simple(text):
            pieces = _SIMPLE_COMMAND.split(text)
            # (a $(find) is left as it is, for the second pass)
            pieces[1::2] = ["{%d}" % index[b] if b in index else "$(%s)" % b for b in pieces[1::2]]
            self.template = "".join(p if p[:1] == "{" and i % 2 else p.replace("{", "{{").replace("}", "}}")
                                    for i, p in enumerate(pieces))


def _first_pass_resolve(text: str, scope: SubstitutionScope) -> str:
    plan = _FIRST_PLANS.get(text)
    if plan is None:
        plan = _FirstPlan(text)
        if len(_FIRST_PLANS) < _PLAN_MAX:
            _FIRST_PLANS[text] = plan
    if plan.nothing:
        return text
    values = []
    dollar = False
    for body, cmd, args in plan.commands:
        if cmd is None:
            raise _unknown(body)
        value = _first_pass(cmd, body, args, scope)
        if "$" in value:
            dollar = True
        values.append(value)
    if plan.template is not None and not dollar:
        # every copy of a `$(...)` text gets its one value, as roslaunch's replace() gives it
        return plan.template.format(*values)
    # a value holds a '$' (it may make or be a `$(...)` text): roslaunch's replacements, one by one
    by_body = {c[0]: v for c, v in zip(plan.commands, values)}
    resolved = text
    for body in plan.order:
        resolved = resolved.replace("$(%s)" % body, by_body[body])
    return resolved


class _FindPlan:
    """What the second pass does to one first-pass result.

    roslaunch replaces the first copy of each `$(find pkg)` text in turn, together with the path
    that follows it up to a space. `steps` are (body, args) of the finds in order, up to an
    unknown command (args None). When the string is simple and no path holds a '$', the k-th
    step always meets the k-th find: `finds` are (body, args, path) of each, and `template` has
    a field for each find and its path, so that one format() does what the steps do.
    """

    __slots__ = ("steps", "finds", "template")

    def __init__(self, resolved: str):
        steps: list[tuple[str, tuple[str, ...] | None]] = []
        for body in collect_commands(resolved):
            words = body.split()
            if not words or words[0] not in VALID_COMMANDS:
                steps.append((body, None))
                break
            if words[0] == "find":
                steps.append((body, tuple(words[1:])))
        self.steps = tuple(steps)
        self.finds: tuple[tuple[str, tuple[str, ...], str], ...] = ()
        self.template: str | None = None
        if steps and steps[-1][1] is not None and _is_simple(resolved):
            finds = []
            pieces: list[str] = []
            pos = 0
            for m in _SIMPLE_COMMAND.finditer(resolved):
                words = m.group(1).split()
                if words[0] != "find":
                    continue
                j = resolved.find(" ", m.end())
                if j < 0:
                    j = len(resolved)
                path = resolved[m.end():j]
                if "$" in path:
                    return
                pieces.append(resolved[pos:m.start()].replace("{", "{{").replace("}", "}}"))
                pieces.append("{%d}" % len(finds))
                finds.append((m.group(1), tuple(words[1:]), path))
                pos = j
            pieces.append(resolved[pos:].replace("{", "{{").replace("}", "}}"))
            self.finds = tuple(finds)
            self.template = "".join(pieces)


def _find_pass_resolve(resolved: str, scope: SubstitutionScope) -> str:
    plan = _FIND_PLANS.get(resolved)
    if plan is None:
        plan = _FindPlan(resolved)
        if len(_FIND_PLANS) < _PLAN_MAX:
            _FIND_PLANS[resolved] = plan
    if plan.template is not None:
        values = []
        dollar = False
        for body, args, path in plan.finds:
            value = _find_value(body, args, path, scope)
            if "$" in value:
                dollar = True
            values.append(value)
        if not dollar:
            return plan.template.format(*values)
    for body, args in plan.steps:  # (a found path holds a '$': roslaunch's steps, one by one)
        if args is None:
            raise _unknown(body)
        resolved = _find(resolved, body, args, scope)
    return resolved


def _first_pass(cmd: str, body: str, args: tuple[str, ...], scope: SubstitutionScope) -> str:
    if cmd == "arg":
        if not args:
            raise SubstitutionError("$(arg var) must specify a variable name [%s]" % body)
        if len(args) > 1:
            raise SubstitutionError("$(arg var) may only specify one arg [%s]" % body)
        return _arg(args[0], scope)
    if cmd == "env":
        if len(args) != 1:
            raise SubstitutionError("$(env var) command only accepts one argument [%s]" % body)
        return _env(args[0], scope)
    if cmd == "optenv":
        if not args:
            raise SubstitutionError("$(optenv var) must specify an environment variable [%s]" % body)
        return scope.environ.get(args[0], " ".join(args[1:]))
    if cmd == "anon":
        if not args:
            raise SubstitutionError("$(anon var) must specify a name [%s]" % body)
        if len(args) > 1:
            raise SubstitutionError("$(anon var) may only specify one name [%s]" % body)
        return _anon(args[0], scope)
    # dirname
    return _dirname(scope)


def _arg(name: str, scope: SubstitutionScope) -> str:
    try:
        value = scope.args[name]
    except KeyError:
        raise ArgNotSet(name) from None
    scope.used_args.add(name)
    return value


def _env(name: str, scope: SubstitutionScope) -> str:
    try:
        return scope.environ[name]
    except KeyError:
        raise SubstitutionError("environment variable '%s' is not set" % name) from None


def _anon(id_: str, scope: SubstitutionScope) -> str:
    name = scope.anon.get(id_)
    if name is None:
        name = scope.anon[id_] = anonymous_name(id_)
    return name


def _dirname(scope: SubstitutionScope) -> str:
    if not scope.filename:
        raise SubstitutionError("Cannot substitute $(dirname), no file/directory information available.")
    return os.path.abspath(os.path.dirname(scope.filename))


def _find(resolved: str, body: str, args: tuple[str, ...], scope: SubstitutionScope) -> str:
    """roslaunch's step: the first copy of `$(find pkg)` and the path after it, up to a space, replaced."""
    cmd = "$(%s)" % body
    i = resolved.find(cmd)
    before, after = resolved[:i], resolved[i + len(cmd):]
    j = after.find(" ")
    path, rest = (after, "") if j < 0 else (after[:j], after[j:])
    return before + _find_value(body, args, path, scope) + rest


def _find_value(body: str, args: tuple[str, ...], path: str, scope: SubstitutionScope) -> str:
    """`$(find pkg)path`: the path decides between executable, share file and source dir."""
    if len(args) != 1:
        raise SubstitutionError("$(find pkg) command only accepts one argument [%s]" % body)
    path = path.replace("\\", "/")
    if path.startswith("/"):
        path = path[1:]
    if path:
        return scope.find_resource(args[0], path)
    return scope.find_package(args[0])


# ---------------------------------------------------------------------------
# $(eval ...)

# roslaunch's names in $(eval), looked up before the args: its constants and every name of
# the math module (sandbox.MATH: xml/sandbox.py bounds the few math functions that could run long).
_ROSLAUNCH_CONSTANTS: dict[str, Any] = {"true": True, "false": False, "True": True, "False": False}


# roslaunch's functions in $(eval), each made for the scope when an expression names it
# (named functions, not lambdas: a misuse like `arg()` is reported with the function's name)
def _eval_arg(scope: SubstitutionScope) -> Callable[[str], Any]:
    def arg(name: str) -> Any:
        return auto_value(_arg(name, scope))
    return arg


def _eval_env(scope: SubstitutionScope) -> Callable[[str], str]:
    def env(name: str) -> str:
        return _env(name, scope)
    return env


def _eval_optenv(scope: SubstitutionScope) -> Callable[..., str]:
    def optenv(name: str, default: str = "") -> str:
        return scope.environ.get(name, default)
    return optenv


def _eval_anon(scope: SubstitutionScope) -> Callable[[str], str]:
    def anon(id_: str) -> str:
        return _anon(id_, scope)
    return anon


def _eval_dirname(scope: SubstitutionScope) -> Callable[[], str]:
    def dirname() -> str:
        return _dirname(scope)
    return dirname


_SCOPE_FUNCTIONS: dict[str, Callable[[SubstitutionScope], Any]] = {
    "arg": _eval_arg, "env": _eval_env, "optenv": _eval_optenv, "anon": _eval_anon, "dirname": _eval_dirname,
    "find": lambda scope: scope.find_package}


def evaluate(expr: str, scope: SubstitutionScope) -> str:
    """`$(eval expr)`: str() of the expression, evaluated by the sandbox over roslaunch's names."""
    # roslaunch's own refusal, kept for its message (the sandbox needs no such rule)
    if "__" in expr:
        raise SubstitutionError("$(eval ...) may not contain double underscore expressions")
    # (imported here: the sandbox and `ast` cost ~2.5 ms to import, and most launches have no $(eval))
    from launcher.xml import sandbox

    def lookup(name: str) -> Any:  # roslaunch's _DictWrapper: its names, then the args auto-typed
        if name in _ROSLAUNCH_CONSTANTS:
            return _ROSLAUNCH_CONSTANTS[name]
        if name in sandbox.MATH:
            return sandbox.MATH[name]
        make = _SCOPE_FUNCTIONS.get(name)
        if make is not None:
            return make(scope)
        value = scope.args[name]  # (KeyError: not an arg; the sandbox goes on to its builtins)
        scope.used_args.add(name)
        return auto_value(value)

    try:
        return str(sandbox.evaluate(expr, lookup))
    except sandbox.EvalError as e:
        raise SubstitutionError("$(eval %s) failed: %s" % (expr.strip(), e)) from None
    except ValueError as e:  # str() of a value Python will not print (an int past its digit limit)
        raise SubstitutionError("$(eval %s) failed: %s" % (expr.strip(), e)) from None
