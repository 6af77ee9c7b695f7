"""launcher/workspace/nodepython.py: which python a node script's `#!/usr/bin/env python3` runs, and whether it is the
system's (a venv's python is a link to the system's and still is not)."""

from __future__ import annotations

import os
import subprocess

import pytest

from launcher.workspace import nodepython

SYSTEM = nodepython.system_python("python3")


def test_script_imports_reads_every_form(tmp_path):
    script = tmp_path / "node"
    script.write_text("#!/usr/bin/env python3\n# import commented\nimport rospy, os.path as p\n"
                      "from std_msgs.msg import String\nfrom . import sibling\n    import yaml  # in a block\n"
                      "print('import text')\nimport rospy\n")
    assert nodepython.script_imports(str(script)) == ["rospy", "os", "std_msgs", "yaml"]


@pytest.mark.parametrize("head, name", [("#!/usr/bin/env python3\n", "python3"), ("#!/bin/env python\n", "python"),
                                        ("#!/usr/bin/python3\n", None), ("#!/usr/bin/env -S python3 -u\n", None),
                                        ("#!/usr/bin/env python3.11\r\n", "python3.11"), ("import rospy\n", None)])
def test_env_python(tmp_path, head, name):
    script = tmp_path / "node"
    script.write_text(head + "pass\n")
    assert nodepython.env_python(str(script)) == name


def test_missing_module_of_a_traceback():
    out = b"Traceback (most recent call last):\n  File \"x\", line 2\nModuleNotFoundError: No module named 'rospy.impl'\n"
    assert nodepython.missing_module(out) == "rospy.impl"
    assert nodepython.missing_module(b"ImportError: cannot import name 'x'\n") is None


@pytest.mark.skipif(SYSTEM is None, reason="no system python3 in /usr/bin or /bin")
def test_a_venv_made_from_the_system_python_is_not_the_system_python(tmp_path):
    subprocess.run([SYSTEM, "-m", "venv", "--without-pip", str(tmp_path / "v")], check=True)
    venv_python = str(tmp_path / "v" / "bin" / "python3")
    assert os.path.realpath(venv_python) == os.path.realpath(SYSTEM)  # the trap: the same file underneath
    assert not nodepython.is_system(venv_python)
    assert nodepython.is_system(SYSTEM)
    env = dict(os.environ, PATH="%s:/usr/bin:/bin" % (tmp_path / "v" / "bin"))
    assert nodepython.on_path("python3", env) == venv_python
    # the venv sees only its own (empty) site-packages: the stdlib is there, the system's packages are not
    cache: dict = {}
    assert nodepython.lacking(venv_python, SYSTEM, ["os", "no_such_module_anywhere"], env, cache) == []
    assert cache[(venv_python, "os")] and not cache[(SYSTEM, "no_such_module_anywhere")]
