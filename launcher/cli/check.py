"""`launcher check [pkg] file.launch [name:=value ...]`: the static checker of launch files, over every if/unless branch.

Nothing is started. The files are loaded by the real loader (`xml.XmlLoader`):
once with the args given, then once for each combination of the values the
file can produce for the args a user may set (declared with a default, or
required, in a top file) that decide an `if`/`unless`: `true` and `false` for
an arg read as a boolean (`$(arg sim)`, a name in `$(eval ...)`, or a boolean
arg the files pass on: it may decide a condition in an included file under
another name), and for an arg a `$(eval ...)` condition compares with literals
(`arg('mode') == 'sim'`, `mode != 'real'`, `mode in ['a', 'b']`; also in
an included file, on an arg its `<include>` sets to `$(arg robot_mode)`), those
literals and its default. Only a top file's args are varied: an included
file's args are set by its `<include>` (or their default), never by the
command line, so the top file's values are all the values they can take.

Each load's error (roslaunch would refuse the file: kind "load"), and what the
loaded configuration gets wrong at run time (kind "run": a node or test whose
package or executable does not exist, a `machine=` that names no `<machine>`,
a `$(find pkg)/path` that does not exist, a parameter XML-RPC cannot send: a
YAML date or null, an integer beyond 32 bits), is a finding with file:line and the
include chain, and, when found only with other arg values, the args that reach
it (`on the branch sim:=true`). An error in one element (an `<include>`, a
`<group>`, an `<arg>`, a `<node>` ...) skips that element only, so the findings
after it are found in the same run. The loader's warnings (unknown
tags and attributes, undeclared command-line args, ...) are warnings.
roslaunch-check follows the default path only (ros_comm #1394, #993) and gives
no line numbers.

Exit status: 0 without errors, 1 with at least one error (warnings alone: 0).
"""

from __future__ import annotations

import argparse
import ast
import math
import os
import re
import sys
from typing import Any, Container, Iterable, NamedTuple

from launcher.model.errors import LaunchError
from launcher.run.load import unsendable_params
from launcher.workspace.packages import PackageIndex, package_of
from launcher.xml import resolve_launch_arguments, sandbox
from launcher.xml.document import read_launch
from launcher.xml.loader import XmlLoader

# loads at most: every combination of the varied args' values up to this many, else one arg at a time
MAX_COMBINATIONS = 256
# attributes whose `$(find pkg)/path` must exist for the launch to load or run; elsewhere (args, values) a
# missing path is only a warning: it may be an output the node creates
PATH_ATTRS = frozenset(("file", "textfile", "binfile"))
_FIND_PATH = re.compile(r"\$\(find\s+([^\s)]+)\)([^\s$\"';:,]*)")
_ARG_REF = re.compile(r"\$\(arg\s+([^\s)]+)\s*\)")
_ARG_ALONE = re.compile(r"\s*\$\(arg\s+([^\s)]+)\s*\)\s*$")
_EVAL_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
_BOOLEAN = ("true", "false", "1", "0")


class Finding(NamedTuple):
    severity: str  # "error" | "warning" | "note" (no fault: what the launch will do, said)
    message: str  # located: "file:line: what\n  included from ..."
    filename: str | None = None
    line: int | None = None
    branch: tuple[str, ...] = ()  # the args set to reach it, e.g. ("sim:=true",); () for the file as given
    kind: str = "load"  # "load": roslaunch refuses the file; "run": it loads, but a node cannot start
    node: str = ""  # a "run" finding about one node or test: its resolved name

    def format(self) -> str:
        text = "%s: %s" % (self.severity, self.message)
        if self.branch:
            text += "\n  on the branch %s" % " ".join(self.branch)
        return text


def _going_on(handler: Any) -> Any:
    """A tag's handler whose error is recorded, and the element skipped, instead of ending the load."""
    def handle(loader: ConditionLoader, el: Any, scope: Any, default_machine: Any) -> Any:
        try:
            return handler(loader, el, scope, default_machine)
        except LaunchError as e:
            loader.errors.append(e)
            return default_machine
    return handle


