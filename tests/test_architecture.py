"""The layering of docs/ARCHITECTURE.md, checked on the source: which part may import which, and no cycles."""

from __future__ import annotations

import ast
import os

import pytest

ROOT = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "launcher")


def _unit(module: str) -> str:
    """The part a module belongs to: a subpackage (`launcher.net`) or a top-level module (`launcher.api`)."""
    parts = module.split(".")
    return ".".join(parts[:2])


def _modules():
    """(module name, its syntax tree) for every module of the package."""
    for dirpath, _dirs, files in os.walk(ROOT):
        for f in files:
            if f.endswith(".py"):
                path = os.path.join(dirpath, f)
                rel = os.path.relpath(path, os.path.dirname(ROOT))[:-3].replace(os.sep, ".")
                with open(path) as source:
                    yield rel[:-9] if rel.endswith(".__init__") else rel, ast.parse(source.read())


def _imports() -> dict[str, set[str]]:
    """module -> the launcher modules it imports (at any depth in the file)."""
    graph: dict[str, set[str]] = {}
    for module, tree in _modules():
        found = set()
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                found.update(a.name for a in node.names if a.name.startswith("launcher"))
            elif isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("launcher"):
                found.add(node.module)
                found.update("%s.%s" % (node.module, a.name) for a in node.names)
        graph[module] = {m for m in found if m != "launcher"}
    return graph


def _calls_import_module(tree: ast.AST) -> bool:
    return any(isinstance(n, ast.Call) and (getattr(n.func, "attr", None) == "import_module"
                                            or getattr(n.func, "id", None) in ("import_module", "__import__"))
               for n in ast.walk(tree))


def _imports_by_name(modules: set[str]) -> dict[str, set[str]]:
    """module -> the launcher modules it imports by name (`importlib.import_module`): in a module that calls it,
    each string that names a module of ours, alone or as `module:function` (`cli/tool.py`'s subcommand table).
    An import by name runs once every module is loaded, so it makes no import-time cycle; it is a dependency
    all the same, and counts for the layers and for purity."""
    found: dict[str, set[str]] = {}
    for module, tree in _modules():
        if _calls_import_module(tree):
            named = {n.value.partition(":")[0] for n in ast.walk(tree)
                     if isinstance(n, ast.Constant) and isinstance(n.value, str)}
            found[module] = {m for m in named if m in modules and m not in (module, "launcher")}
    return found


GRAPH = _imports()
BY_NAME = _imports_by_name(set(GRAPH))
UNITS: dict[str, set[str]] = {}
for _mod, _deps in list(GRAPH.items()) + list(BY_NAME.items()):
    UNITS.setdefault(_unit(_mod), set()).update(_unit(d) for d in _deps if _unit(d) != _unit(_mod))
UNITS = {u: {d for d in deps if d in UNITS} for u, deps in UNITS.items()}

# part -> the parts it may import (docs/ARCHITECTURE.md, "The layers"), lowest layer first; every part is listed
_ = "launcher."
MAY_IMPORT = {_ + part: {_ + d for d in deps.split()} for part, deps in {
    "model": "",
    "net": "",
    "workspace": "model",
    "plan": "model workspace",
    "fleet": "model plan",
    "params": "model workspace",
    "output": "model workspace fleet",
    "health": "model net fleet",
    "xml": "model workspace params",
    "master": "model net params",
    "bag": "model net",
    "process": "model workspace fleet output plan",
    "remote": "model net workspace fleet output health xml process plan",
    "services": "model net workspace params fleet output health xml master process plan remote",
    "run": "model net workspace fleet output xml master process plan remote services",
    "operate": "model net workspace fleet",  # the operator's client reads a run through its server only
    "rostest": "model workspace output xml process plan services run",
    "cli": "model net workspace params fleet output xml bag process plan remote rostest run operate",
    "api": "model workspace operate",  # a run needs the main thread's signals: the API runs `launch` as a child
    "pytest_plugin": "api",
    "__main__": "cli",
    "compat": "",  # what differs between Python 3.8 and 3.13: below every part, which all may import
}.items()}
for _part in MAY_IMPORT:
    if _part != _ + "compat":
        MAY_IMPORT[_part].add(_ + "compat")
# module -> the only modules of ours it may import: the bottom of the tree, which everything else stands on
ONLY = {_ + module: {_ + d for d in deps.split()} for module, deps in {
    "model.names": "", "model.errors": "", "model.units": "", "model.suggest": "", "model.shellwords": "",
    "model.record": "", "model.runopts": "model.record", "model.token": "", "model.patterns": "",
    "model.config": "model.names model.record", "model.graph": "model.record",
    "workspace.roshome": "", "workspace.nodepython": "", "workspace.crawlcache": "workspace.roshome",
    "master.callstats": "",
}.items()}


def test_every_part_is_in_the_table():
    assert set(UNITS) - {"launcher"} == set(MAY_IMPORT)


