"""The loader against roslaunch's semantics: scopes, args across includes, params, remaps, env, nodes, tests.

Expected values were checked against the real roslaunch (Noetic, 1.15.15) on
the same files; the quirky ones say so.
"""

from __future__ import annotations

import pytest

from launcher.model.errors import shorten


def names(config):
    return [n.full_name for n in config.nodes]


# ---------------------------------------------------------------- namespaces and groups

def test_group_namespaces_relative_absolute_and_trailing_slash(ld):
    p = ld.params("""
        <launch>
          <param name="top" value="0"/>
          <group ns="a">
            <param name="pa" value="1"/>
            <param name="/abs" value="2"/>
            <group ns="/x/y"><param name="pxy" value="3"/></group>
            <group ns="t/"><param name="pt" value="4"/></group>
            <group><param name="same" value="5"/></group>
          </group>
        </launch>""")
    assert p == {"/top": 0, "/a/pa": 1, "/abs": 2, "/x/y/pxy": 3, "/a/t/pt": 4, "/a/same": 5}


def test_root_namespace_from_cli_and_environment(ld):
    text = '<launch><node name="n" pkg="tpkg" type="talker"/><param name="p" value="1"/></launch>'
    assert names(ld.load(text, ["__ns:=/robot"])) == ["/robot/n"]
    assert names(ld.load(text, ["__ns:=rel"])) == ["/rel/n"]
    assert names(ld.load(text, env={"ROS_NAMESPACE": "/env_ns"})) == ["/env_ns/n"]
    # __ns:= wins over ROS_NAMESPACE
    assert names(ld.load(text, ["__ns:=/cli"], env={"ROS_NAMESPACE": "/env_ns"})) == ["/cli/n"]


def test_node_namespace_double_slashes_collapse(ld):
    c = ld.load('<launch><group ns="a//b"><node name="n" pkg="tpkg" type="talker"/></group></launch>')
    assert c.nodes[0].namespace == "/a/b/"


# ---------------------------------------------------------------- args

def test_arg_default_value_cli_and_chains(ld):
    text = """
        <launch>
          <arg name="req"/>
          <arg name="d" default="dflt"/>
          <arg name="const" value="c"/>
          <arg name="chain" default="$(arg d)_$(arg req)"/>
          <param name="req" value="$(arg req)"/>
          <param name="d" value="$(arg d)"/>
          <param name="const" value="$(arg const)"/>
          <param name="chain" value="$(arg chain)"/>
        </launch>"""
    assert ld.params(text, ["req:=R"]) == {"/req": "R", "/d": "dflt", "/const": "c", "/chain": "dflt_R"}
    assert ld.params(text, ["req:=R", "d:=  padded  "])["/d"] == "padded"


def test_required_arg_missing_names_the_arg_and_line(ld):
    e = ld.error("""
        <launch>
          <arg name="robot"/>
          <param name="p" value="$(arg robot)"/>
        </launch>""")
    assert e.line == 3 and e.filename.endswith("main.launch")
    assert "robot:=value" in e.message


def test_cli_quirks(ld):
    text = """
        <launch>
          <arg name="a" default="d"/>
          <param name="a" value="$(arg a)"/>
          <param name="undeclared" value="$(arg und)"/>
        </launch>"""
    # an empty value is dropped; _private:= is not an arg; an undeclared CLI arg is still visible
    p = ld.params(text, ["a:=", "_und:=x", "und:=U"])
    assert p == {"/a": "d", "/undeclared": "U"}


def test_arg_with_value_cannot_be_overridden(ld):
    e = ld.error('<launch>\n<arg name="c" value="v"/>\n</launch>', ["c:=other"])
    assert "cannot override arg 'c'" in e.message and e.line == 2


def test_arg_redeclared_is_an_error_but_sibling_groups_may_reuse_a_name(ld):
    p = ld.params("""
        <launch>
          <group ns="l"><arg name="side" value="L"/><param name="s" value="$(arg side)"/></group>
          <group ns="r"><arg name="side" value="R"/><param name="s" value="$(arg side)"/></group>
        </launch>""")
    assert p == {"/l/s": "L", "/r/s": "R"}
    e = ld.error('<launch>\n<arg name="a" default="1"/>\n<arg name="a" default="2"/>\n</launch>')
    assert "already been declared" in e.message and e.line == 3


