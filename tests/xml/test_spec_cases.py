"""Table-driven spec of the launch XML loader, written from roslaunch's and rosmon's test ideas.

Each case is a small package tree (launch files, YAML, text files) with the parameters,
node names, node fields and clear_params roslaunch produces for it. The same table is
checked twice: against our loader (`launcher.xml.load`), and, when Debian's ROS is
installed, against roslaunch's own XmlLoader, so every expectation here is the
reference's behaviour and not our guess.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
from dataclasses import dataclass, field
from typing import Any

import pytest

from launcher.model.errors import LaunchError

MAIN = "launch/main.launch"
PKG = "spec_pkg"


@dataclass
class Case:
    id: str
    files: dict[str, str]                      # path in the package -> text; MAIN is loaded
    argv: list[str] = field(default_factory=list)
    env: dict[str, str] = field(default_factory=dict)
    params: dict[str, Any] | None = None       # the complete --dump-params dict
    nodes: list[str] | None = None             # full names, nodes then tests
    fields: dict[str, dict[str, Any]] = field(default_factory=dict)  # node name -> {attr: value}
    clear: list[str] | None = None             # clear_params, any order
    error: bool = False
    deviation: str | None = None               # why we knowingly differ from roslaunch here
    relation: str | None = None                # Python condition on p = {key: normalised value}
    commands: list[list[str | None]] | None = None  # <rosparam command=dump|delete>: [cmd, key, file]


def L(body: str) -> str:
    return '<launch>\n%s\n</launch>\n' % body


CASES = [
    # ---------------------------------------------------------------- params and typing
    Case("param_inference", {MAIN: L('''
  <param name="i" value="7"/>
  <param name="f" value="7.0"/>
  <param name="e" value="1e3"/>
  <param name="fe" value="2.5e2"/>
  <param name="u" value="1_000"/>
  <param name="h" value="0x10"/>
  <param name="b" value="TrUe"/>
  <param name="s" value="  padded  "/>
  <param name="n" value="nan"/>
  <param name="empty" value=""/>''')},
         params={"/i": 7, "/f": 7.0, "/e": "1e3", "/fe": 250.0, "/u": "1_000", "/h": "0x10", "/b": True,
                 "/s": "padded", "/n": "nan", "/empty": ""}),
    Case("param_types", {MAIN: L('''
  <param name="s" type="str" value="42"/>
  <param name="s2" type="string" value=" 4 2 "/>
  <param name="i" type="int" value=" -12 "/>
  <param name="d" type="double" value="3"/>
  <param name="dn" type="double" value="1e-3"/>
  <param name="b0" type="bool" value="0"/>
  <param name="b1" type="boolean" value="1"/>
  <param name="bt" type="BOOL" value=" TRUE "/>
  <param name="y" type="yaml" value="{a: [1, 2.0, x], b: {c: null}}"/>
  <param name="ys" type="yaml" value="0x10"/>''')},
         params={"/s": "42", "/s2": "4 2", "/i": -12, "/d": 3.0, "/dn": 0.001, "/b0": False, "/b1": True,
                 "/bt": True, "/y": {"a": [1, 2.0, "x"], "b": {"c": None}}, "/ys": 16}),
    Case("param_bad_int", {MAIN: L('<param name="x" type="int" value="1.5"/>')}, error=True),
    Case("param_bad_bool", {MAIN: L('<param name="x" type="bool" value="yes"/>')}, error=True),
    Case("param_bad_type", {MAIN: L('<param name="x" type="float" value="1.5"/>')}, error=True),
    Case("param_bad_yaml", {MAIN: L('<param name="x" type="yaml" value="{a: 1"/>')}, error=True),
    Case("param_no_value", {MAIN: L('<param name="x"/>')}, error=True),
    Case("param_two_sources", {MAIN: L('<param name="x" value="1" textfile="$(find spec_pkg)/t.txt"/>'),
                               "t.txt": "a"}, error=True),
    Case("param_no_name", {MAIN: L('<param value="1"/>')}, error=True),
    Case("param_textfile_not_stripped", {MAIN: L('''
  <param name="t" textfile="$(find spec_pkg)/data/t.txt"/>
  <param name="n" textfile="$(find spec_pkg)/data/n.txt"/>
  <param name="ts" type="str" textfile="$(find spec_pkg)/data/n.txt"/>'''),
                                          "data/t.txt": "  hello\nworld\n", "data/n.txt": "17\n"},
         params={"/t": "  hello\nworld\n", "/n": 17, "/ts": "17\n"}),
    Case("param_textfile_missing", {MAIN: L('<param name="t" textfile="$(find spec_pkg)/nope.txt"/>')},
         error=True),
    Case("param_command", {MAIN: L('''
  <param name="c" command="echo hello   world"/>
  <param name="q" command="printf '%s' 'a  b'"/>''')},
         params={"/c": "hello world\n", "/q": "a  b"}),
    Case("param_command_fails", {MAIN: L('<param name="c" command="false"/>')}, error=True),
    Case("param_override_last_wins_in_place", {MAIN: L('''
  <param name="a" value="1"/>
  <param name="b" value="2"/>
  <param name="a" value="3"/>''')},
         params={"/a": 3, "/b": 2}),
    Case("param_names_and_namespaces", {MAIN: L('''
  <param name="/abs/p" value="1"/>
  <param name="rel/p" value="2"/>
  <param name=" spaced " value="3"/>
  <group ns="g">
    <param name="p" value="4"/>
    <param name="/g2/p" value="5"/>
    <group ns="/top">
      <param name="p" value="6"/>
    </group>
  </group>''')},
         params={"/abs/p": 1, "/rel/p": 2, "/spaced": 3, "/g/p": 4, "/g2/p": 5, "/top/p": 6}),
    Case("param_parent_and_child_both_kept", {MAIN: L('''
  <param name="a" value="1"/>
  <param name="a/b" value="2"/>''')},
         params={"/a": 1, "/a/b": 2}),
    Case("param_entities_and_whitespace", {MAIN: L('''
  <param name="ent" value="&lt;x&gt; &amp; &quot;q&quot;"/>
  <param name="multi" value="line1
     line2"/>''')},
         params={"/ent": '<x> & "q"', "/multi": "line1      line2"}),

    # ---------------------------------------------------------------- private params
    Case("private_params_on_node", {MAIN: L('''
  <node pkg="p" type="t" name="n">
    <param name="a" value="1"/>
    <param name="~b" value="2"/>
    <param name="/c" value="3"/>
  </node>
  <group ns="ns">
    <node pkg="p" type="t" name="m"><param name="a" value="4"/></node>
  </group>''')},
         # roslaunch resolves even a global name inside <node> under the node's namespace
         params={"/n/a": 1, "/n/b": 2, "/n/c": 3, "/ns/m/a": 4}, nodes=["/n", "/ns/m"]),
    Case("launch_level_private_param_attaches_to_later_nodes", {MAIN: L('''
  <node pkg="p" type="t" name="before"/>
  <param name="~shared" value="1"/>
  <node pkg="p" type="t" name="after"/>
  <group ns="g">
    <param name="~inner" value="2"/>
    <node pkg="p" type="t" name="in_group"/>
  </group>
  <node pkg="p" type="t" name="last">
    <param name="shared" value="own"/>
  </node>''')},
         params={"/after/shared": 1, "/g/in_group/shared": 1, "/g/in_group/inner": 2, "/last/shared": "own"},
         nodes=["/before", "/after", "/g/in_group", "/last"]),

    # ---------------------------------------------------------------- rosparam
    Case("rosparam_inline_and_file", {MAIN: L('''
  <rosparam>
    a: 1
    b: {c: two, d: [1, 2]}
  </rosparam>
  <rosparam command="load" file="$(find spec_pkg)/config/p.yaml" ns="fromfile"/>
  <rosparam param="scalar">3.5</rosparam>
  <rosparam param="list">[1, 2, 3]</rosparam>
  <group ns="g"><rosparam>x: y</rosparam></group>'''),
                                      "config/p.yaml": "k: v\nnested:\n  deep: true\n"},
         params={"/a": 1, "/b/c": "two", "/b/d": [1, 2], "/fromfile/k": "v", "/fromfile/nested/deep": True,
                 "/scalar": 3.5, "/list": [1, 2, 3], "/g/x": "y"}),
    Case("rosparam_leading_slash_keys", {MAIN: L('''
  <group ns="g">
    <rosparam>
      /abs: 1
      rel: 2
    </rosparam>
  </group>''')},
         params={"/abs": 1, "/g/rel": 2}),
    Case("rosparam_in_node_is_private", {MAIN: L('''
  <node pkg="p" type="t" name="n">
    <rosparam>a: 1</rosparam>
    <rosparam ns="sub">b: 2</rosparam>
    <rosparam param="c">3</rosparam>
  </node>''')},
         params={"/n/a": 1, "/n/sub/b": 2, "/n/c": 3}, nodes=["/n"]),
    Case("rosparam_private_param_outside_node_is_literal", {MAIN: L('<rosparam param="~x">1</rosparam>')},
         params={"~x": 1}),
    Case("rosparam_subst_value", {MAIN: L('''
  <arg name="speed" default="3"/>
  <rosparam subst_value="true">
    speed: $(arg speed)
    where: $(find spec_pkg)
  </rosparam>
  <rosparam>
    raw: $(arg speed)
  </rosparam>''')},
         # $(find) takes the text up to the next space as a path: here "\n", giving a trailing slash
         params={"/speed": 3, "/where": "@PKG@/", "/raw": "$(arg speed)"}),
    Case("rosparam_angles", {MAIN: L('''
  <rosparam>
    d: deg(180)
    r: rad(pi/2)
    td: !degrees 90
    tr: !radians pi
    q: 'deg(180)'
  </rosparam>''')},
         params={"/d": math.pi, "/r": math.pi / 2, "/td": math.pi / 2, "/tr": math.pi, "/q": "deg(180)"}),
    Case("rosparam_merge_keys", {MAIN: L('''
  <rosparam>
    base: &amp;b {x: 1, y: 2}
    derived:
      &lt;&lt;: *b
      y: 3
  </rosparam>''')},
         params={"/base/x": 1, "/base/y": 2, "/derived/x": 1, "/derived/y": 3}),
    Case("rosparam_empty", {MAIN: L('<rosparam></rosparam><rosparam ns="e"/>')}, params={}),
    Case("rosparam_dict_merges_with_existing", {MAIN: L('''
  <param name="d/a" value="1"/>
  <rosparam param="d">{b: 2}</rosparam>''')},
         params={"/d/a": 1, "/d/b": 2}),
    Case("rosparam_scalar_needs_param", {MAIN: L('<rosparam>42</rosparam>')}, error=True),
    Case("rosparam_bad_yaml", {MAIN: L('<rosparam>a: [1, 2</rosparam>')}, error=True),
    Case("rosparam_missing_file", {MAIN: L('<rosparam command="load" file="$(find spec_pkg)/none.yaml"/>')},
         error=True),
    Case("rosparam_delete_with_file", {MAIN: L('<rosparam command="delete" file="x.yaml" param="a"/>')},
         error=True),
    Case("rosparam_bad_command", {MAIN: L('<rosparam command="frobnicate">a: 1</rosparam>')}, error=True),
    Case("rosparam_dump_and_delete_set_nothing", {MAIN: L('''
  <param name="keep" value="1"/>
  <rosparam command="delete" param="keep"/>
  <rosparam command="dump" file="/tmp/spec_never_written.yaml"/>''')},
         params={"/keep": 1},
         commands=[["delete", "/keep", None], ["dump", "/", "/tmp/spec_never_written.yaml"]]),
    Case("rosparam_dump_delete_scoping", {MAIN: L('''
  <group ns="ns1">
    <node pkg="p" type="t" name="n">
      <rosparam command="delete" param="ns2/param"/>
      <rosparam command="dump" file="dump.yaml"/>
      <rosparam command="delete" param="/abs"/>
      <rosparam command="delete" param="~priv"/>
    </node>
    <rosparam command="dump" file="g.yaml" param="sub"/>
    <rosparam command="delete" param="gone" if="false"/>
  </group>''')},
         nodes=["/ns1/n"],
         commands=[["delete", "/ns1/n/ns2/param", None], ["dump", "/ns1/n/", "dump.yaml"],
                   ["delete", "/abs", None],
                   # ns_join keeps a private name as it is, so the key stays "~priv"
                   ["delete", "~priv", None], ["dump", "/ns1/sub", "g.yaml"]]),

    # ---------------------------------------------------------------- args
    Case("arg_default_and_value", {MAIN: L('''
  <arg name="a" default="1"/>
  <arg name="b" value="two"/>
  <arg name="c" default="$(arg a)-$(arg b)"/>
  <param name="a" value="$(arg a)"/>
  <param name="b" value="$(arg b)"/>
  <param name="c" value="$(arg c)"/>''')},
         params={"/a": 1, "/b": "two", "/c": "1-two"}),
    Case("arg_from_command_line", {MAIN: L('''
  <arg name="a" default="1"/>
  <arg name="req"/>
  <param name="a" value="$(arg a)"/>
  <param name="req" value="$(arg req)"/>''')},
         argv=["a:=5", "req:= padded ", "undeclared:=x"],
         params={"/a": 5, "/req": "padded"}),
    Case("arg_required_missing", {MAIN: L('<arg name="req"/><param name="x" value="$(arg req)"/>')}, error=True),
    Case("arg_undefined", {MAIN: L('<param name="x" value="$(arg nope)"/>')}, error=True),
    Case("arg_value_cannot_be_overridden", {MAIN: L('<arg name="a" value="1"/>')}, argv=["a:=2"], error=True),
    Case("arg_value_and_default", {MAIN: L('<arg name="a" value="1" default="2"/>')}, error=True),
    Case("arg_redeclared", {MAIN: L('<arg name="a" default="1"/><arg name="a" default="2"/>')}, error=True),
    Case("arg_empty_cli_value_ignored", {MAIN: L('<arg name="a" default="d"/><param name="a" value="$(arg a)"/>')},
         argv=["a:="], params={"/a": "d"}),
    Case("arg_group_scoping", {MAIN: L('''
  <arg name="top" default="t"/>
  <group ns="g">
    <arg name="inner" default="i"/>
    <param name="both" value="$(arg top)$(arg inner)"/>
  </group>
  <group>
    <arg name="inner" default="other"/>
    <param name="again" value="$(arg inner)"/>
  </group>''')},
         params={"/g/both": "ti", "/again": "other"}),
    Case("arg_out_of_group_scope", {MAIN: L('''
  <group><arg name="inner" default="i"/></group>
  <param name="x" value="$(arg inner)"/>''')}, error=True),

    # ---------------------------------------------------------------- include
    Case("include_args_and_ns", {
        MAIN: L('''
  <arg name="speed" default="9"/>
  <include file="$(find spec_pkg)/launch/inc.launch" ns="robot">
    <arg name="speed" value="$(arg speed)"/>
    <arg name="name" value="drv"/>
  </include>'''),
        "launch/inc.launch": L('''
  <arg name="speed"/>
  <arg name="name"/>
  <arg name="unset_default" default="dflt"/>
  <param name="speed" value="$(arg speed)"/>
  <param name="default" value="$(arg unset_default)"/>
  <node pkg="p" type="t" name="$(arg name)"/>''')},
         params={"/robot/speed": 9, "/robot/default": "dflt"}, nodes=["/robot/drv"]),
    Case("include_does_not_see_parent_args", {
        MAIN: L('<arg name="a" default="1"/><include file="$(dirname)/inc.launch"/>'),
        "launch/inc.launch": L('<param name="a" value="$(arg a)"/>')}, error=True),
    Case("include_pass_all_args", {
        MAIN: L('''
  <arg name="a" default="1"/>
  <arg name="b" default="2"/>
  <include file="$(dirname)/inc.launch" pass_all_args="true">
    <arg name="b" value="override"/>
  </include>'''),
        "launch/inc.launch": L('''
  <arg name="a"/>
  <arg name="b"/>
  <param name="a" value="$(arg a)"/>
  <param name="b" value="$(arg b)"/>''')},
         params={"/a": 1, "/b": "override"}),
    Case("include_unused_arg", {
        MAIN: L('<include file="$(dirname)/inc.launch"><arg name="nobody" value="1"/></include>'),
        "launch/inc.launch": L('<param name="x" value="1"/>')}, error=True),
    Case("include_missing_required_arg", {
        MAIN: L('<include file="$(dirname)/inc.launch"/>'),
        "launch/inc.launch": L('<arg name="need"/><param name="x" value="$(arg need)"/>')}, error=True),
    Case("include_missing_file", {MAIN: L('<include file="$(dirname)/nothere.launch"/>')}, error=True),
    Case("include_clear_params", {
        MAIN: L('<include file="$(dirname)/inc.launch" ns="inc" clear_params="true"/>'),
        "launch/inc.launch": L('<param name="x" value="1"/>')},
         params={"/inc/x": 1}, clear=["/inc/"]),
    Case("include_if_unless", {
        MAIN: L('''
  <include file="$(dirname)/inc.launch" if="false"/>
  <include file="$(dirname)/inc.launch" unless="false" ns="yes"/>'''),
        "launch/inc.launch": L('<param name="x" value="1"/>')},
         params={"/yes/x": 1}),
    Case("include_arg_default_in_include_tag", {
        MAIN: L('''
  <include file="$(dirname)/inc.launch">
    <arg name="a" default="from_parent"/>
  </include>'''),
        "launch/inc.launch": L('<arg name="a" default="own"/><param name="a" value="$(arg a)"/>')},
         params={"/a": "from_parent"}),
    Case("include_remaps_and_env_inherit", {
        MAIN: L('''
  <remap from="a" to="b"/>
  <env name="SPEC_E" value="1"/>
  <include file="$(dirname)/inc.launch"/>'''),
        "launch/inc.launch": L('<node pkg="p" type="t" name="n"/>')},
         nodes=["/n"], fields={"/n": {"remap_args": [["a", "b"]], "env_args": [["SPEC_E", "1"]]}}),

    # ---------------------------------------------------------------- if / unless
    Case("if_unless_values", {MAIN: L('''
  <param name="if_true" value="1" if="true"/>
  <param name="if_1" value="1" if="1"/>
  <param name="if_false" value="1" if="false"/>
  <param name="if_0" value="1" if="0"/>
  <param name="if_TRUE" value="1" if=" TRUE "/>
  <param name="unless_false" value="1" unless="false"/>
  <param name="unless_true" value="1" unless="true"/>
  <group if="false"><param name="in_false_group" value="1"/></group>''')},
         params={"/if_true": 1, "/if_1": 1, "/if_TRUE": 1, "/unless_false": 1}),
    Case("if_bad_value", {MAIN: L('<param name="x" value="1" if="yes"/>')}, error=True),
    Case("if_and_unless_together", {MAIN: L('<param name="x" value="1" if="true" unless="false"/>')}, error=True),
    Case("if_skips_evaluation_of_other_attributes", {MAIN: L('''
  <param name="x" value="$(arg undefined_arg)" if="false"/>
  <node pkg="p" type="t" name="$(arg nope)" if="false"/>''')},
         params={}),
    Case("if_with_arg_and_eval", {MAIN: L('''
  <arg name="sim" default="true"/>
  <arg name="n" default="3"/>
  <param name="sim_only" value="1" if="$(arg sim)"/>
  <param name="real_only" value="1" unless="$(arg sim)"/>
  <param name="big" value="1" if="$(eval arg('n') > 2)"/>
  <param name="small" value="1" if="$(eval n &lt; 2)"/>''')},
         params={"/sim_only": 1, "/big": 1}),

    # ---------------------------------------------------------------- substitutions
    Case("subst_env_optenv", {MAIN: L('''
  <param name="env" value="$(env SPEC_SET)"/>
  <param name="optenv_set" value="$(optenv SPEC_SET fallback)"/>
  <param name="optenv_unset" value="$(optenv SPEC_UNSET fall  back   words)"/>
  <param name="optenv_empty" value="[$(optenv SPEC_UNSET)]"/>
  <param name="concat" value="a$(env SPEC_SET)b$(env SPEC_SET)"/>''')},
         env={"SPEC_SET": "val"},
         params={"/env": "val", "/optenv_set": "val", "/optenv_unset": "fall back words", "/optenv_empty": "[]",
                 "/concat": "avalbval"}),
    Case("subst_env_missing", {MAIN: L('<param name="x" value="$(env SPEC_NOT_SET_ANYWHERE)"/>')}, error=True),
    Case("subst_find_and_dirname", {MAIN: L('''
  <param name="pkg" value="$(find spec_pkg)"/>
  <param name="file" value="$(find spec_pkg)/config/x.yaml"/>
  <param name="dir" value="$(dirname)"/>
  <param name="dir_rel" value="$(dirname)/../config"/>''')},
         params={"/pkg": "@PKG@", "/file": "@PKG@/config/x.yaml", "/dir": "@PKG@/launch",
                 "/dir_rel": "@PKG@/launch/../config"}),
    Case("subst_find_missing_package", {MAIN: L('<param name="x" value="$(find spec_no_such_pkg)"/>')}, error=True),
    Case("subst_unknown_command", {MAIN: L('<param name="x" value="$(frobnicate y)"/>')}, error=True),
    Case("subst_not_a_substitution", {MAIN: L('''
  <param name="dollar" value="cost: $5"/>
  <param name="parens" value="(x)"/>
  <param name="dollar_paren_space" value="$ (arg x)"/>''')},
         params={"/dollar": "cost: $5", "/parens": "(x)", "/dollar_paren_space": "$ (arg x)"}),
    Case("subst_anon_is_consistent", {MAIN: L('''
  <param name="a1" value="$(anon x)"/>
  <param name="a2" value="$(anon x)"/>
  <param name="same" value="$(eval anon('x') == '$(anon x)')"/>''')},
         params=None),
    Case("subst_eval", {MAIN: L('''
  <arg name="x" default="2"/>
  <arg name="s" default="abc"/>
  <arg name="flag" default="true"/>
  <param name="arith" value="$(eval x * 3 + 1)"/>
  <param name="math" value="$(eval round(sin(pi / 2)))"/>
  <param name="str" value="$(eval s + '_' + str(x))"/>
  <param name="bool" value="$(eval flag and x == 2)"/>
  <param name="list" value="$(eval [1, 2][1])"/>
  <param name="fn_arg" value="$(eval arg('x') ** 2)"/>
  <param name="env" value="$(eval optenv('SPEC_UNSET', 'dflt'))"/>
  <param name="float" value="$(eval 1 / 4)"/>''')},
         params={"/arith": 7, "/math": 1, "/str": "abc_2", "/bool": True, "/list": 2, "/fn_arg": 4,
                 "/env": "dflt", "/float": 0.25}),
    Case("subst_eval_dunder_refused", {MAIN: L('<param name="x" value="$(eval ().__class__)"/>')}, error=True),
    Case("subst_eval_import_refused", {MAIN: L('<param name="x" value="$(eval __import__(\'os\'))"/>')},
         error=True),
    Case("subst_eval_open_refused", {MAIN: L('<param name="x" value="$(eval open(\'/etc/passwd\').read())"/>')},
         error=True, deviation="roslaunch's eval leaks all builtins (open, __import__ via getattr...); "
                               "the issue requires no file system access from $(eval)"),
    Case("subst_eval_not_whole_attribute", {MAIN: L('<param name="x" value="a $(eval 1 + 1)"/>')}, error=True),

    # ---------------------------------------------------------------- nodes
    Case("node_attributes", {MAIN: L('''
  <node pkg="p" type="t" name="full" args="--a  'b c'  d" respawn="true" respawn_delay="2.5"
        output="screen" cwd="node" launch-prefix="nice -n 5" ns="sub"/>
  <node pkg="p" type="t" name="req" required="true" cwd="ROS_HOME" output="log"/>
  <node pkg="p" type="t" name="plain"/>''')},
         nodes=["/sub/full", "/req", "/plain"],
         fields={"/sub/full": {"package": "p", "type": "t", "args": "--a  'b c'  d", "respawn": True,
                               "respawn_delay": 2.5, "output": "screen", "cwd": "node",
                               "launch_prefix": "nice -n 5", "namespace": "/sub/", "required": False},
                 "/req": {"required": True, "respawn": False, "cwd": "ROS_HOME", "output": "log",
                          "launch_prefix": None, "namespace": "/"},
                 "/plain": {"args": "", "output": None, "cwd": None, "respawn_delay": 0.0}}),
    Case("node_ns_forms", {MAIN: L('''
  <group ns="a">
    <node pkg="p" type="t" name="rel" ns="b"/>
    <node pkg="p" type="t" name="abs" ns="/c"/>
    <group ns="/d"><node pkg="p" type="t" name="in_abs_group"/></group>
    <group ns="e/"><node pkg="p" type="t" name="trailing"/></group>
  </group>''')},
         nodes=["/a/b/rel", "/c/abs", "/d/in_abs_group", "/a/e/trailing"]),
    Case("node_ros_namespace_env", {MAIN: L('<node pkg="p" type="t" name="n"/><param name="p" value="1"/>')},
         env={"ROS_NAMESPACE": "/envns"}, nodes=["/envns/n"], params={"/envns/p": 1}),
    Case("node_cli_ns", {MAIN: L('<node pkg="p" type="t" name="n"/><param name="p" value="1"/>')},
         argv=["__ns:=/clins"], nodes=["/clins/n"], params={"/clins/p": 1}),
    Case("node_name_with_slash", {MAIN: L('<node pkg="p" type="t" name="a/b"/>')}, error=True),
    Case("node_missing_type", {MAIN: L('<node pkg="p" name="n"/>')}, error=True),
    Case("node_bad_output", {MAIN: L('<node pkg="p" type="t" name="n" output="file"/>')}, error=True),
    Case("node_bad_cwd", {MAIN: L('<node pkg="p" type="t" name="n" cwd="home"/>')}, error=True),
    Case("node_respawn_and_required", {MAIN: L('<node pkg="p" type="t" name="n" respawn="true" required="true"/>')},
         error=True),
    Case("node_bad_respawn_delay", {MAIN: L('<node pkg="p" type="t" name="n" respawn_delay="soon"/>')},
         error=True),
    Case("node_duplicate_names", {MAIN: L('<node pkg="p" type="t" name="n"/><node pkg="p" type="t2" name="n"/>')},
         error=True),
    Case("node_same_name_other_ns", {MAIN: L('''
  <node pkg="p" type="t" name="n"/>
  <group ns="x"><node pkg="p" type="t" name="n"/></group>''')},
         nodes=["/n", "/x/n"]),
    Case("node_remaps", {MAIN: L('''
  <remap from="top" to="t1"/>
  <group>
    <remap from="g" to="g1"/>
    <remap from="top" to="t2"/>
    <node pkg="p" type="t" name="n">
      <remap from="own" to="o1"/>
      <remap from="g" to="g2"/>
    </node>
  </group>
  <node pkg="p" type="t" name="outside"/>''')},
         nodes=["/n", "/outside"],
         fields={"/n": {"remap_args": [["top", "t2"], ["own", "o1"], ["g", "g2"]]},
                 "/outside": {"remap_args": [["top", "t1"]]}}),
    Case("node_remap_needs_both", {MAIN: L('<remap from="a"/>')}, error=True),
    Case("node_env", {MAIN: L('''
  <env name="SPEC_TOP" value="top"/>
  <group>
    <env name="SPEC_G" value="g"/>
    <node pkg="p" type="t" name="n">
      <env name="SPEC_OWN" value="$(env SPEC_SET)"/>
      <env name="SPEC_TOP" value="again"/>
    </node>
  </group>
  <node pkg="p" type="t" name="outside"/>''')},
         env={"SPEC_SET": "v"}, nodes=["/n", "/outside"],
         fields={"/n": {"env_args": [["SPEC_TOP", "top"], ["SPEC_G", "g"], ["SPEC_OWN", "v"],
                                     ["SPEC_TOP", "again"]]},
                 "/outside": {"env_args": [["SPEC_TOP", "top"]]}}),
    Case("node_clear_params", {MAIN: L('''
  <node pkg="p" type="t" name="n" clear_params="true"/>
  <group ns="g" clear_params="true"><node pkg="p" type="t" name="m" ns="sub" clear_params="true"/></group>''')},
         nodes=["/n", "/g/sub/m"], clear=["/n/", "/g/", "/g/sub/m/"]),
    Case("node_clear_params_needs_name", {MAIN: L('<group clear_params="true"/>')}, error=True),
    Case("node_args_substitution", {MAIN: L('''
  <arg name="rate" default="10"/>
  <node pkg="p" type="t" name="n" args="--rate $(arg rate) --dir $(find spec_pkg)"/>''')},
         nodes=["/n"], fields={"/n": {"args": "--rate 10 --dir @PKG@"}}),
    Case("node_machine", {MAIN: L('''
  <machine name="local" address="localhost" env-loader="/opt/env.sh" default="true"/>
  <node pkg="p" type="t" name="n"/>
  <node pkg="p" type="t" name="m" machine="local"/>''')},
         nodes=["/n", "/m"], fields={"/m": {"machine_name": "local"}}),
    # machines are only assigned when running: introspection accepts an unknown one
    Case("node_unknown_machine", {MAIN: L('<node pkg="p" type="t" name="n" machine="nowhere"/>')},
         nodes=["/n"], fields={"/n": {"machine_name": "nowhere"}}),

    # ---------------------------------------------------------------- tests
    Case("test_tags", {MAIN: L('''
  <test test-name="t1" pkg="p" type="t"/>
  <node pkg="p" type="t" name="n"/>
  <test test-name="t2" name="named" pkg="p" type="t" time-limit="12.5" retry="3" args="-v"/>''')},
         nodes=["/n", "/t1", "/named"],
         fields={"/t1": {"test_name": "t1", "time_limit": 60.0, "retry": 0},
                 "/named": {"test_name": "t2", "time_limit": 12.5, "retry": 3, "args": "-v"}}),
    Case("test_bad_time_limit", {MAIN: L('<test test-name="t" pkg="p" type="t" time-limit="-1"/>')}, error=True),
    Case("test_missing_test_name", {MAIN: L('<test pkg="p" type="t"/>')}, error=True),

    # ---------------------------------------------------------------- more scoping and quirks
    Case("remap_redefined_moves_to_end", {MAIN: L("""
  <remap from="a" to="a1"/>
  <remap from="b" to="b2"/>
  <node pkg="p" type="t" name="n">
    <remap from="a" to="a3"/>
  </node>
  <group>
    <remap from="a" to="a4"/>
    <node pkg="p" type="t" name="m"/>
  </group>""")},
         nodes=["/n", "/m"],
         fields={"/n": {"remap_args": [["b", "b2"], ["a", "a3"]]}, "/m": {"remap_args": [["b", "b2"], ["a", "a4"]]}}),
    Case("remap_to_invalid_name", {MAIN: L('<remap from="a" to="1"/>')}, error=True),
    Case("node_bool_and_enum_spellings", {MAIN: L("""
  <node pkg="p" type="t" name="a" respawn="True" cwd="ros_home"/>
  <node pkg="p" type="t" name="b" required="TRUE" respawn="false"/>""")},
         nodes=["/a", "/b"],
         fields={"/a": {"respawn": True, "cwd": "ROS_HOME"}, "/b": {"required": True, "respawn": False}}),
    # unlike if=/unless= and type="bool", node flags take only true/false
    Case("node_bool_1_is_invalid", {MAIN: L('<node pkg="p" type="t" name="b" required="1"/>')}, error=True),
    Case("node_output_case", {MAIN: L('<node pkg="p" type="t" name="a" output="SCREEN"/>')}, error=True),
    Case("node_empty_ns", {MAIN: L('<group ns="g"><node pkg="p" type="t" name="a" ns=""/></group>')},
         error=True),
    Case("node_if_false_drops_its_params", {MAIN: L("""
  <node pkg="p" type="t" name="off" if="false"><param name="x" value="1"/></node>
  <node pkg="p" type="t" name="on"><param name="x" value="1" unless="true"/><param name="y" value="2"/></node>""")},
         nodes=["/on"], params={"/on/y": 2}),
    Case("node_launch_prefix_and_args_from_args", {MAIN: L("""
  <arg name="debug" default="gdb -ex run --args"/>
  <node pkg="p" type="t" name="n" launch-prefix="$(arg debug)" args="$(optenv SPEC_UNSET a  b)"/>""")},
         nodes=["/n"], fields={"/n": {"launch_prefix": "gdb -ex run --args", "args": "a b"}}),
    Case("anon_node_names_are_generated", {MAIN: L('<node pkg="p" type="t" name="$(anon talker)"/>')},
         nodes=None),
    Case("cli_private_and_unknown_args_ignored", {MAIN: L("""
  <arg name="a" default="x"/>
  <param name="a" value="$(arg a)"/>""")},
         argv=["_a:=private", "b:=undeclared", "a:=  cli  "], params={"/a": "cli"}),
    Case("cli_ns_with_group_and_global", {MAIN: L("""
  <group ns="g"><node pkg="p" type="t" name="n"/></group>
  <group ns="/abs"><node pkg="p" type="t" name="m"/></group>
  <param name="/glob" value="1"/>""")},
         argv=["__ns:=/top"], nodes=["/top/g/n", "/abs/m"], params={"/glob": 1}),
    Case("ros_namespace_relative", {MAIN: L('<node pkg="p" type="t" name="n"/>')},
         env={"ROS_NAMESPACE": "rel"}, nodes=["/rel/n"]),
    Case("arg_doc_and_default_resolved_lazily", {MAIN: L("""
  <arg name="a" default="1" doc="the a"/>
  <arg name="b" default="$(arg a)0"/>
  <param name="b" value="$(arg b)"/>""")},
         argv=["a:=7"], params={"/b": 70}),
    Case("arg_default_uses_later_arg", {MAIN: L("""
  <arg name="b" default="$(arg a)"/>
  <arg name="a" default="1"/>""")}, error=True),
    Case("eval_args_are_typed_like_params", {MAIN: L("""
  <arg name="i" default="3"/>
  <arg name="f" default="0.5"/>
  <arg name="b" default="true"/>
  <arg name="s" default="1_0"/>
  <param name="sum" value="$(eval i + f)"/>
  <param name="neg" value="$(eval not b)"/>
  <param name="s" value="$(eval s + 'x')"/>""")},
         params={"/sum": 3.5, "/neg": False, "/s": "1_0x"}),
    Case("eval_undefined_name", {MAIN: L('<param name="x" value="$(eval nope + 1)"/>')}, error=True),
    Case("include_dirname_is_included_files_dir", {
        MAIN: L('<include file="$(dirname)/sub/inc.launch"/>'),
        "launch/sub/inc.launch": L('<param name="d" value="$(dirname)"/>')},
         params={"/d": "@PKG@/launch/sub"}),
    Case("include_env_child_and_nested_ns", {
        MAIN: L("""
  <group ns="outer">
    <include file="$(dirname)/inc.launch" ns="inner">
      <env name="SPEC_INC" value="yes"/>
    </include>
  </group>
  <node pkg="p" type="t" name="after"/>"""),
        "launch/inc.launch": L('<node pkg="p" type="t" name="n"/><param name="p" value="1"/>')},
         nodes=["/outer/inner/n", "/after"], params={"/outer/inner/p": 1},
         fields={"/outer/inner/n": {"env_args": [["SPEC_INC", "yes"]]}, "/after": {"env_args": []}}),
    Case("include_clear_params_needs_ns", {
        MAIN: L('<include file="$(dirname)/inc.launch" clear_params="true"/>'),
        "launch/inc.launch": "<launch/>"}, error=True),
    Case("include_pass_all_args_with_unused", {
        MAIN: L("""
  <arg name="a" default="1"/>
  <arg name="extra" default="2"/>
  <include file="$(dirname)/inc.launch" pass_all_args="true"/>"""),
        "launch/inc.launch": L('<arg name="a"/><param name="a" value="$(arg a)"/>')},
         params={"/a": 1}),
    Case("include_args_evaluated_in_parent", {
        MAIN: L("""
  <arg name="x" default="parent"/>
  <include file="$(dirname)/inc.launch"><arg name="y" value="$(arg x)-$(dirname)"/></include>"""),
        "launch/inc.launch": L('<arg name="y"/><param name="y" value="$(arg y)"/>')},
         params={"/y": "parent-@PKG@/launch"}),
    Case("include_same_file_twice", {
        MAIN: L("""
  <include file="$(dirname)/inc.launch" ns="one"/>
  <include file="$(dirname)/inc.launch" ns="two"/>"""),
        "launch/inc.launch": L('<node pkg="p" type="t" name="n"/>')},
         nodes=["/one/n", "/two/n"]),
    Case("include_of_non_launch_root", {
        MAIN: L('<include file="$(dirname)/inc.xml"/>'),
        "launch/inc.xml": '<launch><param name="x" value="1"/></launch>'},
         params={"/x": 1}),
    Case("rosparam_load_into_node_ns_and_param", {
        MAIN: L("""
  <node pkg="p" type="t" name="n">
    <rosparam command="load" file="$(find spec_pkg)/c.yaml" ns="sub"/>
    <rosparam command="load" file="$(find spec_pkg)/c.yaml" param="as_param"/>
  </node>
  <group ns="g">
    <rosparam command="load" file="$(find spec_pkg)/c.yaml" param="/abs"/>
  </group>"""),
        "c.yaml": "k: 1\n"},
         nodes=["/n"], params={"/n/sub/k": 1, "/n/as_param/k": 1, "/abs/k": 1}),
    Case("rosparam_multi_document_file", {
        MAIN: L('<rosparam command="load" file="$(find spec_pkg)/c.yaml"/>'),
        "c.yaml": "a: 1\n---\nb: 2\n"}, error=True),
    Case("rosparam_subst_value_in_file", {
        MAIN: L("""
  <arg name="v" default="5"/>
  <rosparam command="load" file="$(find spec_pkg)/c.yaml" subst_value="true"/>"""),
        "c.yaml": "v: $(arg v)\n"},
         params={"/v": 5}),
    Case("rosparam_list_and_nested_values_types", {MAIN: L("""
  <rosparam>
    ints: [1, -2, 0x1F, 0o7]
    floats: [1.0, .5, 1e3, -.inf]
    strs: ['1', "two", 1_000x]
    bools: [yes, No, on, OFF, true]
    nothing: ~
  </rosparam>""")},
         params={"/ints": [1, -2, 31, "0o7"], "/floats": [1.0, 0.5, "1e3", -math.inf],
                 "/strs": ["1", "two", "1_000x"], "/bools": [True, False, True, False, True], "/nothing": None}),
    Case("param_in_group_with_private_ns", {MAIN: L("""
  <group ns="g">
    <param name="~p" value="1"/>
    <node pkg="p" type="t" name="n"/>
  </group>
  <node pkg="p" type="t" name="outside"/>""")},
         nodes=["/g/n", "/outside"], params={"/g/n/p": 1}),
    Case("param_yaml_type_dict_unrolled", {MAIN: L("""
  <param name="d" type="yaml" value="{a: 1, b: {c: 2}}"/>
  <param name="l" type="yaml" value="[{a: 1}]"/>""")},
         # unlike <rosparam>, a yaml-typed <param> keeps its dict as one value
         params={"/d": {"a": 1, "b": {"c": 2}}, "/l": [{"a": 1}]}),
    Case("deprecated_launch_attribute", {MAIN: '<launch deprecated="use other.launch"><param name="x" value="1"/></launch>'},
         params={"/x": 1}),
    Case("machine_attributes", {MAIN: L("""
  <machine name="m1" address="127.0.0.1" user="me" ssh-port="2222" timeout="5.5" default="never"/>
  <node pkg="p" type="t" name="n"/>""")},
         nodes=["/n"], fields={"/n": {"machine_name": None}}),
    Case("machine_bad_ssh_port", {MAIN: L('<machine name="m1" address="h" ssh-port="x"/>')}, error=True),
    Case("machine_missing_address", {MAIN: L('<machine name="m1"/>')}, error=True),
    # ---------------------------------------------------------------- ideas from rosmon's tests
    Case("anon_same_id_same_name_other_id_differs", {MAIN: L("""
  <param name="t1" value="$(anon rviz-1)"/>
  <param name="t2" value="$(anon rviz-1)"/>
  <param name="t3" value="$(anon rviz-2)"/>""")},
         relation="p['/t1'] == p['/t2'] != p['/t3'] and p['/t1'][1].startswith('rviz_1_')"),
    Case("anon_node_name_clash", {MAIN: L("""
  <node name="$(anon foo)" pkg="p" type="t"/>
  <node name="$(anon foo)" pkg="p" type="t"/>""")}, error=True),
    Case("eval_functions", {MAIN: L("""
  <arg name="foo" default="test"/>
  <arg name="radius" default="2.0"/>
  <arg name="input" default="false"/>
  <param name="circ" value="$(eval 2.* pi * arg('radius'))"/>
  <param name="cat" value="$(eval arg('foo') + env('SPEC_SET') + 'bar' + find('spec_pkg'))"/>
  <param name="cat2" value="$(eval foo + optenv('SPEC_NOPE', 'x'))"/>
  <param name="lower_bool" value="$(eval input == true)"/>
  <param name="int" value="$(eval 2 * 20)"/>""")},
         env={"SPEC_SET": "E"},
         params={"/circ": 2.0 * math.pi * 2.0, "/cat": "testEbar@PKG@", "/cat2": "testx", "/lower_bool": False,
                 "/int": 40}),
    Case("eval_syntax_error", {MAIN: L('<param name="x" value="$(eval )))"/>')}, error=True),
    Case("param_yaml_scalar_and_command_types", {MAIN: L("""
  <param name="ys" type="yaml" value="true"/>
  <param name="yd" type="yaml" value="test_param: true"/>
  <param name="yc" type="yaml" command="echo test_param: true"/>
  <param name="n" command="echo -n hello_world"/>
  <param name="ml" command="printf 'hello\\nworld'"/>""")},
         params={"/ys": True, "/yd": {"test_param": True}, "/yc": {"test_param": True}, "/n": "hello_world",
                 "/ml": "hello\nworld"}),
    Case("param_yaml_command_invalid", {MAIN: L('<param name="y" type="yaml" command="echo invalid: {{ yaml}} here"/>')},
         error=True),
    Case("param_value_and_command", {MAIN: L('<param name="x" value="abc" command="echo test"/>')}, error=True),
    # roslaunch does not check <param> names (the master would refuse it at run time)
    Case("param_odd_name_accepted", {MAIN: L('<param name="%*" value="abc"/>')}, params={"/%*": "abc"}),
    Case("rosparam_explicit_tags_and_subst_list", {MAIN: L("""
  <arg name="whitelist" default="[3, 2]"/>
  <rosparam param="whitelist" subst_value="True">$(arg whitelist)</rosparam>
  <rosparam>
    t:
      s: !!str 1
      f: !!float 1
      i: !!int "7"
  </rosparam>""")},
         params={"/whitelist": [3, 2], "/t/s": "1", "/t/f": 1.0, "/t/i": 7}),
    Case("group_root_ns_and_absolute_node_ns", {MAIN: L("""
  <group ns="/"><param name="param1" value="hello"/></group>
  <node name="n" pkg="p" type="t" ns="/racecar"><param name="pp" value="hello again"/></node>""")},
         nodes=["/racecar/n"], params={"/param1": "hello", "/racecar/n/pp": "hello again"}),
    # ---------------------------------------------------------------- YAML that libyaml would accept
    Case("rosparam_tab_after_colon", {MAIN: L('<rosparam>\na:\t1\n</rosparam>')}, error=True),
    Case("rosparam_tab_in_plain_scalar", {MAIN: L('<rosparam>\na: x\ty\n</rosparam>')}, error=True),
    Case("rosparam_bom_inside", {MAIN: L('<rosparam>\na: "x"\n\ufeffb: 2\n</rosparam>')}, params={"/a": "x", "/\ufeffb": 2}),  # (PyYAML keeps a BOM that is not at the start)
    Case("rosparam_bad_explicit_int", {MAIN: L('<rosparam>\na: !!int x\n</rosparam>')}, error=True),
    Case("param_yaml_bad_explicit_float", {MAIN: L('<param name="a" type="yaml" value="!!float"/>')}, error=True),
    Case("rosparam_file_with_tabs", {MAIN: L('<rosparam command="load" file="$(find spec_pkg)/t.yaml"/>'),
                                     "t.yaml": "a: 1\nb:\t2\n"}, error=True),
    Case("yaml_param_angles_need_a_prior_rosparam", {MAIN: L("""
  <param name="first" type="yaml" value="deg(90)"/>
  <group ns="g"><rosparam>x: 1</rosparam></group>
  <param name="after" type="yaml" value="{a: rad(pi), b: !degrees 180}"/>""")},
         params={"/first": "deg(90)", "/g/x": 1, "/after": {"a": math.pi, "b": math.pi}}),
    Case("yaml_param_angle_tag_before_rosparam_is_an_error",
         {MAIN: L('<param name="t" type="yaml" value="!degrees 90"/>')}, error=True),
    # ---------------------------------------------------------------- documents
    Case("empty_launch", {MAIN: "<launch/>"}, params={}, nodes=[]),
    Case("launch_nested_in_other_root", {MAIN: '<root><launch><param name="x" value="1"/></launch></root>'},
         params={"/x": 1}),
    Case("no_launch_tag", {MAIN: '<notlaunch><param name="x" value="1"/></notlaunch>'}, error=True),
    Case("malformed_xml", {MAIN: '<launch><param name="x" value="1"></launch>'}, error=True),
    Case("unknown_tag_is_ignored", {MAIN: L('<frobnicate/><param name="x" value="1" bogus="y"/>')},
         params={"/x": 1}),
    Case("comments_and_cdata", {MAIN: L('''
  <!-- <param name="commented" value="1"/> -->
  <rosparam><![CDATA[
    k: "<not xml>"
  ]]></rosparam>''')},
         params={"/k": "<not xml>"}),
]


# ------------------------------------------------------------------------------ machinery

def _write_case(case: Case, root) -> tuple[str, dict[str, str], str]:
    pkg = root / "pkgs" / PKG
    (pkg / "launch").mkdir(parents=True)
    (pkg / "package.xml").write_text("<package format=\"2\"><name>%s</name></package>\n" % PKG)
    for rel, text in case.files.items():
        path = pkg / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    env = {k: v for k, v in os.environ.items()
           if not k.startswith("ROS_") and not k.startswith("SPEC_") and k != "CMAKE_PREFIX_PATH"}
    env["ROS_PACKAGE_PATH"] = str(root / "pkgs")
    env["ROS_HOME"] = str(root / "home")
    env.update(case.env)
    return str(pkg / MAIN), env, str(pkg)


def _norm(value: Any) -> Any:
    """Type-strict, JSON-able form of a value (1, 1.0 and True must stay different)."""
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


NODE_FIELDS = ("package", "type", "name", "namespace", "args", "remap_args", "env_args", "respawn",
               "respawn_delay", "required", "output", "cwd", "launch_prefix", "machine_name",
               "test_name", "time_limit", "retry")


def _expand(value: Any, pkg: str) -> Any:
    if isinstance(value, str):
        return value.replace("@PKG@", pkg)
    if isinstance(value, list):
        return [_expand(v, pkg) for v in value]
    if isinstance(value, dict):
        return {k: _expand(v, pkg) for k, v in value.items()}
    return value


def _check(case: Case, result: dict, pkg: str, who: str) -> None:
    if case.error:
        assert result["error"], "%s accepted an invalid launch: %s" % (who, result)
        return
    assert not result["error"], "%s refused a valid launch: %s" % (who, result["error"])
    if case.params is not None:
        expected = {k: _norm(v) for k, v in _expand(case.params, pkg).items()}
        assert result["params"] == expected, who
    if case.nodes is not None:
        assert result["nodes"] == case.nodes, who
    for name, attrs in case.fields.items():
        got = result["fields"][name]
        for attr, value in _expand(attrs, pkg).items():
            assert got[attr] == _norm(value), "%s: %s.%s" % (who, name, attr)
    if case.clear is not None:
        assert sorted(result["clear"]) == sorted(case.clear), who
    if case.commands is not None:
        assert result["commands"] == _expand(case.commands, pkg), who
    if case.relation:
        assert eval(case.relation, {}, {"p": result["params"]}), "%s: %s" % (who, case.relation)  # noqa: S307


def _ours(path: str, env: dict[str, str], argv: list[str]) -> dict:
    from launcher.workspace.packages import PackageIndex
    from launcher.xml import load

    try:
        config = load([path], argv, environ=env, packages=PackageIndex(env), core=False)
    except LaunchError as e:
        return {"error": str(e) or "LaunchError"}
    nodes = list(config.nodes) + list(config.tests)
    return {
        "error": None,
        "params": {k: _norm(p.value) for k, p in config.params.items()},
        "nodes": [n.full_name for n in nodes],
        "fields": {n.full_name: {f: _norm(getattr(n, f, None)) for f in NODE_FIELDS} for n in nodes},
        "clear": list(config.clear_params),
        "commands": [list(c) for c in getattr(config, "rosparam_commands", ())],
    }


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_loader(case, tmp_path):
    path, env, pkg = _write_case(case, tmp_path)
    _check(case, _ours(path, env, case.argv), pkg, "launcher")


def test_case_ids_unique():
    assert len({c.id for c in CASES}) == len(CASES)


# ------------------------------------------------------------------------------ the reference

REFERENCE_RUNNER = r"""
import json, os, sys
import yaml
import roslaunch.config, roslaunch.loader, roslaunch.xmlloader, roslaunch.core, roslaunch.substitution_args
# each case must see a fresh process: roslaunch imports rosparam at the first <rosparam>,
# which registers the angle syntax on PyYAML's SafeLoader for every later type="yaml" param
PRISTINE = (dict(yaml.SafeLoader.yaml_constructors),
            {k: list(v) for k, v in yaml.SafeLoader.yaml_implicit_resolvers.items()})