class ConditionLoader(XmlLoader):
    """The loader, recording the text of every computed if/unless it evaluates, and going on after an
    error in an element (each is one finding, and that element is skipped: the rest of the file is still
    checked). A `<param>` or `<rosparam>` inside a `<node>` is skipped alone, the node is not."""

    tag_handlers = {tag: _going_on(handler) for tag, handler in XmlLoader.tag_handlers.items()}

    def __init__(self, **kw: Any):
        super().__init__(**kw)
        self.conditions: list[str] = []
        self.errors: list[LaunchError] = []
        # (file, line) of each <node>/<test> -> its include chain (a Node does not carry it)
        self.chains: dict[tuple[str, int], tuple[tuple[str, int], ...]] = {}
        self.top_args: dict[str, str | None] = {}  # each top file's declared args -> default (None: required)
        # an arg set from another one alone (<arg name="mode" value="$(arg robot_mode)"/>, mostly in an
        # <include>): a condition on `mode` in the included file is one on `robot_mode` too
        self.passed_args: dict[str, set[str]] = {}

    def load_file(self, filename: str) -> None:
        self.root_scope = None
        try:
            super().load_file(filename)
        finally:
            if self.root_scope is not None:  # (this top file's scope: the args the command line sets)
                for name, (_doc, default) in self.root_scope.arg_docs.items():
                    self.top_args.setdefault(name, default)

    def _node_tag(self, el: Any, scope: Any, *args: Any, **kw: Any) -> None:
        self.chains[(scope.source, el.sourceline or 0)] = tuple(scope.include_chain)
        super()._node_tag(el, scope, *args, **kw)

    def _param_tag(self, *args: Any, **kw: Any) -> None:
        try:
            super()._param_tag(*args, **kw)
        except LaunchError as e:
            self.errors.append(e)

    def _rosparam_tag(self, *args: Any, **kw: Any) -> None:
        try:
            super()._rosparam_tag(*args, **kw)
        except LaunchError as e:
            self.errors.append(e)

    def _arg_tag(self, el: Any, scope: Any) -> None:
        name = el.attrib.get("name")
        for attr in ("value", "default"):
            m = _ARG_ALONE.match(el.attrib.get(attr) or "")
            if m and name and m.group(1) != name:
                self.passed_args.setdefault(name, set()).add(m.group(1))
        try:
            super()._arg_tag(el, scope)
        except LaunchError as e:
            self.errors.append(e)

    def _if_unless(self, el: Any, scope: Any) -> bool:
        get = el.attrib.get
        raw = get("if") if get("if") is not None else get("unless")
        if raw is not None and "$(" in raw:
            self.conditions.append(raw)
        return super()._if_unless(el, scope)


def condition_args(condition: str, free: dict[str, str | None]) -> set[str]:
    """The settable args a condition reads: `$(arg x)`, or a name inside `$(eval ...)`."""
    names = set(_ARG_REF.findall(condition))
    if "$(eval" in condition:
        names.update(_EVAL_NAME.findall(condition))
    return {n for n in names if n in free}


def condition_literals(condition: str, names: Container[str]) -> dict[str, list[str]]:
    """The literals a `$(eval ...)` condition compares one of these args with (`==`, `!=`, `in`, `not in` a
    list of literals), as the strings that give those values: the values of that arg the file names."""
    text = condition.strip()
    if not (text.startswith("$(eval ") and text.endswith(")")):
        return {}
    try:
        tree = sandbox.parse(text[7:-1])  # (the loader's parse, cached: bounded in length and depth)
    except sandbox.EvalError:
        return {}  # (the load says so)
    found: dict[str, list[str]] = {}
    for node in ast.walk(tree):
        if not isinstance(node, ast.Compare):
            continue
        operands = [node.left, *node.comparators]
        for op, left, right in zip(node.ops, operands, operands[1:]):
            if isinstance(op, (ast.Eq, ast.NotEq)):
                pairs = ((left, [right]), (right, [left]))
            elif isinstance(op, (ast.In, ast.NotIn)) and isinstance(right, (ast.List, ast.Tuple, ast.Set)):
                pairs = ((left, right.elts),)  # (`'x' in mode` is a substring test: no value to name)
            else:
                continue
            for operand, literals in pairs:
                name = _arg_operand(operand, names)
                if name is None:
                    continue
                values = found.setdefault(name, [])
                for lit in literals:
                    if isinstance(lit, ast.Constant) and isinstance(lit.value, (str, int, float)) \
                            and _arg_text(lit.value) not in values:
                        values.append(_arg_text(lit.value))
    return found