def test_conditional_arg_declarations(ld):
    text = """
        <launch>
          <arg name="fast" default="false"/>
          <arg name="speed" value="hi" if="$(arg fast)"/>
          <arg name="speed" value="lo" unless="$(arg fast)"/>
          <param name="speed" value="$(arg speed)"/>
        </launch>"""
    assert ld.params(text)["/speed"] == "lo"
    assert ld.params(text, ["fast:=true"])["/speed"] == "hi"


# ---------------------------------------------------------------- include

def test_include_args_ns_env_and_files(ld):
    child = ld.write("inc/child.launch", """
        <launch>
          <arg name="who"/>
          <arg name="opt" default="child_default"/>
          <param name="who" value="$(arg who)"/>
          <param name="opt" value="$(arg opt)"/>
          <param name="dir" value="$(dirname)"/>
          <node name="cn" pkg="tpkg" type="talker"/>
        </launch>""")
    c = ld.load("""
        <launch>
          <arg name="top" default="T"/>
          <include file="$(dirname)/inc/child.launch" ns="sub">
            <env name="FROM_INCLUDE" value="1"/>
            <arg name="who" value="$(arg top)_x"/>
          </include>
        </launch>""")
    p = {k: v.value for k, v in c.params.items()}
    assert p == {"/sub/who": "T_x", "/sub/opt": "child_default", "/sub/dir": str(ld.launch / "inc")}
    assert names(c) == ["/sub/cn"]
    assert c.nodes[0].env_args == (("FROM_INCLUDE", "1"),)
    assert c.nodes[0].filename == child
    assert set(c.files) == {child, str(ld.launch / "main.launch")}


def test_include_missing_arg_error_points_into_child_with_include_chain(ld):
    ld.write("child.launch", """
        <launch>
          <arg name="need"/>
          <param name="p" value="$(arg need)"/>
        </launch>""")
    e = ld.error("""
        <launch>
          <group ns="g">
            <include file="$(dirname)/child.launch"/>
          </group>
        </launch>""")
    assert e.filename.endswith("child.launch") and e.line == 3
    assert e.include_chain == ((str(ld.launch / "main.launch"), 3),)
    assert "included from %s:3" % (ld.launch / "main.launch") in str(e)
    assert "need" in e.message


def test_include_unused_arg_and_undeclared_value_are_errors(ld):
    ld.write("plain.launch", "<launch><param name='p' value='1'/></launch>")
    e = ld.error("""
        <launch>
          <include file="$(dirname)/plain.launch">
            <arg name="nobody_wants_me" value="1"/>
          </include>
        </launch>""")
    assert "unused args [nobody_wants_me]" in e.message and e.line == 2
    e = ld.error("""
        <launch>
          <include file="$(dirname)/plain.launch">
            <arg name="no_value"/>
          </include>
        </launch>""")
    assert "no_value" in e.message


def test_unused_arg_quirk_arg_declared_only_in_a_group_of_the_child(ld):
    # roslaunch only counts the child's top-level declarations as "used"
    ld.write("child.launch", '<launch><group ns="g"><arg name="x" default="2"/></group></launch>')
    e = ld.error('<launch><include file="$(dirname)/child.launch"><arg name="x" value="1"/></include></launch>')
    assert "unused args [x]" in e.message


def test_pass_all_args(ld):
    ld.write("child.launch", """
        <launch>
          <arg name="a"/>
          <arg name="b" value="child_fixed"/>
          <param name="a" value="$(arg a)"/>
          <param name="b" value="$(arg b)"/>
        </launch>""")
    p = ld.params("""
        <launch>
          <arg name="a" default="1"/>
          <arg name="b" default="2"/>
          <arg name="extra" default="3"/>
          <include file="$(dirname)/child.launch" pass_all_args="true"><arg name="b" value="over"/></include>
        </launch>""")
    # with pass_all_args a value= in the child overrides instead of failing; unused args are fine
    assert p == {"/a": 1, "/b": "child_fixed"}


def test_include_relative_path_is_relative_to_cwd(ld, monkeypatch):
    ld.write("inc/plain.launch", "<launch><param name='p' value='1'/></launch>")
    monkeypatch.chdir(ld.launch)
    assert ld.params('<launch><include file="inc/plain.launch"/></launch>') == {"/p": 1}


