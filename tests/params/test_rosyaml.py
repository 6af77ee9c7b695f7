"""ROS YAML: rosparam's angle syntax, binary data, errors with lines, dumping like roslaunch."""

from __future__ import annotations

import glob
import json
import math
import os
import subprocess
import sys

import pytest
import yaml
from hypothesis import example, given, settings
from hypothesis import strategies as st

from launcher.model.errors import LaunchError
from launcher.params import rosyaml
from launcher.params.rosyaml import RosYamlError, degrees_value, dump_yaml, load_yaml, radians_value

from helpers import COMPAT


@pytest.mark.parametrize("text,expected", [
    ("a: deg(90)", math.pi / 2),
    ("a: deg(-180)", -math.pi),
    ("a: deg(0.5)", 0.5 * math.pi / 180),
    ("a: rad(pi)", math.pi),
    ("a: rad(2*pi/3)", 2 * math.pi / 3),
    ("a: rad(-pi/4)", -math.pi / 4),
    ("a: rad(1.5)", 1.5),
    ("a: !degrees 45", math.pi / 4),
    ("a: !degrees deg(45)", math.pi / 4),
    ("a: !radians pi", math.pi),
    ("a: !radians 2**3", 8.0),
    ("a: !radians rad(pi/2)", math.pi / 2),
    ("a: !radians math.sqrt(4)", 2.0),
    ("a: !radians (1+1)*pi", 2 * math.pi),
])
def test_angles(text, expected):
    assert load_yaml(text)["a"] == pytest.approx(expected, rel=0, abs=0)


@pytest.mark.parametrize("text,expected", [
    ("a: 'deg(90)'", "deg(90)"),          # quoted: no implicit resolution
    ("a: degrees(90)", "degrees(90)"),
    ("a: rad(math.sqrt(4))", "rad(math.sqrt(4))"),  # ')' inside: rosparam's pattern does not match
    ("a: xdeg(90)", "xdeg(90)"),
])
def test_not_angles(text, expected):
    assert load_yaml(text)["a"] == expected


def test_angles_in_lists_and_nested_maps():
    data = load_yaml("list: [deg(0), deg(90), rad(pi)]\nnested:\n  yaw: !degrees 45\n")
    assert data["list"] == [0.0, math.pi / 2, math.pi]
    assert data["nested"]["yaw"] == math.pi / 4


def test_angles_disabled_is_plain_safe_load():
    assert load_yaml("a: deg(90)", angles=False) == {"a": "deg(90)"}
    with pytest.raises(RosYamlError):
        load_yaml("a: !degrees 90", angles=False)


@pytest.mark.parametrize("text,line", [
    ("a: 1\nb: rad(pi/0)\n", 2),
    ("a: 1\n\nb: !degrees pi\n", 3),
    ("a: !radians __import__('os').getcwd()", 1),
    ("a: !radians open('/etc/passwd')", 1),
    ("a: !radians (1).__class__", 1),
    ("a: !radians 10**10**10", 1),
    ("a: !radians lambda: 1", 1),
    ("a: !radians [1, 2]", 1),
])
def test_bad_angles_are_errors_with_line(text, line):
    with pytest.raises(RosYamlError) as err:
        load_yaml(text, filename="f.yaml")
    assert err.value.line == line
    assert str(err.value).startswith("f.yaml:%d: " % line)


def test_radians_evaluator_is_not_eval():
    with pytest.raises(ValueError):
        radians_value("__import__('os').system('true')")
    with pytest.raises(ValueError):
        radians_value("math.factorial(10**9)")
    assert radians_value("  rad(pi/2)  ") == math.pi / 2
    assert degrees_value("deg(180)") == math.pi


def test_pi_substitution_quirk_matches_rosparam():
    # rosparam replaces every 'pi' textually, so 'pi' inside a longer word breaks the expression
    with pytest.raises(ValueError):
        radians_value("spin")


