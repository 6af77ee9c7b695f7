"""Differential test: random launch files, our loader against roslaunch's own loader.

A seeded generator writes a few hundred mostly-valid launch trees (groups, namespaces,
args with defaults and if/unless, params of every type, inline rosparam YAML, remaps,
env, private params, node attributes, includes with args). Each is loaded by
`launcher.xml.load` and, in one Debian-python process, by roslaunch's XmlLoader; the
parameters, node names and node fields, clear_params and "is it an error" must agree.
"""

from __future__ import annotations

import json
import os
import random
import subprocess

import pytest

from launcher.model.errors import LaunchError

N_DOCS = 400
SEED = 20261121
PKG = "spec_diff_pkg"
FIELDS = ("package", "type", "name", "namespace", "args", "remap_args", "env_args", "respawn", "respawn_delay",
          "required", "output", "cwd", "launch_prefix", "machine_name")
TEST_FIELDS = FIELDS + ("test_name", "time_limit", "retry")

NAMES = ["a", "b", "c", "speed", "robot", "x1", "gain_p", "~priv", "/abs", "a/b", "~p/q", "/g/h", "_u"]
NS = ["", "g", "robot", "/top", "a/b", "/", "sub/", "r2", "g", "~"]
VALUES = ["1", "1.5", "-2", "true", "False", "yes", "0x10", "1e3", "1_000", "nan", "hello world", " pad ", "",
          "deg(90)", "[1, 2]", "{a: 1}", "$(arg v)", "pre_$(arg v)_post", "$(optenv SPEC_DIFF_X dflt)",
          "$(env SPEC_DIFF_SET)", "$(find %s)/cfg" % PKG, "$(dirname)", "$(eval 1 + 2)", "$(eval arg('v') * 2)"]
TYPES = [None, None, None, "str", "int", "double", "bool", "yaml", "string", "boolean"]
BOOLS = ["true", "false", "1", "0", "$(arg flag)", "$(arg neg)", "$(eval 1 == 1)"]
YAML = ["a: 1", "a: {b: [1, 2.5, x]}\nc: deg(180)", "/abs: 1\nrel: 2", "k: !degrees 90", "list: [1, 2]",
        "m: &x {p: 1}\nn: *x", "s: 'quoted'\nt: yes", "{}", "nested:\n  deep:\n    deeper: rad(pi)"]


def _attrs(pairs: dict[str, str]) -> str:
    def esc(v: str) -> str:
        return v.replace("&", "&amp;").replace('"', "&quot;").replace("<", "&lt;")
    return "".join(' %s="%s"' % (k, esc(v)) for k, v in pairs.items())