def test_include_missing_file(ld):
    e = ld.error('<launch>\n<param name="x" value="1"/>\n<include file="$(dirname)/nope.launch"/>\n</launch>')
    assert e.line == 3 and "nope.launch" in e.message


# ---------------------------------------------------------------- params

@pytest.mark.parametrize("attrs,expected", [
    ('value="7"', 7), ('value=" 8 "', 8), ('value="7.0"', 7.0), ('value=".5"', 0.5),
    ('value="1e3"', "1e3"), ('value="1_000"', "1_000"), ('value="0x10"', "0x10"),
    ('value="TRUE"', True), ('value="yes"', "yes"), ('value=""', ""),
    ('type="str" value="123"', "123"), ('type="int" value="42"', 42), ('type="double" value="3"', 3.0),
    ('type="bool" value="1"', True), ('type="boolean" value=" false "', False), ('type="INT" value="5"', 5),
    ('type="yaml" value="[1, 2.5, x]"', [1, 2.5, "x"]), ('type="yaml" value="{a: {b: 1}}"', {"a": {"b": 1}}),
])
def test_param_typing(ld, attrs, expected):
    got = ld.params('<launch><param name="p" %s/></launch>' % attrs)["/p"]
    assert got == expected and type(got) is type(expected)


@pytest.mark.parametrize("attrs,match", [
    ('type="int" value="4.5"', "not of type int"),
    ('type="bool" value="yes"', "bool"),
    ('type="float" value="1"', "Unknown type"),
    ('type=" " value="1"', "Unknown type ''"),  # (roslaunch strips the type after its `or 'auto'`)
    ('type="yaml" value="[1, 2"', "YAML"),
    ('value="1" textfile="x"', "one and only one"),
    ('command="false"', "returned with code [1]"),
    ('textfile="/no/such/file"', "No such file"),
])
def test_param_errors_have_the_line(ld, attrs, match):
    e = ld.error('<launch>\n\n<param name="p" %s/>\n</launch>' % attrs)
    assert match in e.message and e.line == 3


def test_textfile_binfile_command(ld):
    (ld.launch / "blob.bin").write_bytes(b"\x00\x01\xff")
    p = ld.params("""
        <launch>
          <param name="text" textfile="$(find tpkg)/data/note.txt"/>
          <param name="bin" binfile="$(dirname)/blob.bin"/>
          <param name="cmd" command="echo 17"/>
          <param name="cmd_str" type="str" command="printf 'a b'"/>
        </launch>""")
    assert p == {"/text": "hello\n", "/bin": b"\x00\x01\xff", "/cmd": 17, "/cmd_str": "a b"}


def test_failing_command_reports_its_stderr(ld):
    e = ld.error('<launch><param name="p" command="sh -c \'echo broken-thing >&amp;2; exit 3\'"/></launch>')
    assert "returned with code [3]" in e.message and "broken-thing" in e.message


def test_later_param_replaces_in_place_and_parent_child_conflict_is_a_warning(ld):
    c = ld.load("""
        <launch>
          <param name="a" value="first"/>
          <param name="b" value="x"/>
          <param name="a" value="2"/>
          <param name="b/c" value="3"/>
        </launch>""", core=False)
    assert list(c.params) == ["/a", "/b", "/b/c"] and c.params["/a"].value == 2
    assert any("conflicts with parent parameter [/b]" in w and ":5:" in w for w in c.warnings)


def test_private_params_attach_to_later_nodes_only(ld):
    p = ld.params("""
        <launch>
          <node name="before" pkg="tpkg" type="talker"/>
          <param name="~scoped" value="s"/>
          <node name="after" pkg="tpkg" type="talker"/>
          <group ns="g">
            <param name="~g" value="1"/>
            <node name="gn" pkg="tpkg" type="talker">
              <param name="scoped" value="node wins"/>
              <param name="~tilde" value="t"/>
              <param name="/glob" value="x"/>
            </node>
          </group>
          <node name="after2" pkg="tpkg" type="talker"/>
          <rosparam param="~rp">{k: 1}</rosparam>
        </launch>""")
    assert p == {"/after/scoped": "s", "/g/gn/g": 1, "/g/gn/scoped": "node wins", "/g/gn/tilde": "t",
                 "/g/gn/glob": "x", "/after2/scoped": "s", "~rp/k": 1}