def fresh_yaml():
    yaml.SafeLoader.yaml_constructors = dict(PRISTINE[0])
    yaml.SafeLoader.yaml_implicit_resolvers = {k: list(v) for k, v in PRISTINE[1].items()}
    sys.modules.pop("rosparam", None)
    roslaunch.loader.rosparam = None

FIELDS = %r

def norm(value):
    if isinstance(value, bool): return ["bool", value]
    if isinstance(value, int): return ["int", value]
    if isinstance(value, float): return ["float", repr(value)]
    if isinstance(value, str): return ["str", value]
    if value is None: return ["none"]
    if isinstance(value, (list, tuple)): return ["list", [norm(v) for v in value]]
    if isinstance(value, dict): return ["dict", sorted([str(k), norm(v)] for k, v in value.items())]
    return ["other", repr(value)]

base_env = dict(os.environ)
out = []
for path, env, argv in json.loads(sys.stdin.read()):
    os.environ.clear(); os.environ.update(env)
    sys.argv = ["roslaunch", path] + argv
    roslaunch.substitution_args._rospack = None  # its package cache would outlive the case
    fresh_yaml()
    config = roslaunch.config.ROSLaunchConfig()
    loader = roslaunch.xmlloader.XmlLoader()
    try:
        loader.load(path, config, verbose=False)
        nodes = list(config.nodes) + list(config.tests)
        names = [n.namespace + n.name for n in nodes]
        if len(set(names)) != len(names):
            raise roslaunch.core.RLException("duplicate node name")  # config.validate would refuse it
        out.append({"error": None,
                    "params": {k: norm(p.value) for k, p in config.params.items()},
                    "nodes": names,
                    "fields": {n.namespace + n.name: {f: norm(getattr(n, f, None)) for f in FIELDS} for n in nodes},
                    "clear": list(config.clear_params),
                    "commands": [[e.args[0], e.args[-1], e.args[1] if e.args[0] == "dump" else None]
                                 for e in config.executables if e.command == "rosparam"]})
    except Exception as e:
        out.append({"error": "%%s: %%s" %% (type(e).__name__, e)})
