"""ROS graph names: the same answers as rosgraph.names (Debian's, run by its own python) on many names."""

from __future__ import annotations

import itertools
import json
import random
import subprocess

from launcher.model import names

from helpers import ROS_PYTHON

# rosgraph.names' answers for each case: [function, args...] -> ["val", result] or ["err", exception type]
REFERENCE = r"""
import json, sys
import rosgraph.names as n
out = []
for fn, *args in json.load(sys.stdin):
    try:
        out.append(["val", getattr(n, fn)(*args)])
    except Exception as e:
        out.append(["err", type(e).__name__])
print(json.dumps(out))
"""

PIECES = ["", "/", "//", "~", "a", "b_1", "/a", "a/", "/a/b", "a//b", "/a/b/", "~p", "~p/q", "//a", "/a//b//"]


def _cases() -> list[list]:
    rnd = random.Random(11)
    made = {"".join(rnd.choice(PIECES) for _ in range(rnd.randint(1, 4))) for _ in range(300)}
    words = sorted(set(PIECES) | made)
    cases: list[list] = []
    for w in words:
        cases += [["canonicalize_name", w], ["namespace", w]]
    for name, ns in itertools.product(words, ["", "/", "/node", "/ns/node", "/ns/", "rel", "/a//b/"]):
        cases.append(["resolve_name", name, ns])
        cases.append(["resolve_name", name, ns, {"/ns/a": "/remapped", "/a": "/other"}])
    return cases


def _ours(fn: str, *args) -> list:
    try:
        return ["val", getattr(names, fn)(*args)]
    except Exception as e:  # noqa: BLE001 - the exception type is part of the behaviour
        return ["err", type(e).__name__]


def test_canonicalize_namespace_and_resolve_answer_as_rosgraph(ros_env, ros_part_missing):
    cases = _cases()
    r = subprocess.run([ROS_PYTHON, "-c", REFERENCE], input=json.dumps(cases), capture_output=True, text=True,
                       timeout=60)
    if r.returncode and "No module named 'rosgraph'" in r.stderr:
        ros_part_missing("rosgraph (Debian's python3-rosgraph) not importable")
    assert r.returncode == 0, r.stderr
    theirs = json.loads(r.stdout)
    assert len(theirs) == len(cases) > 3000
    differ = [(case, mine, ref) for case, ref in zip(cases, theirs) if (mine := _ours(*case)) != ref]
    assert not differ, differ[:10]


def test_the_master_resolves_against_the_caller_id():
    assert names.resolve_name("", "") == "/"  # an empty caller id: the root namespace, as rosmaster
    assert names.resolve_name("p", "/ns/node") == "/ns/p"
    assert names.resolve_name("~p", "/ns/node") == "/ns/node/p"
    assert names.resolve_name("/a//b/", "/n") == "/a/b"
