"""The command line of a launch: `name:=value` args, `__ns:=`, and `[pkg] file.launch...` resolution."""

from __future__ import annotations

import os

from launcher.model.errors import LaunchError, UsageError
from launcher.model.names import REMAP, make_global_ns
from launcher.workspace.packages import PackageNotFound
from launcher.model.suggest import did_you_mean, near_file

TYPE_CHECKING = False  # (typing.TYPE_CHECKING without importing typing: ~3 ms a start; the annotations are text)
if TYPE_CHECKING:
    from typing import Any, Callable, Iterable, Mapping

LAUNCH_FILE_ENDINGS = (".launch", ".xml", ".test")  # what a hint for `launch PKG FILE` may offer


def is_mapping(token: str) -> bool:
    return REMAP in token


def load_mappings(argv: Iterable[str], warn: Callable[[str], None] | None = None) -> dict[str, str]:
    """`name:=value` tokens as roslaunch reads them (rosgraph.names.load_mappings).

    Values and names are stripped, empty ones dropped, `_name:=` (a private
    parameter for a node) is not an arg; `__ns:=` and friends are kept.
    """
    out: dict[str, str] = {}
    for token in argv:
        if REMAP not in token:
            continue
        parts = token.split(REMAP)
        if len(parts) != 2:
            if warn:
                warn("ignoring invalid command-line argument '%s' (more than one ':=')" % token)
            continue
        src, dst = parts[0].strip(), parts[1].strip()
        if src and dst:
            if len(src) > 1 and src[0] == "_" and src[1] != "_":
                continue
            out[src] = dst
    return out


def root_namespace(argv: Iterable[str], environ: Mapping[str, str]) -> str:
    """The namespace the launch is loaded in: `__ns:=` on the command line, else ROS_NAMESPACE, else `/`."""
    for token in argv:
        if token.startswith("__ns:="):
            ns = token[len("__ns:="):]
            break
    else:
        ns = environ.get("ROS_NAMESPACE", "/")
    try:
        return make_global_ns(ns)
    except ValueError:
        raise LaunchError("the launch namespace [%s] must not be a private name" % ns) from None


def resolve_launch_arguments(positional: list[str], packages: Any) -> tuple[list[str], list[str]]:
    """Split `[pkg] file.launch... name:=value...` into (launch files, name:=value tokens).

    As roslaunch: with two or more words, `pkg file` is tried first (the file
    is searched for inside the package); otherwise the words must be files.
    """
    words = [a for a in positional if not is_mapping(a)]
    argv = [a for a in positional if is_mapping(a)]
    if not words:
        return [], argv
    if len(words) >= 2 and not os.path.isfile(words[0]):
        found = None
        try:
            found = packages.find_launch_file(words[0], words[1])
            hint = "" if found else _file_hint(packages, words[0], words[1])
        except PackageNotFound as e:
            hint = "no package [%s]: %s" % (words[0], e.hint) if e.hint else near_file(words[0])
        if found:
            files = [found] + words[2:]
        else:
            raise LaunchError("[%s] is neither a launch file in package [%s] nor is [%s] a launch file name%s"
                              % (words[1], words[0], words[0], " (%s)" % hint if hint else ""))
    else:
        files = words
    missing = [f for f in files if f != "-" and not os.path.isfile(f)]
    if missing:
        if len(words) == 1:
            hint = near_file(missing[0])
            raise LaunchError("[%s] is not a launch file name%s" % (missing[0], " (%s)" % hint if hint else ""))
        # roslaunch's parser.error: a usage error (exit status 2), as a mistyped `name:=value` usually is
        args = [f.replace("=", ":=", 1) for f in missing if "=" in f and os.path.sep not in f]
        raise UsageError("The following input files do not exist: %s%s" % (
            ", ".join(missing), " (did you mean %s?)" % " ".join(args) if args else ""))
    return files, argv


def _file_hint(packages: Any, pkg: str, filename: str) -> str:
    """"package [P] has no [F]: did you mean ...?" among the package's launch files, or ""."""
    hint = did_you_mean(filename, (f for f in packages.file_names(pkg) if f.endswith(LAUNCH_FILE_ENDINGS)))
    return "package [%s] has no [%s]: %s" % (pkg, filename, hint) if hint else ""
