"""Substitution args: the `$(...)` parser, each command, the second `$(find)` pass (`$(eval)`: test_sandbox.py)."""

from __future__ import annotations

import os

import pytest

from launcher.model.errors import LaunchError
from launcher.xml.substitution import (ArgNotSet, SubstitutionError, SubstitutionScope, auto_value,
                                       collect_commands, resolve)


def scope(args=None, env=None, filename="/ws/launch/a.launch", packages=None):
    packages = packages or {"pkg": "/pkgs/pkg"}

    def find_package(name):
        if name not in packages:
            raise LaunchError("Resource not found: %s" % name)
        return packages[name]

    def find_resource(name, rel):
        return os.path.join(find_package(name), rel)

    return SubstitutionScope(dict(args or {}), {}, filename, dict(env or {}), find_package, find_resource)


@pytest.mark.parametrize("text,expected", [
    ("$(arg a)", ["arg a"]),
    ("x $(arg a) y $(env B)", ["arg a", "env B"]),
    ("$$(arg a)", ["arg a"]),          # a repeated dollar stays a dollar
    ("$ (arg a)", []),                 # '(' must follow '$' at once
    ("$(arg a", []),                   # unterminated: nothing collected
    ("cost: 5$", []),
    ("$( arg  a )", [" arg  a "]),
])
def test_collect_commands(text, expected):
    assert collect_commands(text) == expected


def test_nested_dollar_is_an_error():
    with pytest.raises(SubstitutionError, match="Dollar signs"):
        collect_commands("$(arg $(arg a))")


def test_arg_env_optenv_dirname():
    s = scope(args={"a": "A"}, env={"E": "env value"})
    assert resolve("$(arg a)-$(env E)", s) == "A-env value"
    assert resolve("$(optenv NOPE)", s) == ""
    assert resolve("$(optenv NOPE fall  back words)", s) == "fall back words"
    assert resolve("$(optenv E ignored)", s) == "env value"
    assert resolve("$(dirname)/x", s) == "/ws/launch/x"
    assert resolve("$( arg  a )", s) == "A"


def test_every_copy_of_a_command_is_replaced():
    assert resolve("$(arg a)/$(arg a)", scope(args={"a": "x"})) == "x/x"


def test_undefined_arg_and_env():
    with pytest.raises(ArgNotSet) as e:
        resolve("$(arg missing)", scope())
    assert e.value.name == "missing"
    with pytest.raises(SubstitutionError, match="NOPE"):
        resolve("$(env NOPE)", scope())


@pytest.mark.parametrize("text,match", [
    ("$(foo bar)", "Unknown substitution command"),
    ("$(env)", "only accepts one argument"),
    ("$(env A B)", "only accepts one argument"),
    ("$(anon)", "must specify a name"),
    ("$(anon a b)", "only specify one name"),
    ("$(arg)", "must specify a variable name"),
    ("$(arg a b)", "may only specify one arg"),
    ("$(find)", "only accepts one argument"),
    ("x=$(eval 1 + 1)", "Unknown substitution command"),  # eval must be the whole attribute
])
def test_bad_commands(text, match):
    with pytest.raises(SubstitutionError, match=match):
        resolve(text, scope(args={"a": "1"}, env={"A": "1", "B": "2"}))


def test_anon_is_stable_within_a_scope_and_distinct_between_ids():
    s = scope()
    a1 = resolve("$(anon a)", s)
    assert resolve("$(anon a)", s) == a1
    assert resolve("$(anon b)", s) != a1
    assert a1.startswith("a_") and "-" not in a1 and "." not in a1


def test_find_uses_the_path_up_to_the_first_space():
    seen = []

    def find_resource(pkg, rel):
        seen.append((pkg, rel))
        return "/share/%s/%s" % (pkg, rel)

    s = SubstitutionScope({}, {}, None, {}, lambda p: "/src/" + p, find_resource)
    assert resolve("$(find pkg)/a/b.yaml --flag", s) == "/share/pkg/a/b.yaml --flag"
    assert seen == [("pkg", "a/b.yaml")]
    assert resolve("$(find pkg)", s) == "/src/pkg"
    assert resolve("$(find pkg)/", s) == "/src/pkg"  # roslaunch drops the lone slash
    assert resolve("$(find  pkg )/x", s) == "/share/pkg/x"


def test_find_runs_after_args_so_an_arg_may_hold_a_find():
    s = scope(args={"where": "$(find pkg)"})
    assert resolve("$(arg where)/f", s) == "/pkgs/pkg/f"


def test_find_of_a_missing_package_raises_launch_error():
    with pytest.raises(LaunchError, match="nope"):
        resolve("$(find nope)", scope())


def test_dirname_without_a_file():
    with pytest.raises(SubstitutionError, match="dirname"):
        resolve("$(dirname)", scope(filename=None))


@pytest.mark.parametrize("value,expected", [
    ("7", 7), ("-3", -3), ("7.5", 7.5), (".5", 0.5), ("1e3", "1e3"), ("1_000", "1_000"),
    ("true", True), ("FALSE", False), ("yes", "yes"), ("", ""),
])
def test_auto_value(value, expected):
    got = auto_value(value)
    assert got == expected and type(got) is type(expected)


