"""`<param>` typing: roslaunch's type= conversions and inference, quirks included."""

from __future__ import annotations

import json
import math
import os
import subprocess

import pytest

from launcher.params.rosyaml import RosYamlError
from launcher.params.values import PARAM_TYPES, convert_value, to_bool

# (text, type, (result type name, repr of result or error message)), produced by running
# roslaunch.loader.convert_value (ROS Noetic 1.15.15) on each pair.
REFERENCE = [
    ('7', 'auto', ('int', '7')),
    ('7', 'int', ('int', '7')),
    ('7', 'double', ('float', '7.0')),
    ('7', 'bool', ('ValueError', "7 is not a 'bool' type")),
    ('7', 'str', ('str', "'7'")),
    ('7', 'string', ('str', "'7'")),
    ('7', 'boolean', ('ValueError', "7 is not a 'boolean' type")),
    ('7', 'Int', ('int', '7')),
    ('7', 'DOUBLE', ('float', '7.0')),
    ('7.0', 'auto', ('float', '7.0')),
    ('7.0', 'int', ('ValueError', "invalid literal for int() with base 10: '7.0'")),
    ('7.0', 'double', ('float', '7.0')),
    ('7.0', 'bool', ('ValueError', "7.0 is not a 'bool' type")),
    ('7.0', 'str', ('str', "'7.0'")),
    ('7.0', 'string', ('str', "'7.0'")),
    ('7.0', 'boolean', ('ValueError', "7.0 is not a 'boolean' type")),
    ('7.0', 'Int', ('ValueError', "invalid literal for int() with base 10: '7.0'")),
    ('7.0', 'DOUBLE', ('float', '7.0')),
    (' 7 ', 'auto', ('int', '7')),
    (' 7 ', 'int', ('int', '7')),
    (' 7 ', 'double', ('float', '7.0')),
    (' 7 ', 'bool', ('ValueError', "7 is not a 'bool' type")),
    (' 7 ', 'str', ('str', "' 7 '")),
    (' 7 ', 'string', ('str', "' 7 '")),
    (' 7 ', 'boolean', ('ValueError', "7 is not a 'boolean' type")),
    (' 7 ', 'Int', ('int', '7')),
    (' 7 ', 'DOUBLE', ('float', '7.0')),
    ('7\n', 'auto', ('int', '7')),
    ('7\n', 'int', ('int', '7')),
    ('7\n', 'double', ('float', '7.0')),
    ('7\n', 'bool', ('ValueError', "7 is not a 'bool' type")),
    ('7\n', 'str', ('str', "'7\\n'")),
    ('7\n', 'string', ('str', "'7\\n'")),
    ('7\n', 'boolean', ('ValueError', "7 is not a 'boolean' type")),
    ('7\n', 'Int', ('int', '7')),
    ('7\n', 'DOUBLE', ('float', '7.0')),
    ('1e3', 'auto', ('str', "'1e3'")),
    ('1e3', 'int', ('ValueError', "invalid literal for int() with base 10: '1e3'")),
    ('1e3', 'double', ('float', '1000.0')),
    ('1e3', 'bool', ('ValueError', "1e3 is not a 'bool' type")),
    ('1e3', 'str', ('str', "'1e3'")),
    ('1e3', 'string', ('str', "'1e3'")),
    ('1e3', 'boolean', ('ValueError', "1e3 is not a 'boolean' type")),
    ('1e3', 'Int', ('ValueError', "invalid literal for int() with base 10: '1e3'")),
    ('1e3', 'DOUBLE', ('float', '1000.0')),
    ('1.5e3', 'auto', ('float', '1500.0')),
    ('1.5e3', 'int', ('ValueError', "invalid literal for int() with base 10: '1.5e3'")),
    ('1.5e3', 'double', ('float', '1500.0')),
    ('1.5e3', 'bool', ('ValueError', "1.5e3 is not a 'bool' type")),
    ('1.5e3', 'str', ('str', "'1.5e3'")),
    ('1.5e3', 'string', ('str', "'1.5e3'")),
    ('1.5e3', 'boolean', ('ValueError', "1.5e3 is not a 'boolean' type")),
    ('1.5e3', 'Int', ('ValueError', "invalid literal for int() with base 10: '1.5e3'")),
    ('1.5e3', 'DOUBLE', ('float', '1500.0')),
    ('1_000', 'auto', ('str', "'1_000'")),
    ('1_000', 'int', ('int', '1000')),
    ('1_000', 'double', ('float', '1000.0')),
    ('1_000', 'bool', ('ValueError', "1_000 is not a 'bool' type")),
    ('1_000', 'str', ('str', "'1_000'")),
    ('1_000', 'string', ('str', "'1_000'")),
    ('1_000', 'boolean', ('ValueError', "1_000 is not a 'boolean' type")),
    ('1_000', 'Int', ('int', '1000')),
    ('1_000', 'DOUBLE', ('float', '1000.0')),
    ('1_0.5', 'auto', ('float', '10.5')),
    ('1_0.5', 'int', ('ValueError', "invalid literal for int() with base 10: '1_0.5'")),
    ('1_0.5', 'double', ('float', '10.5')),
    ('1_0.5', 'bool', ('ValueError', "1_0.5 is not a 'bool' type")),
    ('1_0.5', 'str', ('str', "'1_0.5'")),
    ('1_0.5', 'string', ('str', "'1_0.5'")),
    ('1_0.5', 'boolean', ('ValueError', "1_0.5 is not a 'boolean' type")),
    ('1_0.5', 'Int', ('ValueError', "invalid literal for int() with base 10: '1_0.5'")),
    ('1_0.5', 'DOUBLE', ('float', '10.5')),
    ('0x10', 'auto', ('str', "'0x10'")),
    ('0x10', 'int', ('ValueError', "invalid literal for int() with base 10: '0x10'")),
    ('0x10', 'double', ('ValueError', "could not convert string to float: '0x10'")),
    ('0x10', 'bool', ('ValueError', "0x10 is not a 'bool' type")),
    ('0x10', 'str', ('str', "'0x10'")),
    ('0x10', 'string', ('str', "'0x10'")),
    ('0x10', 'boolean', ('ValueError', "0x10 is not a 'boolean' type")),
    ('0x10', 'Int', ('ValueError', "invalid literal for int() with base 10: '0x10'")),
    ('0x10', 'DOUBLE', ('ValueError', "could not convert string to float: '0x10'")),
    ('nan', 'auto', ('str', "'nan'")),
    ('nan', 'int', ('ValueError', "invalid literal for int() with base 10: 'nan'")),
    ('nan', 'double', ('float', 'nan')),
    ('nan', 'bool', ('ValueError', "nan is not a 'bool' type")),
    ('nan', 'str', ('str', "'nan'")),
    ('nan', 'string', ('str', "'nan'")),
    ('nan', 'boolean', ('ValueError', "nan is not a 'boolean' type")),
    ('nan', 'Int', ('ValueError', "invalid literal for int() with base 10: 'nan'")),
    ('nan', 'DOUBLE', ('float', 'nan')),
    ('NaN', 'auto', ('str', "'NaN'")),
    ('NaN', 'int', ('ValueError', "invalid literal for int() with base 10: 'NaN'")),
    ('NaN', 'double', ('float', 'nan')),
    ('NaN', 'bool', ('ValueError', "nan is not a 'bool' type")),
    ('NaN', 'str', ('str', "'NaN'")),
    ('NaN', 'string', ('str', "'NaN'")),
    ('NaN', 'boolean', ('ValueError', "nan is not a 'boolean' type")),
    ('NaN', 'Int', ('ValueError', "invalid literal for int() with base 10: 'NaN'")),
    ('NaN', 'DOUBLE', ('float', 'nan')),
    ('inf', 'auto', ('str', "'inf'")),
    ('inf', 'int', ('ValueError', "invalid literal for int() with base 10: 'inf'")),
    ('inf', 'double', ('float', 'inf')),
    ('inf', 'bool', ('ValueError', "inf is not a 'bool' type")),
    ('inf', 'str', ('str', "'inf'")),
    ('inf', 'string', ('str', "'inf'")),
    ('inf', 'boolean', ('ValueError', "inf is not a 'boolean' type")),
    ('inf', 'Int', ('ValueError', "invalid literal for int() with base 10: 'inf'")),
    ('inf', 'DOUBLE', ('float', 'inf')),
    ('inf.', 'auto', ('str', "'inf.'")),
    ('inf.', 'int', ('ValueError', "invalid literal for int() with base 10: 'inf.'")),
    ('inf.', 'double', ('ValueError', "could not convert string to float: 'inf.'")),
    ('inf.', 'bool', ('ValueError', "inf. is not a 'bool' type")),
    ('inf.', 'str', ('str', "'inf.'")),
    ('inf.', 'string', ('str', "'inf.'")),
    ('inf.', 'boolean', ('ValueError', "inf. is not a 'boolean' type")),
    ('inf.', 'Int', ('ValueError', "invalid literal for int() with base 10: 'inf.'")),
    ('inf.', 'DOUBLE', ('ValueError', "could not convert string to float: 'inf.'")),
    ('.5', 'auto', ('float', '0.5')),
    ('.5', 'int', ('ValueError', "invalid literal for int() with base 10: '.5'")),
    ('.5', 'double', ('float', '0.5')),
    ('.5', 'bool', ('ValueError', ".5 is not a 'bool' type")),
    ('.5', 'str', ('str', "'.5'")),
    ('.5', 'string', ('str', "'.5'")),
    ('.5', 'boolean', ('ValueError', ".5 is not a 'boolean' type")),
    ('.5', 'Int', ('ValueError', "invalid literal for int() with base 10: '.5'")),
    ('.5', 'DOUBLE', ('float', '0.5')),
    ('5.', 'auto', ('float', '5.0')),
    ('5.', 'int', ('ValueError', "invalid literal for int() with base 10: '5.'")),
    ('5.', 'double', ('float', '5.0')),
    ('5.', 'bool', ('ValueError', "5. is not a 'bool' type")),
    ('5.', 'str', ('str', "'5.'")),
    ('5.', 'string', ('str', "'5.'")),
    ('5.', 'boolean', ('ValueError', "5. is not a 'boolean' type")),
    ('5.', 'Int', ('ValueError', "invalid literal for int() with base 10: '5.'")),
    ('5.', 'DOUBLE', ('float', '5.0')),
    ('-3', 'auto', ('int', '-3')),
    ('-3', 'int', ('int', '-3')),
    ('-3', 'double', ('float', '-3.0')),
    ('-3', 'bool', ('ValueError', "-3 is not a 'bool' type")),
    ('-3', 'str', ('str', "'-3'")),
    ('-3', 'string', ('str', "'-3'")),
    ('-3', 'boolean', ('ValueError', "-3 is not a 'boolean' type")),
    ('-3', 'Int', ('int', '-3')),
    ('-3', 'DOUBLE', ('float', '-3.0')),
    ('+5', 'auto', ('int', '5')),
    ('+5', 'int', ('int', '5')),
    ('+5', 'double', ('float', '5.0')),
    ('+5', 'bool', ('ValueError', "+5 is not a 'bool' type")),
    ('+5', 'str', ('str', "'+5'")),
    ('+5', 'string', ('str', "'+5'")),
    ('+5', 'boolean', ('ValueError', "+5 is not a 'boolean' type")),
    ('+5', 'Int', ('int', '5')),
    ('+5', 'DOUBLE', ('float', '5.0')),
    ('٣', 'auto', ('int', '3')),
    ('٣', 'int', ('int', '3')),
    ('٣', 'double', ('float', '3.0')),
    ('٣', 'bool', ('ValueError', "٣ is not a 'bool' type")),
    ('٣', 'str', ('str', "'٣'")),
    ('٣', 'string', ('str', "'٣'")),
    ('٣', 'boolean', ('ValueError', "٣ is not a 'boolean' type")),
    ('٣', 'Int', ('int', '3')),
    ('٣', 'DOUBLE', ('float', '3.0')),
    ('1.2.3', 'auto', ('str', "'1.2.3'")),
    ('1.2.3', 'int', ('ValueError', "invalid literal for int() with base 10: '1.2.3'")),
    ('1.2.3', 'double', ('ValueError', "could not convert string to float: '1.2.3'")),
    ('1.2.3', 'bool', ('ValueError', "1.2.3 is not a 'bool' type")),
    ('1.2.3', 'str', ('str', "'1.2.3'")),
    ('1.2.3', 'string', ('str', "'1.2.3'")),
    ('1.2.3', 'boolean', ('ValueError', "1.2.3 is not a 'boolean' type")),
    ('1.2.3', 'Int', ('ValueError', "invalid literal for int() with base 10: '1.2.3'")),
    ('1.2.3', 'DOUBLE', ('ValueError', "could not convert string to float: '1.2.3'")),
    ('yes', 'auto', ('str', "'yes'")),
    ('yes', 'int', ('ValueError', "invalid literal for int() with base 10: 'yes'")),
    ('yes', 'double', ('ValueError', "could not convert string to float: 'yes'")),
    ('yes', 'bool', ('ValueError', "yes is not a 'bool' type")),
    ('yes', 'str', ('str', "'yes'")),
    ('yes', 'string', ('str', "'yes'")),
    ('yes', 'boolean', ('ValueError', "yes is not a 'boolean' type")),
    ('yes', 'Int', ('ValueError', "invalid literal for int() with base 10: 'yes'")),
    ('yes', 'DOUBLE', ('ValueError', "could not convert string to float: 'yes'")),
    ('True', 'auto', ('bool', 'True')),
    ('True', 'int', ('ValueError', "invalid literal for int() with base 10: 'True'")),
    ('True', 'double', ('ValueError', "could not convert string to float: 'True'")),
    ('True', 'bool', ('bool', 'True')),
    ('True', 'str', ('str', "'True'")),
    ('True', 'string', ('str', "'True'")),
    ('True', 'boolean', ('bool', 'True')),
    ('True', 'Int', ('ValueError', "invalid literal for int() with base 10: 'True'")),
    ('True', 'DOUBLE', ('ValueError', "could not convert string to float: 'True'")),
    ('tRUE', 'auto', ('bool', 'True')),
    ('tRUE', 'int', ('ValueError', "invalid literal for int() with base 10: 'tRUE'")),
    ('tRUE', 'double', ('ValueError', "could not convert string to float: 'tRUE'")),
    ('tRUE', 'bool', ('bool', 'True')),
    ('tRUE', 'str', ('str', "'tRUE'")),
    ('tRUE', 'string', ('str', "'tRUE'")),
    ('tRUE', 'boolean', ('bool', 'True')),
    ('tRUE', 'Int', ('ValueError', "invalid literal for int() with base 10: 'tRUE'")),
    ('tRUE', 'DOUBLE', ('ValueError', "could not convert string to float: 'tRUE'")),
    ('false', 'auto', ('bool', 'False')),
    ('false', 'int', ('ValueError', "invalid literal for int() with base 10: 'false'")),
    ('false', 'double', ('ValueError', "could not convert string to float: 'false'")),
    ('false', 'bool', ('bool', 'False')),
    ('false', 'str', ('str', "'false'")),
    ('false', 'string', ('str', "'false'")),
    ('false', 'boolean', ('bool', 'False')),
    ('false', 'Int', ('ValueError', "invalid literal for int() with base 10: 'false'")),
    ('false', 'DOUBLE', ('ValueError', "could not convert string to float: 'false'")),
    (' true ', 'auto', ('str', "' true '")),
    (' true ', 'int', ('ValueError', "invalid literal for int() with base 10: ' true '")),
    (' true ', 'double', ('ValueError', "could not convert string to float: ' true '")),
    (' true ', 'bool', ('bool', 'True')),
    (' true ', 'str', ('str', "' true '")),
    (' true ', 'string', ('str', "' true '")),
    (' true ', 'boolean', ('bool', 'True')),
    (' true ', 'Int', ('ValueError', "invalid literal for int() with base 10: ' true '")),
    (' true ', 'DOUBLE', ('ValueError', "could not convert string to float: ' true '")),
    ('true\n', 'auto', ('str', "'true\\n'")),
    ('true\n', 'int', ('ValueError', "invalid literal for int() with base 10: 'true\\n'")),
    ('true\n', 'double', ('ValueError', "could not convert string to float: 'true\\n'")),
    ('true\n', 'bool', ('bool', 'True')),
    ('true\n', 'str', ('str', "'true\\n'")),
    ('true\n', 'string', ('str', "'true\\n'")),
    ('true\n', 'boolean', ('bool', 'True')),
    ('true\n', 'Int', ('ValueError', "invalid literal for int() with base 10: 'true\\n'")),
    ('true\n', 'DOUBLE', ('ValueError', "could not convert string to float: 'true\\n'")),
    ('', 'auto', ('str', "''")),
    ('', 'int', ('ValueError', "invalid literal for int() with base 10: ''")),
    ('', 'double', ('ValueError', "could not convert string to float: ''")),
    ('', 'bool', ('ValueError', " is not a 'bool' type")),
    ('', 'str', ('str', "''")),
    ('', 'string', ('str', "''")),
    ('', 'boolean', ('ValueError', " is not a 'boolean' type")),
    ('', 'Int', ('ValueError', "invalid literal for int() with base 10: ''")),
    ('', 'DOUBLE', ('ValueError', "could not convert string to float: ''")),
    ('abc', 'auto', ('str', "'abc'")),
    ('abc', 'int', ('ValueError', "invalid literal for int() with base 10: 'abc'")),
    ('abc', 'double', ('ValueError', "could not convert string to float: 'abc'")),
    ('abc', 'bool', ('ValueError', "abc is not a 'bool' type")),
    ('abc', 'str', ('str', "'abc'")),
    ('abc', 'string', ('str', "'abc'")),
    ('abc', 'boolean', ('ValueError', "abc is not a 'boolean' type")),
    ('abc', 'Int', ('ValueError', "invalid literal for int() with base 10: 'abc'")),
    ('abc', 'DOUBLE', ('ValueError', "could not convert string to float: 'abc'")),
    ('−1', 'auto', ('str', "'−1'")),
    ('−1', 'int', ('ValueError', "invalid literal for int() with base 10: '−1'")),
    ('−1', 'double', ('ValueError', "could not convert string to float: '−1'")),
    ('−1', 'bool', ('ValueError', "−1 is not a 'bool' type")),
    ('−1', 'str', ('str', "'−1'")),
    ('−1', 'string', ('str', "'−1'")),
    ('−1', 'boolean', ('ValueError', "−1 is not a 'boolean' type")),
    ('−1', 'Int', ('ValueError', "invalid literal for int() with base 10: '−1'")),
    ('−1', 'DOUBLE', ('ValueError', "could not convert string to float: '−1'")),
    ('00012', 'auto', ('int', '12')),
    ('00012', 'int', ('int', '12')),
    ('00012', 'double', ('float', '12.0')),
    ('00012', 'bool', ('ValueError', "00012 is not a 'bool' type")),
    ('00012', 'str', ('str', "'00012'")),
    ('00012', 'string', ('str', "'00012'")),
    ('00012', 'boolean', ('ValueError', "00012 is not a 'boolean' type")),
    ('00012', 'Int', ('int', '12')),
    ('00012', 'DOUBLE', ('float', '12.0')),
    ('-0', 'auto', ('int', '0')),
    ('-0', 'int', ('int', '0')),
    ('-0', 'double', ('float', '-0.0')),
    ('-0', 'bool', ('ValueError', "-0 is not a 'bool' type")),
    ('-0', 'str', ('str', "'-0'")),
    ('-0', 'string', ('str', "'-0'")),
    ('-0', 'boolean', ('ValueError', "-0 is not a 'boolean' type")),
    ('-0', 'Int', ('int', '0')),
    ('-0', 'DOUBLE', ('float', '-0.0')),
]


