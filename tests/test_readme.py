"""README's two promised commands (run the demo, run the whole test suite): one way of installing, and CI runs the
test command exactly as written."""

from __future__ import annotations

import os
import re
import shlex

from readme import ROOT, shell_block

VENV = ".venv/bin/"


def _commands(block: str) -> list[list[str]]:
    """Each simple command of a one-line block (split at && and ;), environment assignments dropped."""
    words = []
    for part in re.split(r"&&|;|\|\|", " ".join(block.split("\n"))):
        argv = shlex.split(part)
        while argv and re.match(r"^[A-Z_]+=", argv[0]):
            argv.pop(0)
        if argv:
            words.append(argv)
    return words


def test_try_it_and_run_the_tests_both_work_in_the_same_venv():
    """No bare `pip` (Debian's python refuses it, PEP 668) nor a bare `python3` running our code: both blocks make
    .venv with `python3 -m venv` and run everything else from it."""
    for heading in ("Try it", "Run the tests"):
        block = shell_block(heading).strip()
        assert "\n" not in block, "%r: one command line" % heading
        commands = _commands(block)
        assert commands[0] == ["python3", "-m", "venv", ".venv"], (heading, commands[0])
        for argv in commands[1:]:
            assert argv[0].startswith(VENV), "%r runs %s outside the venv" % (heading, argv[0])
        assert any(a[0] == VENV + "pip" and "install" in a for a in commands), heading


def test_ci_runs_the_readme_test_command_as_written():
    with open(os.path.join(ROOT, ".ci", "run")) as f:
        ci = f.read()
    command = shell_block("Run the tests").strip()
    assert any(line.startswith(command) for line in ci.splitlines()), "README's test command is not run by .ci/run"
