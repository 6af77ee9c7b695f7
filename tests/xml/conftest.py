"""Fixtures for loader tests: a small package tree and a helper that writes launch files and loads them."""

from __future__ import annotations

import os
import textwrap

import pytest

PACKAGE_XML = """<?xml version="1.0"?>
<package format="2"><name>%s</name><version>0.0.1</version><description>t</description>
<maintainer email="t@example.com">t</maintainer><license>BSD</license></package>
"""


def make_package(root, name, executables=("talker",), files=None):
    d = root / name
    (d / "scripts").mkdir(parents=True)
    (d / "package.xml").write_text(PACKAGE_XML % name)
    for exe in executables:
        p = d / "scripts" / exe
        p.write_text("#!/bin/sh\nexit 0\n")
        p.chmod(0o755)
    for rel, text in (files or {}).items():
        f = d / rel
        f.parent.mkdir(parents=True, exist_ok=True)
        f.write_text(text)
    return d


class LaunchDir:
    """Writes launch files into a temp dir and loads them with a controlled environment."""

    def __init__(self, root):
        self.root = root
        self.pkgs = root / "pkgs"
        self.launch = root / "launch"
        self.launch.mkdir()
        make_package(self.pkgs, "tpkg", ("talker", "listener"),
                     {"config/params.yaml": "a: 1\nb:\n  c: two\n", "data/note.txt": "hello\n"})
        self.environ = {"ROS_PACKAGE_PATH": str(self.pkgs), "CMAKE_PREFIX_PATH": "",
                        "ROS_HOME": str(root / "home"), "PATH": os.environ.get("PATH", "")}

    def write(self, name, text):
        p = self.launch / name
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(textwrap.dedent(text).lstrip("\n"))
        return str(p)

    def load(self, text_or_files, argv=(), env=None, **kw):
        from launcher.xml import load
        if isinstance(text_or_files, str):
            files = [self.write("main.launch", text_or_files)]
        else:
            files = list(text_or_files)
        environ = dict(self.environ, **(env or {}))
        return load(files, list(argv), environ=environ, **kw)

    def params(self, text, argv=(), env=None, **kw):
        return {k: p.value for k, p in self.load(text, argv, env, core=False, **kw).params.items()}

    def error(self, text, argv=(), env=None, **kw):
        from launcher.model.errors import LaunchError
        with pytest.raises(LaunchError) as e:
            self.load(text, argv, env, **kw)
        return e.value


@pytest.fixture
def ld(tmp_path):
    return LaunchDir(tmp_path)