def test_private_param_declared_in_an_include_reaches_later_nodes_of_the_parent(ld):
    # roslaunch shares the ~param list with the include when it is non-empty
    ld.write("child.launch", '<launch><param name="~from_child" value="c"/></launch>')
    text = """
        <launch>
          %s
          <include file="$(dirname)/child.launch"/>
          <node name="after" pkg="tpkg" type="talker"/>
        </launch>"""
    assert ld.params(text % '<param name="~outer" value="o"/>') == {"/after/outer": "o", "/after/from_child": "c"}
    assert ld.params(text % "") == {}


# ---------------------------------------------------------------- rosparam

def test_rosparam_load_ns_param_subst_and_inline(ld):
    p = ld.params("""
        <launch>
          <arg name="who" default="bot"/>
          <rosparam command="load" file="$(find tpkg)/config/params.yaml"/>
          <rosparam file="$(find tpkg)/config/params.yaml" ns="n" param="p"/>
          <rosparam param="list">[1, two]</rosparam>
          <rosparam param="subst" subst_value="true">{who: $(arg who)}</rosparam>
          <rosparam param="nosubst">{who: $(arg who)}</rosparam>
          <rosparam param="deg">deg(180)</rosparam>
          <rosparam>{/abs_key: 1}</rosparam>
          <rosparam param="empty_dict">{}</rosparam>
          <rosparam command="delete" param="gone"/>
          <node name="n" pkg="tpkg" type="talker"><rosparam>{k: v}</rosparam></node>
        </launch>""")
    assert p == {"/a": 1, "/b/c": "two", "/n/p/a": 1, "/n/p/b/c": "two", "/list": [1, "two"],
                 "/subst/who": "bot", "/nosubst/who": "$(arg who)", "/deg": pytest.approx(3.141592653589793),
                 "/abs_key": 1, "/n/k": "v"}


def test_rosparam_commands_are_recorded_in_order(ld):
    c = ld.load("""
        <launch><group ns="g">
          <rosparam command="delete" param="x"/>
          <rosparam command="dump" file="out.yaml" param="y"/>
        </group></launch>""")
    assert c.rosparam_commands == (("delete", "/g/x", None), ("dump", "/g/y", "out.yaml"))
    assert not c.warnings


def test_a_rosparam_dump_without_a_file_is_said_at_its_line(ld):
    c = ld.load('<launch>\n<rosparam command="dump" param="y"/>\n</launch>')
    assert c.warnings == ('%s:2: <rosparam command="dump"> without a file= dumps nothing (roslaunch\'s launch fails '
                          'on it)' % (ld.launch / "main.launch"),)


def test_rosparam_yaml_error_reports_the_yaml_files_own_line(ld):
    bad = ld.launch / "bad.yaml"
    bad.write_text("a: 1\nb: 2\nc: [1, 2\n")
    e = ld.error('<launch>\n<rosparam file="%s"/>\n</launch>' % bad)
    assert e.filename == str(bad) and e.line in (3, 4)
    assert e.include_chain[0] == (str(ld.launch / "main.launch"), 2)


def test_rosparam_non_dict_needs_param(ld):
    e = ld.error("<launch>\n<rosparam>5</rosparam>\n</launch>")
    assert "'param' attribute must be set" in e.message and e.line == 2


def test_yaml_param_angles_only_after_a_rosparam(ld):
    p = ld.params("""
        <launch>
          <param name="before" type="yaml" value="deg(90)"/>
          <rosparam param="r">1</rosparam>
          <param name="after" type="yaml" value="deg(90)"/>
        </launch>""")
    assert p["/before"] == "deg(90)" and p["/after"] == pytest.approx(1.5707963267948966)


# ---------------------------------------------------------------- remaps, env

def test_remap_order_inheritance_and_redefinition(ld):
    c = ld.load("""
        <launch>
          <remap from="chatter" to="top"/>
          <remap from="x" to="y"/>
          <group ns="g">
            <remap from="chatter" to="group"/>
            <node name="n" pkg="tpkg" type="talker"><remap from="own" to="o"/></node>
          </group>
          <node name="after" pkg="tpkg" type="talker"/>
        </launch>""")
    n, after = c.nodes
    assert n.remap_args == (("x", "y"), ("chatter", "group"), ("own", "o"))
    assert after.remap_args == (("chatter", "top"), ("x", "y"))


