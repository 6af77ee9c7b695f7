"""Which nodes an operator's PATTERN selects: exact name, then glob, then regular expression."""

from launcher.model.patterns import match

NAMES = ["/a", "/ab", "/g/b", "/g/c", "/g/sub/d", "/cam_left", "/cam_right"]


def test_exact_name_with_or_without_the_root_slash():
    assert match("/a", NAMES) == ["/a"]
    assert match("a", NAMES) == ["/a"]  # not /ab: a name is exact
    assert match("g/b", NAMES) == ["/g/b"]


def test_glob_selects_every_matching_name():
    assert match("/g/*", NAMES) == ["/g/b", "/g/c", "/g/sub/d"]
    assert match("/cam_*", NAMES) == ["/cam_left", "/cam_right"]
    assert match("/a?", NAMES) == ["/ab"]


def test_regex_when_no_name_or_glob_matches():
    assert match("/g/.*", NAMES) == ["/g/b", "/g/c", "/g/sub/d"]  # as a glob ('.' literal) it names nothing
    assert match("/cam_(left|right)", NAMES) == ["/cam_left", "/cam_right"]
    assert match("g/[bc]", NAMES) == ["/g/b", "/g/c"]
    assert match("a.", NAMES) == ["/ab"]  # fully matched: not /a


def test_nothing_matches():
    assert match("zz", NAMES) == []
    assert match("", NAMES) == []
    assert match("(", NAMES) == []  # a bad regex selects nothing rather than failing
