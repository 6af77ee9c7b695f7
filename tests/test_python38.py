"""The package runs on Python 3.8 (Ubuntu 20.04's, the ros:noetic images'): what came after it is found in the source
here, on every Python, and CI runs the unit tier on 3.8 itself (which finds the rest: syntax, a removed parameter).

A minimum-version linter reads annotations and syntax; the two mistakes this project made were neither: a
union of types evaluated at run time (`_Network = ipaddress.IPv4Network | ipaddress.IPv6Network`, 3.10) and a
method that 3.8's str lacks (`removeprefix`, 3.9). Newer calls go through launcher/compat.py, the one place
that may name them.
"""

from __future__ import annotations

import ast
import builtins
import os

import pytest

from helpers import ROOT

PACKAGE = os.path.join(ROOT, "launcher")
COMPAT = os.path.join(PACKAGE, "compat.py")

# module attribute -> the Python that brought it
NEWER_CALLS = {
    ("asyncio", "to_thread"): "3.9", ("asyncio", "timeout"): "3.11", ("asyncio", "TaskGroup"): "3.11",
    ("asyncio", "Runner"): "3.11", ("os", "pidfd_open"): "3.9", ("os", "P_PIDFD"): "3.9", ("os", "splice"): "3.10",
    ("os", "eventfd"): "3.10", ("functools", "cache"): "3.9", ("math", "lcm"): "3.9", ("typing", "TypeAlias"): "3.10",
    ("typing", "ParamSpec"): "3.10", ("typing", "Self"): "3.11", ("typing", "TypeGuard"): "3.10",
    ("itertools", "pairwise"): "3.10", ("itertools", "batched"): "3.12", ("random", "randbytes"): "3.9",
    ("contextlib", "aclosing"): "3.10", ("contextlib", "chdir"): "3.11", ("zoneinfo", None): "3.9",
    ("tomllib", None): "3.11", ("graphlib", None): "3.9",
    ("asyncio", "wait_for"): "3.12",  # (there before, but it lost a cancel that came as its awaitable completed)
}
# methods of built-in types that 3.8 lacks: whatever the object, the name alone is suspect
NEWER_METHODS = {"removeprefix": "3.9", "removesuffix": "3.9", "bit_count": "3.10", "is_relative_to": "3.9",
                 "with_stem": "3.9"}
BUILTIN_TYPES = {n for n in dir(builtins) if isinstance(getattr(builtins, n), type)} | {"None"}


def _sources():
    for folder, dirs, files in os.walk(PACKAGE):
        dirs[:] = [d for d in dirs if d != "__pycache__"]
        for name in sorted(files):
            path = os.path.join(folder, name)
            if name.endswith(".py") and path != COMPAT:
                yield os.path.relpath(path, ROOT), path


def _annotations(tree: ast.AST) -> set[int]:
    """ids of every node inside an annotation: not evaluated at run time under `from __future__ import
    annotations` (which every module of the package has: checked below)."""
    roots = []
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            roots += [a.annotation for a in node.args.args + node.args.kwonlyargs + node.args.posonlyargs]
            roots += [node.args.vararg and node.args.vararg.annotation, node.args.kwarg and node.args.kwarg.annotation,
                      node.returns]
        elif isinstance(node, ast.AnnAssign):
            roots.append(node.annotation)
    return {id(n) for root in roots if root is not None for n in ast.walk(root)}


def _typelike(node: ast.AST) -> bool:
    """A name that reads as a type: a builtin type, None, or a CamelCase name (constants are ALL_CAPS: `re.I | re.M`
    is no union)."""
    if isinstance(node, ast.Constant) and node.value is None:
        return True
    if isinstance(node, ast.Subscript):
        return _typelike(node.value)
    name = node.id if isinstance(node, ast.Name) else node.attr if isinstance(node, ast.Attribute) else None
    if name is None:
        return False
    return name in BUILTIN_TYPES or (name[0].isupper() and any(c.islower() for c in name))


