"""The python that a node script's `#!/usr/bin/env python3` runs, and the trap when it is not the system's.

ROS's Python packages (rospy, rospkg, the message modules) are installed for
the system's interpreter, /usr/bin/python3. A node script that starts with
`#!/usr/bin/env python3` runs whichever `python3` comes first on PATH: a
virtual environment's `bin` there (an activated venv, or the launcher's own
venv put on PATH to reach `launch`) or a version manager's shim (pyenv's)
gives it an interpreter that cannot import rospy, and every such node dies at
once with ModuleNotFoundError. roslaunch's nodes meet the same trap (a node's
PATH is the launcher's, as under roslaunch); this module names it:
`launcher doctor` runs both interpreters on each node script's imports, and
`launch` (output/screen.py) says it in one line when a node's output shows
that import error, from a look at the system's package folders (no process).
"""

from __future__ import annotations

import os
import re
import subprocess
from typing import Iterable, Mapping

SYSTEM_BIN = ("/usr/bin", "/bin")
# An import error this soon after the start is the node's own imports failing (a node that ran for a
# while and then failed an import is another story).
AT_ONCE_S = 10.0
# (patterns compiled at their first use, by re's cache: `launch` imports this module at every start)
_MISSING = rb"ModuleNotFoundError: No module named '([A-Za-z_][\w.]*)'"
_ENV_PYTHON = rb"#![ \t]*/\S*/env[ \t]+(python[0-9.]*)[ \t]*\r?\n"
_IMPORT = r"(?m)^[ \t]*(?:import[ \t]+([^#;\n]+)|from[ \t]+([A-Za-z_][\w.]*)[ \t]+import\b)"
# Run by an interpreter: which of the module names in argv it can find (find_spec runs no module code).
_FINDABLE = ("import importlib.util, sys\n"
             "for m in sys.argv[1:]:\n"
             "    try:\n"
             "        found = importlib.util.find_spec(m) is not None\n"
             "    except (ImportError, ValueError):\n"
             "        found = False\n"
             "    if found:\n"
             "        print(m)\n")


def env_python(script: str) -> str | None:
    """The interpreter a script names through `env` (`python3` for `#!/usr/bin/env python3`), or None."""
    try:
        with open(script, "rb") as f:
            head = f.readline(256)
    except OSError:
        return None
    m = re.match(_ENV_PYTHON, head)
    return m.group(1).decode() if m else None


def on_path(name: str, environ: Mapping[str, str]) -> str | None:
    import shutil  # (with its compressors: only for a node dead of the PATH trap, not at every start)
    return shutil.which(name, path=environ.get("PATH", os.defpath))


def system_python(name: str = "python3") -> str | None:
    for folder in SYSTEM_BIN:
        path = os.path.join(folder, name)
        if os.access(path, os.X_OK):
            return path
    return None


def in_venv(interpreter: str) -> bool:
    """Whether `interpreter` is a virtual environment's (its python is a link to the system's, with packages of
    its own: pyvenv.cfg beside its `bin`)."""
    folder = os.path.dirname(os.path.abspath(interpreter))
    return (os.path.exists(os.path.join(folder, "pyvenv.cfg"))
            or os.path.exists(os.path.join(os.path.dirname(folder), "pyvenv.cfg")))


def is_system(interpreter: str, name: str = "python3") -> bool:
    """Whether `interpreter` is the system's `name` (True when there is no system's to compare with)."""
    system = system_python(name)
    if system is None:
        return True
    return os.path.realpath(interpreter) == os.path.realpath(system) and not in_venv(interpreter)


def script_imports(script: str) -> list[str]:
    """The top-level modules a Python script imports (`import a.b, c as d`, `from e.f import g`), in order."""
    try:
        with open(script, errors="replace") as f:
            text = f.read(1 << 20)
    except OSError:
        return []
    names: list[str] = []
    for plain, source in re.findall(_IMPORT, text):
        for item in (plain.split(",") if plain else [source]):
            words = item.strip().strip("()\\").split()
            top = words[0].split(".")[0] if words else ""
            if top.isidentifier() and top not in names:
                names.append(top)
    return names