def _arg_operand(node: ast.expr, names: Container[str]) -> str | None:
    """The arg an operand reads: `mode`, `arg('mode')`, or either inside int()/float()/str()."""
    if isinstance(node, ast.Name):
        return node.id if node.id in names else None
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and len(node.args) == 1 and not node.keywords:
        inner = node.args[0]
        if node.func.id == "arg" and isinstance(inner, ast.Constant) and isinstance(inner.value, str):
            return inner.value if inner.value in names else None
        if node.func.id in ("int", "float", "str"):
            return _arg_operand(inner, names)
    return None


def _arg_text(value: Any) -> str:
    """The `name:=value` text that gives an arg this value in `$(eval)` (args are auto-typed there)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    return str(value)


def _branch_values(default: str | None, literals: Iterable[str]) -> tuple[str, ...]:
    """The values other than its default of an arg its conditions can see: true and false, when the arg is a
    boolean (or required); the literals the conditions compare it with."""
    values: list[str] = []
    if default is None or default.strip().lower() in _BOOLEAN:
        values += ["true", "false"]
    values += [v for v in literals if v not in values]
    # (the default is what the branch without this arg sees)
    return tuple(v for v in values if default is None or v.lower() != default.strip().lower())


def check(files: list[str], argv: Iterable[str] = (), *, environ: dict[str, str] | None = None,
          packages: Any = None) -> list[Finding]:
    """Every finding of every branch, errors first, in the order found."""
    environ = dict(os.environ) if environ is None else environ
    packages = packages if packages is not None else PackageIndex(environ)
    argv = list(argv)
    given = {a.split(":=", 1)[0] for a in argv if ":=" in a}
    findings: dict[str, Finding] = {}
    loaded_files: dict[str, None] = {}
    done: set[tuple[str, ...]] = set()
    varied: dict[str, tuple[tuple[str, ...], bool]] = {}  # arg -> (the values tried, the arg is required)
    todo: list[tuple[str, ...]] = [()]
    while todo:
        branch = todo.pop(0)
        if branch in done:
            continue
        done.add(branch)
        loader = ConditionLoader(environ=environ, packages=packages, argv=argv + list(branch))
        config = None
        try:
            for f in files:
                loader.load_file(f)
            config = loader.config()
        except LaunchError as e:
            _add(findings, Finding("error", str(e), e.filename, e.line, branch))
        except RecursionError:
            _add(findings, Finding("error", "elements or includes are nested too deeply", files[-1], None, branch))
        for e in loader.errors:
            _add(findings, Finding("error", str(e), e.filename, e.line, branch))
        for w in loader.warnings:
            _add(findings, Finding("warning", w, None, None, branch))
        for f in loader.files:
            loaded_files.setdefault(os.path.abspath(f))
        if config is not None:
            for finding in _check_config(config, packages, branch, loader.chains):
                _add(findings, finding)
        # the args a user may set (declared with a default, or required, in a top file) that decide a condition
        free = {n: d for n, d in loader.top_args.items() if n not in given}
        deciding = set()
        literals: dict[str, list[str]] = {}
        known = set(free) | set(loader.passed_args)
        for cond in loader.conditions:
            deciding |= condition_args(cond, free)
            for name, values in condition_literals(cond, known).items():
                for source in _settable_sources(name, loader.passed_args, free):
                    deciding.add(source)
                    literals.setdefault(source, []).extend(values)
        # a boolean arg passed on to an included file may decide a condition there under another name
        # (<arg name="sim" value="$(arg use_sim)"/>): every boolean arg the files read is varied too
        deciding |= {n for n in loader._used_args if n in free and free[n] is not None
                     and free[n].strip().lower() in _BOOLEAN}
        new = False
        for name in sorted(deciding):
            # (a branch may reach a condition that names more values: they are added)
            tried = varied.get(name, ((), False))[0]
            values = tried + tuple(v for v in _branch_values(free[name], literals.get(name, ())) if v not in tried)
            if values != tried:
                varied[name] = (values, free[name] is None)
                new = True
        if new:
            todo.extend(_combinations(varied))
    located = {(os.path.abspath(f.filename), f.line) for f in findings.values() if f.filename}
    for f in loaded_files:
        for finding in _check_find_paths(f, packages):
            if (finding.filename, finding.line) not in located:  # (the load said it already)
                _add(findings, finding)
    ordered = list(findings.values())
    return [f for f in ordered if f.severity == "error"] + [f for f in ordered if f.severity != "error"]


def _settable_sources(name: str, passed: dict[str, set[str]], free: Container[str]) -> set[str]:
    """The settable args an arg's value may come from: itself, or the args it is set from, transitively."""
    found, todo, seen = set(), [name], set()
    while todo:
        n = todo.pop()
        if n in seen:
            continue
        seen.add(n)
        if n in free:
            found.add(n)
        todo.extend(passed.get(n, ()))
    return found