def newer_than_38(source: str) -> list[str]:
    """What in `source` needs a Python newer than 3.8, one line each (line number first)."""
    tree = ast.parse(source)
    in_annotation = _annotations(tree)
    found = []
    for node in ast.walk(tree):
        if id(node) in in_annotation:
            continue
        line = getattr(node, "lineno", 0)
        if type(node).__name__ == "Match":
            found.append("%d: a match statement (3.10)" % line)
        elif isinstance(node, ast.BinOp) and isinstance(node.op, ast.BitOr) and (
                _typelike(node.left) and _typelike(node.right)):
            found.append("%d: a union of types evaluated at run time (3.10): use typing.Union/Optional" % line)
        elif isinstance(node, ast.Subscript) and isinstance(node.value, ast.Name) and node.value.id in (
                "list", "dict", "tuple", "set", "frozenset", "type"):
            found.append("%d: %s[...] evaluated at run time (3.9): use typing's" % (line, node.value.id))
        elif isinstance(node, ast.Attribute):
            base = node.value.id if isinstance(node.value, ast.Name) else None
            if (base, node.attr) in NEWER_CALLS:
                found.append("%d: %s.%s (%s): through launcher.compat" % (line, base, node.attr,
                                                                          NEWER_CALLS[base, node.attr]))
            elif node.attr in NEWER_METHODS and base != "compat":
                found.append("%d: .%s() (%s): through launcher.compat" % (line, node.attr, NEWER_METHODS[node.attr]))
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            for alias in node.names:
                key = (node.module, alias.name)
                if key in NEWER_CALLS:
                    found.append("%d: from %s import %s (%s)" % (line, node.module, alias.name, NEWER_CALLS[key]))
            if (node.module, None) in NEWER_CALLS:
                found.append("%d: the module %s (%s)" % (line, node.module, NEWER_CALLS[node.module, None]))
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if (alias.name, None) in NEWER_CALLS:
                    found.append("%d: the module %s (%s)" % (line, alias.name, NEWER_CALLS[alias.name, None]))
    for call in (n for n in ast.walk(tree) if isinstance(n, ast.Call)):
        if isinstance(call.func, ast.Name) and call.func.id == "zip" and any(k.arg == "strict" for k in call.keywords):
            found.append("%d: zip(strict=) (3.10)" % call.lineno)
    return sorted(found, key=lambda s: int(s.split(":")[0]))


@pytest.mark.parametrize("rel,path", list(_sources()), ids=[rel for rel, _ in _sources()])
def test_nothing_newer_than_38(rel, path):
    with open(path) as f:
        source = f.read()
    assert newer_than_38(source) == [], "%s needs a newer Python than 3.8" % rel


@pytest.mark.parametrize("rel,path", list(_sources()), ids=[rel for rel, _ in _sources()])
def test_annotations_are_not_evaluated(rel, path):
    """Annotations may use 3.10's `X | None` only where they are never evaluated."""
    with open(path) as f:
        tree = ast.parse(f.read())
    has_annotations = bool(_annotations(tree))
    future = any(isinstance(n, ast.ImportFrom) and n.module == "__future__" and
                 any(a.name == "annotations" for a in n.names) for n in tree.body)
    assert future or not has_annotations, "%s: annotations without `from __future__ import annotations`" % rel


@pytest.mark.parametrize("code,what", [
    ("import ipaddress\n_Network = ipaddress.IPv4Network | ipaddress.IPv6Network\n", "union of types"),
    ("x = isinstance(v, int | None)\n", "union of types"),
    ("name = path.removeprefix('TEST-')\n", ".removeprefix()"),
    ("import asyncio\nasync def f():\n    await asyncio.to_thread(print)\n", "asyncio.to_thread"),
    ("import os\nfd = os.pidfd_open(1)\n", "os.pidfd_open"),
    ("import asyncio\nasync def f(w):\n    await asyncio.wait_for(w, 1)\n", "asyncio.wait_for"),
    ("from functools import cache\n", "import cache"),
    ("Rows = list[tuple[int, str]]\n", "list[...]"),
    ("for a, b in zip(x, y, strict=True):\n    pass\n", "zip(strict=)"),
])
def test_the_check_finds_what_it_must(code, what):
    """Each kind of mistake, the two this project made among them, is found."""
    found = newer_than_38(code)
    assert any(what in line for line in found), found


@pytest.mark.parametrize("code", [
    "from __future__ import annotations\ndef f(x: int | None) -> list[str]: ...\n",
    "import re\nflags = re.I | re.M\n",
    "import os\nflags = os.O_RDONLY | os.O_CLOEXEC\nos.readlink('/proc/self/exe')\n",
    "a = {1} | {2}\n",
    "from typing import Optional, Union\nX = Union[int, str]\n",
])
def test_the_check_passes_what_38_runs(code):
    assert newer_than_38(code) == []