class Gen:
    def __init__(self, rng: random.Random):
        self.r = rng
        self.node_count = 0

    def cond(self) -> dict[str, str]:
        roll = self.r.random()
        if roll < 0.1:
            return {"if": self.r.choice(BOOLS)}
        if roll < 0.2:
            return {"unless": self.r.choice(BOOLS)}
        return {}

    def param(self) -> str:
        a = {"name": self.r.choice(NAMES), "value": self.r.choice(VALUES)}
        t = self.r.choice(TYPES)
        if t:
            a["type"] = t
        a.update(self.cond())
        return "<param%s/>" % _attrs(a)

    def rosparam(self) -> str:
        a: dict[str, str] = {}
        roll = self.r.random()
        if roll < 0.15:
            a = {"command": "delete", "param": self.r.choice(NAMES)}
            a.update(self.cond())
            return "<rosparam%s/>" % _attrs(a)
        if roll < 0.2:
            a = {"command": "dump", "file": "out.yaml"}
            if self.r.random() < 0.5:
                a["param"] = self.r.choice(NAMES)
            return "<rosparam%s/>" % _attrs(a)
        if self.r.random() < 0.3:
            a["ns"] = self.r.choice(NS[1:5])
        if self.r.random() < 0.2:
            a["param"] = self.r.choice(NAMES[:6])
        if self.r.random() < 0.2:
            a["subst_value"] = "true"
        a.update(self.cond())
        text = self.r.choice(YAML + ["v: $(arg v)"])
        return "<rosparam%s>\n%s\n</rosparam>" % (_attrs(a), text.replace("&", "&amp;").replace("<", "&lt;"))

    def node(self, depth: int) -> str:
        self.node_count += 1
        a = {"pkg": "p", "type": "t", "name": "n%d" % self.node_count}
        for attr, values in (("ns", NS[1:]), ("args", ["--x 1", "'a b'  c", "$(arg v)"]), ("respawn", ["true", "false"]),
                             ("output", ["screen", "log"]), ("cwd", ["node", "ROS_HOME"]),
                             ("launch-prefix", ["nice", "gdb --args"]), ("clear_params", ["true", "false"]),
                             ("respawn_delay", ["1", "2.5"]), ("required", ["false"]), ("machine", ["m1", "m2"])):
            if self.r.random() < 0.15:
                a[attr] = self.r.choice(values)
        a.update(self.cond())
        children = [self.r.choice([self.param, self.rosparam, self.remap, self.env])() for _ in range(self.r.randint(0, 3))]
        return "<node%s>%s</node>" % (_attrs(a), "".join(children))

    def test(self) -> str:
        self.node_count += 1
        a = {"pkg": "p", "type": "t", "test-name": "t%d" % self.node_count}
        for attr, values in (("name", ["tn%d" % self.node_count]), ("time-limit", ["5", "2.5"]), ("retry", ["2"]),
                             ("ns", NS[1:4]), ("args", ["-v"])):
            if self.r.random() < 0.3:
                a[attr] = self.r.choice(values)
        a.update(self.cond())
        children = [self.r.choice([self.param, self.remap, self.env])() for _ in range(self.r.randint(0, 2))]
        return "<test%s>%s</test>" % (_attrs(a), "".join(children))

    def file_param(self) -> str:
        if self.r.random() < 0.5:
            return "<param%s/>" % _attrs({"name": self.r.choice(NAMES[:6]), "textfile": "$(find %s)/text.txt" % PKG,
                                          **({"type": "int"} if self.r.random() < 0.3 else {})})
        a = {"command": "load", "file": "$(find %s)/data.yaml" % PKG}
        if self.r.random() < 0.5:
            a["ns"] = self.r.choice(NS[1:5])
        return "<rosparam%s/>" % _attrs(a)

    def remap(self) -> str:
        return "<remap%s/>" % _attrs({"from": self.r.choice(["in", "out", "~x", "/abs"]),
                                      "to": self.r.choice(["a", "b/c", "/d", "~e"])})

    def env(self) -> str:
        return "<env%s/>" % _attrs({"name": self.r.choice(["SPEC_DIFF_A", "SPEC_DIFF_B"]),
                                    "value": self.r.choice(["1", "x y", "$(arg v)"])})

    def arg(self) -> str:
        # mostly fresh names (a re-declared arg is an error, which teaches us little when frequent)
        self.node_count += 1
        name = self.r.choice(["v", "flag"]) if self.r.random() < 0.1 else "e%d" % self.node_count
        kind = self.r.random()
        a = {"name": name}
        if kind < 0.6:
            a["default"] = self.r.choice(["1", "true", "false", "word", "2.5"])
        elif kind < 0.9:
            a["value"] = self.r.choice(["1", "true", "false", "word"])
        return "<arg%s/>" % _attrs(a)

    def group(self, depth: int) -> str:
        a: dict[str, str] = {}
        if self.r.random() < 0.7:
            a["ns"] = self.r.choice(NS)
        if self.r.random() < 0.1 and a.get("ns"):
            a["clear_params"] = "true"
        a.update(self.cond())
        return "<group%s>%s</group>" % (_attrs(a), self.body(depth + 1))

    def machine(self) -> str:
        a = {"name": self.r.choice(["m1", "m2"]), "address": self.r.choice(["localhost", "127.0.0.1", "$(arg v)"])}
        for attr, values in (("default", ["true", "false", "never"]), ("user", ["me"]), ("ssh-port", ["22", "x"]),
                             ("timeout", ["3", "x"]), ("env-loader", ["/opt/env.sh"])):
            if self.r.random() < 0.2:
                a[attr] = self.r.choice(values)
        return "<machine%s/>" % _attrs(a)

    def include(self) -> str:
        a = {"file": "$(dirname)/%s" % self.r.choice(["inc.launch", "inc.launch", "inc2.launch"])}
        if self.r.random() < 0.5:
            a["ns"] = self.r.choice(NS[1:5])
        if self.r.random() < 0.3:
            a["pass_all_args"] = "true"
        a.update(self.cond())
        child = '<arg name="iv" %s="%s"/>' % (self.r.choice(["value", "value", "default"]),
                                               self.r.choice(["1", "two", "$(arg v)"]))
        if a.get("pass_all_args"):
            child = ""
        if self.r.random() < 0.2:
            child += self.env()
        if self.r.random() < 0.1:
            a["clear_params"] = "true"
        return "<include%s>%s</include>" % (_attrs(a), child)

    def body(self, depth: int = 0) -> str:
        items = []
        for _ in range(self.r.randint(1, 6 if depth < 2 else 3)):
            roll = self.r.random()
            if roll < 0.3:
                items.append(self.param())
            elif roll < 0.45:
                items.append(self.node(depth))
            elif roll < 0.55:
                items.append(self.rosparam())
            elif roll < 0.65 and depth < 3:
                items.append(self.group(depth))
            elif roll < 0.75:
                items.append(self.remap())
            elif roll < 0.82:
                items.append(self.env())
            elif roll < 0.86:
                items.append(self.arg())
            elif roll < 0.89:
                items.append(self.test())
            elif roll < 0.91:
                items.append(self.file_param())
            elif roll < 0.92:
                items.append(self.machine())
            else:
                items.append(self.include())
        return "\n".join(items)

    def document(self) -> str:
        head = '<arg name="v" default="3"/><arg name="flag" default="true"/><arg name="neg" default="false"/>'
        return "<launch>\n%s\n%s\n</launch>\n" % (head, self.body())


