"""The layering of docs/ARCHITECTURE.md, checked on the source: which part may import which, and no cycles."""

from __future__ import annotations

import ast
import os

import pytest

ROOT = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "launcher")


def _unit(module: str) -> str:
    """The part a module belongs to: a subpackage (`launcher.net`) or a top-level module (`launcher.runtime`)."""
    parts = module.split(".")
    return ".".join(parts[:2])


def _imports() -> dict[str, set[str]]:
    """module -> the launcher modules it imports (at any depth in the file)."""
    graph: dict[str, set[str]] = {}
    for dirpath, _dirs, files in os.walk(ROOT):
        for f in files:
            if not f.endswith(".py"):
                continue
            path = os.path.join(dirpath, f)
            rel = os.path.relpath(path, os.path.dirname(ROOT))[:-3].replace(os.sep, ".")
            module = rel[:-9] if rel.endswith(".__init__") else rel
            found = set()
            for node in ast.walk(ast.parse(open(path).read())):
                if isinstance(node, ast.Import):
                    found.update(a.name for a in node.names if a.name.startswith("launcher"))
                elif isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("launcher"):
                    found.add(node.module)
                    found.update("%s.%s" % (node.module, a.name) for a in node.names)
            graph[module] = {m for m in found if m != "launcher"}
    return graph


GRAPH = _imports()
UNITS: dict[str, set[str]] = {}
for _mod, _deps in GRAPH.items():
    UNITS.setdefault(_unit(_mod), set()).update(_unit(d) for d in _deps if _unit(d) != _unit(_mod))
UNITS = {u: {d for d in deps if d in UNITS} for u, deps in UNITS.items()}

# part -> the only parts it may import (docs/ARCHITECTURE.md, "The parts")
ONLY = {
    "launcher.names": set(),
    "launcher.errors": set(),
    "launcher.roshome": set(),
    "launcher.units": set(),
    "launcher.runopts": set(),
    "launcher.suggest": set(),
    "launcher.shellwords": set(),
    "launcher.config": {"launcher.names"},
    "launcher.nodepython": set(),
}
# part -> parts it must not import
NEVER = {
    "launcher.params": {"launcher.xml", "launcher.process", "launcher.net", "launcher.master", "launcher.runtime"},
    "launcher.packages": {"launcher.xml", "launcher.process", "launcher.net", "launcher.master"},
    "launcher.xml": {"launcher.process", "launcher.net", "launcher.master", "launcher.runtime"},
    "launcher.net": {"launcher.xml", "launcher.process", "launcher.master", "launcher.runtime", "launcher.config"},
    "launcher.master": {"launcher.xml", "launcher.process", "launcher.runtime", "launcher.config"},
    "launcher.process": {"launcher.xml", "launcher.runtime", "launcher.introspect"},
    "launcher.runtime": {"launcher.introspect", "launcher.cli"},
    "launcher.plan": {"launcher.xml", "launcher.net", "launcher.master", "launcher.remote", "launcher.operate",
                      "launcher.runtime", "launcher.cli", "launcher.child", "launcher.masterlink"},
    "launcher.child": {"launcher.cli", "launcher.runtime"},
    # a run's services: each knows its own collaborators, none the run that orders them
    "launcher.masterlink": {"launcher.runtime", "launcher.nodeservice", "launcher.servers", "launcher.remote",
                            "launcher.operate", "launcher.cli"},
    "launcher.nodeservice": {"launcher.runtime", "launcher.servers", "launcher.masterlink", "launcher.operate",
                             "launcher.xml", "launcher.cli"},
    "launcher.servers": {"launcher.runtime", "launcher.nodeservice", "launcher.masterlink", "launcher.remote",
                         "launcher.cli"},
    # the API server sees a narrow view of the run (servers.RunView), never the run or its services
    "launcher.operate": {"launcher.runtime", "launcher.servers", "launcher.nodeservice", "launcher.masterlink",
                         "launcher.cli"},
}


@pytest.mark.parametrize("unit", sorted(ONLY))
def test_parts_that_import_little(unit):
    assert UNITS.get(unit, set()) <= ONLY[unit], UNITS.get(unit, set()) - ONLY[unit]


@pytest.mark.parametrize("unit", sorted(NEVER))
def test_parts_that_must_not_import_others(unit):
    assert not (UNITS.get(unit, set()) & NEVER[unit]), UNITS.get(unit, set()) & NEVER[unit]


def test_no_import_cycle_between_parts():
    seen: dict[str, int] = {}  # 1: on the path, 2: done

    def visit(u: str, path: list[str]) -> None:
        seen[u] = 1
        for d in sorted(UNITS.get(u, ())):
            if seen.get(d) == 1:
                raise AssertionError("import cycle: %s" % " -> ".join(path[path.index(d):] + [u, d]))
            if d not in seen:
                visit(d, path + [u])
        seen[u] = 2

    for u in sorted(UNITS):
        if u not in seen:
            visit(u, [])
