"""model/config.py's records: namedtuples (model/record.py) built by position (the loader's fast path) or by keyword.

The loader builds thousands of Params and Nodes with positional arguments; the
rest of the code builds them by keyword. Both must make the same immutable
objects, compared, hashed and printed by field.
"""

from __future__ import annotations

import copy
import pickle

import pytest

from launcher.model.config import LaunchConfig, Machine, Node, Param, new_param

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
def test_record_by_keyword_and_by_position_is_the_same_immutable_value(cls, kwargs):
    obj = cls(**kwargs)
    assert tuple(obj) == tuple(kwargs.get(f, getattr(obj, f)) for f in cls._fields)
    assert repr(obj) == "%s(%s)" % (cls.__name__, ", ".join("%s=%r" % (f, getattr(obj, f)) for f in cls._fields))
    positional = cls(*obj)
    assert positional == obj and repr(positional) == repr(obj) and positional is not obj
    assert positional == tuple(obj)  # a record is a tuple, and compares as one
    if all(isinstance(v, (str, int, float, tuple, type(None))) for v in obj):
        assert hash(positional) == hash(obj) == hash(tuple(obj))
    else:
        with pytest.raises(TypeError):
            hash(obj)  # an unhashable field (a dict, a list) makes the record unhashable
    first = cls._fields[0]
    assert cls(**dict(kwargs, **{first: "other"})) != obj
    with pytest.raises(AttributeError):
        setattr(obj, first, "x")
    with pytest.raises(AttributeError):
        obj.new_attribute = 1
    for dup in (copy.copy(obj), copy.deepcopy(obj), pickle.loads(pickle.dumps(obj))):
        assert dup == obj and type(dup) is cls


def test_loader_fast_param_is_the_constructors():
    # the loader builds its thousands of Params with new_param (no Python-level call)
    for args in (("/a/b", [1, 2], "f.launch", 7), ("/a", "x", "", 0)):
        fast, public = new_param(*args), Param(*args)
        assert type(fast) is Param and fast == public and repr(fast) == repr(public)
        assert (fast.key, fast.value, fast.filename, fast.line) == args
    assert Param("/a", 1) == ("/a", 1, "", 0)


def test_fresh_default_dicts():
    a, b = LaunchConfig(), LaunchConfig()
    assert a.params == {} and a.params is not b.params and a.machines is not b.machines
    assert a._replace(files=("f",)).files == ("f",) and type(a._replace()) is LaunchConfig


def test_node_properties():
    n = Node(**NODE_KWARGS)
    assert n.full_name == "/ns/n" and not n.is_test
    assert Node("p", "t", "n", namespace="/ns").full_name == "/ns/n"
    assert Node("p", "t", "n", test_name="tn").is_test
    assert Machine("m", "127.0.1.1").is_local and not Machine("m", "robot").is_local


def test_config_imports_nothing_of_the_launcher_but_names_and_record():
    # and not dataclasses (with inspect, ~5 ms on the way to `launch --nodes`) nor typing (~3 ms)
    import subprocess
    import sys
    code = ("import sys; before = set(sys.modules); import launcher.model.config; "
            "print(sorted(m for m in set(sys.modules) - before if m.startswith('launcher.') or m in ('dataclasses', 'typing')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "['launcher.model', 'launcher.model.config', 'launcher.model.names', 'launcher.model.record']"