@pytest.mark.parametrize("unit", sorted(MAY_IMPORT))
def test_parts_import_only_the_layers_below(unit):
    assert UNITS.get(unit, set()) <= MAY_IMPORT[unit], UNITS.get(unit, set()) - MAY_IMPORT[unit]


@pytest.mark.parametrize("module", sorted(ONLY))
def test_modules_that_import_little(module):
    ours = {m for m in GRAPH[module] if m.rpartition(".")[0] in GRAPH or m in GRAPH}
    ours = {m if m in GRAPH else m.rpartition(".")[0] for m in ours}
    assert ours <= ONLY[module], ours - ONLY[module]


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


# Who may ask a master about registrations (lookupNode, getSystemState): the master itself, and the watcher of a
# master found running (services/masterwatch.py), which tells the run's graph. The launch's own parts (readiness,
# hang, stall, systemd's READY=1, the bound holds) listen to the graph and the fleet instead of asking.
REGISTRATION_CALLS = ("lookupNode", "getSystemState")
MAY_ASK_REGISTRATIONS = ("launcher.master", "launcher.services.masterwatch")
# ROS clients that are no part of a launch's supervision, and ask as the ROS tool they stand for does: `bag record
# --node` (rosbag asks which topics the node has), the web view's topic list (a process apart, as rostopic
# list), the Python API's wait for a publisher (a test's client of the graph)
CLIENTS = {"launcher.bag.record": "rosbag record --node", "launcher.operate.web": "the page's topic list",
           "launcher.api": "Launch.wait_for_topic"}


def _registration_calls() -> dict[str, list[int]]:
    """module -> the lines where it names a registration call (a method name given to a call, or an attribute)."""
    found: dict[str, list[int]] = {}
    for module, tree in _modules():
        for node in ast.walk(tree):
            named = (node.value if isinstance(node, ast.Constant) else
                     node.attr if isinstance(node, ast.Attribute) else None)
            if named in REGISTRATION_CALLS:
                found.setdefault(module, []).append(node.lineno)
    return found


def test_only_the_master_and_its_watcher_ask_about_registrations():
    calls = _registration_calls()
    asking = {m: lines for m, lines in calls.items()
              if not any(m == p or m.startswith(p + ".") for p in MAY_ASK_REGISTRATIONS) and m not in CLIENTS}
    assert asking == {}, "asks the master about registrations (listen to model.graph / the fleet instead)"
    assert "launcher.services.masterwatch" in calls  # (the check sees what it looks for)
    assert set(CLIENTS) <= set(calls), "a client no longer asks: take it off the list"


