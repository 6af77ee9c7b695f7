"""The plain-YAML reader gives PyYAML's (rosparam's) values, or declines: checked against PyYAML itself."""

from __future__ import annotations

import string

import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from launcher.params.plain_yaml import NOT_PLAIN, load_plain, scalar_is_str


def _pyyaml(text: str):
    return yaml.load(text, Loader=yaml.SafeLoader)  # rosparam's loader (pure Python)


def _same(text: str) -> bool:
    """load_plain agrees with PyYAML on `text` (or declines it); returns whether it answered."""
    ours = load_plain(text)
    if ours is NOT_PLAIN:
        return False
    theirs = _pyyaml(text)
    assert ours == theirs and repr(ours) == repr(theirs), text  # repr: 1 vs 1.0 vs True, key order
    return True


PARAM_FILE = """\
# a comment
key_0: false
sec_1:
  key_0: 'str_1_233543'
  key_1: [0.87, 0.47, 0.36, 0.18, 0.21, 0.20]
  key_2: true

  sub:
    deep: -21.9043
    empty:
  key_5: frame_73
key_2: /abs/path.yaml
flow: {a: 2, b: [1, 2, 2], c: {d: x}, e: [], f: {}}
dq: "double quoted"
yes_no: [yes, No, ON, off, y, n, Null, NULL]
nums: [0, -0, +5, 12, 1.5, -0.0, +2.25, 00.5]
"""


@pytest.mark.parametrize("text", [
    PARAM_FILE, "{a: 2, b: [1, 2, 2]}", "{frame: base_0, limits: [0, 10]}", "[1, 2]", "5", "-1.5", "word",
    "\n    gains: {p: 0.44, i: 0.61, d: 0.52}\n    leaf: 0\n  ", "", "  \n", "# only a comment\n", "a:", "a: null",
    "a:\n  b:\n    c: 1\n  d: 2\ne: 3\n", "a: 'it is'\n", "k: v  \n",
])
def test_plain_documents_read_as_pyyaml_reads_them(text):
    assert _same(text)


@pytest.mark.parametrize("text", [
    "a: 1_000", "a: 0x1F", "a: 012", "a: 1e5", "a: 1.0e+5", "a: .inf", "a: 2001-12-14", "a: 1:30",
    "a: b c", "a: [1, 2, ]", "a: 'it''s'", 'a: "esc\\n"', "a: &x 1\nb: *x", "a: !!str 1", "- a\n- b",
    "a:\n- 1\n- 2", "a: |\n  text\n", "a: 1 # comment", "a: 1\n  b: 2", "  a: 1\nb: 2", "---\na: 1",
    "a:\tb", "a: caf\u00e9", "1: a", "yes: 1", "a: {b: 1, c}", "a: [1, 2", "a: x:y", "{a:1}", "a: deg(90)",
    "a: 'multi\n  line'", "a: {b: 1}\n  c: 2", "a:b", "? a\n: b", "a: -", "a: ~", "a: =", "a: <<",
])
def test_everything_else_is_left_to_pyyaml(text):
    # declining is always safe; answering must be right (some of these PyYAML refuses outright)
    ours = load_plain(text)
    if ours is not NOT_PLAIN:
        assert ours == _pyyaml(text), text


def test_each_call_gets_its_own_containers():
    a = load_plain("k: [1, 2]\nm: {x: 1}")
    a["k"].append(3)
    a["m"]["y"] = 2
    assert load_plain("k: [1, 2]\nm: {x: 1}") == {"k": [1, 2], "m": {"x": 1}}


_resolver = yaml.resolver.Resolver()


def _pyyaml_says_str(text: str) -> bool:
    return _resolver.resolve(yaml.ScalarNode, text, (True, False)) == "tag:yaml.org,2002:str"


WORDS = ["yes", "Yes", "YES", "yEs", "no", "No", "NO", "true", "True", "TRUE", "tRue", "false", "on", "On", "ON",
         "off", "Off", "OFF", "y", "Y", "n", "N", "null", "Null", "NULL", "nULL", "nan", "NaN", "inf", "e5", "_1",
         "/a", "a.b", "a-b", "1", "01", "-1", "+1", "1.5", "1.", ".5", "-.5", "1_0", "1.5_0", "0x1", "0o7", "0b1",
         "1e5", "1.5e+5", "2001-12-14", "1:30", "-", "+", ".", "..", "1.2.3", "0", "-0", "+0.0"]


@pytest.mark.parametrize("text", WORDS)
def test_scalar_typing_matches_pyyaml_resolver(text):
    known = scalar_is_str(text)
    if known is not None:
        assert known == _pyyaml_says_str(text)
    if known is not None or text in ("yes", "1", "1.5", "a.b"):
        assert _same("k: %s" % text)


