"""What pyproject.toml declares matches what the code needs."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import zipfile

import pytest

from launcher.cli import tool

from helpers import ROOT, free_port

try:
    import tomllib
except ImportError:  # (Python before 3.11: the same parser, published as tomli)
    import tomli as tomllib

# distribution name -> the module it provides, where they differ
MODULE_OF = {"pyyaml": "yaml"}
# rosbags' own dependencies (0.9's), bounded on 3.8 only for Ubuntu 20.04's pip 20.0.2 (pyproject.toml says why;
# tests/integration/test_pythons.py installs with that pip)
FOR_OLD_PIP = {"numpy", "lz4", "ruamel.yaml", "zstandard"}



def test_every_runtime_dependency_is_imported_by_launcher():
    with open(os.path.join(ROOT, "pyproject.toml"), "rb") as f:
        deps = tomllib.load(f)["project"]["dependencies"]
    sources = []
    for folder, _dirs, files in os.walk(os.path.join(ROOT, "launcher")):
        sources += [open(os.path.join(folder, n)).read() for n in files if n.endswith(".py")]
    code = "\n".join(sources)
    for dep in deps:
        name = re.match(r"[A-Za-z0-9_.-]+", dep).group().lower()
        if name in FOR_OLD_PIP:
            assert "python_version < '3.9'" in dep, "%s is there only for pip 20.0.2 on 3.8" % dep
            continue
        module = MODULE_OF.get(name, name.replace("-", "_"))
        assert re.search(r"^\s*(?:import|from) %s\b" % re.escape(module), code, re.M), \
            "%s is a runtime dependency but no launcher module imports %s" % (name, module)
        assert module in tool.REQUIRED_PACKAGES, "launcher.cli.tool's clear error does not know %s" % module


def test_pytest_plugin_is_registered_by_entry_point():
    with open(os.path.join(ROOT, "pyproject.toml"), "rb") as f:
        project = tomllib.load(f)["project"]
    module = project["entry-points"]["pytest11"]["launcher"]
    assert os.path.isfile(os.path.join(ROOT, *module.split(".")) + ".py")
    assert "def ros_launch" in open(os.path.join(ROOT, *module.split(".")) + ".py").read()


def test_a_python_without_a_dependency_gets_a_clear_error_not_a_traceback():
    """`launcher test` run by an interpreter launcher was not installed for (Debian's python3 lacks lxml)."""
    code = "import sys; sys.modules['lxml'] = None\nfrom launcher.cli.tool import main\nsys.exit(main(['test', '--help']))"
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       cwd=ROOT)
    assert p.returncode == 1
    assert "Traceback" not in p.stderr
    assert "lacks lxml" in p.stderr and sys.executable in p.stderr


# -- the distribution as published: sdist and wheel built, checked, the wheel installed and run ---------------

def _source_files() -> set[str]:
    """Every file of the `launcher` package in this tree (what it may need at run time), as wheel paths."""
    files = set()
    for folder, dirs, names in os.walk(os.path.join(ROOT, "launcher")):
        dirs[:] = [d for d in dirs if d != "__pycache__"]
        files.update(os.path.relpath(os.path.join(folder, n), ROOT).replace(os.sep, "/")
                     for n in names if not n.endswith((".pyc", ".pyo")))
    return files


@pytest.fixture(scope="module")
def dist(tmp_path_factory):
    """`python -m build`: the sdist, then the wheel built from it (as a package index would get them)."""
    out = tmp_path_factory.mktemp("dist")
    r = subprocess.run([sys.executable, "-m", "build", "--outdir", str(out), ROOT], capture_output=True, text=True,
                       timeout=600)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    sdists, wheels = sorted(out.glob("*.tar.gz")), sorted(out.glob("*.whl"))
    assert len(sdists) == 1 and len(wheels) == 1, os.listdir(out)
    return sdists[0], wheels[0], r.stdout + r.stderr


def test_the_build_is_warned_of_nothing(dist):
    """setuptools warns of metadata it will stop accepting (a `license` table: "your builds will no longer be
    supported"): none of that."""
    assert "Warning" not in dist[2] and "deprecated" not in dist[2], dist[2][-3000:]


def test_twine_accepts_the_sdist_and_the_wheel(dist):
    r = subprocess.run([sys.executable, "-m", "twine", "check", "--strict", *map(str, dist[:2])], capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr
    assert r.stdout.count("PASSED") == 2, r.stdout


def test_the_wheel_holds_every_file_of_the_package_and_its_commands(dist):
    with zipfile.ZipFile(dist[1]) as whl:
        names = set(whl.namelist())
        entry_points = next(whl.read(n).decode() for n in names if n.endswith(".dist-info/entry_points.txt"))
    packaged = {n for n in names if n.startswith("launcher/")}
    assert _source_files() - packaged == set(), "files the installed package would lack"
    assert packaged - _source_files() == set(), "files in the wheel that are not in the package"
    with open(os.path.join(ROOT, "pyproject.toml"), "rb") as f:
        project = tomllib.load(f)["project"]
    for name, target in list(project["scripts"].items()) + list(project["entry-points"]["pytest11"].items()):
        assert "%s = %s" % (name, target) in entry_points, entry_points


def test_the_wheel_installed_in_a_fresh_venv_runs_the_demo(dist, tmp_path):
    """The wheel alone (no source tree on the path) in a new virtual environment: its `launch` runs README's demo
    from this repository's examples to its end, exit status 0."""
    # nothing of this tree's (PYTHONPATH) nor of a ROS set-up: what a new user's shell has
    env = {k: v for k, v in os.environ.items() if not k.startswith(("PYTHON", "ROS_")) and k != "VIRTUAL_ENV"}
    port = free_port()
    # the demo's plain-Python nodes run the system's python3, as README's install leaves them
    env.update(PATH="/usr/bin:/bin", ROS_PACKAGE_PATH=os.path.join(ROOT, "examples"), ROS_HOME=str(tmp_path / "home"),
               ROS_MASTER_URI="http://127.0.0.1:%d/" % port)
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=300, env=env)
    r = subprocess.run([str(venv / "bin" / "pip"), "install", "-q", str(dist[1])], capture_output=True, text=True,
                       timeout=600, env=env, cwd=tmp_path)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    where = subprocess.run([str(venv / "bin" / "python"), "-c", "import launcher; print(launcher.__file__)"],
                           cwd=tmp_path, env=env, capture_output=True, text=True, timeout=60)
    assert where.stdout.startswith(str(venv)), where.stdout + where.stderr
    r = subprocess.run([str(venv / "bin" / "launch"), os.path.join(ROOT, "examples", "launch", "demo.launch"),
                        "duration:=3"], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert "[/demo/greeter] parameters from the master: greeting='hello from the parameter server'" in r.stdout
    assert "REQUIRED process [mission-5] has died!\nprocess has finished cleanly" in r.stderr
