"""Fuzzing the loader: whatever the launch file, only a LaunchError may escape, never a traceback.

Inputs are the compat corpus's launch files mutated structurally (attributes dropped,
elements duplicated or renamed, values replaced by random substitution args, deep
nesting) and at the byte level (truncation, junk), plus small generated documents.
Where a file loads, each node's command line is computed too, as `--args` would.
"""

from __future__ import annotations

import glob
import os
import pickle
import shutil
from unittest import mock

import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st
from lxml import etree

from launcher.model.errors import LaunchError

from helpers import COMPAT

CORPUS = sorted(p for ext in ("launch", "xml", "test")
                for p in glob.glob(COMPAT + "/pkgs/**/*." + ext, recursive=True)
                if not p.endswith("package.xml"))
TAGS = ["launch", "node", "include", "group", "arg", "param", "rosparam", "remap", "env", "machine", "test",
        "master", "bogus"]
ATTRS = ["name", "value", "default", "type", "pkg", "file", "ns", "if", "unless", "command", "textfile",
         "binfile", "args", "respawn", "required", "output", "cwd", "launch-prefix", "clear_params",
         "pass_all_args", "subst_value", "param", "from", "to", "machine", "address", "test-name", "time-limit",
         "retry", "respawn_delay", "doc", "default", "env-loader", "ssh-port"]
SUBST_WORDS = ["arg", "find", "env", "optenv", "anon", "eval", "dirname", "nosuch", ""]
SAFE_TOOLS = ("echo", "cat", "printf", "false", "true")

pytestmark = pytest.mark.skipif(not CORPUS, reason="compat corpus missing")


@pytest.fixture(scope="module")
def sandbox(tmp_path_factory):
    """Environment for every load: the compat packages, and a PATH holding only harmless tools,
    because fuzzed `<param command=...>` attributes are executed by the loader."""
    root = tmp_path_factory.mktemp("fuzz")
    bindir = root / "bin"
    bindir.mkdir()
    for tool in SAFE_TOOLS:
        real = shutil.which(tool)
        if real:
            os.symlink(real, bindir / tool)
    env = {"PATH": str(bindir), "HOME": str(root), "ROS_HOME": str(root / "home"),
           "ROS_PACKAGE_PATH": COMPAT + "/pkgs", "CMAKE_PREFIX_PATH": COMPAT + "/ws"}
    from launcher.workspace.packages import PackageIndex
    return root, env, PackageIndex(env)


substitution = st.builds(
    lambda word, args, before, after, close: "%s$(%s%s%s%s" % (before, word, " " if args else "", " ".join(args),
                                                               ")" if close else "") + after,
    st.sampled_from(SUBST_WORDS),
    st.lists(st.sampled_from(["x", "roslaunch_compat", "compat_nodes", "HOME", "1 + 1", "__import__", "a b",
                              "$(arg x)", "(", ")", "$", "'s'", "pi", "true"]), max_size=3),
    st.sampled_from(["", "a", "$", "/"]), st.sampled_from(["", "/x", ")", " z", "$("]), st.booleans())

attr_value = st.one_of(
    substitution,
    st.sampled_from(["", " ", "true", "false", "1", "0", "yes", "-1", "1e400", "nan", "/", "~", "~p", "//a//b",
                     "a/b", "1abc", "screen", "log", "node", "ROS_HOME", "yaml", "int", "double", "bool", "str",
                     "load", "dump", "delete", "{a: 1", "[1, 2]", "deg(90)", "!degrees x", "x" * 300]),
    st.text(max_size=20))


def _mutate_tree(data, root) -> None:
    try:
        _mutate_elements(data, root)
    except ValueError:
        pass  # lxml refuses to build XML with control characters; the byte mutations cover those


def _mutate_elements(data, root) -> None:
    elements = list(root.iter(etree.Element))
    for _ in range(data.draw(st.integers(1, 4), label="mutations")):
        if not elements:
            return
        el = data.draw(st.sampled_from(elements), label="element")
        op = data.draw(st.sampled_from(["del_attr", "set_attr", "rename", "dup", "remove", "nest", "text", "child"]),
                       label="op")
        if op == "del_attr" and el.attrib:
            del el.attrib[data.draw(st.sampled_from(sorted(el.attrib)), label="attr")]
        elif op == "set_attr":
            el.set(data.draw(st.sampled_from(ATTRS), label="attr"), data.draw(attr_value, label="value"))
        elif op == "rename":
            el.tag = data.draw(st.sampled_from(TAGS), label="tag")
        elif op == "dup" and el.getparent() is not None:
            el.addnext(etree.fromstring(etree.tostring(el)))
        elif op == "remove" and el.getparent() is not None:
            el.getparent().remove(el)
            elements = list(root.iter(etree.Element))
        elif op == "nest" and el.getparent() is not None:
            depth = data.draw(st.sampled_from([1, 5, 50, 200]), label="depth")
            parent, index = el.getparent(), el.getparent().index(el)
            outer = inner = etree.Element("group")
            for _ in range(depth - 1):
                inner = etree.SubElement(inner, "group")
            parent.remove(el)
            inner.append(el)
            parent.insert(index, outer)
            elements = list(root.iter(etree.Element))
        elif op == "text":
            el.text = data.draw(st.one_of(attr_value, st.sampled_from(["a: [1", "a: 1\nb: !radians x", "42",
                                                                         "- 1\n- 2", "a: !!binary aGk="])),
                                label="text")
        elif op == "child":
            child = etree.SubElement(el, data.draw(st.sampled_from(TAGS), label="tag"))
            for _ in range(data.draw(st.integers(0, 3), label="n_attrs")):
                child.set(data.draw(st.sampled_from(ATTRS), label="attr"), data.draw(attr_value, label="value"))