def test_env_scoping(ld):
    c = ld.load("""
        <launch>
          <env name="TOP" value="t"/>
          <group ns="g"><env name="G" value="g"/><node name="a" pkg="tpkg" type="talker"><env name="N" value=""/></node></group>
          <node name="b" pkg="tpkg" type="talker"/>
        </launch>""")
    a, b = c.nodes
    assert a.env_args == (("TOP", "t"), ("G", "g"), ("N", ""))
    assert b.env_args == (("TOP", "t"),)


# ---------------------------------------------------------------- if/unless

def test_if_unless(ld):
    p = ld.params("""
        <launch>
          <param name="a" value="1" if="true"/>
          <param name="b" value="1" if="0"/>
          <param name="c" value="1" unless="False"/>
          <param name="d" value="1" if=" 1 "/>
          <group if="false"><param name="e" value="1"/></group>
        </launch>""")
    assert p == {"/a": 1, "/c": 1, "/d": 1}
    e = ld.error('<launch>\n<param name="p" value="1" if="yes"/>\n</launch>')
    assert e.line == 2 and "yes" in e.message
    e = ld.error('<launch>\n<param name="p" value="1" if="1" unless="0"/>\n</launch>')
    assert "both" in e.message


# ---------------------------------------------------------------- nodes and tests

def test_node_attributes(ld):
    c = ld.load("""
        <launch>
          <node name="n" pkg="tpkg" type="talker" args="a 'b c'" respawn="true" respawn_delay="2.5"
                output="screen" cwd="ros_home" launch-prefix="gdb --args" machine="" ns="sub" clear_params="true"/>
        </launch>""")
    (n,) = c.nodes
    assert (n.full_name, n.args, n.respawn, n.respawn_delay, n.output, n.cwd, n.launch_prefix, n.machine_name) == (
        "/sub/n", "a 'b c'", True, 2.5, "screen", "ROS_HOME", "gdb --args", None)
    assert c.clear_params == ("/sub/n/",)


@pytest.mark.parametrize("attrs,match", [
    ('name="a/b"', "cannot contain a namespace"),
    ('name="n" output="file"', "output must be one of"),
    ('name="n" respawn="true" required="true"', "respawn and required"),
    ('name="n" respawn="maybe"', "invalid bool value for respawn"),
    ('name="n" respawn_delay="soon"', "respawn_delay"),
    ('name="n" cwd="elsewhere"', "cwd must be one of"),
    ('pkg_missing="1" name="n"', "missing required attribute: 'pkg'"),
])
def test_node_errors(ld, attrs, match):
    pkg = "" if "pkg_missing" in attrs else 'pkg="tpkg"'
    e = ld.error('<launch>\n<node %s type="talker" %s/>\n</launch>' % (pkg, attrs))
    assert match in e.message and e.line == 2


def test_duplicate_node_names_and_core_rosout(ld):
    e = ld.error("""
        <launch>
          <node name="d" pkg="tpkg" type="talker"/>
          <group ns="other"><node name="d" pkg="tpkg" type="talker"/></group>
          <node name="d" pkg="tpkg" type="listener"/>
        </launch>""")
    assert "multiple nodes named [/d]" in e.message and e.line == 4
    text = '<launch><node name="rosout" pkg="tpkg" type="talker"/></launch>'
    assert "multiple nodes named [/rosout]" in ld.error(text).message
    assert names(ld.load(text, core=False)) == ["/rosout"]


def test_tests(ld):
    c = ld.load("""
        <launch>
          <test test-name="t1" pkg="tpkg" type="talker" time-limit="12.5" retry="3"/>
          <test test-name="t2" name="named" pkg="tpkg" type="talker"/>
          <node name="n" pkg="tpkg" type="talker"/>
        </launch>""")
    assert names(c) == ["/n"]
    t1, t2 = c.tests
    assert (t1.full_name, t1.time_limit, t1.retry, t1.output, t1.test_name) == ("/t1", 12.5, 3, "log", "t1")
    assert (t2.full_name, t2.time_limit) == ("/named", 60.0)
    e = ld.error('<launch>\n<test test-name="t" pkg="tpkg" type="talker" respawn="true"/>\n</launch>')
    assert "cannot have 'respawn'" in e.message and e.line == 2


# ---------------------------------------------------------------- machines

