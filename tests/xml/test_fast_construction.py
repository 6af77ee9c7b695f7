"""config.py's hand-written records behave exactly as the frozen dataclasses they replace.

The loader builds thousands of Params and Nodes with positional arguments (the fast
path); the rest of the code builds them by keyword. Both must make the same objects,
and those must compare, hash, print and refuse assignment as frozen dataclasses with
the same fields would (the reference classes below).
"""

from __future__ import annotations

import copy
import dataclasses
import inspect
import pickle
from typing import Any

import pytest

from launcher.config import FrozenInstanceError, LaunchConfig, Machine, Node, Param, new_param


def _reference(cls: type) -> type:
    """A frozen dataclass with `cls`'s fields, defaults and name: what `cls` must behave like."""
    fields = []
    for p in inspect.signature(cls).parameters.values():
        if p.default is inspect.Parameter.empty:
            fields.append((p.name, Any))
        elif p.default is None and p.name in ("params", "machines"):  # LaunchConfig's fresh dicts
            fields.append((p.name, Any, dataclasses.field(default_factory=dict)))
        else:
            fields.append((p.name, Any, dataclasses.field(default=p.default)))
    ref = dataclasses.make_dataclass(cls.__name__, fields, frozen=True)
    ref.__qualname__ = cls.__qualname__
    return ref


NODE_KWARGS = dict(package="pkg", type="t", name="n", namespace="/ns/", args="-a", remap_args=(("a", "b"),),
                   env_args=(("E", "1"),), respawn=True, respawn_delay=1.5, required=False, output="screen",
                   cwd=None, launch_prefix=None, machine_name=None, filename="f.launch", line=3, test_name=None,
                   time_limit=None, retry=0)
CASES = [
    (Param, dict(key="/a/b", value=[1, 2], filename="f.launch", line=7)),
    (Param, dict(key="/a", value="x")),
    (Node, NODE_KWARGS),
    (Node, dict(package="p", type="t", name="n")),
    (Machine, dict(name="m", address="localhost", ssh_port=2222, timeout=5.0)),
    (LaunchConfig, dict(nodes=(Node("p", "t", "n"),), params={"/a": Param("/a", 1)}, files=("f",))),
    (LaunchConfig, {}),
]


@pytest.mark.parametrize("cls, kwargs", CASES)
def test_record_behaves_as_the_frozen_dataclass(cls, kwargs):
    ref = _reference(cls)
    assert cls._fields == tuple(f.name for f in dataclasses.fields(ref))
    obj, expected = cls(**kwargs), ref(**kwargs)
    assert repr(obj) == repr(expected)
    assert obj.astuple() == dataclasses.astuple(expected)
    # positional construction (the loader's fast path) builds the very same object
    positional = cls(*obj.astuple())
    assert positional == obj and repr(positional) == repr(obj) and positional is not obj
    if all(isinstance(v, (str, int, float, tuple, type(None))) for v in obj.astuple()):
        assert hash(positional) == hash(obj) == hash(expected)
    else:
        with pytest.raises(TypeError):
            hash(obj)  # an unhashable field makes the record unhashable, as in the dataclass
    # equality is by type and fields
    other_field = cls._fields[0]
    changed = cls(**dict(kwargs, **{other_field: "other"}))
    assert changed != obj and obj != expected and obj != obj.astuple()
    # immutable
    with pytest.raises(FrozenInstanceError):
        setattr(obj, other_field, "x")
    with pytest.raises(FrozenInstanceError):
        delattr(obj, other_field)
    with pytest.raises(AttributeError):
        obj.new_attribute = 1
    assert isinstance(FrozenInstanceError("x"), AttributeError)
    # copies and pickles are equal objects
    for dup in (copy.copy(obj), copy.deepcopy(obj), pickle.loads(pickle.dumps(obj))):
        assert dup == obj and type(dup) is cls


def test_loader_fast_param_is_the_constructors():
    # the loader builds its thousands of Params with new_param (no Python-level call)
    for args in (("/a/b", [1, 2], "f.launch", 7), ("/a", "x", "", 0)):
        fast, public = new_param(*args), Param(*args)
        assert type(fast) is Param and fast == public and repr(fast) == repr(public)
        assert (fast.key, fast.value, fast.filename, fast.line) == args
    assert Param("/a", 1) != ("/a", 1, "", 0) and not Param("/a", 1) == ("/a", 1, "", 0)


def test_fresh_default_dicts():
    a, b = LaunchConfig(), LaunchConfig()
    assert a.params == {} and a.params is not b.params and a.machines is not b.machines


def test_node_properties():
    n = Node(**NODE_KWARGS)
    assert n.full_name == "/ns/n" and not n.is_test
    assert Node("p", "t", "n", namespace="/ns").full_name == "/ns/n"
    assert Node("p", "t", "n", test_name="tn").is_test
    assert Machine("m", "127.0.1.1").is_local and not Machine("m", "robot").is_local
