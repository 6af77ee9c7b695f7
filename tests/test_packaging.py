"""What pyproject.toml declares matches what the code needs."""

from __future__ import annotations

import os
import re

import pytest

from launcher import tool

from helpers import ROOT

tomllib = pytest.importorskip("tomllib")

# distribution name -> the module it provides, where they differ
MODULE_OF = {"pyyaml": "yaml"}


def test_every_runtime_dependency_is_imported_by_launcher():
    with open(os.path.join(ROOT, "pyproject.toml"), "rb") as f:
        deps = tomllib.load(f)["project"]["dependencies"]
    sources = []
    for folder, _dirs, files in os.walk(os.path.join(ROOT, "launcher")):
        sources += [open(os.path.join(folder, n)).read() for n in files if n.endswith(".py")]
    code = "\n".join(sources)
    for dep in deps:
        name = re.match(r"[A-Za-z0-9_.-]+", dep).group().lower()
        module = MODULE_OF.get(name, name.replace("-", "_"))
        assert re.search(r"^\s*(?:import|from) %s\b" % re.escape(module), code, re.M), \
            "%s is a runtime dependency but no launcher module imports %s" % (name, module)
        assert module in tool.REQUIRED_PACKAGES, "launcher.tool's clear error does not know %s" % module


def test_pytest_plugin_is_registered_by_entry_point():
    with open(os.path.join(ROOT, "pyproject.toml"), "rb") as f:
        project = tomllib.load(f)["project"]
    module = project["entry-points"]["pytest11"]["launcher"]
    assert os.path.isfile(os.path.join(ROOT, *module.split(".")) + ".py")
    assert "def ros_launch" in open(os.path.join(ROOT, *module.split(".")) + ".py").read()


def test_a_python_without_a_dependency_gets_a_clear_error_not_a_traceback():
    """`launcher test` run by an interpreter launcher was not installed for (Debian's python3 lacks lxml)."""
    import subprocess
    import sys
    code = "import sys; sys.modules['lxml'] = None\nfrom launcher.tool import main\nsys.exit(main(['test', '--help']))"
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       cwd=ROOT)
    assert p.returncode == 1
    assert "Traceback" not in p.stderr
    assert "lacks lxml" in p.stderr and sys.executable in p.stderr