sys.stdout.write(json.dumps(out))
"""


def test_expectations_are_roslaunchs(ros_env, tmp_path):
    """Every expectation in CASES is what roslaunch 1.15's own loader produces."""
    jobs, pkgs = [], []
    for i, case in enumerate(CASES):
        path, env, pkg = _write_case(case, tmp_path / str(i))
        env["PATH"] = ros_env["path"]
        jobs.append([path, env, case.argv])
        pkgs.append(pkg)
    proc = subprocess.run([ros_env["python"], "-c", REFERENCE_RUNNER % (NODE_FIELDS,)],
                          input=json.dumps(jobs), capture_output=True, text=True, timeout=300,
                          env=dict(os.environ, PATH=ros_env["path"]))
    assert proc.returncode == 0, proc.stderr
    results = json.loads(proc.stdout)
    failures = []
    for case, result, pkg in zip(CASES, results, pkgs):
        if case.deviation:
            continue
        try:
            _check(case, result, pkg, "roslaunch")
        except AssertionError as e:
            failures.append("%s: %s" % (case.id, str(e)[:600]))
    assert not failures, "\n".join(failures)


# ------------------------------------------------------------------------------ import-order quirk

YAML_BEFORE_ROSPARAM = L("""
  <param name="first" type="yaml" value="deg(90)"/>
  <param name="first_rad" type="yaml" value="rad(pi)"/>
  <rosparam param="r">deg(180)</rosparam>
  <param name="after" type="yaml" value="deg(90)"/>""")
YAML_BEFORE_ROSPARAM_PARAMS = {"/first": "deg(90)", "/first_rad": "rad(pi)", "/r": math.pi, "/after": math.pi / 2}


def test_yaml_param_angles_only_after_a_rosparam(tmp_path):
    """roslaunch registers rosparam's angle syntax when it first meets a <rosparam> tag, so a
    type="yaml" param before it keeps `deg(90)` as a string and one after it gets radians."""
    case = Case("yaml_before_rosparam", {MAIN: YAML_BEFORE_ROSPARAM}, params=YAML_BEFORE_ROSPARAM_PARAMS)
    path, env, pkg = _write_case(case, tmp_path)
    _check(case, _ours(path, env, []), pkg, "launcher")


def test_yaml_param_angles_quirk_is_roslaunchs(ros_env, tmp_path):
    import yaml
    case = Case("yaml_before_rosparam", {MAIN: YAML_BEFORE_ROSPARAM})
    path, env, _pkg = _write_case(case, tmp_path)
    env["PATH"] = ros_env["path"]
    proc = subprocess.run(["roslaunch", "--dump-params", path], env=env, capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert yaml.safe_load(proc.stdout) == YAML_BEFORE_ROSPARAM_PARAMS