def outcome(text, ptype):
    try:
        v = convert_value(text, ptype)
    except ValueError as e:
        return ("ValueError", str(e))
    return (type(v).__name__, repr(v))


@pytest.mark.parametrize("text,ptype,expected", REFERENCE)
def test_matches_roslaunch_table(text, ptype, expected):
    assert outcome(text, ptype) == expected


@pytest.mark.parametrize("ptype", [None, "", "auto", "AUTO", " auto "])
def test_missing_or_auto_type_infers(ptype):
    assert convert_value("3", ptype) == 3 and type(convert_value("3", ptype)) is int


def test_unknown_type_is_refused_with_roslaunch_words():
    with pytest.raises(ValueError) as err:
        convert_value("1.0", "float")
    assert str(err.value) == "Unknown type 'float'"


def test_yaml_type_parses_structures():
    assert convert_value("{a: 1, b: {c: [x, y]}}", "yaml") == {"a": 1, "b": {"c": ["x", "y"]}}
    assert convert_value("[1, 2.5, three, true]", "yaml") == [1, 2.5, "three", True]
    assert convert_value("", "yaml") is None
    assert convert_value("0x10", "yaml") == 16
    assert convert_value("'quoted'", "yaml") == "quoted"


def test_yaml_angles_only_when_enabled():
    assert convert_value("deg(90)", "yaml") == pytest.approx(math.pi / 2)
    # roslaunch's plain yaml.safe_load before any <rosparam> tag imported rosparam
    assert convert_value("deg(90)", "yaml", angles=False) == "deg(90)"