# $(eval) itself: tests/xml/test_sandbox.py


def _roslaunch_collect(text):
    """roslaunch's _collect_args state machine, written out again as the oracle for our fast path."""
    out, buf, state = [], [], 0
    for c in text:
        if c == "$":
            if state == 0:
                state = 1
            elif state != 1:
                raise SubstitutionError("$")
        elif c == "(":
            if state == 1:
                state = 2
            elif state != 0:
                raise SubstitutionError("(")
        elif c == ")":
            if state == 3:
                out.append("".join(buf))
                buf = []
            state = 0
        elif state == 1:
            state = 0
        elif state == 2:
            state = 3
        if state == 3:
            buf.append(c)
    return out


from hypothesis import given, settings, strategies as st  # noqa: E402


@settings(max_examples=3000, deadline=None)
@given(st.lists(st.sampled_from(["$", "(", ")", "a", " ", "$(", "arg x", "env Y", ")", "$$"]), max_size=12))
def test_collect_commands_matches_roslaunchs_state_machine(parts):
    text = "".join(parts)
    try:
        expected = _roslaunch_collect(text)
    except SubstitutionError:
        with pytest.raises(SubstitutionError):
            collect_commands(text)
        return
    assert collect_commands(text) == expected


def test_repeated_text_takes_each_scopes_values():
    """What a text asks for is planned once; the values come from each scope every time."""
    text = "$(arg a)/$(optenv E dflt)/$(find pkg)/x"
    first = resolve(text, scope({"a": "1"}, packages={"pkg": "/p1"}))
    second = resolve(text, scope({"a": "2"}, {"E": "set"}, packages={"pkg": "/p2"}))
    assert (first, second) == ("1/dflt//p1/x", "2/set//p2/x")
    # an arg whose value holds a $(find) is expanded by the second pass, per scope
    assert resolve("$(arg a)", scope({"a": "$(find pkg)/y"})) == "/pkgs/pkg/y"
    assert resolve("$(arg a)", scope({"a": "plain"})) == "plain"


def test_repeated_text_keeps_its_error_order():
    """Errors come in text order, also from a planned text: a missing arg before a later unknown command."""
    text = "$(arg missing) $(bogus x)"
    for _ in range(2):
        with pytest.raises(ArgNotSet):
            resolve(text, scope())
        with pytest.raises(SubstitutionError, match="Unknown substitution command"):
            resolve(text, scope({"missing": "v"}))


# ---------------------------------------------------------------- linear time, roslaunch's replacements kept

def _roslaunch_words(body):
    return [w for w in body.split(" ") if w]  # roslaunch: `[s for s in a.split(' ') if s]`


def _roslaunch_resolve(text, sc):
    """roslaunch's resolve_args: for each `$(...)` in order, every copy of its text replaced in the string
    as it stands; then, for each `$(find)` of the result in order, its first copy and the path after it."""
    resolved = text
    for body in _roslaunch_collect(text):
        words = _roslaunch_words(body)
        if not words or words[0] not in ("arg", "anon", "find"):
            raise SubstitutionError("unknown command")
        if words[0] == "arg":
            resolved = resolved.replace("$(%s)" % body, sc.args[words[1]])
        elif words[0] == "anon":
            resolved = resolved.replace("$(%s)" % body, sc.anon.setdefault(words[1], "anon_" + words[1]))
    for body in _roslaunch_collect(resolved):
        words = _roslaunch_words(body)
        if not words or words[0] not in ("arg", "anon", "find"):
            raise SubstitutionError("unknown command")
        if words[0] == "find":
            i = resolved.find("$(%s)" % body)
            after = resolved[i + len(body) + 3:]
            path = after.split(" ", 1)[0]
            rest = after[len(path):]
            path = path[1:] if path.startswith("/") else path
            value = sc.find_resource(words[1], path) if path else sc.find_package(words[1])
            resolved = resolved[:i] + value + rest
    return resolved


@settings(max_examples=3000, deadline=None)
@given(st.lists(st.sampled_from(["$(arg a)", "$(arg b)", "$(anon n)", "$(anon m)", "$(find pkg)", "$(find q)", "/x",
                                 " ", "$", "(", ")", "y", "$$(", "{", "}", "{0}", "$(arg\ta)"]), max_size=12),
       st.sampled_from(["A", "", "$(arg b)", "$(find q)/z", "(", "$", "$(anon n)", "(arg b)", "{1}", "$(", "(anon m)"]),
       st.sampled_from(["B", "$(arg a)", "$(find pkg)", ")", "", "$(arg b)$(arg a)", "(arg a)", "$$("]),
       st.sampled_from(["anon_m", "", "(anon n)", "$"]))
