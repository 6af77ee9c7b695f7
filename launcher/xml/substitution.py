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

import os.path
import re
from typing import Any, Callable, Mapping

from launcher.names import anonymous_name
from launcher.params.values import auto_value
from launcher.xml import sandbox

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

    __slots__ = ("args", "anon", "filename", "environ", "find_package", "find_resource")

    def __init__(self, args: Mapping[str, str], anon: dict[str, str], filename: str | None,
                 environ: Mapping[str, str], find_package: Callable[[str], str],
                 find_resource: Callable[[str, str], str]):
        self.args = args
        self.anon = anon
        self.filename = filename
        self.environ = environ
        self.find_package = find_package
        self.find_resource = find_resource


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
    resolved = text
    for placeholder, body, cmd, args in _first_pass_plan(text):
        if placeholder is None:
            raise SubstitutionError("Unknown substitution command [%s]. Valid commands are %s"
                                    % (body, list(VALID_COMMANDS)))
        resolved = resolved.replace(placeholder, _first_pass(cmd, body, args, scope))
    if "$" in resolved:
        for body, args in _find_plan(resolved):
            if args is None:
                raise SubstitutionError("Unknown substitution command [%s]. Valid commands are %s"
                                        % (body, list(VALID_COMMANDS)))
            resolved = _find(resolved, body, args, scope)
    return resolved


# A launch tree repeats the same attribute texts many times (the same include's nodes and
# params, once per include): what a text asks for is worked out once per distinct text. The
# plans depend on the text alone; the values come from the scope at every use.
_PLAN_MAX = 16384
_FIRST_PLANS: dict[str, tuple[tuple[Any, ...], ...]] = {}
_FIND_PLANS: dict[str, tuple[tuple[Any, ...], ...]] = {}


def _first_pass_plan(text: str) -> tuple[tuple[Any, ...], ...]:
    """(placeholder, body, command, args) for each non-find command of `text`, in order; an
    unknown command is a step with placeholder None, where resolution stops with its error."""
    plan = _FIRST_PLANS.get(text)
    if plan is None:
        steps: list[tuple[Any, ...]] = []
        for body in collect_commands(text):  # (raises for a malformed text: nothing cached)
            words = body.split()
            if not words or words[0] not in VALID_COMMANDS:
                steps.append((None, body, None, None))
                break
            if words[0] != "find":
                steps.append(("$(%s)" % body, body, words[0], tuple(words[1:])))
        plan = tuple(steps)
        if len(_FIRST_PLANS) < _PLAN_MAX:
            _FIRST_PLANS[text] = plan
    return plan


def _find_plan(resolved: str) -> tuple[tuple[Any, ...], ...]:
    """(body, args) for each `$(find)` of the first pass's result, in order; an unknown command
    is a step with args None, where resolution stops with its error."""
    plan = _FIND_PLANS.get(resolved)
    if plan is None:
        steps: list[tuple[Any, ...]] = []
        for body in collect_commands(resolved):
            words = body.split()
            if not words or words[0] not in VALID_COMMANDS:
                steps.append((body, None))
                break
            if words[0] == "find":
                steps.append((body, tuple(words[1:])))
        plan = tuple(steps)
        if len(_FIND_PLANS) < _PLAN_MAX:
            _FIND_PLANS[resolved] = plan
    return plan


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
        return scope.args[name]
    except KeyError:
        raise ArgNotSet(name) from None


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
    if len(args) != 1:
        raise SubstitutionError("$(find pkg) command only accepts one argument [%s]" % body)
    cmd = "$(%s)" % body
    i = resolved.find(cmd)
    before, after = resolved[:i], resolved[i + len(cmd):]
    # the path that follows, up to the first space, decides between executable, share file and source dir
    j = after.find(" ")
    path, rest = (after, "") if j < 0 else (after[:j], after[j:])
    path = path.replace("\\", "/")
    if path.startswith("/"):
        path = path[1:]
    if path:
        return before + scope.find_resource(args[0], path) + rest
    return before + scope.find_package(args[0]) + rest


# ---------------------------------------------------------------------------
# $(eval ...)

# roslaunch's names in $(eval), looked up before the args: its constants and every name of
# the math module (xml/sandbox.py bounds the few math functions that could run long).
_ROSLAUNCH_NAMES: dict[str, Any] = {**sandbox.MATH, "true": True, "false": False, "True": True, "False": False}


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

    def lookup(name: str) -> Any:  # roslaunch's _DictWrapper: its names, then the args auto-typed
        if name in _ROSLAUNCH_NAMES:
            return _ROSLAUNCH_NAMES[name]
        make = _SCOPE_FUNCTIONS.get(name)
        if make is not None:
            return make(scope)
        return auto_value(scope.args[name])

    try:
        return str(sandbox.evaluate(expr, lookup))
    except sandbox.EvalError as e:
        raise SubstitutionError("$(eval %s) failed: %s" % (expr.strip(), e)) from None
    except ValueError as e:  # str() of a value Python will not print (an int past its digit limit)
        raise SubstitutionError("$(eval %s) failed: %s" % (expr.strip(), e)) from None