def test_yaml_errors_are_value_errors_with_a_line():
    with pytest.raises(ValueError) as err:
        convert_value("a: 1\nb: [1, 2", "yaml", filename="x.launch", first_line=7)
    assert isinstance(err.value, RosYamlError)
    assert err.value.filename == "x.launch"
    assert err.value.line == 8  # second line of text starting on line 7
    assert str(err.value).startswith("x.launch:8: ")


def test_to_bool_words_errors_like_roslaunch():
    assert to_bool(" TRUE ") is True and to_bool("0") is False
    with pytest.raises(ValueError) as err:
        to_bool(" Yes ")
    assert str(err.value) == "yes is not a 'bool' type"


def test_param_types_listed():
    for t in PARAM_TYPES:
        convert_value("1", t)


REF_SCRIPT = r"""
import json, sys
from roslaunch.loader import convert_value
import rosparam  # roslaunch imports it at the first <rosparam>: angles in yaml params
out = []
for text, ptype in json.loads(sys.argv[1]):
    try:
        v = convert_value(text, ptype)
        out.append([type(v).__name__, repr(v)])
    except Exception as e:
        out.append(["ValueError", None])
print(json.dumps(out))
"""

DIFF_INPUTS = ["1", "1.", "-.5e-3", "1__0", "0_1", "12345678901234567890", "1e400", "-1e-400", "1.0.0",
               "\t5\t", "5 ", "TRUE", "faLSE", "t", "1\n2", "٣.٥", "inf.0", "Infinity", "+nan.0",
               "[1, 2]", "{a: b}", "deg(180)", "rad(pi)", "!degrees 90", "a: &x 1\nb: *x", "null", "~",
               "yes", "on", "2001-12-14", "!!binary aGVsbG8=", "0o17", "0b11", "1:20", "'q'", "- a\n- b"]


