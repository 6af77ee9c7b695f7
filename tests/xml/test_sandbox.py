"""The `$(eval)` sandbox: escapes are refused, work is bounded, and roslaunch's expressions still evaluate as roslaunch does."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import pytest

from launcher.model.errors import LaunchError
from launcher.xml import sandbox
from launcher.xml.substitution import SubstitutionError, SubstitutionScope, resolve

ARGS = {"a": "3", "b": "4", "ratio": "0.5", "name": "bot", "flag": "true", "off": "False", "e": "not math"}


def scope(args=None, env=None):
    def find_package(name):
        if name != "pkg":
            raise LaunchError("Resource not found: %s" % name)
        return "/pkgs/pkg"
    return SubstitutionScope(dict(ARGS if args is None else args), {}, "/ws/launch/a.launch",
                             dict(env or {"E": "x"}), find_package, lambda p, rel: "/pkgs/pkg/" + rel)


def ev(expr, **kw):
    return resolve("$(eval %s)" % expr, scope(**kw))


# Every escape we know of, each one refused. The first is the report's own: a generator's
# frame walked back to substitution.py's globals, passed by a `'{}'.format` that made the
# old name check approve the whole expression.
ESCAPES = [
    "'{}'.format(1) and (lambda l, lst: (l.append(((lambda b: b.exec('import os; os.system(\"touch PWNED\")', "
    "{'_'+'_builtins_'+'_': b}))(y.gi_frame.f_back.f_back.f_back.f_globals['builtins']) for y in l)), "
    "lst(l[0]))[1])([], list)",
    "[y.gi_frame for y in (x for x in [1])]",
    "(x for x in [1]).gi_frame",
    "[x.gi_frame for x in [(y for y in [1])]]",
    "().__class__.__bases__[0].__subclasses__()",
    "''.__class__",
    "[].copy.__self__",
    "arg.__globals__",
    "find.__self__",
    "str.mro()",
    "str.format('{0.real}', 1)",
    "'{0.real}'.format(1)",
    "'{0[x]}'.format({'x': 1})",
    "'{:{0.real}}'.format(1)",
    "'{}'.format_map({})",
    "name.format_map({})",
    "(lambda: 1)()",
    "getattr(find, 'gi_frame')",
    "type(1)",
    "vars()",
    "globals()",
    "locals()",
    "dir()",
    "open('/etc/passwd').read()",
    "eval('1')",
    "exec('x=1')",
    "compile('1', 'x', 'eval')",
    "__import__('os')",
    "__builtins__",
    "breakpoint()",
    "help()",
    "input()",
    "memoryview(b'x')",
    "b'x'",
    "[x := 1]",
    "f'{().__class__}'",
    "f'{find.__name__}'",
    "'%(a)s' % vars()",
    "map(str, [1]).__reduce__()",
    "range(3).start",
    "(1).real",
    "name.encode()",
    "{}.fromkeys([1])",
    "dict.fromkeys([1])",
    "isinstance.__call__(1, int)",
    "pi.hex()",
]


@pytest.mark.parametrize("expr", ESCAPES)
def test_escapes_are_refused(expr, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SubstitutionError):
        ev(expr)
    assert not (tmp_path / "PWNED").exists()


def test_the_reported_exploit_through_launch_nodes_creates_nothing(tmp_path):
    """The report's reproducer, as a user would run it: `launch --nodes x.launch` executes nothing."""
    target = tmp_path / "PWNED"
    payload = ("'{}'.format(1) and (lambda l, lst: (l.append(((lambda b: b.exec('import os; "
               "os.system(&quot;id > %s&quot;)', {'_'+'_builtins_'+'_': b}))(y.gi_frame.f_back.f_back.f_back"
               ".f_globals['builtins']) for y in l)), lst(l[0]))[1])([], list)" % target)
    f = tmp_path / "x.launch"
    f.write_text('<launch><param name="p" value="$(eval %s)"/></launch>' % payload)
    for option in ("--nodes", "--dump-params"):
        r = subprocess.run([sys.executable, "-m", "launcher", option, str(f)], capture_output=True, text=True,
                           timeout=60, env=dict(os.environ, ROS_HOME=str(tmp_path)))
        assert r.returncode == 1, r.stderr
        assert "x.launch" in r.stderr and "Traceback" not in r.stderr
        assert not target.exists()


