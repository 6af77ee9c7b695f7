"""Shell completion for `launch` and `launcher`: the bash/zsh script, and the candidates it asks us for.

`launcher completion bash` (or `zsh`) prints a script to `eval` or to save in the
shell's completion directory (README). On TAB the script runs
`launcher __complete "<the line up to the cursor>"`, which prints one candidate
a line:

    launch <TAB>                    package names and launch files here (options after '-')
    launch PKG <TAB>                the package's .launch/.test files
    launch [PKG] FILE <TAB>         NAME:= for each <arg> the file lets a caller set
    launcher <TAB>                  the subcommands
    launcher start|stop|... <TAB>   the nodes of the running launch, where the subcommand can list them

bash splits words at ':' and '=' (COMP_WORDBREAKS), so for a word holding them
the candidates are given from the last such character on, as bash expects.
"""

from __future__ import annotations

import importlib
import os
import shlex
import sys
from typing import Iterable

from launcher.model.errors import LaunchError
from launcher.workspace.packages import PackageIndex
from launcher.cli.tool import SUBCOMMANDS
from launcher.xml import load_arg_docs

LAUNCH_OPTIONS = (
    "--args", "--nodes", "--find-node", "--dump-params", "--files", "--ros-args", "--core", "--wait", "--local",
    "--screen", "--log", "--required", "--skip-log-check", "--run_id", "--pid", "--port", "--disable-title",
    "--sigint-timeout", "--sigterm-timeout", "--numworkers", "--timeout", "--master-logger-level",
    "--no-summary", "--verbose", "--version", "--help", "-p", "-v")
LAUNCH_FILE_ENDINGS = (".launch", ".test")
WORDBREAKS = ":="

BASH = r'''# bash completion for launch and launcher (from `launcher completion bash`)
_launcher_complete() {
    local IFS=$'\n'
    local line="${COMP_LINE:0:$COMP_POINT}"
    COMPREPLY=($(launcher __complete "$line" 2>/dev/null))
    # NAME:= and directories want more typing after them, not a space
    if [[ ${#COMPREPLY[@]} -eq 1 && ( "${COMPREPLY[0]}" == *= || "${COMPREPLY[0]}" == */ ) ]]; then
        compopt -o nospace 2>/dev/null
    fi
}
complete -F _launcher_complete launch launcher
'''

ZSH = r'''# zsh completion for launch and launcher (from `launcher completion zsh`)
autoload -U +X bashcompinit && bashcompinit
''' + BASH


def main(argv: list[str]) -> int:
    if len(argv) == 1 and argv[0] in ("bash", "zsh"):
        sys.stdout.write(BASH if argv[0] == "bash" else ZSH)
        return 0
    print("usage: launcher completion bash|zsh\n\n"
          "Prints the completion script. Use it now with  eval \"$(launcher completion bash)\"  or keep it:\n"
          "  launcher completion bash > ~/.local/share/bash-completion/completions/launch\n"
          "  (and a symlink named 'launcher' beside it), or in ~/.zshrc:  eval \"$(launcher completion zsh)\"",
          file=sys.stderr)
    return 2


def complete_main(argv: list[str]) -> int:
    """`launcher __complete LINE`: the candidates, one a line."""
    for candidate in candidates(argv[0] if argv else "", os.environ):
        print(candidate)
    return 0


def candidates(line: str, environ: dict[str, str] | os._Environ) -> list[str]:
    try:
        words = shlex.split(line)
    except ValueError:  # an open quote: complete what is there
        words = line.split()
    if not line or line[-1].isspace():
        words.append("")
    if len(words) < 2:
        return []
    command, args, current = os.path.basename(words[0]), words[1:-1], words[-1]
    if command == "launcher":
        found = _launcher(args, current, environ)
    else:
        found = _launch(args, current, environ)
    return _after_wordbreak(current, sorted(set(c for c in found if c.startswith(current))))


def _after_wordbreak(current: str, found: Iterable[str]) -> list[str]:
    cut = max(current.rfind(c) for c in WORDBREAKS) + 1
    return [c[cut:] for c in found]


def _launch(args: list[str], current: str, environ) -> list[str]:
    if current.startswith("-"):
        return list(LAUNCH_OPTIONS)
    positional = [a for a in args if not a.startswith("-") and ":=" not in a]
    packages = PackageIndex(environ, use_cache=True)
    if not positional:
        return _files_here(current) + sorted(packages.packages())
    if len(positional) == 1 and not _is_launch_file(positional[0]):
        try:
            return _package_launch_files(packages, positional[0])
        except LaunchError:
            return []
    files = _launch_files(packages, positional)
    # after a launch file: its args; more launch files only once a path is being typed
    return _settable_args(files, environ, packages) + (_files_here(current) if "/" in current else [])


def _launcher(args: list[str], current: str, environ) -> list[str]:
    if not args:
        return [name for name in SUBCOMMANDS if not name.startswith("_")]
    # a subcommand that can name the running launch's nodes offers them (`node_names(environ)`)
    entry = SUBCOMMANDS.get(args[0])
    if entry is None or current.startswith("-"):
        return []
    module = importlib.import_module(entry[0].partition(":")[0])
    names = getattr(module, "complete_node_names", None)
    return list(names(environ)) if names is not None else []


def _is_launch_file(word: str) -> bool:
    return word.endswith(LAUNCH_FILE_ENDINGS) or os.path.isfile(word)


def _files_here(current: str) -> list[str]:
    """Launch files and directories next to what is typed, as a path."""
    directory = os.path.dirname(current)
    try:
        entries = os.listdir(directory or ".")
    except OSError:
        return []
    out = []
    for name in entries:
        path = os.path.join(directory, name)
        if os.path.isdir(path) and not name.startswith("."):
            out.append(path + "/")
        elif name.endswith(LAUNCH_FILE_ENDINGS):
            out.append(path)
    return out


def _package_launch_files(packages: PackageIndex, package: str) -> list[str]:
    found = []
    for d, dirs, files in os.walk(packages.get_path(package)):
        dirs[:] = [x for x in dirs if not x.startswith(".")]
        found.extend(f for f in files if f.endswith(LAUNCH_FILE_ENDINGS))
    return found


def _launch_files(packages: PackageIndex, positional: list[str]) -> list[str]:
    if len(positional) == 2 and not _is_launch_file(positional[0]):
        try:
            found = packages.find_launch_file(positional[0], positional[1])
        except LaunchError:
            return []
        return [found] if found else []
    return [p for p in positional if os.path.isfile(p)]


def _settable_args(files: list[str], environ, packages: PackageIndex) -> list[str]:
    if not files:
        return []
    try:
        docs = load_arg_docs(files, environ=environ, packages=packages)
    except LaunchError:
        return []
    return ["%s:=" % name for name in docs]