def test_binary_is_bytes_and_dumps_as_binary():
    data = load_yaml("blob: !!binary aGVsbG8=")
    assert data == {"blob": b"hello"}
    assert dump_yaml(data) == "blob: !!binary |\n  aGVsbG8=\n"


def test_merge_keys():
    text = "base: &b {x: 1, y: 2}\nderived:\n  <<: *b\n  y: 3\n"
    assert load_yaml(text)["derived"] == {"x": 1, "y": 3}


def test_yaml_1_1_scalars_like_pyyaml():
    data = load_yaml("a: yes\nb: off\nc: 0x1F\nd: 1_000\ne: 1e3\nf: .inf\ng: ~\nh: 2001-12-14\n")
    assert data["a"] is True and data["b"] is False and data["c"] == 31 and data["d"] == 1000
    assert data["e"] == "1e3" and data["f"] == math.inf and data["g"] is None
    assert str(data["h"]) == "2001-12-14"


def test_error_line_is_offset_by_first_line():
    text = "a: 1\nb: 2\nc: [unclosed\nd: {\n"
    with pytest.raises(RosYamlError) as err:
        load_yaml(text, filename="robot.launch", first_line=20)
    assert isinstance(err.value, LaunchError) and isinstance(err.value, ValueError)
    assert err.value.filename == "robot.launch"
    assert 22 <= err.value.line <= 24
    assert "robot.launch:%d:" % err.value.line in str(err.value)


def test_error_in_file_points_at_problem_line():
    with pytest.raises(RosYamlError) as err:
        load_yaml("ok: 1\nbad: : x\n", filename="p.yaml")
    assert err.value.line == 2
    assert "mapping values are not allowed here" in err.value.message


def test_unprintable_character_error_has_line():
    with pytest.raises(RosYamlError) as err:
        load_yaml("a: 1\nb: \x07\n", filename="p.yaml")
    assert err.value.line == 2
    assert "#x0007" in err.value.message


def test_deep_nesting_is_an_error_not_a_crash():
    with pytest.raises(RosYamlError):
        load_yaml("[" * 20000)


def test_multiple_documents_are_an_error():
    with pytest.raises(RosYamlError):
        load_yaml("a: 1\n---\nb: 2\n")