# Work that would hang or exhaust memory is a clean error, found before the work is done.
BOMBS = [
    "10**5000", "9**9**9", "2**100000", "1 << 100000", "10**4000 * 10**4000",
    "list(range(10**8))", "range(10**8)", "'x' * 10**10", "[0] * 10**9", "'x' * 10**6 * 10**6",
    "[[0] * 1000] * 1000", "[[[0] * 100] * 100] * 100",
    "[x for x in range(10**6)]", "[1 for a in range(1000) for b in range(1000)]",
    "['x' * 10**5 for i in range(100)]",
    "'a'.ljust(10**9)", "'a'.center(10**9)", "'a'.zfill(10**9)", "'{:>999999999}'.format(1)",
    "f'{1:>999999999}'", "'%999999999d' % 1", "'%*d' % (10**9, 1)", "('x' * 1000).replace('', 'y' * 1000)",
    "','.join(['x' * 1000] * 1000)", "sum([[1]] * 1000, [])", "factorial(10**6)", "pow(9, 9**9)",
    "sorted(range(10**6))", "-" * 5000 + "1", "(" * 5000 + "1" + ")" * 5000,
]


@pytest.mark.parametrize("expr", BOMBS)
def test_huge_work_is_a_clean_error(expr):
    start = time.monotonic()
    with pytest.raises(SubstitutionError):
        ev(expr)
    assert time.monotonic() - start < 5


def test_size_error_names_the_file_and_line(tmp_path):
    f = tmp_path / "big.launch"
    f.write_text('<launch>\n\n<param name="p" value="$(eval 10**5000)"/>\n</launch>\n')
    r = subprocess.run([sys.executable, "-m", "launcher", "--dump-params", str(f)], capture_output=True,
                       text=True, timeout=60, env=dict(os.environ, ROS_HOME=str(tmp_path)))
    assert r.returncode == 1
    assert "big.launch:3" in r.stderr and "too large" in r.stderr and "Traceback" not in r.stderr


EXPRESSIONS = [
    ("a + b", "7"),
    ("arg('a') * 2", "6"),
    ("ratio * 4", "2.0"),
    ("name.upper() + '_' + str(a)", "BOT_3"),
    ("flag and a < b", "True"),
    ("true or false", "True"),
    ("round(sqrt(2), 3)", "1.414"),
    ("pi > 3", "True"),
    ("e > 2.7", "True"),  # roslaunch's names come before the args: math's e wins
    ("len(list(map(str, range(a))))", "3"),
    ("[1, 2][0]", "1"),
    ("optenv('NOPE', 'd') + env('E')", "dx"),
    ("optenv('NOPE', default='d')", "d"),
    ("find('pkg') + '/x'", "/pkgs/pkg/x"),
    ("dirname()", "/ws/launch"),
    ("7 // 2", "3"),
    ("7 % 3", "1"),
    ("'%s_%d' % (name, a)", "bot_3"),
    ("'{}_link/{:>3}'.format(name, a)", "bot_link/  3"),
    ("'{n}'.format(n=name)", "bot"),
    ("f'{name}_{a:03d}'", "bot_003"),
    ("[x * 2 for x in range(a) if x != 1]", "[0, 4]"),
    ("{k: v for k, v in zip('ab', [1, 2])}", "{'a': 1, 'b': 2}"),
    ("sum(x for x in [1, 2, 3])", "6"),
    ("','.join(str(i) for i in range(3))", "0,1,2"),
    ("max([3, 1, 2]) if off == False else 0", "3"),
    ("name[1:]", "ot"),
    ("name in ['bot', 'arm']", "True"),
    ("not flag", "False"),
    ("-a ** 2", "-9"),
    ("a < b < 10", "True"),
    ("{'x': 1}.get('y', 2)", "2"),
    ("sorted({'b': 1, 'a': 2}.keys())", "['a', 'b']"),
    ("isinstance(a, int)", "True"),
    ("int('12') + float('0.5')", "12.5"),
    ("degrees(pi)", "180.0"),
    ("anon('x') == anon('x')", "True"),
    ("2**10", "1024"),
    ("10**4000 > 0", "True"),
]