def _random_inputs(n: int = 600, seed: int = 7) -> list[str]:
    """Seeded random strings built from the characters that matter to the conversions."""
    import random
    rng = random.Random(seed)
    pieces = list("0123456789.-+_eExXoObB ") + ["\t", "\n", "nan", "inf", "true", "False", "yes", "0x", "1_0", "٣",
                                                 "[", "]", "{", "}", ":", "'", '"', "deg(", "rad(", ")", "pi", "#"]
    return ["".join(rng.choice(pieces) for _ in range(rng.randint(0, 6))) for _ in range(n)]


def test_differential_against_roslaunch(ros_env):
    inputs = DIFF_INPUTS + _random_inputs()
    pairs = [[t, p] for t in inputs for p in ("auto", "int", "double", "bool", "str", "yaml")]
    env = dict(os.environ, PATH=ros_env["path"])
    ref = json.loads(subprocess.run([ros_env["python"], "-c", REF_SCRIPT, json.dumps(pairs)], env=env,
                                    capture_output=True, text=True, check=True, timeout=120).stdout)
    mismatches = []
    for (text, ptype), (rtype, rrepr) in zip(pairs, ref):
        try:
            v = convert_value(text, ptype)
            ours = [type(v).__name__, repr(v)]
        except ValueError:
            ours = ["ValueError", None]
        if rtype == "Binary":  # rosparam wraps binary data; we keep plain bytes
            rtype, rrepr = "bytes", repr(b"hello")
        if ours != [rtype, rrepr]:
            mismatches.append((text, ptype, ours, [rtype, rrepr]))
    assert not mismatches