def test_machines_and_default_machine(ld):
    c = ld.load("""
        <launch>
          <node name="before" pkg="tpkg" type="talker"/>
          <machine name="m" address="localhost" default="true" ssh-port="2222" timeout="5"/>
          <machine name="never" address="h" default="never"/>
          <node name="after" pkg="tpkg" type="talker"/>
          <node name="explicit" pkg="tpkg" type="talker" machine="never"/>
        </launch>""")
    assert [n.machine_name for n in c.nodes] == [None, "m", "never"]
    m = c.machines["m"]
    assert (m.address, m.ssh_port, m.timeout, m.assignable) == ("localhost", 2222, 5.0, True)
    assert c.machines["never"].assignable is False
    for attrs, match in (('default="sometimes"', "default"), ('ssh-port="x"', "ssh-port"),
                         ('timeout="-1"', "timeout"), ('timeout=""', "timeout")):
        e = ld.error('<launch>\n<machine name="m" address="a" %s/>\n</launch>' % attrs)
        assert match in e.message and e.line == 2


# ---------------------------------------------------------------- documents and warnings

def test_malformed_xml_has_the_line(ld):
    e = ld.error("<launch>\n  <group>\n  </grop>\n</launch>")
    assert e.line == 3 and "Invalid roslaunch XML syntax" in e.message
    e = ld.error("")
    assert "empty" in e.message


def test_launch_element_may_be_wrapped_but_only_once(ld):
    assert ld.params("<root><launch><param name='w' value='1'/></launch></root>") == {"/w": 1}
    e = ld.error("<launch>\n<group>\n<launch/>\n</group>\n</launch>")
    assert e.line == 3


def test_entities_and_dtd_are_not_expanded_from_outside(ld, tmp_path):
    secret = tmp_path / "secret.txt"
    secret.write_text("TOP SECRET")
    text = ('<?xml version="1.0"?>\n<!DOCTYPE launch [<!ENTITY x SYSTEM "file://%s">]>\n'
            '<launch><param name="p" value="a"/><rosparam param="r">&x;</rosparam></launch>' % secret)
    try:
        p = ld.params(text)
    except Exception as e:  # refusing is fine too, as long as the file is not read
        assert "TOP SECRET" not in str(e)
    else:
        assert "TOP SECRET" not in repr(p)


def test_unknown_tags_and_attributes_are_warned_with_file_and_line(ld):
    seen = []
    c = ld.load("""
        <launch>
          <bogus/>
          <param name="p" value="1" bogus_attr="x"/>
          <node name="n" pkg="tpkg" type="talker"><bogus_child/></node>
          <master auto="start"/>
          <include file="$(dirname)/other.launch"><remap from="a" to="b"/></include>
        </launch>""", warn=seen.append) if ld.write("other.launch", "<launch/>") else None
    main = str(ld.launch / "main.launch")
    expect = {2: "bogus", 3: "bogus_attr", 4: "bogus_child", 5: "master", 6: "remap"}
    for line, word in expect.items():
        assert any(w.startswith("%s:%d:" % (main, line)) and word in w for w in c.warnings), (line, c.warnings)
    assert seen == list(c.warnings)


def test_deprecated_launch_is_a_warning(ld):
    c = ld.load('<launch deprecated="use other.launch"/>')
    assert any("DEPRECATED: use other.launch" in w for w in c.warnings)


def test_args_only_mode_evaluates_only_args(ld):
    from launcher.xml import load_arg_docs
    f = ld.write("a.launch", """
        <launch>
          <arg name="req" doc="needed"/>
          <arg name="opt" default="$(optenv NOPE x)y"/>
          <arg name="const" value="c"/>
          <param name="broken" value="$(arg undefined)"/>
          <group><arg name="in_group" default="1"/></group>
        </launch>""")
    docs = load_arg_docs([f], environ=ld.environ)
    assert docs == {"req": ("needed", None), "opt": (None, "xy")}


def test_multiple_files_share_nodes_and_params_but_not_args(ld):
    a = ld.write("a.launch", '<launch><arg name="s" default="A"/><param name="a" value="$(arg s)"/>'
                             '<param name="common" value="a"/><node name="na" pkg="tpkg" type="talker"/></launch>')
    b = ld.write("b.launch", '<launch><arg name="s" default="B"/><param name="b" value="$(arg s)"/>'
                             '<param name="common" value="b"/><node name="nb" pkg="tpkg" type="talker"/></launch>')
    c = ld.load([a, b], core=False)
    assert {k: p.value for k, p in c.params.items()} == {"/a": "A", "/common": "b", "/b": "B"}
    assert names(c) == ["/na", "/nb"]
    assert "multiple nodes named [/na]" in ld.error([a, a]).message