def test_the_metrics_are_made_in_one_module():
    """prometheus_client is the exporter's (services/metrics.py) alone: the rest of the launch counts in plain
    data (master/callstats.py, the fleet) and never pays for the library's import or its locks."""
    users = set()
    for dirpath, _dirs, files in os.walk(ROOT):
        for f in files:
            if f.endswith(".py"):
                tree = ast.parse(open(os.path.join(dirpath, f)).read())
                for node in ast.walk(tree):
                    names = ([a.name for a in node.names] if isinstance(node, ast.Import) else
                             [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
                    if any(n.split(".")[0] == "prometheus_client" for n in names):
                        users.add(os.path.relpath(os.path.join(dirpath, f), ROOT))
    assert users == {os.path.join("services", "metrics.py")}


def test_no_import_cycle_between_modules():
    """Inside a package too (issue 33): no module imports one that imports it back, through any chain. A module
    names a sibling by its own path (`import launcher.master.registry as reg`), not through the package's
    __init__, which imports the package's modules."""
    seen: dict[str, int] = {}

    def visit(m: str, path: list[str]) -> None:
        seen[m] = 1
        for d in sorted(GRAPH.get(m, ())):
            if d not in GRAPH:
                continue
            if seen.get(d) == 1:
                raise AssertionError("import cycle: %s" % " -> ".join(path[path.index(d):] + [m, d]))
            if d not in seen:
                visit(d, path + [m])
        seen[m] = 2

    for m in sorted(GRAPH):
        if m not in seen:
            visit(m, [])


# The pure modules (docs/ARCHITECTURE.md, "Protocols sans I/O"): state machines, decisions and codecs, functions of
# what they are fed and a clock given to them, tested without sockets, processes or the wall clock. Each imports
# none of I/O_MODULES, at any depth in its file or by name, and neither does any module of ours it loads (what
# those run when imported: a function's own lazy import, such as `model.names.anonymous_name`'s socket, is that
# function's, which no pure module calls).
PURE = [_ + module for module in (
    "fleet.lifecycle",  # the node state machine
    "fleet.launchphase",  # the launch's phase
    "fleet.actions",  # the node table's actions carried out
    "fleet.restart",  # the restart decision
    "fleet.lastexit",  # a node's last exit, kept by every reader of its changes
    "fleet.relations",  # what the bound-node relations make follow a change, and the stop order
    "plan.diff",  # a reload's difference of two plans
    "plan.remote",  # the nodes of other machines, binned, and the load's checks of them
    "plan.plan",  # what a run runs: the loaded launch, its master URI, its other machines
    "plan.relations",  # who is bound to whom and who waits for whom, from the nodes' policies
    "remote.session",  # a machine's session with its child
    "master.outbox",  # which callback to a node goes when
    "net.http",  # HTTP/1.1 framing
    "net.xmlrpc_codec",  # XML-RPC requests, responses and faults
    "net.tcpros",  # TCPROS connection headers and frames
    "net.linkstate",  # a TCPROS connection's handshake and end, at either side, and when a publisher is tried again
    "operate.view",  # the live view's state
    "operate.columns",  # a node's columns and a change's words, which the view draws
)]
I_O_MODULES = {"asyncio", "socket", "os", "time", "subprocess", "threading"}
def _stdlib_imports(tree: ast.AST, top_only: bool) -> set[str]:
    """The top-level names of the modules a syntax tree imports: at any depth, or what runs at import only."""
    nodes = ast.walk(tree) if not top_only else _run_at_import(tree)
    found = set()
    for node in nodes:
        if isinstance(node, ast.Import):
            found.update(a.name.split(".")[0] for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            found.add(node.module.split(".")[0])
        elif isinstance(node, ast.Call) and isinstance(node.func, (ast.Attribute, ast.Name)) and node.args:
            name = getattr(node.func, "attr", None) or getattr(node.func, "id", None)
            if name in ("import_module", "__import__") and isinstance(node.args[0], ast.Constant):
                found.add(str(node.args[0].value).split(".")[0])
    return found


def _run_at_import(tree: ast.AST):
    """The nodes a module runs when imported: all but the bodies of its functions."""
    todo = [tree]
    while todo:
        node = todo.pop()
        yield node
        todo.extend(c for c in ast.iter_child_nodes(node) if not isinstance(c, (ast.FunctionDef, ast.AsyncFunctionDef,
                                                                                  ast.Lambda)))


TREES = dict(_modules())


def _ours(names: set[str]) -> set[str]:
    """The modules of ours among imported names (`from launcher.fleet import lifecycle` names
    launcher.fleet.lifecycle)."""
    return {n if n in GRAPH else n.rpartition(".")[0] for n in names
            if n not in ("launcher", "launcher.__init__") and (n in GRAPH or n.rpartition(".")[0] in GRAPH)} - {"launcher"}


def _imports_at_import(tree: ast.AST) -> set[str]:
    """The modules of ours a module imports when it is itself imported."""
    found = set()
    for node in _run_at_import(tree):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("launcher"):
            found.add(node.module)
            found.update("%s.%s" % (node.module, a.name) for a in node.names)
    return _ours(found)


def _packages_of(module: str) -> set[str]:
    parts = module.split(".")
    return {".".join(parts[:i]) for i in range(2, len(parts))}


def _io_loaded_by(module: str) -> dict[str, set[str]]:
    """module -> the I/O modules it imports: `module` itself at any depth (and by name), then each module of ours
    it loads, at import (not followed past `stop_at`)."""
    bad = {}
    own = _stdlib_imports(TREES[module], top_only=False) & I_O_MODULES
    if own:
        bad[module] = own
    seen, todo = {module}, sorted(_ours(GRAPH[module] | BY_NAME.get(module, set())) | _packages_of(module))
    while todo:
        m = todo.pop()
        if m in seen:
            continue
        seen.add(m)
        todo.extend(_packages_of(m))  # (importing launcher.a.b runs launcher/a/__init__.py first)
        found = _stdlib_imports(TREES[m], top_only=True) & I_O_MODULES
        if found:
            bad[m] = found
        todo.extend(_imports_at_import(TREES[m]))
    return bad


@pytest.mark.parametrize("module", PURE)
def test_pure_modules_import_no_io(module):
    bad = _io_loaded_by(module)
    assert bad == {}, "loads I/O: %s" % bad


def test_the_purity_check_sees_io():
    """(the check sees what it looks for: modules known to do I/O are found doing it, directly and through others)"""
    assert _io_loaded_by(_ + "net.xmlrpc")[_ + "net.xmlrpc"] >= {"socket"}
    assert {_ + "fleet.state", _ + "compat"} <= set(_io_loaded_by(_ + "output.narrate"))  # (compat: through state)
    assert _io_loaded_by(_ + "xml.sandbox").get(_ + "xml") == {"os"}  # (its package's __init__, loaded first)
    lazy = ast.parse("def f():\n    import socket\nimport re\n")
    assert _stdlib_imports(lazy, top_only=True) == {"re"} and _stdlib_imports(lazy, top_only=False) == {"re", "socket"}