@pytest.mark.parametrize("expr,expected", EXPRESSIONS)
def test_expressions_evaluate(expr, expected):
    assert ev(expr) == expected


MISTAKES = [
    ("1/0", "ZeroDivisionError"),
    ("undefined_name + 1", "name 'undefined_name' is not defined"),
    ("1 +", "invalid"),
    ("int('x')", "ValueError"),
    ("[1][5]", "IndexError"),
    ("name.nosuch()", "'str.nosuch' is not allowed"),
    ("a()", "not callable"),
]


@pytest.mark.parametrize("expr,words", MISTAKES)
def test_user_mistakes_are_substitution_errors(expr, words):
    with pytest.raises(SubstitutionError, match=words):
        ev(expr)


# Expressions roslaunch itself evaluates (with Python's eval): ours must give the same text.
DIFFERENTIAL = [
    "a + b", "arg('a') * 2", "ratio * 4", "name.upper() + '_' + str(a)", "flag and a < b", "true or false",
    "round(sqrt(2), 4)", "pi", "e", "len(list(map(str, [1, 2, 3])))", "[1, 2][0]", "7 / 2", "7 // 2",
    "2.0 * 3", "-a", "(a**2 + b**2) ** 0.5", "'big' if a > 2 else 'small'", "off == False", "off",
    "'{}_link'.format(name)", "'%s-%s' % (name, a)", "str(1.0/3)", "[i for i in range(3)]",
    "dict(x=1)", "list('ab')", "float('inf')", "int(ratio * 10)", "name * 2", "name[::-1]",
    "dirname()", "optenv('NOPE', 'dflt')", "abs(-2) + max(1, 2) + min(3, 4)", "log(e)", "floor(2.5)",
    "tan(0) + cos(0)", "radians(180) == pi", "hypot(3, 4)", "1e3", "3 if not flag else 4",
]


def test_same_results_as_roslaunch(ros_env):
    code = r"""
import json, sys
from roslaunch.substitution_args import resolve_args
args = json.loads(sys.argv[1]); out = []
for expr in json.loads(sys.argv[2]):
    ctx = {"arg": dict(args), "filename": "/ws/launch/a.launch"}
    try:
        out.append(resolve_args("$(eval %s)" % expr, context=ctx))
    except Exception as e:
        out.append("ERROR %s" % type(e).__name__)
print(json.dumps(out))
"""
    r = subprocess.run([ros_env["python"], "-c", code, json.dumps(ARGS), json.dumps(DIFFERENTIAL)],
                       capture_output=True, text=True, timeout=60, env={"PATH": ros_env["path"]})
    assert r.returncode == 0, r.stderr
    theirs = json.loads(r.stdout)
    ours = [ev(expr, env={}) for expr in DIFFERENTIAL]
    assert ours == theirs


def test_parse_is_cached_and_values_are_not():
    """The tree of a text is parsed once; the args are read at every evaluation."""
    assert ev("a + 1", args={"a": "1"}) == "2"
    assert ev("a + 1", args={"a": "5"}) == "6"
    assert sandbox.parse("a + 1") is sandbox.parse("a + 1")