INCLUDED = ('<launch><arg name="iv" default="0"/><arg name="v" default="9"/>'
            '<param name="inc_p" value="$(arg iv)"/><node pkg="p" type="t" name="inc_n"/></launch>')
# a second level: passes everything down, and refers to the parent's args
INCLUDED2 = ('<launch><arg name="iv" default="0"/><arg name="v" default="9"/><arg name="flag" default="true"/>'
             '<group ns="deeper" if="$(arg flag)"><include file="$(dirname)/inc.launch" pass_all_args="true"/></group>'
             '<param name="inc2_p" value="$(arg v)-$(arg iv)"/></launch>')


def _norm(value):
    if isinstance(value, bool):
        return ["bool", value]
    if isinstance(value, int):
        return ["int", value]
    if isinstance(value, float):
        return ["float", repr(value)]
    if isinstance(value, str):
        return ["str", value]
    if value is None:
        return ["none"]
    if isinstance(value, (list, tuple)):
        return ["list", [_norm(v) for v in value]]
    if isinstance(value, dict):
        return ["dict", sorted([str(k), _norm(v)] for k, v in value.items())]
    return ["other", repr(value)]


@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    root = tmp_path_factory.mktemp("diff")
    pkg = root / "pkgs" / PKG
    pkg.mkdir(parents=True)
    (pkg / "package.xml").write_text("<package><name>%s</name></package>" % PKG)
    (pkg / "text.txt").write_text("42\n")
    (pkg / "data.yaml").write_text("from_file: {x: 1, y: [a, b]}\nangle: deg(45)\n")
    rng = random.Random(SEED)
    files = []
    for i in range(N_DOCS):
        d = pkg / ("d%03d" % i)
        d.mkdir()
        (d / "inc.launch").write_text(INCLUDED)
        (d / "inc2.launch").write_text(INCLUDED2)
        (d / "main.launch").write_text(Gen(rng).document())
        # command-line args for some documents: overrides, undeclared names, empty values, __ns
        argv = rng.sample(["v:=7", "flag:=false", "neg:= true ", "e3:=cli", "nobody:=1", "v:=", "__ns:=/cli"],
                          rng.choice([0, 0, 1, 2]))
        extra = {"ROS_NAMESPACE": rng.choice(["/envns", "rel", "/a/b/"])} if rng.random() < 0.15 else {}
        files.append((str(d / "main.launch"), argv, extra))
    env = {k: v for k, v in os.environ.items()
           if not k.startswith("ROS_") and not k.startswith("SPEC_") and k != "CMAKE_PREFIX_PATH"}
    # (ROS_DISTRO names the default env-loader of <machine>s, as a sourced setup.bash sets it)
    env.update(ROS_PACKAGE_PATH=str(root / "pkgs"), ROS_HOME=str(root / "home"), SPEC_DIFF_SET="set",
               ROS_DISTRO="noetic")
    return files, env


def _ours(path, env, argv=()):
    from launcher.workspace.packages import PackageIndex
    from launcher.xml import load
    try:
        config = load([path], list(argv), environ=env, packages=PackageIndex(env), core=False)
    except LaunchError as e:
        return {"error": str(e)}
    nodes = list(config.nodes) + list(config.tests)
    return {"error": None, "params": {k: _norm(p.value) for k, p in config.params.items()},
            "nodes": [n.full_name for n in nodes],
            "fields": {n.full_name: {f: _norm(getattr(n, f, None)) for f in (TEST_FIELDS if n.is_test else FIELDS)}
                       for n in nodes},
            "clear": sorted(config.clear_params),
            "commands": [list(c) for c in config.rosparam_commands],
            "machines": {name: [m.address, m.user, m.ssh_port, m.env_loader, float(m.timeout)]
                         for name, m in sorted(config.machines.items())}}


