"""The loader's fast Param/Node construction builds exactly what the dataclass constructors build."""

from __future__ import annotations

import dataclasses

import pytest

from launcher.config import Node, Param
from launcher.xml import loader


def test_param_equals_constructor():
    p = loader._param("/a/b", [1, 2], "f.launch", 7)
    q = Param("/a/b", [1, 2], "f.launch", 7)
    assert p == q and repr(p) == repr(q)
    assert dataclasses.astuple(p) == ("/a/b", [1, 2], "f.launch", 7)
    with pytest.raises(dataclasses.FrozenInstanceError):
        p.key = "/x"  # type: ignore[misc]


def test_node_equals_constructor():
    kwargs = dict(package="pkg", type="t", name="n", namespace="/ns/", args="-a", remap_args=(("a", "b"),),
                  env_args=(("E", "1"),), respawn=True, respawn_delay=1.5, required=False, output="screen",
                  cwd=None, launch_prefix=None, machine_name=None, filename="f.launch", line=3, test_name=None,
                  time_limit=None, retry=0)
    n = loader._node(**kwargs)
    m = Node(**kwargs)
    assert n == m and hash(n) == hash(m) and repr(n) == repr(m)
    assert n.full_name == "/ns/n"
    assert [f.name for f in dataclasses.fields(Node)] == list(loader._NODE_FIELDS)
    with pytest.raises(dataclasses.FrozenInstanceError):
        n.name = "x"  # type: ignore[misc]