@pytest.mark.parametrize("how", ["inline", "typed", "file"])
def test_an_integer_too_long_for_python_is_a_clean_error_with_file_and_line(tmp_path, how):
    # Python refuses int() of more than 4300 digits; roslaunch reports it as invalid YAML (so do we, in our words)
    digits = "9" * 5000
    launch = tmp_path / "main.launch"
    where = str(launch)
    if how == "inline":
        launch.write_text("<launch>\n<rosparam>\na: 1\nb: %s\n</rosparam>\n</launch>\n" % digits)
        line = 4
    elif how == "typed":
        launch.write_text('<launch>\n\n<param name="p" type="yaml" value="%s"/>\n</launch>\n' % digits)
        line = 3
    else:
        (tmp_path / "big.yaml").write_text("x: 1\n\nb: %s\n" % digits)
        launch.write_text('<launch>\n<rosparam file="%s"/>\n</launch>\n' % (tmp_path / "big.yaml"))
        where, line = str(tmp_path / "big.yaml"), 3
    out = subprocess.run([sys.executable, "-m", "launcher", "--dump-params", str(launch)],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 1, out
    assert out.stderr.startswith("%s:%d: " % (where, line)), out.stderr
    assert "invalid YAML" in out.stderr and "has more than 4300 digits" in out.stderr, out.stderr
    assert "Traceback" not in out.stderr and "internal error" not in out.stderr


def test_loaders_use_pyyaml_resolution_unpatched():
    # PyYAML's resolver internals are no API: our loader classes only add constructors and
    # implicit resolvers through PyYAML's class methods
    for cls in (rosyaml._C_ROS, rosyaml._C_PLAIN, rosyaml._PY_ROS, rosyaml._PY_PLAIN):
        if cls is None:
            continue
        for name in ("resolve", "descend_resolver", "ascend_resolver"):
            assert getattr(cls, name) is getattr(yaml.resolver.BaseResolver, name), (cls, name)


def test_global_pyyaml_loaders_untouched():
    load_yaml("a: deg(90)")
    assert yaml.safe_load("a: deg(90)") == {"a": "deg(90)"}


def test_dump_like_roslaunch_dump_params():
    value = {"/b": 1.0, "/a": "h\xe9llo \u2713", "/c": [1, True, None], "/d": {"x": "1"}, "/e": float("nan")}
    assert dump_yaml(value) == (
        '/a: "h\\xE9llo \\u2713"\n/b: 1.0\n/c:\n- 1\n- true\n- null\n/d:\n  x: \'1\'\n/e: .nan\n')
    assert dump_yaml({}) == "{}\n"


# -- libyaml vs PyYAML: the fast path must never change a result --------------------------

yaml_scalars = st.one_of(
    st.sampled_from(["1", "1.5", "-2", "deg(90)", "rad(pi/2)", "!degrees 30", "!radians pi", "yes", "~",
                     "'q'", '"d\\n"', "0x1f", "1e3", ".nan", "2001-01-01", "!!binary aGk=", "a b", "&a 1", "*a",
                     "[]", "{}", "|\n  lit\n", ">\n  fold\n", "x: y", "- z", "\t", "#c", "?", "%", "@", "`"]),
    st.text(alphabet=st.characters(min_codepoint=9, max_codepoint=0x2FF), max_size=8))


@st.composite
def yaml_docs(draw):
    lines = []
    for _ in range(draw(st.integers(1, 8))):
        indent = " " * draw(st.sampled_from([0, 0, 2, 4]))
        key = draw(st.sampled_from(["a", "b", "<<", "k k", "'q'", "- ", ""]))
        lines.append("%s%s: %s" % (indent, key, draw(yaml_scalars)) if key != "- " else indent + "- " + draw(yaml_scalars))
    return "\n".join(lines)


def _outcome(loader, text):
    try:
        return ("ok", repr(yaml.load(text, Loader=loader)))
    except Exception as e:  # noqa: BLE001 - any failure counts as "refused"
        return ("error", type(e).__name__ if not isinstance(e, yaml.YAMLError) else "YAMLError")


@pytest.mark.skipif(rosyaml._C_ROS is None, reason="libyaml not available")
@settings(max_examples=300, deadline=None)
@given(yaml_docs())
def test_libyaml_agrees_with_pyyaml(text):
    py = _outcome(rosyaml._PY_ROS, text)
    ours = ("ok", repr(load_yaml(text))) if py[0] == "ok" else None
    if py[0] == "ok":
        assert ours == py
    else:
        with pytest.raises(RosYamlError):
            load_yaml(text)


# -- against rosparam itself -------------------------------------------------------------------

REF_SCRIPT = r"""
import json, sys, yaml
import rosparam  # registers rosparam's constructors on PyYAML's SafeLoader, as roslaunch does
out = []
for path in json.loads(sys.argv[1]):
    with open(path) as f:
        text = f.read()
    try:
        out.append(["ok", repr(yaml.safe_load(text))])
    except Exception as e:
        out.append(["error", None])
print(json.dumps(out))
"""


def test_matches_rosparam_on_corpus_yaml_files(ros_env, tmp_path):
    files = sorted(glob.glob(COMPAT + "/pkgs/**/*.yaml", recursive=True))
    extra = {
        "angles.yaml": "a: deg(30)\nb: rad(pi/3)\nc: !degrees 10\nd: !radians 2*pi\ne: [deg(1), 'deg(1)']\n",
        "bin.yaml": "b: !!binary aGVsbG8=\n",
        "merge.yaml": "x: &x {a: 1}\ny: {<<: *x, b: 2}\n",
        "bad.yaml": "a: [1,\n",
        "badangle.yaml": "a: !degrees pi\n",
        "scalars.yaml": "a: yes\nb: 0o17\nc: 017\nd: 1_0\ne: +.5\nf: -.inf\ng: 1:30\nh: 2001-12-14 21:59:43.10 -5\n",
    }
    for name, text in extra.items():
        (tmp_path / name).write_text(text)
        files.append(str(tmp_path / name))
    assert len(files) > 6
    env = dict(os.environ, PATH=ros_env["path"])
    ref = json.loads(subprocess.run([ros_env["python"], "-c", REF_SCRIPT, json.dumps(files)], env=env,
                                    capture_output=True, text=True, check=True, timeout=120).stdout)
    for path, (status, rrepr) in zip(files, ref):
        text = open(path).read()
        if status == "error":
            with pytest.raises(RosYamlError):
                load_yaml(text, filename=path)
        else:
            # rosparam wraps binary data in xmlrpc Binary; we keep plain bytes
            expected = rrepr.replace("<xmlrpc.client.Binary", "<bin") if rrepr else rrepr
            got = repr(load_yaml(text, filename=path))
            if "Binary" in (rrepr or ""):
                assert "b'hello'" in got
            else:
                assert got == expected, path


# -- the fast dumper must write exactly what PyYAML writes ----------------------------------

_tricky_strings = st.one_of(
    st.sampled_from(["", "a", "/a/b", "123", "1_000", "0x1f", "1e3", "1.5", "true", "Yes", "off", "null", "~",
                     "nan", ".nan", "-", "-a", ".a", "...", "---", "a:b", "a: b", "#x", "a#b", "x" * 99,
                     "x" * 101, "y" * 130, "é", "a\nb", " lead", "trail ", "'q'", '"d"', "2001-12-14", "1:20",
                     "=", "<<", "a.b-c_d/e", "_x", "/", "//", "1abc", "inf", "-.inf", "0o7", "+1", "...",
                     "817", "10.0/2", "1/2", "+1/2", "-1/2", "0b_", "NULL", "On", "Null_x", "_", "/1"]),
    st.sampled_from(["joint_3/link 4", "a b", "a  b", "a b ", "a - b", "a -b", "a #b", "a# b", "a ? b", "_x 1",
                     "/a b/c", "a b: c", "yes no", "a " + "b" * 76, "a " + "b" * 77, "2001-12-14 21:59:43.10",
                     "1 2", ".a b", "-a b", "a\tb", "a b\nc"]),
    st.lists(st.text(alphabet="aZ1_./-", min_size=1, max_size=30), min_size=2, max_size=5).map(" ".join),
    st.lists(st.text(alphabet="aZ1_./-", min_size=1, max_size=90), min_size=2, max_size=40).map(" ".join),
    st.builds(lambda c, n: c * n, st.sampled_from(["x", "1", "a_1/", "-", ".5"]), st.integers(90, 600)),
    st.text(alphabet="ab1_./-()$ '\":#,[]{}&*!|>%@`?=~+<;", min_size=60, max_size=400),
    st.text(max_size=12),
    st.text(alphabet="ab01_./-:# '\"\n", max_size=12))
_scalars = st.one_of(st.none(), st.booleans(), st.integers(), st.integers(min_value=-2**70, max_value=2**70),
                     st.floats(allow_nan=True, allow_infinity=True), _tricky_strings)
_values = st.recursive(_scalars, lambda inner: st.one_of(st.lists(inner, max_size=4),
                                                         st.dictionaries(_tricky_strings, inner, max_size=3)),
                       max_leaves=8)


@settings(max_examples=400, deadline=None)
@given(st.dictionaries(_tricky_strings, _values, max_size=8))
def test_dump_yaml_is_byte_identical_to_pyyaml(params):
    assert dump_yaml(params) == rosyaml._pyyaml_dump(params)


def test_dump_yaml_writes_strings_with_inner_spaces_itself(monkeypatch):
    # real parameter files hold such strings ("joint_3/link 4", frame descriptions): one
    # PyYAML emitter run per parameter made --dump-params several times slower
    value = {"/a": "joint_3/link 4", "/b": ["front left", "x y z"], "/c": {"d": "two words", "e": ["a b"]}}
    expected = rosyaml._pyyaml_dump(value)

    def refuse(value):
        raise AssertionError("PyYAML used for %r" % (value,))
    monkeypatch.setattr("launcher.params.dump._pyyaml_dump", refuse)
    assert dump_yaml(value) == expected
    # a long one is folded at column 80 as PyYAML folds it (its emitter took ~1 s a megabyte)
    long = {"/k": "a " + "b" * 80 + " c" * 200, "/l": ["x " * 100 + "y"], "/m": {"n": "p " * 100 + "q"},
            "/o": "u" * 300_000}
    monkeypatch.undo()
    expected = rosyaml._pyyaml_dump(long)
    monkeypatch.setattr("launcher.params.dump._pyyaml_dump", refuse)
    assert dump_yaml(long) == expected


def test_dump_yaml_shared_containers_keep_pyyaml_anchors():
    shared = [1, 2]
    value = {"/a": shared, "/b": shared}
    assert dump_yaml(value) == rosyaml._pyyaml_dump(value)
    assert "&id001" in dump_yaml(value)


def test_dump_yaml_matches_every_compat_golden():
    if not os.path.isdir(COMPAT + "/golden"):
        pytest.skip("compat corpus missing")
    checked = 0
    for path in glob.glob(COMPAT + "/golden/**/*.json", recursive=True):
        if path.endswith("_meta.json"):
            continue
        with open(path) as f:
            result = json.load(f)["results"].get("--dump-params")
        if not result or result["rc"] != 0 or not result["stdout"]:
            continue
        text = result["stdout"].replace("@COMPAT@", COMPAT)
        assert dump_yaml(yaml.safe_load(text)) + "\n" == text, path
        checked += 1
    assert checked > 50


def test_dump_yaml_nested_fast_path_shapes():
    value = {"/a": {"b": [1, 2.5, "x"], "c": {"d": "yes", "e": {}, "f": [], "g": {"h": None}}, "i": True},
             "/z": [], "/y": {}}
    expected = rosyaml._pyyaml_dump(value)
    assert dump_yaml(value) == expected
    assert expected.startswith("/a:\n  b:\n  - 1\n  - 2.5\n  - x\n  c:\n    d: 'yes'\n")


def test_repeated_text_gives_independent_equal_values():
    text = "a: {b: [1, 2]}\nc: &x [3]\nd: *x\n"
    first = load_yaml(text)
    first["a"]["b"].append(99)
    first["c"].append(4)
    second = load_yaml(text)
    assert second == {"a": {"b": [1, 2]}, "c": [3], "d": [3]}
    assert second["c"] is second["d"]  # alias sharing survives the copy, as in a fresh parse
    assert second["a"] is not first["a"]


def test_repeated_bad_text_keeps_failing_with_its_own_location():
    for first_line in (1, 10):
        with pytest.raises(RosYamlError) as err:
            load_yaml("a: [1\n", filename="f%d.yaml" % first_line, first_line=first_line)
        assert err.value.filename == "f%d.yaml" % first_line and err.value.line >= first_line


def test_angles_flag_is_part_of_the_memo():
    assert load_yaml("a: deg(90)", angles=False) == {"a": "deg(90)"}
    assert load_yaml("a: deg(90)") == {"a": math.pi / 2}
    assert load_yaml("a: deg(90)", angles=False) == {"a": "deg(90)"}


# -- raw-text differential: the libyaml fast path must agree with PyYAML's pure loader -------


@pytest.mark.parametrize("text", ["[a? ]", "[a?, b]", "{a? : 1}", "k: [a ? b]", "[http://host/x?y=1]",
                                  "{url: http://h/x?y=1}", "[? a]", "{? a : b}", "url: http://h/x?y=1",
                                  "a: [1, 2]\nb: x?"])
def test_a_question_mark_in_a_flow_collection_is_read_as_pyyaml_reads_it(text):
    # inside [] and {} PyYAML (roslaunch's loader) ends a plain scalar at '?', a key's mark; libyaml does not
    rosyaml._parsed.clear()
    try:
        expected = ("ok", yaml.load(text, Loader=rosyaml._PY_ROS))
    except yaml.YAMLError:
        expected = ("error", None)
    try:
        got = ("ok", load_yaml(text))
    except RosYamlError:
        got = ("error", None)
    assert got == expected

_YAML_PIECES = st.sampled_from(
    list("ab01 :-[]{},#&*!|>'\"\n\t?%@`.~\\x")
    + ["deg(", "rad(", ")", "pi", "!degrees ", "!radians ", "!!binary ", "<<: ", "- ", "\u00e9", "\u2028", "\x85",
       "\ufeff", "\r", "\r\n", "\x00", "\x7f", "\U0001F600", "!!str ", "!!int ", "!!float ", "!!bool ",
       "!!timestamp ", "!!map ", "!!seq ", "!!set ", "!!omap ", "!!pairs ", "null", "yes", "1e3", "0x", "---", "...",
       "&a ", "*a", "? ", "%YAML 1.1\n", "%TAG ! tag:x,2000:\n", "!x ", "!<tag:yaml.org,2002:str> ", '"\\x41"',
       "'it''s'", "|-\n  ", ">+\n  ", "  ", "\n  ", "\n- ", ": ", "#"])


@settings(max_examples=1500, deadline=None)
@given(st.lists(_YAML_PIECES, max_size=40).map("".join), st.booleans())
@example("[a? ]", False)  # (found by this test on 11-29: libyaml keeps a '?' in a flow scalar, PyYAML does not)
def test_raw_text_same_as_pure_pyyaml(text, angles):
    reference = rosyaml._PY_ROS if angles else yaml.SafeLoader  # what roslaunch parses with
    try:
        expected = ("ok", repr(yaml.load(text, Loader=reference)))
    except Exception:  # noqa: BLE001 - any failure of the reference is a refusal
        expected = ("error", None)
    rosyaml._parsed.clear()
    try:
        got = ("ok", repr(load_yaml(text, angles=angles)))
    except RosYamlError:
        got = ("error", None)
    assert got == expected


@pytest.mark.parametrize("text", ["a:\tb", "a: b\tc", "a: 1\t# c", ">#", "a: |#\n  x"])
def test_texts_libyaml_accepts_but_roslaunch_refuses(text):
    with pytest.raises(RosYamlError):
        load_yaml(text)


@pytest.mark.parametrize("text", ["!!int a", "!!float", "!!int 0x", "x: [1, !!timestamp nope]", "a: !!bool maybe"])
def test_bad_explicit_tags_are_yaml_errors(text):
    with pytest.raises(RosYamlError) as err:
        load_yaml(text, filename="t.yaml")
    assert str(err.value).startswith("t.yaml:1: ")


# -- limits of the interpreter that a document can reach ------------------------------------

def _nested(kind, depth):
    """A document whose collections nest `depth` deep (the top mapping included)."""
    if kind == "flow-seq":
        return "a: " + "[" * (depth - 1) + "1" + "]" * (depth - 1)
    if kind == "flow-map":
        return "a: " + "{a: " * (depth - 1) + "1" + "}" * (depth - 1)
    if kind == "block-map":
        return "".join(" " * i + "a:\n" for i in range(depth - 1)) + " " * (depth - 1) + "a: 1\n"
    if kind == "compact-seq":
        return "a:\n" + "- " * (depth - 1) + "1\n"
    raise AssertionError(kind)


@pytest.mark.parametrize("kind", ["flow-seq", "flow-map", "block-map", "compact-seq"])
def test_nesting_is_limited_with_the_line(kind):
    """Collections up to MAX_DEPTH deep load and dump (roslaunch's own loader gives up at Python's recursion
    limit, ~480, and its --dump-params fails on lists ~320 deep); deeper is an error with its line."""
    from launcher.params.rosyaml import MAX_DEPTH
    value = load_yaml(_nested(kind, MAX_DEPTH))
    assert dump_yaml({"/p": value["a"]}) == rosyaml._pyyaml_dump({"/p": value["a"]})
    with pytest.raises(RosYamlError, match="nested more than %d deep" % MAX_DEPTH) as e:
        load_yaml(_nested(kind, MAX_DEPTH + 1), filename="f.yaml", first_line=10)
    assert e.value.filename == "f.yaml" and e.value.line >= 10


@pytest.mark.parametrize("kind", ["flow-seq", "compact-seq"])
def test_deep_nesting_never_reaches_libyamls_composer(kind):
    """libyaml's composer recurses in C: 100,000 levels (200 kB of text) crashed the process."""
    script = ("import sys; from launcher.params.rosyaml import load_yaml, RosYamlError\n"
              "try:\n    load_yaml(sys.stdin.read())\nexcept RosYamlError as e:\n    print(e)\n")
    out = subprocess.run([sys.executable, "-c", script], input=_nested(kind, 100_000), capture_output=True,
                         text=True, timeout=60)
    assert out.returncode == 0 and "nested" in out.stdout, (out.returncode, out.stdout, out.stderr[-500:])


def test_aliases_cannot_nest_deeper_than_the_limit():
    """A deep list held by an alias inside another deep list: each is under the limit, the value is not."""
    text = "a: &x %s1%s\nb: %s*x%s\n" % ("[" * 200, "]" * 200, "[" * 100, "]" * 100)
    with pytest.raises(RosYamlError, match="nested more than"):
        load_yaml(text)


def test_a_value_that_holds_itself_loads_as_in_roslaunch():
    """`&x [*x]`: roslaunch loads it, and its --dump-params writes it back with an alias."""
    value = load_yaml("a: &x [1, *x]\n" + "# pad\n" * 300)
    assert value["a"][1] is value["a"]
    assert dump_yaml(value) == rosyaml._pyyaml_dump(value)


@pytest.mark.parametrize("text", ["a: 0x" + "f" * 5000, "a: 0b" + "1" * 20_000, "a: 1" + ":59" * 3000,
                                  "a: 0" + "7" * 6000, "a: " + "9" * 5000, "a: 1" + ":00" * 1_000_000,
                                  "? " + "9" * 5000 + "\n: 1", "a: !!int 0x" + "f" * 5000],
                         ids=["hex", "binary", "base-60", "octal", "decimal", "base-60-huge", "key", "tagged"])
def test_an_integer_python_cannot_print_is_refused_before_it_is_made(text):
    """Python's str() refuses ints of more than 4300 digits, and --dump-params then failed with an internal
    error; a base-60 one of a million parts took hours to compute."""
    with pytest.raises(RosYamlError, match="has more than 4300 digits") as e:
        load_yaml("x: 1\n" + text, filename="f.yaml")
    assert e.value.line == 2


def test_aliases_that_double_a_map_thirty_times_are_refused():
    """A kilobyte of `&a1 {p: *a0, q: *a0}`: every path a parameter, 2**30 of them (roslaunch makes them all:
    hours); past MAX_VALUES values, an error. Aliases in a real file stay well under it."""
    lines = ["a0: &a0 {x: 1, y: 1}"] + ["a%d: &a%d {p: *a%d, q: *a%d}" % (i, i, i - 1, i - 1) for i in range(1, 31)]
    with pytest.raises(RosYamlError, match="aliases make more than"):
        load_yaml("\n".join(lines))
    value = load_yaml("\n".join(lines[:10]))
    assert value["a9"]["p"]["q"] is value["a7"]