def findable(interpreter: str, modules: Iterable[str], environ: Mapping[str, str]) -> set[str] | None:
    """The `modules` that `interpreter` finds with the node's environment; None when it does not run."""
    modules = list(modules)
    try:
        r = subprocess.run([interpreter, "-c", _FINDABLE, *modules], env=dict(environ), capture_output=True,
                           text=True, timeout=60)
    except (OSError, subprocess.SubprocessError):
        return None
    if r.returncode != 0:
        return None
    return set(r.stdout.split()) & set(modules)


def missing_module(output: bytes) -> str | None:
    """The module of a `ModuleNotFoundError: No module named 'x'` line in a node's output, or None."""
    m = re.search(_MISSING, output)
    return m.group(1).decode() if m else None


def _system_package_dirs(system: str) -> list[str]:
    """Where the system's interpreter finds packages (Debian's and Ubuntu's layout), PYTHONPATH left out: a
    module there is found by any interpreter."""
    real = os.path.realpath(system)  # /usr/bin/python3.11
    version = os.path.basename(real)
    prefix = os.path.dirname(os.path.dirname(real))
    lib = os.path.join(prefix, "lib")
    return [os.path.join(lib, version), os.path.join(lib, version, "lib-dynload"),
            os.path.join("/usr/local/lib", version, "dist-packages"), os.path.join(lib, "python3", "dist-packages"),
            os.path.join(lib, version, "dist-packages"), os.path.join(lib, version, "site-packages")]


def _has_module(folder: str, name: str) -> bool:
    if os.path.isdir(os.path.join(folder, name)) or os.path.isfile(os.path.join(folder, name + ".py")):
        return True
    try:
        return any(f.startswith(name + ".") and f.endswith(".so") for f in os.listdir(folder))
    except OSError:
        return False


def import_hint(node: str, module: str, environ: Mapping[str, str]) -> tuple[str, str] | None:
    """(the python3 on PATH, the line `launch` prints) when a node died at once of `module` missing because
    that python3 is not the system's and the system's has it; else None."""
    interpreter = on_path("python3", environ)
    system = system_python("python3")
    if interpreter is None or system is None or is_system(interpreter):
        return None
    top = module.split(".")[0]
    if not any(_has_module(d, top) for d in _system_package_dirs(system)):
        return None
    return interpreter, (
        "[%s] cannot import %s: python3 on PATH is %s, not the system's %s which has it ('#!/usr/bin/env python3' "
        "nodes run it): take %s off PATH (README: 'Installing for everyday use'), or see `launcher doctor`"
        % (node, module, interpreter, system, os.path.dirname(interpreter)))


def lacking(interpreter: str, system: str, modules: list[str], environ: Mapping[str, str],
            cache: dict[tuple[str, str], bool]) -> list[str] | None:
    """The `modules` that the system's interpreter finds and `interpreter` does not (None: one of them does not
    run). `cache` keeps (interpreter, module) -> findable across the calls of one check."""
    for python in (system, interpreter):
        unknown = [m for m in modules if (python, m) not in cache]
        if unknown:
            found = findable(python, unknown, environ)
            if found is None:
                return None
            cache.update(((python, m), m in found) for m in unknown)
    return [m for m in modules if cache[(system, m)] and not cache[(interpreter, m)]]


def trap(script: str, environ: Mapping[str, str],
         cache: dict[tuple[str, str], bool]) -> tuple[str, str, list[str]] | None:
    """(interpreter, the system's, modules) when `script` runs through `env` an interpreter that cannot import
    modules it imports which the system's can; else None."""
    name = env_python(script)
    if name is None:
        return None
    interpreter = on_path(name, environ)
    system = system_python(name)
    if interpreter is None or system is None or is_system(interpreter, name):
        return None
    missing = lacking(interpreter, system, script_imports(script), environ, cache)
    return (interpreter, system, missing) if missing else None