def _combinations(varied: dict[str, tuple[tuple[str, ...], bool]]) -> list[tuple[str, ...]]:
    """Each combination of the varied args' values, fewest args set first (one arg at a time when there are
    too many); an arg left at its default is not set, so each branch names only what it changes."""
    options = [[("%s:=%s" % (n, v),) for v in values] + ([] if required else [()])
               for n, (values, required) in varied.items() if values]
    if math.prod(len(o) for o in options) > MAX_COMBINATIONS:
        return [c for o in options for c in o if c]
    combos: list[tuple[str, ...]] = [()]
    for o in options:
        combos = [c + v for c in combos for v in o]
    return sorted((c for c in combos if c), key=len)  # (stable: the order of the values stays)


def _add(findings: dict[str, Finding], finding: Finding) -> None:
    # the same problem found on several branches is reported once, with the first (least forced) branch
    findings.setdefault(finding.message, finding)


def _located(node: Any, chain: tuple[tuple[str, int], ...], msg: str) -> str:
    return LaunchError(msg, node.filename or None, node.line or None, chain).format()


def _check_config(config: Any, packages: Any, branch: tuple[str, ...],
                  chains: dict[tuple[str, int], tuple[tuple[str, int], ...]]) -> Iterable[Finding]:
    for node in config.nodes + config.tests:
        chain = chains.get((node.filename, node.line), ())

        kind = "test" if node.is_test else "node"
        try:
            packages.find_node(node.package, node.type)
        except LaunchError as e:
            yield Finding("error", _located(node, chain, "<%s> [%s]: %s" % (kind, node.full_name, e.message)),
                          node.filename, node.line, branch, "run", node.full_name)
        if node.machine_name and node.machine_name not in config.machines:
            yield Finding("error", _located(node, chain, "<%s> [%s] uses machine [%s], which no <machine> tag declares"
                                            % (kind, node.full_name, node.machine_name)),
                          node.filename, node.line, branch, "run", node.full_name)
        if node.policy is not None and not node.policy.registers:
            yield Finding("note", _located(node, chain, "<%s> [%s] has registers=\"false\": not a ROS node, up once "
                                           "its process runs (no registration with the master is awaited)"
                                           % (kind, node.full_name)),
                          node.filename, node.line, branch, "run", node.full_name)
    for e in unsendable_params(config):
        yield Finding("error", e.format(), e.filename, e.line, branch, "run")