def test_resolve_replaces_as_roslaunch_does(parts, a, b, m):
    """Each `$(...)` text is evaluated once; the result is what roslaunch's one-replace-per-`$(...)` gives,
    also when a value holds `$(...)` texts (or a '$', or is empty after a '$'), and for `$(find)`s whose
    path runs into the next `$(...)`."""
    text = "".join(parts)
    packages = {"pkg": "/p", "q": "/q$(arg a)"}

    def fresh():
        sc = scope({"a": a, "b": b}, packages=packages)
        sc.anon.update(n="anon_n", m=m)
        return sc
    try:
        expected = _roslaunch_resolve(text, fresh())
    except SubstitutionError:
        with pytest.raises(SubstitutionError):
            resolve(text, fresh())
        return
    assert resolve(text, fresh()) == expected


def test_a_tab_is_part_of_a_word_as_in_roslaunch():
    """roslaunch splits a `$(...)` at spaces only: `$(arg<TAB>a)` is an unknown command, `$(arg a<TAB>b)` the
    arg named "a<TAB>b"."""
    with pytest.raises(SubstitutionError, match="Unknown substitution command"):
        resolve("$(arg\ta)", scope({"a": "1"}))
    assert resolve("x$(arg a\tb)", scope({"a\tb": "2"})) == "x2"


def test_many_copies_of_a_substitution_take_linear_time():
    """50,000 copies of `$(anon x)` in one attribute took 72 s (one scan of the string per copy)."""
    import time
    text = "$(anon x)/" * 50_000 + "$(find pkg)/a " * 2_000 + "$(arg a)" * 50_000
    start = time.monotonic()
    out = resolve(text, scope({"a": "A"}))
    elapsed = time.monotonic() - start
    words = out.split("/")
    assert len(set(words[:50_000])) == 1 and words[0].startswith("x_")  # every copy gets the one name
    assert out.endswith("/pkgs/pkg/a " + "A" * 50_000)
    assert elapsed < 2.0, "took %.1f s" % elapsed


# ---------------------------------------------------------------- documented limits

def test_a_value_longer_than_the_limit_is_an_error(monkeypatch):
    from launcher.xml import substitution
    monkeypatch.setattr(substitution, "MAX_VALUE_CHARS", 1000)
    s = scope({"a": "x" * 100, "d": "$"})
    assert resolve("$(arg a)" * 9, s) == "x" * 900
    for text in ("$(arg a)" * 11,                       # one format()
                 "$(arg d)" + "$(arg a)" * 11,          # roslaunch's replacements
                 "$(find pkg)/" + "y" * 1000):          # the $(find) pass
        with pytest.raises(SubstitutionError, match="more than the limit of 1000"):
            resolve(text, s)


def test_args_that_double_each_other_meet_the_load_limit():
    """Each arg twice the one before: 2**40 characters at the 40th, unless the load's budget stops it."""
    from launcher.xml.substitution import LoadBudget
    s = scope({"a0": "x" * 1000})
    s.budget = LoadBudget(10_000_000)
    with pytest.raises(SubstitutionError, match="more than .* characters of text in this launch"):
        for i in range(1, 40):
            s.args["a%d" % i] = resolve("$(arg a{0})$(arg a{0})".format(i - 1), s)


def test_a_value_alone_is_the_args_own_string():
    """`value="$(arg big)"` makes no copy of a 5 MB arg, and costs the load's budget nothing."""
    from launcher.xml.substitution import LoadBudget
    big = "u" * 5_000_000
    s = scope({"big": big})
    s.budget = LoadBudget(1000)
    assert resolve("$(arg big)", s) is big


def test_values_that_make_each_others_texts_meet_the_replacement_limit(monkeypatch):
    """`$(arg a)` makes `$(arg b)`, which makes `$(arg a)` ...: every copy is replaced at each of the text's
    own `$(...)`s, quadratic in the text; past MAX_REPLACEMENTS that is an error."""
    from launcher.xml import substitution
    monkeypatch.setattr(substitution, "MAX_REPLACEMENTS", 10_000)
    s = scope({"a": "$(arg b)", "b": "$(arg a)"})
    assert resolve("$(arg a)$(arg b)" * 10, s) == _roslaunch_resolve("$(arg a)$(arg b)" * 10, s)
    with pytest.raises(SubstitutionError, match="more than 10000"):
        resolve("$(arg a)$(arg b)" * 1000, s)


def test_finds_whose_paths_run_into_each_other_meet_the_rescan_limit():
    """`$(find pkg)/x$(find pkg)/x...`: each path runs to the next space, so each $(find) takes the rest of the
    string as its path and roslaunch's steps rescan it; a short text is done as roslaunch does it."""
    s = scope()
    short = "$(find pkg)/a$(find pkg)/b"
    assert resolve(short, s) == _roslaunch_resolve(short, s) == "/pkgs/pkg/a/pkgs/pkg/b"
    with pytest.raises(SubstitutionError, match="put a space after each path"):
        resolve("$(find pkg)/launch/x.launch" * 200_000, s)


def test_errors_quote_a_long_text_by_its_start_and_end():
    text = "$(arg " + "v" * 100_000 + " w)"
    with pytest.raises(SubstitutionError) as e:
        resolve(text, scope())
    assert len(str(e.value)) < 1000 and "characters ...]" in str(e.value)