_CHARS = string.ascii_letters[:6] + "yesnotrufalNUL" + string.digits + "_./+-"


@settings(max_examples=400, deadline=None)
@given(st.text(alphabet=_CHARS, min_size=1, max_size=8))
def test_scalar_typing_fuzz(text):
    known = scalar_is_str(text)
    if known is not None:
        assert known == _pyyaml_says_str(text), text
    try:
        expected = _pyyaml("k: %s" % text)
    except Exception:  # noqa: BLE001 - PyYAML refuses it (some bad scalars fail in its constructor)
        expected = NOT_PLAIN
    ours = load_plain("k: %s" % text)
    if ours is not NOT_PLAIN:
        assert repr(ours) == repr(expected), text


_scalars = st.one_of(st.text(alphabet=_CHARS, min_size=1, max_size=6),
                     st.text(alphabet=string.ascii_letters + " _-", max_size=6).map(lambda s: "'%s'" % s),
                     st.integers(-10 ** 6, 10 ** 6).map(str), st.floats(-1e6, 1e6).map(lambda f: "%.3f" % f))
_keys = st.text(alphabet=string.ascii_letters + "_", min_size=1, max_size=5)


def _flow_node(depth: int):
    if depth == 0:
        return _scalars
    inner = _flow_node(depth - 1)
    return st.one_of(_scalars,
                     st.lists(inner, max_size=4).map(lambda xs: "[%s]" % ", ".join(xs)),
                     st.dictionaries(_keys, inner, max_size=3).map(
                         lambda d: "{%s}" % ", ".join("%s: %s" % kv for kv in d.items())))


@st.composite
def _block(draw, indent=0, depth=0):
    lines = []
    for key in draw(st.lists(_keys, min_size=1, max_size=4)):
        if depth < 2 and draw(st.booleans()):
            lines.append("%s%s:" % (" " * indent, key))
            step = draw(st.sampled_from([1, 2, 4]))
            lines.extend(draw(_block(indent + step, depth + 1)))
        else:
            lines.append("%s%s: %s" % (" " * indent, key, draw(_flow_node(2))))
        if draw(st.integers(0, 9)) == 0:
            lines.append(draw(st.sampled_from(["", "# c", "   ", "  # x"])))
    return lines


@settings(max_examples=300, deadline=None)
@given(_block(indent=0), st.sampled_from(["", "\n", "  \n", "\n  "]), st.integers(0, 4))
def test_generated_documents_match_pyyaml(lines, tail, shift):
    text = "\n".join(" " * shift + ln if ln.strip() else ln for ln in lines) + tail
    try:
        expected = _pyyaml(text)
    except Exception:  # noqa: BLE001 - PyYAML refuses it
        expected = NOT_PLAIN
    ours = load_plain(text)
    if ours is not NOT_PLAIN:
        assert repr(ours) == repr(expected), text


def test_plain_parameter_yaml_dumps_as_with_pyyaml(tmp_path):
    # a launch whose YAML is plain is loaded and dumped by this module, and the output is what it is
    # with PyYAML doing all the reading and typing (whether PyYAML got imported is measured by
    # benchmarks/startup_budget.py, not asserted here)
    import subprocess
    import sys
    param_file = PARAM_FILE.replace("double quoted", "double_quoted")  # (PyYAML writes strings with spaces)
    (tmp_path / "p.yaml").write_text(param_file)
    (tmp_path / "main.launch").write_text(
        '<launch><rosparam command="load" file="%s/p.yaml" ns="f"/><rosparam>{a: 1, b: [x, "2"]}</rosparam>'
        '<param name="y" type="yaml" value="{c: 10.0/2}"/><param name="s" type="str" value="817"/></launch>'
        % tmp_path)
    run = ("from launcher.xml import load; from launcher.introspect import dump_params; "
           "text = dump_params(load([sys.argv[1]], core=False)); print(text)")
    without_plain = ("import launcher.params.plain_yaml as p, launcher.xml.loader as l, launcher.params.rosyaml as r, "
                     "launcher.params.dump as d; l.load_plain = r.load_plain = lambda t: p.NOT_PLAIN; "
                     "d.scalar_is_str = lambda t: None; d.WORD_FIRST_CHARS = frozenset(); ")
    outs = [subprocess.run([sys.executable, "-c", "import sys; " + pre + run, str(tmp_path / "main.launch")],
                           capture_output=True, text=True, check=True).stdout for pre in ("", without_plain)]
    text = outs[0]
    assert outs[1] == text
    assert "/f/sec_1/sub/deep: -21.9043\n" in text and "/y:\n  c: 10.0/2\n" in text and "/s: '817'\n" in text
