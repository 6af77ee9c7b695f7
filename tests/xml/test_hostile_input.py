"""Hostile input to the loader (issue 21): huge attribute values, `$(anon x)` by the hundred thousand,
integers longer than Python prints, in every place each can go; and the work of a load, counted,
growing in proportion to its input.

The fuzz bar, as a test: no internal error, no traceback, no run over 10 s, nothing but a
LaunchError escaping, and every error naming file and line. Most runs are in-process (the load,
then what `--dump-params` and `--args` compute from it); a few are `launch` itself, with a 10 s
deadline. The linearity test counts operations (every call, and a string method weighed by the
length of the string it works on, so a loop that rescans a long attribute shows as the square it
is) instead of timing on a shared machine.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from xml.sax.saxutils import quoteattr

import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from launcher.model.errors import LaunchError

MB = 1_000_000
DEADLINE_S = 10.0

# every attribute the loader substitutes, as (tag, attribute) -> a launch file using the value `V`
# (XML-quoted); `$(arg d)` is '$' and `$(arg e)` is '(' so that values can bring them in
_PRELUDE = '<arg name="d" value="$"/><arg name="e" value="("/><arg name="a" value="A"/>'
_NODE = '<node pkg="tpkg" type="talker" name="n" %s/>'
TARGETS = {
    ("node", "name"): '<node pkg="tpkg" type="talker" name=@V/>',
    ("node", "pkg"): '<node pkg=@V type="talker" name="n"/>',
    ("node", "type"): '<node pkg="tpkg" type=@V name="n"/>',
    ("node", "args"): _NODE % "args=@V",
    ("node", "ns"): _NODE % "ns=@V",
    ("node", "machine"): _NODE % "machine=@V",
    ("node", "launch-prefix"): _NODE % "launch-prefix=@V",
    ("node", "cwd"): _NODE % "cwd=@V",
    ("node", "output"): _NODE % "output=@V",
    ("node", "respawn"): _NODE % "respawn=@V",
    ("node", "respawn_delay"): _NODE % 'respawn="true" respawn_delay=@V',
    ("node", "required"): _NODE % "required=@V",
    ("node", "clear_params"): _NODE % "clear_params=@V",
    ("node", "if"): _NODE % "if=@V",
    ("node", "respawn_max_retries"): _NODE % 'respawn="true" respawn_max_retries=@V',
    ("test", "test-name"): '<test pkg="tpkg" type="talker" test-name=@V/>',
    ("test", "time-limit"): '<test pkg="tpkg" type="talker" test-name="t" time-limit=@V/>',
    ("test", "retry"): '<test pkg="tpkg" type="talker" test-name="t" retry=@V/>',
    ("machine", "name"): '<machine name=@V address="localhost"/>',
    ("machine", "address"): '<machine name="m" address=@V/>',
    ("machine", "user"): '<machine name="m" address="localhost" user=@V/>',
    ("machine", "env-loader"): '<machine name="m" address="localhost" env-loader=@V/>',
    ("machine", "ssh-port"): '<machine name="m" address="localhost" ssh-port=@V/>',
    ("machine", "timeout"): '<machine name="m" address="localhost" timeout=@V/>',
    ("param", "name"): '<param name=@V value="1"/>',
    ("param", "value"): '<param name="p" value=@V/>',
    ("param", "value-yaml"): '<param name="p" type="yaml" value=@V/>',
    ("param", "textfile"): '<param name="p" textfile=@V/>',
    ("param", "binfile"): '<param name="p" binfile=@V/>',
    ("param", "command"): '<param name="p" command=@V/>',
    ("rosparam", "command"): '<rosparam command=@V>a: 1</rosparam>',
    ("rosparam", "ns"): '<rosparam ns=@V>a: 1</rosparam>',
    ("rosparam", "param"): '<rosparam param=@V>a: 1</rosparam>',
    ("rosparam", "file"): '<rosparam file=@V/>',
    ("rosparam", "subst_value"): '<rosparam subst_value=@V>a: 1</rosparam>',
    ("arg", "value"): '<arg name="c" value=@V/><param name="p" value="$(arg c)"/>',
    ("arg", "default"): '<arg name="c" default=@V/><param name="p" value="$(arg c)$(arg c)"/>',
    ("arg", "name"): '<arg name=@V value="1"/>',
    ("include", "file"): '<include file=@V/>',
    ("include", "ns"): '<include file="$(find tpkg)/launch/inc.launch" ns=@V/>',
    ("include", "arg"): '<include file="$(find tpkg)/launch/inc.launch"><arg name="x" value=@V/></include>',
    ("env", "value"): '<env name="E" value=@V/>' + _NODE % "",
    ("env", "name"): '<env name=@V value="1"/>',
    ("group", "ns"): '<group ns=@V><param name="p" value="1"/></group>',
    ("group", "clear_params"): '<group ns="g" clear_params=@V/>',
    ("remap", "from"): '<remap from=@V to="b"/>' + _NODE % "",
    ("remap", "to"): '<remap from="a" to=@V/>' + _NODE % "",
}
BODY_TARGET = ("rosparam", "body")  # <rosparam subst_value="true"> text


def document(target, value):
    if target == BODY_TARGET:
        body = value.replace("&", "&amp;").replace("<", "&lt;")
        return '<launch>%s<rosparam subst_value="true">k: %s</rosparam></launch>' % (_PRELUDE, body)
    return "<launch>%s%s</launch>" % (_PRELUDE, TARGETS[target].replace("@V", quoteattr(value)))


# the mutant kinds: a value of about `n` characters
KINDS = {
    "plain": lambda n: "x" * n,
    "anon": lambda n: "$(anon x)" * (n // 9),
    "stray-paren": lambda n: "(" + "$(anon x)" * (n // 9),               # not one `$(...)` per '(' and '$'
    "dollar-value": lambda n: "$(arg d)x" * (n // 9),                     # a value bringing a '$'
    "after-dollar": lambda n: "$$(arg a)" * (n // 9),                     # a '$' before each copy
    "paren-value": lambda n: "$$(arg e)anon x)" * (n // 16),              # ... whose value is '('
    "finds": lambda n: "$(find tpkg)/x" * (n // 14),                      # paths running into each other
    "spaced-finds": lambda n: "$(find tpkg)/x " * (n // 15),
    "distinct": lambda n: "".join("$(anon x%d)" % i for i in range(n // 12)),
}


@pytest.fixture(scope="module")
def sandbox(tmp_path_factory):
    """The packages, and a PATH with nothing on it: a `<param command>` made of junk must not run anything."""
    root = tmp_path_factory.mktemp("hostile")
    pkg = root / "pkgs" / "tpkg"
    for rel, text in {"package.xml": "<package><name>tpkg</name><version>0.0.1</version></package>",
                      "scripts/talker": "#!/bin/sh\nexit 0\n",
                      "launch/inc.launch": '<launch><arg name="x" default="1"/></launch>'}.items():
        (pkg / rel).parent.mkdir(parents=True, exist_ok=True)
        (pkg / rel).write_text(text)
    (pkg / "scripts" / "talker").chmod(0o755)
    pkgs = root / "pkgs"
    (root / "empty").mkdir()
    env = {"ROS_PACKAGE_PATH": str(pkgs), "CMAKE_PREFIX_PATH": "", "ROS_HOME": str(root / "home"),
           "PATH": str(root / "empty"), "HOME": str(root)}
    from launcher.workspace.packages import PackageIndex
    return root, env, PackageIndex(env)


_LOCATED = re.compile(r"^(.+?):(\d+): ", re.S)
_INCLUDED = re.compile(r"\n  included from (.+):(\d+)$")


def load_and_compute(path, env, packages):
    """Load `path` as `launch --dump-params` and `--args` would, then compute what they print. Returns
    the LaunchError (checked: it names the file and a line) or None; anything else escapes."""
    from launcher.plan.command import node_command
    from launcher.params.dump import dump_yaml
    from launcher.xml import load

    try:
        config = load([str(path)], [], environ=env, packages=packages, core=False)
    except LaunchError as e:
        text = str(e)
        # the launch file, or a file it reads (a YAML file, an include); an include that cannot be read at all is
        # located by the chain's `included from FILE:LINE` (<include file="////">: "Is a directory")
        m = _LOCATED.match(text) or (e.include_chain and _INCLUDED.search(text))
        assert m and os.path.isfile(m.group(1)) and int(m.group(2)) >= 1, text[:500]
        assert len(text) < 5000, "a %d-character error message" % len(text)
        return e
    dump_yaml({k: p.value for k, p in config.params.items()})
    for node in list(config.nodes) + list(config.tests):
        try:
            node_command(node, master_uri="http://127.0.0.1:11311/", environ=env, packages=packages)
        except LaunchError:
            pass
    return None


def _run_in_process(sandbox, target, kind, size):
    root, env, packages = sandbox
    path = root / ("%s-%s-%s.launch" % (target[0], target[1], kind))
    path.write_text(document(target, KINDS[kind](size)))
    start = time.process_time()
    load_and_compute(path, env, packages)
    elapsed = time.process_time() - start
    assert elapsed < DEADLINE_S, "%s=%s (%s, %d chars) took %.1f s" % (target + (kind, size, elapsed))


_ALL_TARGETS = sorted(TARGETS) + [BODY_TARGET]


# (the kinds whose cost is the same wherever they are, a $(find)'s file checks or an anonymous name's
# making, are given to every attribute below only once)
_TAKING_TURNS = [k for k in sorted(KINDS) if k not in ("spaced-finds", "distinct")]


@pytest.mark.parametrize("target", _ALL_TARGETS, ids=["%s-%s" % t for t in _ALL_TARGETS])
def test_a_1mb_value_on_every_substituted_attribute(sandbox, target):
    """Each attribute with a 1 MB value, the kind of value taking turns among the attributes (all of them
    on one attribute, below, whose value --dump-params also writes)."""
    kind = _TAKING_TURNS[_ALL_TARGETS.index(target) % len(_TAKING_TURNS)]
    _run_in_process(sandbox, target, kind, MB)


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_every_kind_of_1mb_value(sandbox, kind):
    _run_in_process(sandbox, ("param", "value"), kind, MB)


# -------------------------------------------------------------------------------- integers

BIG_INTS = {
    "decimal": "9" * 5000,
    "hex": "0x" + "f" * 5000,
    "binary": "0b" + "1" * 20000,
    "octal": "0" + "7" * 6000,
    "base-60": "1" + ":59" * 3000,
    "base-60-huge": "1" + ":59" * 300_000,  # computing it would take hours
}


def _yaml_places(root, digits):
    """Every place the loader reads YAML, holding the integer `digits` (file name -> launch text)."""
    (root / "big.yaml").write_text("a: 1\nb: %s\n" % digits)
    (root / "bigkey.yaml").write_text("%s: 1\n" % digits)
    (root / "big.txt").write_text(digits + "\n")
    return {
        "rosparam": "<launch>\n<rosparam>\nb: %s\n</rosparam>\n</launch>" % digits,
        "rosparam-list": "<launch>\n<rosparam param=\"l\">[1, %s]</rosparam>\n</launch>" % digits,
        "rosparam-subst": "<launch>\n<arg name=\"n\" value=\"%s\"/>\n<rosparam subst_value=\"true\">\nb: $(arg n)\n"
                          "</rosparam>\n</launch>" % digits,
        "rosparam-file": "<launch>\n<rosparam file=\"%s\"/>\n</launch>" % (root / "big.yaml"),
        "rosparam-key": "<launch>\n<rosparam file=\"%s\"/>\n</launch>" % (root / "bigkey.yaml"),
        "param-yaml": "<launch>\n<param name=\"p\" type=\"yaml\" value=\"%s\"/>\n</launch>" % digits,
        "param-yaml-textfile": "<launch>\n<param name=\"p\" type=\"yaml\" textfile=\"%s\"/>\n</launch>"
                               % (root / "big.txt"),
        "param-yaml-after-rosparam": "<launch>\n<rosparam>x: 1</rosparam>\n<param name=\"p\" type=\"yaml\" "
                                     "value=\"[%s]\"/>\n</launch>" % digits,
        "param-int": "<launch>\n<param name=\"p\" type=\"int\" value=\"%s\"/>\n</launch>" % digits,
        "param-auto": "<launch>\n<param name=\"p\" value=\"%s\"/>\n</launch>" % digits,
        "eval": "<launch>\n<param name=\"p\" value=\"$(eval %s + 1)\"/>\n</launch>" % digits,
    }


@pytest.mark.parametrize("kind", sorted(BIG_INTS))
def test_integers_longer_than_python_prints_in_every_place_yaml_is_read(sandbox, kind):
    """roslaunch fails on them ("Exceeds the limit (4300 digits) for integer string conversion"), where it
    does not take them as strings (an untyped <param value>); so do we, with the file and line, never an
    internal error, and a base-60 one of 300,000 parts is refused before it is computed."""
    root, env, packages = sandbox
    for place, text in _yaml_places(root, BIG_INTS[kind]).items():
        path = root / ("int-%s-%s.launch" % (kind, place))
        path.write_text(text)
        start = time.process_time()
        error = load_and_compute(path, env, packages)
        assert time.process_time() - start < DEADLINE_S, (kind, place)
        assert (error is None) == (place == "param-auto"), (kind, place, error)


def test_an_integer_python_can_print_is_kept():
    from launcher.params.rosyaml import load_yaml
    assert load_yaml("a: 0x%s" % ("f" * 3000))["a"] == int("f" * 3000, 16)
    assert load_yaml("a: %s" % ("9" * 4300))["a"] == int("9" * 4300)


# -------------------------------------------------------------------------------- `launch` itself

def _cli_env(env):
    out = dict(os.environ)
    out.update(env, PATH=os.environ.get("PATH", ""))
    return out


def _launch(argv, env, timeout=DEADLINE_S):
    start = time.monotonic()
    try:
        out = subprocess.run([sys.executable, "-m", "launcher"] + argv, capture_output=True, text=True,
                             timeout=timeout, env=env)
    except subprocess.TimeoutExpired:
        pytest.fail("launch %s ran over %.0f s" % (" ".join(argv[:1]), timeout))
    return out, time.monotonic() - start


@pytest.mark.parametrize("mode,target,kind,size", [
    ("--nodes", ("node", "name"), "stray-paren", 5 * MB),
    ("--nodes", ("node", "pkg"), "dollar-value", 5 * MB),
    ("--nodes", ("machine", "address"), "after-dollar", 5 * MB),
    ("--nodes", ("rosparam", "command"), "anon", 900_000),   # `$(anon x)` 100,000 times
    ("--dump-params", BODY_TARGET, "stray-paren", 5 * MB),
    ("--dump-params", ("param", "value"), "finds", 5 * MB),
], ids=["node-name", "node-pkg", "machine-address", "rosparam-command", "rosparam-body", "param-value"])
def test_launch_with_a_5mb_value(sandbox, mode, target, kind, size):
    root, env, _ = sandbox
    path = root / ("cli-%s-%s.launch" % (target[1], kind))
    path.write_text(document(target, KINDS[kind](size)))
    out, _ = _launch([mode, str(path)], _cli_env(env))
    assert out.returncode in (0, 1), out.stderr[-2000:]
    assert "Traceback" not in out.stderr and "internal error" not in out.stderr, out.stderr[-2000:]
    if out.returncode == 1:
        assert out.stderr.startswith("%s:" % path) and len(out.stderr) < 5000, out.stderr[:2000]


def test_launch_dump_params_of_a_5000_digit_integer(sandbox):
    root, env, _ = sandbox
    path = root / "cli-int.launch"
    path.write_text('<launch>\n<rosparam subst_value="true">\na: 0x%s\n</rosparam>\n</launch>' % ("f" * 5000))
    out, _ = _launch(["--dump-params", str(path)], _cli_env(env))
    assert out.returncode == 1 and out.stderr.startswith("%s:3: " % path), out.stderr[:2000]
    assert "Traceback" not in out.stderr and "internal error" not in out.stderr


# -------------------------------------------------------------------------------- linear work

_PREFIX_ONLY = ("startswith", "endswith")  # (they look at the start or end of the string, not all of it)


class Work:
    """Operations a piece of code does: one per call, and a method of a str weighed by the length of the
    string (what a `replace` or `find` scans; a `find` from an offset is counted whole too). Regex and C
    parser calls count one: they are linear per call, and a loop calling them shows in its calls."""

    def __init__(self):
        self.ops = 0

    def __call__(self, frame, event, arg):
        if event == "call":
            self.ops += 1
        elif event == "c_call":
            receiver = getattr(arg, "__self__", None)
            self.ops += 1 + (len(receiver) if type(receiver) is str and arg.__name__ not in _PREFIX_ONLY else 0)

    def measure(self, fn, *args):
        self.ops = 0
        sys.setprofile(self)
        try:
            fn(*args)
        except LaunchError:
            pass
        finally:
            sys.setprofile(None)
        return self.ops


_TOKENS = ["$(anon x)", "$(anon y)", "$(arg a)", "$(arg d)", "$(arg e)", "$(find tpkg)", "$(find tpkg)/x", " ",
           "(", ")", "$", "$$(", "x", "/", "{", "$(optenv NOPE d f)", "$(dirname)", "$(arg\ta)"]


def _forget_what_loads_remember():
    """The memos a load keeps for the next one (plans of texts, parsed YAML and expressions, legal names):
    each measured load starts from none, as the first load of a process does."""
    from launcher.params import rosyaml
    from launcher.xml import sandbox, scope, substitution
    substitution._FIRST_PLANS.clear()
    substitution._FIND_PLANS.clear()
    rosyaml._parsed.clear()
    rosyaml._memo_chars = 0
    sandbox._PARSED.clear()
    scope.is_legal_name.cache_clear()


@settings(max_examples=80, deadline=None, database=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(target=st.sampled_from(_ALL_TARGETS), unit=st.lists(st.sampled_from(_TOKENS), min_size=1, max_size=6))
def test_the_work_of_a_load_grows_in_proportion_to_an_attribute(sandbox, target, unit):
    """An attribute ten times as long costs at most ~ten times the operations (roslaunch's one rescan per
    `$(...)` made it a hundred times, at these sizes)."""
    root, env, packages = sandbox
    text = "".join(unit)
    work = []
    for size in (2_000, 20_000):
        path = root / ("work-%d.launch" % size)
        path.write_text(document(target, text * (size // len(text) + 1)))
        load_and_compute(path, env, packages)  # (what a first load imports is not the attribute's work)
        _forget_what_loads_remember()
        run_env = dict(env, ROS_HOME=str(root / ("home-%d-%d" % (size, len(os.listdir(root))))))
        work.append(Work().measure(load_and_compute, path, run_env, packages))
    event("ops at 20 kB: %s" % ("<10k" if work[1] < 10_000 else "<100k" if work[1] < 100_000 else ">=100k"))
    assert work[1] <= 13 * work[0], "%d -> %d operations for %r x10 in %s" % (work[0], work[1], text, target)


def test_elements_nested_past_the_recursion_limit_are_an_error_at_their_line(sandbox):
    """10,000 nested <group>s (roslaunch: "maximum recursion depth exceeded", without a place), and a deep
    YAML list inside a few hundred of them: an error at the element the walk had reached."""
    root, env, packages = sandbox
    for name, inner in (("groups", '<param name="x" value="1"/>'), ("groups-yaml", "<rosparam>a: %s1%s</rosparam>"
                                                                                  % ("[" * 250, "]" * 250))):
        depth = 10_000 if name == "groups" else 400
        path = root / ("%s.launch" % name)
        path.write_text("<launch>\n" + "<group>\n" * depth + inner + "</group>" * depth + "</launch>\n")
        error = load_and_compute(path, env, packages)
        assert error is not None and "nested too deeply" in str(error) and error.line > 1, error
