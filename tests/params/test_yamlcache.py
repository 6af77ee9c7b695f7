"""The YAML cache under ROS_HOME: an unchanged document is not parsed again (PyYAML is not even imported),
a changed one always is, and what comes out is what the parser gives."""

from __future__ import annotations

import marshal
import os
import subprocess
import sys

import pytest

from launcher.model.errors import LaunchError
from launcher.params import yamlcache
from launcher.params.rosyaml import load_yaml
from launcher.params.yamlcache import YamlCache

from helpers import ROOT

# A launch that loads a parameter file, then tells whether PyYAML was imported and what it loaded.
PROBE = r"""
import json, sys
from launcher.xml import load
config = load([sys.argv[1]])
print(json.dumps({"yaml_imported": "yaml" in sys.modules,
                  "params": {k: repr(p.value) for k, p in config.params.items()}}))
"""


def probe(tmp_path, launch):
    env = dict(os.environ, ROS_HOME=str(tmp_path / "home"), PYTHONPATH=ROOT)
    out = subprocess.run([sys.executable, "-c", PROBE, str(launch)], env=env, capture_output=True, text=True,
                         check=True).stdout
    import json
    return json.loads(out)


@pytest.fixture
def launch(tmp_path):
    params = tmp_path / "params.yaml"
    params.write_text("# comment\nrate: 10\nframe: base_link\ngains: [1.0, 2.5]\nnested: {a: true, b: ~}\n")
    launch = tmp_path / "a.launch"
    launch.write_text('<launch><rosparam command="load" file="%s" ns="robot"/>'
                      '<rosparam>inline: [1, 2]</rosparam></launch>' % params)
    return launch


def test_an_unchanged_file_is_not_parsed_again(tmp_path, launch):
    first = probe(tmp_path, launch)
    assert first["yaml_imported"]
    second = probe(tmp_path, launch)
    assert not second["yaml_imported"]
    assert second["params"] == first["params"]
    assert second["params"]["/robot/gains"] == "[1.0, 2.5]" and second["params"]["/robot/nested/b"] == "None"


def test_a_changed_file_is_parsed_even_with_the_same_size_and_time(tmp_path, launch):
    probe(tmp_path, launch)
    params = tmp_path / "params.yaml"
    st = os.stat(params)
    params.write_text(params.read_text().replace("rate: 10", "rate: 99"))
    os.utime(params, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert os.stat(params).st_size == st.st_size
    again = probe(tmp_path, launch)
    assert again["params"]["/robot/rate"] == "99"


def test_documents_that_are_not_plain_are_parsed_every_time(tmp_path):
    launch = tmp_path / "b.launch"
    launch.write_text('<launch><rosparam>blob: !!binary aGVsbG8=\nwhen: 2001-12-14</rosparam></launch>')
    for _ in range(2):
        out = probe(tmp_path, launch)
        assert out["yaml_imported"]
        assert out["params"]["/blob"] == "b'hello'"


def test_errors_are_never_cached(tmp_path):
    cache = YamlCache(str(tmp_path))
    for _ in range(2):
        with pytest.raises(LaunchError) as e:
            cache.load("a: [1, 2\n", filename="bad.yaml")
        assert e.value.filename == "bad.yaml" and e.value.line
        cache.save()
    assert not os.path.exists(tmp_path / yamlcache.FILE)


def test_each_load_gets_its_own_value(tmp_path):
    cache = YamlCache(str(tmp_path))
    one = cache.load("a: [1, 2]\n")
    one["a"].append(3)
    assert cache.load("a: [1, 2]\n") == {"a": [1, 2]}
    cache.save()
    again = YamlCache(str(tmp_path))
    two = again.load("a: [1, 2]\n")
    two["a"].append(4)
    assert again.load("a: [1, 2]\n") == {"a": [1, 2]}


@pytest.mark.parametrize("text", ["a: 1\n", "- deg(90)\n- rad(pi)\n", "x: .inf\ny: -0.0\nz: 123456789012345678901\n",
                                  "'yes': no\n1: [true, null, 'str']\n"])
def test_a_cached_value_is_the_parsers_value(tmp_path, text):
    for angles in (True, False):
        learning = YamlCache(str(tmp_path))
        learning.load(text, angles=angles)
        learning.save()
        cached = YamlCache(str(tmp_path))
        value = cached.load(text, angles=angles)
        assert cached._learned is False  # (it came from the file)
        expected = load_yaml(text, angles=angles)
        assert repr(value) == repr(expected) and type(value) is type(expected)


def test_a_cache_file_of_an_earlier_reading_is_not_used(tmp_path):
    # version 2 kept libyaml's reading of a '?' inside [] (a value); roslaunch's loader refuses that text
    path = tmp_path / yamlcache.FILE
    path.parent.mkdir(parents=True)
    path.write_bytes(marshal.dumps((2, {("x: [a? ]\n", True): marshal.dumps({"x": ["a?"]})})))
    with pytest.raises(LaunchError):
        YamlCache(str(tmp_path)).load("x: [a? ]\n")


def test_a_broken_cache_file_is_ignored(tmp_path):
    path = tmp_path / yamlcache.FILE
    path.parent.mkdir(parents=True)
    path.write_bytes(b"\x00not marshal")
    assert YamlCache(str(tmp_path)).load("a: 1\n") == {"a": 1}


def test_the_file_keeps_this_runs_documents_first_and_stays_bounded(tmp_path, monkeypatch):
    monkeypatch.setattr(yamlcache, "MAX_CHARS", 40)
    old = YamlCache(str(tmp_path))
    for i in range(5):
        old.load("old_%d: 1234567\n" % i)  # 16 characters each
    old.save()
    new = YamlCache(str(tmp_path))
    new.load("new: 1\n")
    new.save()
    kept = YamlCache(str(tmp_path))._read()
    texts = [text for text, _angles in kept]
    assert texts[0] == "new: 1\n"
    assert sum(len(t) for t in texts) <= 40 and len(texts) == 3
