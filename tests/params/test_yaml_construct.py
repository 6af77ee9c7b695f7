"""rosyaml's libyaml path (cached tag resolution, direct construction) gives exactly what PyYAML's gives."""

from __future__ import annotations

import math

import pytest
import yaml

from launcher.params import rosyaml

CASES = [
    "a: 1\nb: -2\nc: +3\nd: 0\ne: 012\nf: 0x1F\ng: 0b101\nh: 1_000\ni: 1:30\n",
    "a: 1.5\nb: -0.0\nc: +1.0e+5\nd: .inf\ne: -.Inf\nf: .nan\ng: 1_0.5\nh: 1:30.5\ni: 6.8523015e+5\n",
    "a: yes\nb: No\nc: on\nd: OFF\ne: true\nf: False\ng: ~\nh: null\ni:\nj: 'yes'\nk: \"1\"\n",
    "list: [1, 2.0, x, true, null, [a, b], {c: d}]\nempty_list: []\nempty_map: {}\n",
    "base: &b {x: 1, y: [1, 2]}\nuse: *b\nmerged:\n  <<: *b\n  z: 3\n",
    "shared: &s [1, 2]\nagain: *s\n",
    "when: 2001-12-14\nstamp: 2001-12-14t21:59:43.10-05:00\n",
    "bin: !!binary aGVsbG8=\nset: !!set {a, b}\nomap: !!omap [a: 1, b: 2]\n",
    "angle: deg(90)\nrad: rad(pi/2)\ntagged: !degrees 180\n",
    "explicit_str: !!str 123\nexplicit_int: !!int \"42\"\nexplicit_float: !!float 3\n",
    "1: int key\n2.5: float key\ntrue: bool key\n~: null key\n",
    "=: value key\n",
    "- just\n- a\n- list\n",
    "plain scalar",
    "",
    "nested:\n  deeper:\n    deepest: [1, {k: v}]\n",
    "unicode: \u00e9t\u00e9\nlong: " + "x" * 500 + "\n",
    "? [complex, key]\n: value\n",
]


def typed(value, seen=None):
    """A comparable form that keeps types (True != 1 != 1.0) and NaN, and records alias sharing."""
    if seen is None:
        seen = {}
    if isinstance(value, (dict, list)):
        if id(value) in seen:
            return ("alias", seen[id(value)])
        seen[id(value)] = len(seen)
        if isinstance(value, dict):
            return ("dict", [(typed(k, seen), typed(v, seen)) for k, v in value.items()])
        return ("list", [typed(v, seen) for v in value])
    if isinstance(value, float) and math.isnan(value):
        return ("float", "nan")
    return (type(value).__name__, repr(value))


def reference(angles: bool) -> type:
    """PyYAML's own libyaml loader (its resolve and constructor), with rosparam's tags if `angles`."""
    ref = type("Reference", (yaml.CSafeLoader,), {})
    return rosyaml._with_ros_syntax(ref) if angles else ref


@pytest.mark.parametrize("text", CASES)
@pytest.mark.parametrize("angles", [True, False])
def test_same_as_safe_constructor(text, angles):
    cls = rosyaml._C_ROS if angles else rosyaml._C_PLAIN
    if cls is None:
        pytest.skip("PyYAML without libyaml")
    try:
        expected = ("ok", typed(yaml.load(text, Loader=reference(angles))))
    except yaml.YAMLError as e:
        expected = ("error", type(e).__name__)
    try:
        got = ("ok", typed(rosyaml._load_c(text, cls)))
    except yaml.YAMLError as e:
        got = ("error", type(e).__name__)
    assert got == expected


def test_plain_documents_skip_pyyaml_constructor(monkeypatch):
    """The fast path is really taken for plain documents (so the comparison above tests it)."""
    cls = rosyaml._C_ROS
    if cls is None:
        pytest.skip("PyYAML without libyaml")

    def refuse(self, node):
        raise AssertionError("PyYAML's constructor used for a plain document")

    monkeypatch.setattr(cls, "construct_document", refuse)
    assert rosyaml._load_c("a: [1, 2.5, x, true, null]\nb: {c: d}\n", cls) == {
        "a": [1, 2.5, "x", True, None], "b": {"c": "d"}}


def test_repeated_plain_text_gives_independent_values():
    """A memoised document without aliases is copied by the plain-tree copier: nothing is shared."""
    rosyaml._parsed.clear()
    text = "a: {b: [1, {c: 2}]}\nd: [[3], []]\n"
    first = rosyaml.load_yaml(text)
    assert rosyaml._parsed[(text, True)][1] is True  # taken as a plain tree
    first["a"]["b"][1]["c"] = 99
    first["d"][0].append(4)
    second = rosyaml.load_yaml(text)
    third = rosyaml.load_yaml(text)
    assert second == third == {"a": {"b": [1, {"c": 2}]}, "d": [[3], []]}
    assert second["a"]["b"][1] is not third["a"]["b"][1] and second["d"][1] is not third["d"][1]


def test_aliased_text_is_not_a_plain_tree():
    rosyaml._parsed.clear()
    text = "x: &s [1]\ny: *s\n"
    value = rosyaml.load_yaml(text)
    assert value["x"] is value["y"]
    assert rosyaml._parsed[(text, True)][1] is False
