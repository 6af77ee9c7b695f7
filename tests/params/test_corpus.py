"""Real ROS parameter files (tests/params/corpus): read as rosparam reads them, dumped as PyYAML dumps them."""

from __future__ import annotations

import glob
import json
import os
import re
import subprocess

import pytest
import yaml

from launcher.params import rosyaml
from launcher.params.dump import dump_yaml
from launcher.params.rosyaml import load_yaml

CORPUS = os.path.join(os.path.dirname(__file__), "corpus")
FILES = sorted(glob.glob(os.path.join(CORPUS, "*.yaml")))

# rosparam's own loader, in Debian's python: PyYAML's (pure-Python) SafeLoader with the
# constructors rosparam registers on it at import, as roslaunch loads <rosparam> files
REF_SCRIPT = r"""
import json, sys, yaml
import rosparam
print(json.dumps([repr(yaml.load(open(p).read(), Loader=yaml.SafeLoader)) for p in json.loads(sys.argv[1])]))
"""


def _flatten(ns: str, value, out: dict) -> dict:
    """roslaunch's <rosparam> load: a mapping sets one parameter per leaf."""
    if type(value) is dict and value:
        for k, v in value.items():
            _flatten(ns + "/" + str(k), v, out)
    else:
        out[ns] = value
    return out


def test_corpus_is_real_files_each_named_in_the_readme():
    assert len(FILES) >= 20
    readme = open(os.path.join(CORPUS, "README.md")).read()
    for path in FILES:
        assert "`%s`" % os.path.basename(path) in readme, path
    texts = [open(p).read() for p in FILES]
    # what the benchmark's "real" YAML imitates is there: comments, block lists, double quotes
    assert sum("#" in t for t in texts) >= 10
    assert sum(re.search(r"^ *- ", t, re.M) is not None for t in texts) >= 3
    assert any('"' in t for t in texts)


def test_corpus_reads_exactly_as_rosparam_reads_it(ros_env):
    env = dict(os.environ, PATH=ros_env["path"])
    ref = json.loads(subprocess.run([ros_env["python"], "-c", REF_SCRIPT, json.dumps(FILES)], env=env,
                                    capture_output=True, text=True, check=True, timeout=120).stdout)
    for path, expected in zip(FILES, ref):
        assert repr(load_yaml(open(path).read(), filename=path)) == expected, path


@pytest.mark.parametrize("path", FILES, ids=os.path.basename)
def test_corpus_reads_as_pyyaml_pure_loader_reads_it(path):
    text = open(path).read()
    expected = yaml.load(text, Loader=rosyaml._PY_ROS)
    got = load_yaml(text, filename=path)
    assert repr(got) == repr(expected)
    assert repr(load_yaml(text, filename=path, angles=False)) == repr(yaml.load(text, Loader=rosyaml._PY_PLAIN))


@pytest.mark.parametrize("path", FILES, ids=os.path.basename)
def test_corpus_dumps_byte_for_byte_as_pyyaml(path):
    params = _flatten("/ns", load_yaml(open(path).read(), filename=path), {})
    assert dump_yaml(params) == rosyaml._pyyaml_dump(params)