REFERENCE_RUNNER = r"""
import json, os, sys
import yaml
import roslaunch.config, roslaunch.loader, roslaunch.xmlloader, roslaunch.substitution_args
# each document must see a fresh process: roslaunch imports rosparam at the first <rosparam>,
# which registers the angle syntax on PyYAML's SafeLoader for every later type="yaml" param
PRISTINE = (dict(yaml.SafeLoader.yaml_constructors),
            {k: list(v) for k, v in yaml.SafeLoader.yaml_implicit_resolvers.items()})
def fresh_yaml():
    yaml.SafeLoader.yaml_constructors = dict(PRISTINE[0])
    yaml.SafeLoader.yaml_implicit_resolvers = {k: list(v) for k, v in PRISTINE[1].items()}
    sys.modules.pop("rosparam", None)
    roslaunch.loader.rosparam = None
FIELDS, TEST_FIELDS = %r
def norm(value):
    if isinstance(value, bool): return ["bool", value]
    if isinstance(value, int): return ["int", value]
    if isinstance(value, float): return ["float", repr(value)]
    if isinstance(value, str): return ["str", value]
    if value is None: return ["none"]
    if isinstance(value, (list, tuple)): return ["list", [norm(v) for v in value]]
    if isinstance(value, dict): return ["dict", sorted([str(k), norm(v)] for k, v in value.items())]
    return ["other", repr(value)]
paths, env = json.loads(sys.stdin.read())
out = []
for path, argv, extra in paths:
    os.environ.clear(); os.environ.update(env); os.environ.update(extra)
    fresh_yaml()
    sys.argv = ["roslaunch", path] + argv
    config = roslaunch.config.ROSLaunchConfig()
    try:
        roslaunch.xmlloader.XmlLoader().load(path, config, verbose=False)
        nodes = list(config.nodes) + list(config.tests)
        names = [n.namespace + n.name for n in nodes]
        if len(set(names)) != len(names):
            raise ValueError("duplicate node names")
        out.append({"error": None, "params": {k: norm(p.value) for k, p in config.params.items()},
                    "nodes": names,
                    "fields": {n.namespace + n.name: {f: norm(getattr(n, f, None))
                                                      for f in (TEST_FIELDS if hasattr(n, "test_name") else FIELDS)}
                               for n in nodes},
                    "clear": sorted(config.clear_params),
                    "commands": [[e.args[0], e.args[-1], e.args[1] if e.args[0] == "dump" else None]
                                 for e in config.executables if e.command == "rosparam"],
                    "machines": {name: [m.address, m.user, m.ssh_port, m.env_loader, float(m.timeout)]
                                 for name, m in sorted(config.machines.items()) if name}})
    except Exception as e:
        out.append({"error": "%%s: %%s" %% (type(e).__name__, e)})
print(json.dumps(out))
"""


def test_generator_makes_varied_documents(corpus):
    files, env = corpus
    outcomes = [_ours(f, dict(env, **extra), argv)["error"] is None for f, argv, extra in files]
    # both valid and invalid documents, mostly valid, or the comparison says little
    assert 0.4 * len(files) < sum(outcomes) < len(files)


def test_same_results_as_roslaunch(ros_env, corpus):
    files, env = corpus
    proc = subprocess.run([ros_env["python"], "-c", REFERENCE_RUNNER % ((FIELDS, TEST_FIELDS),)],
                          input=json.dumps([files, dict(env, PATH=ros_env["path"])]), text=True,
                          capture_output=True, timeout=600, env=dict(os.environ, PATH=ros_env["path"]))
    assert proc.returncode == 0, proc.stderr[-3000:]
    refs = json.loads(proc.stdout)
    mismatches = []
    for (path, argv, extra), ref in zip(files, refs):
        ours = _ours(path, dict(env, **extra), argv)
        path = "%s %s %s" % (path, " ".join(argv), extra or "")
        if (ours["error"] is None) != (ref["error"] is None):
            mismatches.append("%s: roslaunch %s, ours %s" % (path, "error: %s" % ref["error"] if ref["error"] else "ok",
                                                            "error: %s" % ours["error"] if ours["error"] else "ok"))
            continue
        if ours["error"] is None:
            for key in ("params", "nodes", "fields", "clear", "commands", "machines"):
                if ours[key] != ref[key]:
                    detail = ""
                    if key == "fields":
                        detail = "; ".join("%s.%s: ours %s ref %s" % (n, f, ours[key].get(n, {}).get(f),
                                                                     ref[key].get(n, {}).get(f))
                                           for n in sorted(set(ours[key]) | set(ref[key])) for f in TEST_FIELDS
                                           if ours[key].get(n, {}).get(f) != ref[key].get(n, {}).get(f))
                    elif isinstance(ours[key], dict):
                        diff = sorted(k for k in set(ours[key]) | set(ref[key]) if ours[key].get(k) != ref[key].get(k))
                        detail = "; ".join("%s: ours %s ref %s" % (k, ours[key].get(k), ref[key].get(k))
                                           for k in diff[:3])
                    else:
                        detail = "ours %s ref %s" % (ours[key], ref[key])
                    mismatches.append("%s: %s differ: %s" % (path, key, detail[:800]))
    assert not mismatches, "%d of %d differ:\n%s" % (len(mismatches), len(files), "\n".join(mismatches[:15]))
