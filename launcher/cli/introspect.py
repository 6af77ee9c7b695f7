"""The introspection options: `--nodes --args --find-node --dump-params --files --ros-args` (print and exit).

Each is a function of the loaded `LaunchConfig` only; output is roslaunch's,
byte for byte where the compat goldens pin it. Where roslaunch exits 0 after
an error (`--dump-params`, `--find-node`) or dies with a traceback (`--args`
for a missing executable, `--dump-params` with a `binfile`), we print a clean
message and exit 1.
"""

from __future__ import annotations

import os
import sys

from launcher.model.errors import LaunchError
from launcher.model.names import SEP, make_global_ns, ns_join
from launcher.workspace.packages import PackageIndex
from launcher.model.suggest import did_you_mean
from launcher.xml import load, load_arg_docs, resolve_launch_arguments
from launcher.xml.arguments import root_namespace

TYPE_CHECKING = False  # (typing.TYPE_CHECKING without importing typing: ~3 ms a start; the annotations are text)
if TYPE_CHECKING:
    from typing import Any, Mapping

NO_FILE = "you must specify at least one input file"


def _warn(msg: str) -> None:
    sys.stderr.write("warning: %s\n" % msg)


def resolve_node_name(name: str, argv: list[str], environ: Mapping[str, str]) -> str:
    """A node name given on the command line, resolved as roslaunch does (rosgraph's script_resolve_name)."""
    ns = root_namespace(argv, environ)
    if not name:
        return ns
    if name[0] == SEP:
        return name
    if name[0] == "~":
        return ns_join(make_global_ns(ns_join(ns, "roslaunch")), name[1:])
    return ns + name


def _full_name(node: Any) -> str | None:
    return ns_join(node.namespace, node.name) if node.name else None


def _find(config: Any, name: str, files: list[str]) -> Any:
    matches = [n for n in config.nodes + config.tests if _full_name(n) == name]
    if len(matches) > 1:
        raise LaunchError("ERROR: multiple nodes named [%s] in [%s].\nPlease fix the launch files as duplicate "
                          "names are not allowed." % (name, ", ".join(files)))
    return matches[0] if matches else None


def main(opts: Any) -> int:
    """Run the one introspection option `opts` asks for; returns the exit status. (`launch` calls it with the cyclic
    collector paused: loading and printing make ~10^5 long-lived objects and free almost nothing.)"""
    environ = os.environ
    packages = PackageIndex(environ, warn=_warn)
    files, argv = resolve_launch_arguments(list(opts.positional or []), packages)
    if not files:
        raise LaunchError(NO_FILE)
    out = sys.stdout
    # one option runs, in roslaunch's order of precedence
    if opts.node_args:
        config = load(files, argv, environ=environ, packages=packages, warn=_warn)
        name = resolve_node_name(opts.node_args, argv, environ)
        node = _find(config, name, files)
        if node is None:
            names = [n for n in (_full_name(x) for x in config.nodes + config.tests) if n]
            hint = did_you_mean(name, names)
            raise LaunchError("ERROR: Cannot find node named [%s] in [%s].\nNode names are:\n%s%s"
                              % (name, ", ".join(files), "\n".join(" * %s" % n for n in names),
                                 "\n" + hint if hint else ""))
        # (only --args needs the command line's module; the other options do not pay for its import)
        from launcher.plan.command import master_uri, node_command
        cmd = node_command(node, master_uri=master_uri(argv, environ), environ=environ, packages=packages)
        out.write(cmd.format_args() + "\n")
        return 0

    if opts.find_node:
        config = load(files, argv, environ=environ, packages=packages, warn=_warn)
        name = resolve_node_name(opts.find_node, argv, environ)
        node = _find(config, name, files)
        if node is None:  # (said, with exit status 0: roslaunch's print_node_filename prints and returns)
            hint = did_you_mean(name, (n for n in (_full_name(x) for x in config.nodes + config.tests) if n))
            sys.stderr.write("ERROR: cannot find node named [%s]. Run \n\tlaunch --nodes <files>\nto see list of "
                             "node names.%s\n" % (name, "\n" + hint if hint else ""))
            return 0
        out.write(node.filename + "\n")
        return 0

    if opts.dump_params:
        # as roslaunch: roscore.xml (and so its /rosout node) is not loaded for --dump-params
        config = load(files, argv, environ=environ, packages=packages, core=False, warn=_warn)
        out.write(dump_params(config))
        return 0

    if opts.files:
        config = load(files, argv, environ=environ, packages=packages, warn=_warn)
        out.write("".join(f + "\n" for f in config.files))
        return 0

    if opts.ros_args:
        docs = load_arg_docs(files, argv, environ=environ, packages=packages)
        out.write(format_ros_args(docs))
        return 0

    # --nodes
    config = load(files, argv, environ=environ, packages=packages, warn=_warn)
    names = [n for n in (_full_name(x) for x in config.nodes + config.tests) if n]
    out.write("\n".join(names) + "\n")
    return 0


def format_ros_args(docs: dict[str, tuple[str | None, str | None]]) -> str:
    if not docs:
        return "No arguments.\n"
    required = sorted((name, doc or "undocumented") for name, (doc, default) in docs.items() if not default)
    optional = sorted((name, doc or "undocumented", default) for name, (doc, default) in docs.items() if default)
    lines = []
    if required:
        lines.append("Required Arguments:")
        lines += ["  %s: %s" % r for r in required]
    if optional:
        lines.append("Optional Arguments:")
        lines += ['  %s (default "%s"): %s' % (name, default, doc) for name, doc, default in optional]
    return "\n".join(lines) + "\n"


def _has_binary(value: Any) -> bool:
    stack = [value]
    while stack:
        v = stack.pop()
        kind = type(v)
        if kind in _PLAIN_SCALARS:
            continue
        if isinstance(v, (bytes, bytearray)):
            return True
        if isinstance(v, dict):
            stack.extend(v.values())
        elif isinstance(v, list):
            stack.extend(v)
    return False


_PLAIN_SCALARS = frozenset((str, int, float, bool, type(None)))


def dump_params(config: Any) -> str:
    """`--dump-params`: YAML of the flat {key: value} dict, as roslaunch prints it."""
    from launcher.params.dump import dump_yaml  # (its regexes cost --nodes ~1 ms when imported at the top)
    data = {k: p.value for k, p in config.params.items()}
    try:
        text = dump_yaml(data)
    except Exception:  # noqa: BLE001 - PyYAML cannot write it: binary data is the one case we produce
        text = "!!binary"
    if "!!binary" in text:  # (bytes are only ever written as !!binary; else no value holds any)
        for p in config.params.values():
            if _has_binary(p.value):
                raise LaunchError("cannot print parameter [%s] as YAML: it holds binary data (binfile= or "
                                  "!!binary), which roslaunch cannot print either" % p.key, p.filename or None,
                                  p.line or None)
        if text == "!!binary":
            text = dump_yaml(data)  # not binary after all: let its error through
    return text + "\n"