def test_include_cycle_is_an_error_not_a_crash(ld):
    ld.write("a.launch", '<launch>\n<include file="$(dirname)/b.launch"/>\n</launch>')
    ld.write("b.launch", '<launch>\n\n<include file="$(dirname)/a.launch"/>\n</launch>')
    e = ld.error([str(ld.launch / "a.launch")])
    assert "cycle" in e.message and e.filename.endswith("b.launch") and e.line == 3
    # the same file included twice side by side is fine
    ld.write("leaf.launch", '<launch><param name="p" value="1"/></launch>')
    assert ld.params('<launch><include file="$(dirname)/leaf.launch"/><include file="$(dirname)/leaf.launch"/>'
                     '</launch>') == {"/p": 1}


def test_warnings_for_what_roslaunch_silently_ignores(ld):
    c = ld.load("""
        <launch>
          <param name="~used" value="1"/>
          <node name="a" pkg="tpkg" type="talker" machine="nowhere" respawn_delay="2"/>
          <param name="~unused" value="1"/>
          <rosparam param="~rp">{k: 1}</rosparam>
        </launch>""")
    main = str(ld.launch / "main.launch")
    w = "\n".join(c.warnings)
    assert "%s:4: private parameter [~unused] is not set for any node" % main in w
    assert "[~used]" not in w
    assert "nowhere" not in w  # (an unknown machine: the run's error, plan.Plan.check_nodes; --nodes as roslaunch's)
    assert "%s:3: respawn_delay has no effect" % main in w
    assert "%s:5: <rosparam param=\"~rp\"> sets its parameters under the literal name [~rp], which the master " \
           "resolves against roslaunch's own name, as for roslaunch: [/roslaunch/rp], not a node's" % main in w


def test_undeclared_command_line_arg_is_warned_unless_read(ld):
    text = '<launch><arg name="a" default="1"/><param name="u" value="$(arg used)"/></launch>'
    c = ld.load(text, ["a:=2", "typo:=3", "used:=4", "__ns:=/x"])
    w = [x for x in c.warnings if "command-line argument" in x]
    assert len(w) == 1 and "[typo:=3]" in w[0]


def test_undeclared_command_line_arg_counts_as_read_only_when_a_substitution_reads_it(ld):
    """What $(arg) and $(eval arg()) read while loading counts, not the text of the files: an arg
    named in a comment or in a skipped group is still ignored, and the warning says so."""
    inc = ld.write("inc.launch", '<launch><param name="i" value="$(arg viainclude)"/></launch>')
    text = """<launch>
      <!-- $(arg incomment) -->
      <group if="false"><param name="s" value="$(arg skipped)"/></group>
      <param name="e" value="$(eval arg('ev') + 1)"/>
      <include file="%s" pass_all_args="true"/>
    </launch>""" % inc
    c = ld.load(text, ["incomment:=1", "skipped:=2", "ev:=3", "viainclude:=4"])
    w = sorted(x for x in c.warnings if "command-line argument" in x)
    assert len(w) == 2 and "[incomment:=1]" in w[0] and "[skipped:=2]" in w[1]


def test_a_very_deep_parameter_name_takes_linear_time(ld):
    """A parameter name of 160,000 `ns/` segments took 11 s (every prefix sliced and looked up)."""
    import time
    deep = "ns/" * 160_000
    path = ld.write("deep.launch", '<launch><param name="p" value="0"/><param name="%sx" value="1"/>'
                                   '<param name="%sx/y" value="2"/></launch>' % (deep, deep))
    start = time.monotonic()
    config = ld.load([path])
    elapsed = time.monotonic() - start
    assert {k: p.value for k, p in config.params.items()} == {"/p": 0, "/" + deep + "x": 1, "/" + deep + "x/y": 2}
    # the parent check still sees the parent parameter, however deep (the warning shows its start and end)
    assert any("conflicts with parent parameter [%s]" % shorten("/%sx" % deep) in w for w in config.warnings)
    assert elapsed < 2.0, "took %.1f s" % elapsed
