"""The tables' tests check what each transition does, not only where it goes: every `Action(...)` of the node's
table (`launcher/fleet/lifecycle.py`) and of the launch's (`launcher/fleet/launchphase.py`) made a no-op in turn (the
call replaced by `Action(NOTE)`, a note with no words) is caught by that table's own unit tests
(tests/fleet/test_lifecycle.py, tests/fleet/test_launchphase.py). 0 survivors."""

from __future__ import annotations

import ast
import concurrent.futures
import os
import subprocess
import sys

import pytest

from helpers import ROOT

# each table (a module of launcher.fleet), with its own unit tests, and how many Action(...) sites it has at least
TABLES = {"lifecycle": ("test_lifecycle.py", 20), "launchphase": ("test_launchphase.py", 5)}

# Runs a table's tests with launcher.fleet.<argv[3]> made from the source in argv[1] (installed before anything
# imports it: launcher.fleet.state, which the tests use too, takes the same module).
RUN = r"""
import sys, types
import launcher.fleet as package
source, name = open(sys.argv[1]).read(), sys.argv[3]
module = types.ModuleType("launcher.fleet." + name)
module.__file__ = sys.argv[1]
sys.modules["launcher.fleet." + name] = module
setattr(package, name, module)
exec(compile(source, "launcher/fleet/%s.py (mutant)" % name, "exec"), module.__dict__)
import pytest
sys.exit(pytest.main([sys.argv[2], "-x", "-q", "-p", "no:cacheprovider", "-p", "no:randomly"]))
"""


def action_sites(source: str) -> list[ast.Call]:
    """Every call of Action(...) in the module, in the order of the source."""
    calls = [n for n in ast.walk(ast.parse(source)) if isinstance(n, ast.Call)
             and isinstance(n.func, ast.Name) and n.func.id == "Action"]
    return sorted(calls, key=lambda c: (c.lineno, c.col_offset))


def mutant(source: str, call: ast.Call) -> str:
    """The source with `call` replaced by Action(NOTE)."""
    lines = source.splitlines(keepends=True)
    start = sum(len(line) for line in lines[:call.lineno - 1]) + call.col_offset
    end = sum(len(line) for line in lines[:call.end_lineno - 1]) + call.end_col_offset
    return source[:start] + "Action(NOTE)" + source[end:]


def table_tests(table: str, source: str, tmp_path, name: str) -> subprocess.CompletedProcess:
    path = tmp_path / ("%s.py" % name)
    path.write_text(source)
    tests = os.path.join(ROOT, "tests", "fleet", TABLES[table][0])
    return subprocess.run([sys.executable, "-c", RUN, str(path), tests, table], cwd=ROOT, capture_output=True,
                          text=True, timeout=600, env=dict(os.environ, PYTHONPATH=ROOT))


@pytest.mark.parametrize("table", sorted(TABLES))
def test_every_action_of_the_table_made_a_no_op_is_caught_by_its_tests(table, tmp_path):
    source = open(os.path.join(ROOT, "launcher", "fleet", table + ".py")).read()
    sites = action_sites(source)
    assert len(sites) >= TABLES[table][1]  # (the check finds what it looks for)
    baseline = table_tests(table, source, tmp_path, "unchanged")
    assert baseline.returncode == 0, baseline.stdout[-3000:] + baseline.stderr[-3000:]
    mutated = [(i, call) for i, call in enumerate(sites) if ast.get_source_segment(source, call) != "Action(NOTE)"]  # (else: no mutant)
    with concurrent.futures.ThreadPoolExecutor(2) as pool:  # (each run is a process of its own)
        runs = list(pool.map(lambda ic: table_tests(table, mutant(source, ic[1]), tmp_path, "mutant%d" % ic[0]),
                             mutated))
    # 1: a test failed (anything else, 0 or a broken run, caught nothing)
    survivors = [table + ".py:%d %s (pytest exit %d)" % (call.lineno, ast.get_source_segment(source, call), run.returncode)
                 for (_, call), run in zip(mutated, runs) if run.returncode != 1]
    assert survivors == []