def _mutate_bytes(data, raw: bytes) -> bytes:
    op = data.draw(st.sampled_from(["none", "none", "truncate", "junk", "flip"]), label="byte op")
    if op == "truncate" and raw:
        return raw[:data.draw(st.integers(0, len(raw) - 1), label="cut")]
    if op == "junk":
        at = data.draw(st.integers(0, len(raw)), label="at")
        return raw[:at] + data.draw(st.binary(min_size=1, max_size=16), label="junk") + raw[at:]
    if op == "flip" and raw:
        at = data.draw(st.integers(0, len(raw) - 1), label="at")
        return raw[:at] + bytes([raw[at] ^ data.draw(st.integers(1, 255), label="xor")]) + raw[at + 1:]
    return raw


def _event(name: str) -> None:
    """Count outcomes in hypothesis' statistics (--hypothesis-show-statistics), outside it a no-op."""
    from hypothesis.errors import InvalidArgument
    try:
        event(name)
    except InvalidArgument:
        pass


def _load_and_compute(path: str, argv: list[str], env: dict, packages) -> None:
    from launcher.model.names import AnonNames
    from launcher.plan.command import node_command
    from launcher.plan.plan import Plan
    from launcher.params.rosyaml import dump_yaml
    from launcher.xml import load

    with mock.patch.dict(os.environ, {"PATH": env["PATH"]}):
        try:
            config = load([path], argv, environ=env, packages=packages, core=False)
        except LaunchError as e:
            assert str(e)
            _event("load refused")
            return
        _event("loaded")
        # (a launch's plan crosses a pipe from the process that read its files: run/apart.py)
        plan = Plan(config, "http://127.0.0.1:11311/", env, packages=packages, anon_names=AnonNames())
        crossed = pickle.loads(pickle.dumps(plan, pickle.HIGHEST_PROTOCOL))
        assert repr(crossed.config) == repr(config) and crossed.packages.ros_paths == packages.ros_paths
        dump_yaml({k: p.value for k, p in config.params.items()})
        for node in list(config.nodes) + list(config.tests):
            try:
                cmd = node_command(node, master_uri="http://127.0.0.1:11311/", environ=env, packages=packages)
            except LaunchError as e:
                assert str(e)
                continue
            assert cmd.argv and all(isinstance(a, str) for a in cmd.argv)
            _event("node command computed")


FUZZ_SETTINGS = settings(max_examples=200, deadline=None, database=None,
                         suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture,
                                                HealthCheck.data_too_large])


@FUZZ_SETTINGS
@given(data=st.data())
def test_mutated_corpus_files(sandbox, data):
    root, env, packages = sandbox
    source = data.draw(st.sampled_from(CORPUS), label="corpus file")
    with open(source, "rb") as f:
        raw = f.read()
    try:
        tree = etree.fromstring(raw, etree.XMLParser(resolve_entities=False, no_network=True))
        _mutate_tree(data, tree)
        raw = etree.tostring(tree)
    except etree.XMLSyntaxError:
        pass  # corpus files that are malformed on purpose are fuzzed at the byte level only
    raw = _mutate_bytes(data, raw)
    path = root / "case.launch"
    path.write_bytes(raw)
    argv = data.draw(st.lists(st.sampled_from(["a:=1", "x:=", "__ns:=/fz", "required:=x", "_p:=1", "b:=$(arg a)",
                                               "if_test:=0", "foo:=bar"]), max_size=3), label="argv")
    _load_and_compute(str(path), argv, env, packages)


@st.composite
def generated_document(draw, depth=0):
    tag = draw(st.sampled_from(TAGS[1:]))
    attrs = " ".join('%s="%s"' % (a, draw(attr_value).replace("&", "&amp;").replace('"', "&quot;")
                                  .replace("<", "&lt;"))
                     for a in draw(st.lists(st.sampled_from(ATTRS), max_size=4, unique=True)))
    children = ""
    if depth < 3 and tag in ("group", "node", "include", "test", "launch"):
        children = "".join(draw(st.lists(generated_document(depth + 1), max_size=3)))
    return "<%s %s>%s</%s>" % (tag, attrs, children, tag)


@FUZZ_SETTINGS
@given(body=st.lists(generated_document(), max_size=5))
def test_generated_documents(sandbox, body):
    root, env, packages = sandbox
    path = root / "gen.launch"
    path.write_text("<launch>%s</launch>" % "".join(body), encoding="utf-8", errors="surrogatepass")
    _load_and_compute(str(path), [], env, packages)


def test_fuzz_harness_sees_errors(sandbox):
    """The harness must distinguish: a broken file raises LaunchError, a good one loads."""
    from launcher.xml import load
    root, env, packages = sandbox
    bad = root / "bad.launch"
    bad.write_text("<launch><param name='x' type='int' value='no'/></launch>")
    with pytest.raises(LaunchError):
        load([str(bad)], [], environ=env, packages=packages, core=False)
    good = root / "good.launch"
    good.write_text("<launch><node pkg='compat_nodes' type='talker' name='t'/></launch>")
    config = load([str(good)], [], environ=env, packages=packages, core=False)
    from launcher.plan.command import node_command
    cmd = node_command(config.nodes[0], master_uri="http://127.0.0.1:11311/", environ=env, packages=packages)
    assert cmd.argv[0].endswith("compat_nodes/scripts/talker")


@pytest.mark.parametrize("source", CORPUS, ids=[os.path.relpath(p, COMPAT + "/pkgs") for p in CORPUS])
def test_every_corpus_file_loads_or_fails_cleanly(sandbox, source):
    _root, env, packages = sandbox
    _load_and_compute(source, [], env, packages)