# What the compiled closures may not change: each expression above, and a few the compiled node kinds
# meet in other ways (a refusal in a branch not taken, starred and keyword arguments, chained compares).
MORE = ["true or (lambda: 1)", "false and ().__class__", "(lambda: 1) if false else 2", "max(*[1, 5], 3)",
        "dict(**{'a': 1}, b=2)", "dict(**[1])", "'-'.join([*'ab', 'c'])", "[*a]", "(1, *[2, 3])",
        "1 < a < 2", "not a is None", "-(-a)", "~a", "a @ b", "b'x' if false else 1", "b'x'", "f(1)"]


def _outcome(expr):
    try:
        return "ok", ev(expr)
    except SubstitutionError as e:
        return "error", str(e)


@pytest.mark.parametrize("expr", [e for e, _ in EXPRESSIONS] + [e for e, _ in MISTAKES] + ESCAPES + BOMBS
                         + DIFFERENTIAL + MORE)
def test_the_compiled_expression_does_what_the_walk_does(expr, monkeypatch):
    compiled = _outcome(expr)
    monkeypatch.setattr(sandbox, "compiled", lambda text: sandbox._walked(sandbox.parse(text)))
    assert _outcome(expr) == compiled


def test_the_common_node_kinds_are_compiled(monkeypatch):
    """(else the test above compares the walk with itself)"""
    walked = []
    walk = sandbox.Evaluator.eval
    monkeypatch.setattr(sandbox.Evaluator, "eval", lambda self, node: walked.append(node) or walk(self, node))
    assert ev("max(*[1, a], 2, key=abs) + (1 if not a < 2 or a > 5 else len('a'.upper())) or (b, [a])") == "4"
    assert walked == []
    assert ev("[x for x in [a]]") == "[3]" and len(walked) > 0


# An expression over args only is kept by the values of the args it can read (xml/substitution.py): the
# same text over the same args gives the kept text, and marks the same args used.
def _used_and_outcome(expr, **kw):
    s = scope(**kw)
    try:
        out = ("ok", resolve("$(eval %s)" % expr, s))
    except SubstitutionError as e:
        out = ("error", str(e))
    return out, set(s.used_args)


@pytest.mark.parametrize("expr", [e for e, _ in EXPRESSIONS] + DIFFERENTIAL + MORE
                         + ["true or arg('b')", "arg('a') if false else arg('b')", "arg('nope')", "[a for a in 'xy']",
                            "arg('a') + arg('a')", "str + 'x'"])
def test_a_kept_value_is_what_evaluating_gives(expr):
    first = _used_and_outcome(expr)
    assert _used_and_outcome(expr) == first  # (kept, if it can be)
    from launcher.xml import substitution
    substitution._EVAL_VALUES.clear()
    assert _used_and_outcome(expr) == first  # (evaluated again)


def test_a_kept_value_follows_the_args_and_what_is_not_an_arg_is_not_kept():
    assert _used_and_outcome("str(arg('a')) + '/1'") == (("ok", "3/1"), {"a"})
    assert _used_and_outcome("str(arg('a')) + '/1'", args=dict(ARGS, a="5")) == (("ok", "5/1"), {"a"})
    assert _used_and_outcome("b * 2", args=dict(ARGS, b="x")) == (("ok", "xx"), {"b"})
    assert _used_and_outcome("b * 2") == (("ok", "8"), {"b"})
    assert _used_and_outcome("str * 2", args=dict(ARGS, str="s")) == (("ok", "ss"), {"str"})  # (an arg named str)
    assert _used_and_outcome("str(1)")[0] == ("ok", "1")
    # the environment, the disk and made names are read at every evaluation
    assert ev("optenv('E') + str(a)", env={"E": "x"}) == "x3" and ev("optenv('E') + str(a)", env={"E": "y"}) == "y3"
    assert ev("env('E')", env={"E": "1"}) == "1" and ev("env('E')", env={"E": "2"}) == "2"
    assert ev("anon('n')") != ev("anon('n')")  # (a new scope each: a new anonymous name)