def _check_find_paths(filename: str, packages: Any) -> Iterable[Finding]:
    """`$(find pkg)/path` in any attribute of any element, taken or not, whose path does not exist."""
    try:
        doc = read_launch(filename)
    except LaunchError:
        return  # reported by the load
    for el in doc.launch.iter():
        for attr, value in el.attrib.items():
            if "$(find" not in value or (el.tag == "rosparam" and el.attrib.get("command") == "dump"):
                continue  # (a dump's file is written, not read)
            for m in _FIND_PATH.finditer(value):
                pkg, rel = m.group(1), m.group(2)
                if "$(" in pkg or not rel.startswith("/"):
                    continue
                try:
                    path = packages.find_resource(pkg, rel)  # (roslaunch's order: catkin spaces, then the source)
                except LaunchError:
                    yield Finding("error", "%s:%d: <%s %s=\"%s\">: package [%s] not found"
                                  % (filename, el.sourceline, el.tag, attr, value, pkg), filename, el.sourceline,
                                  (), "run")
                    continue
                if os.path.exists(path):
                    continue
                severity = "error" if attr in PATH_ATTRS else "warning"
                yield Finding(severity, "%s:%d: <%s %s=\"%s\">: [%s] does not exist"
                              % (filename, el.sourceline, el.tag, attr, value, path), filename, el.sourceline,
                              (), "run")


def junit_xml(findings: list[Finding], files: list[str]) -> bytes:
    """roslaunch-check's JUnit layout: a suite named after the file, one `roslaunch.RoslaunchCheck` case
    named `<pkg>_<path in the package>`, failed with every error (each with its branch) when there is one."""
    import xml.etree.ElementTree as ET  # (only with --junit-xml)
    name = files[-1]
    try:
        pkg, pkg_dir = package_of(name)
        outname = os.path.abspath(name)[len(pkg_dir) + 1:].replace(".", "_").replace(os.sep, "_")
    except LaunchError:
        pkg, outname = "", os.path.basename(name).replace(".", "_")
    errors = [f for f in findings if f.severity == "error"]
    suite = ET.Element("testsuite", tests="1", failures="1" if errors else "0", time="1", errors="0", name=name)
    case = ET.SubElement(suite, "testcase", name="%s_%s" % (pkg, outname) if pkg else outname, status="run", time="1",
                         classname="roslaunch.RoslaunchCheck")
    if errors:
        failure = ET.SubElement(case, "failure", message="roslaunch check [%s] failed" % name, type="")
        failure.text = "\n".join(f.format() for f in errors)  # (CI pages show a failure's text)
    out = ET.SubElement(suite, "system-out")
    out.text = "\n".join(f.format() for f in findings)
    return ET.tostring(suite, encoding="utf-8", xml_declaration=True)


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="launcher check",
                                usage="launcher check [options] [package] <file.launch> [name:=value ...]",
                                description="Check launch files without starting anything, over every if/unless "
                                            "branch: the args of the top files (not of included files: their "
                                            "includer sets them) are varied over true/false and over the values "
                                            "an $(eval) condition compares them with.")
    p.add_argument("--junit-xml", metavar="PATH", help="also write the findings as JUnit XML (roslaunch-check's)")
    p.add_argument("-q", "--quiet", action="store_true", help="print errors only")
    p.add_argument("positional", nargs="*", metavar="ARG", help="[package] file.launch ... name:=value ...")
    opts = p.parse_intermixed_args(argv)
    environ = dict(os.environ)
    packages = PackageIndex(environ)
    try:
        files, args = resolve_launch_arguments(list(opts.positional), packages)
        if not files:
            raise LaunchError("you must specify at least one launch file")
    except LaunchError as e:
        print(str(e), file=sys.stderr)
        return 1
    findings = check(files, args, environ=environ, packages=packages)
    errors = sum(1 for f in findings if f.severity == "error")
    for f in findings:
        if f.severity == "error" or not opts.quiet:
            print(f.format())
    warnings = sum(1 for f in findings if f.severity == "warning")
    notes = len(findings) - errors - warnings
    print("%s: %d error(s), %d warning(s)%s" % (" ".join(files), errors, warnings,
                                                ", %d note(s)" % notes if notes else ""),
          file=sys.stderr if errors else sys.stdout)
    if opts.junit_xml:
        try:
            os.makedirs(os.path.dirname(os.path.abspath(opts.junit_xml)), exist_ok=True)
            with open(opts.junit_xml, "wb") as out:
                out.write(junit_xml(findings, files))
        except OSError as e:
            print("cannot write [%s]: %s" % (opts.junit_xml, e.strerror), file=sys.stderr)
            return 1
    return 1 if errors else 0
