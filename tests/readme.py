"""README.md as the tests read it: the shell block under a heading (the commands it promises to work)."""

from __future__ import annotations

import os
import re

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
README = os.path.join(ROOT, "README.md")


def text() -> str:
    with open(README) as f:
        return f.read()


def section(heading: str) -> str:
    """The text under `## heading` (or `###`), up to the next heading of any level."""
    m = re.search(r"^#{2,3} %s\n(.*?)(?=^#{1,3} |\Z)" % re.escape(heading), text(), re.M | re.S)
    assert m, "README.md has no section %r" % heading
    return m.group(1)


def shell_block(heading: str) -> str:
    """The first ```sh block of that section."""
    m = re.search(r"^```sh\n(.*?)^```", section(heading), re.M | re.S)
    assert m, "README.md's %r has no ```sh block" % heading
    return m.group(1)
