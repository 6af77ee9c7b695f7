"""The supervision extension attributes: parsed into `Node.policy`, scoped defaults, rosmon spellings, errors."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from launcher.model.config import NodePolicy


def policies(config):
    return {n.full_name: n.policy for n in config.nodes if n.full_name != "/rosout"}


def test_no_extension_attribute_means_no_policy(ld):
    c = ld.load('<launch><group ns="g"><node name="n" pkg="tpkg" type="talker" respawn="true"/></group></launch>')
    assert policies(c) == {"/g/n": None}
    assert not c.warnings


def test_every_attribute_on_a_node(ld):
    c = ld.load("""
        <launch>
          <node name="n" pkg="tpkg" type="talker" respawn="true" respawn_on="failure" success_exit_codes="0 3,4"
                respawn_backoff="2" respawn_delay_max="30" respawn_min_uptime="5" respawn_max_retries="4"
                on_fatal="shutdown" restart_warn_threshold="7" sigint_timeout="3" sigterm_timeout="0.5"
                spawn_delay="1.5" wait_for="topic:/scan service:/static_map param:/robot_description node:/amcl"
                wait_timeout="20" hang_timeout="6" memory_limit="500MB" cpu_limit="0.9" on_limit="restart"
                enable_coredumps="true" registers="false"/>
        </launch>""")
    assert not c.warnings
    assert policies(c)["/n"] == NodePolicy(
        respawn_on="failure", success_exit_codes=frozenset({0, 3, 4}), respawn_backoff=2.0, respawn_delay_max=30.0,
        respawn_min_uptime=5.0, respawn_max_retries=4, on_fatal="shutdown", restart_warn_threshold=7,
        sigint_timeout=3.0, sigterm_timeout=0.5, spawn_delay=1.5,
        wait_for=(("topic", "/scan"), ("service", "/static_map"), ("param", "/robot_description"), ("node", "/amcl")),
        wait_timeout=20.0, hang_timeout=6.0, memory_limit=500_000_000, cpu_limit=0.9, on_limit="restart",
        enable_coredumps=True, registers=False)


def test_scoped_defaults_nearest_wins(ld):
    inc = ld.write("inc.launch", """
        <launch respawn_max_retries="9">
          <node name="i" pkg="tpkg" type="talker" respawn="true"/>
          <node name="j" pkg="tpkg" type="talker" respawn="true" respawn_max_retries="1"/>
        </launch>""")
    c = ld.load("""
        <launch respawn_backoff="2" memory_limit="1GB">
          <node name="top" pkg="tpkg" type="talker" respawn="true"/>
          <group ns="g" respawn_backoff="3" respawn_max_retries="5">
            <node name="a" pkg="tpkg" type="talker" respawn="true"/>
            <node name="b" pkg="tpkg" type="talker" respawn="true" respawn_backoff="1.5" memory_limit="2k"/>
          </group>
          <include file="%s" ns="inc" respawn_max_retries="8" cpu_limit="0.5"/>
          <node name="after" pkg="tpkg" type="talker"/>
        </launch>""" % inc)
    p = policies(c)
    assert (p["/top"].respawn_backoff, p["/top"].respawn_max_retries, p["/top"].memory_limit) == (2, None, 10**9)
    assert (p["/g/a"].respawn_backoff, p["/g/a"].respawn_max_retries, p["/g/a"].memory_limit) == (3, 5, 10**9)
    assert (p["/g/b"].respawn_backoff, p["/g/b"].respawn_max_retries, p["/g/b"].memory_limit) == (1.5, 5, 2000)
    # the included file's <launch> is nearer than the <include>, the node nearer still
    assert (p["/inc/i"].respawn_max_retries, p["/inc/i"].cpu_limit, p["/inc/i"].respawn_backoff) == (9, 0.5, 2)
    assert p["/inc/j"].respawn_max_retries == 1
    # a group's defaults end with the group
    assert (p["/after"].respawn_backoff, p["/after"].respawn_max_retries, p["/after"].cpu_limit) == (2, None, None)
    assert not c.warnings


def test_rosmon_spellings(ld):
    c = ld.load("""
        <launch rosmon-stop-timeout="4">
          <node name="n" pkg="tpkg" type="talker" respawn="true" rosmon-memory-limit="15 MB" rosmon-cpu-limit="0.05"
                rosmon-spawn-delay="2" rosmon-restart-warn-threshold="3" enable-coredumps="1"/>
          <group rosmon-memory-limit="1.5GiB" enable-coredumps="false">
            <node name="m" pkg="tpkg" type="talker"/>
          </group>
        </launch>""")
    assert not c.warnings
    p = policies(c)
    assert p["/n"] == NodePolicy(sigint_timeout=4.0, memory_limit=15_000_000, cpu_limit=0.05, spawn_delay=2.0,
                                 restart_warn_threshold=3, enable_coredumps=True)
    assert (p["/m"].memory_limit, p["/m"].enable_coredumps, p["/m"].sigint_timeout) == (int(1.5 * 2**30), False, 4.0)


def test_substitution_args_in_extension_attributes(ld):
    inc = ld.write("inc.launch", """
        <launch><arg name="tries"/><node name="n" pkg="tpkg" type="talker" respawn="true"
                                           respawn_max_retries="$(arg tries)"/></launch>""")
    c = ld.load("""
        <launch>
          <arg name="mem" default="200k"/>
          <group memory_limit="$(arg mem)" spawn_delay="$(eval 0.5 * 2)">
            <include file="%s" respawn_backoff="$(arg b)"><arg name="tries" value="6"/></include>
          </group>
        </launch>""" % inc, ["b:=4"])
    assert policies(c)["/n"] == NodePolicy(memory_limit=200_000, spawn_delay=1.0, respawn_backoff=4.0,
                                           respawn_max_retries=6)


def test_wait_for_names_resolved_like_the_node_would(ld):
    c = ld.load("""
        <launch>
          <group ns="robot" wait_for="topic:scan">
            <node name="amcl" pkg="tpkg" type="talker" wait_for="topic:scan service:/static_map param:~map node:laser"/>
            <node name="other" pkg="tpkg" type="talker"/>
          </group>
        </launch>""")
    p = policies(c)
    assert p["/robot/amcl"].wait_for == (("topic", "/robot/scan"), ("service", "/static_map"),
                                         ("param", "/robot/amcl/map"), ("node", "/robot/laser"))
    assert p["/robot/other"].wait_for == (("topic", "/robot/scan"),)


def test_wait_for_output_takes_a_quoted_pattern_and_resolves_its_node(ld):
    c = ld.load("""
        <launch>
          <group ns="robot">
            <node name="amcl" pkg="tpkg" type="talker"
                  wait_for="topic:scan output:driver:'ready to go' output:/cam:&quot;port \\d+: ok&quot; output:/x:\\w"/>
          </group>
        </launch>""")
    assert policies(c)["/robot/amcl"].wait_for == (("topic", "/robot/scan"), ("output", "/robot/driver:ready to go"),
                                                   ("output", "/cam:port \\d+: ok"), ("output", "/x:\\w"))


@pytest.mark.parametrize("attr, value, expected", [
    ("respawn_backoff", "fast", "invalid value for respawn_backoff: 'fast' (expected a factor of 1 or more)"),
    ("respawn_backoff", "0.5", "invalid value for respawn_backoff: '0.5'"),
    ("memory_limit", "lots", "invalid value for memory_limit: 'lots' (expected a size such as 500MB"),
    ("memory_limit", "5 parsecs", "invalid value for memory_limit: '5 parsecs'"),
    ("memory_limit", "0", "invalid value for memory_limit: '0' (expected a size greater than zero)"),
    ("log_max_size", "0.5B", "invalid value for log_max_size: '0.5B' (expected a size greater than zero)"),
    ("rosmon-memory-limit", "-1MB", "invalid value for rosmon-memory-limit: '-1MB'"),
    ("wait_for", "socket:/x", "invalid value for wait_for: 'socket:/x' (expected kind:name items with a kind of "
                              "topic, service, param, node, output (got 'socket:/x'))"),
    ("wait_for", "topic:", "invalid value for wait_for: 'topic:'"),
    ("wait_for", "output:/driver", "invalid value for wait_for: 'output:/driver' (expected output:NODE:PATTERN with a "
                                   "node name and a pattern (got 'output:/driver'))"),
    ("wait_for", "output:/driver:(ready", "invalid value for wait_for: 'output:/driver:(ready' (expected "
                                          "output:NODE:PATTERN with a Python regular expression (got "
                                          "'output:/driver:(ready': missing ), unterminated subpattern"),
    ("wait_for", "output:/driver:'ready", "invalid value for wait_for: 'output:/driver:'ready' (expected kind:name "
                                          "items, a pattern with spaces in quotes (an unclosed quote: 'ready))"),
    ("respawn_on", "sometimes", "invalid value for respawn_on: 'sometimes' (expected always or failure)"),
    ("on_limit", "kill", "invalid value for on_limit: 'kill' (expected warn or restart)"),
    ("on_fatal", "panic", "invalid value for on_fatal: 'panic' (expected none or shutdown)"),
    ("success_exit_codes", "0 x", "invalid value for success_exit_codes: '0 x'"),
    ("success_exit_codes", "256", "invalid value for success_exit_codes: '256'"),
    ("respawn_max_retries", "2.5", "invalid value for respawn_max_retries: '2.5' (expected a whole number"),
    ("sigint_timeout", "0", "invalid value for sigint_timeout: '0' (expected a number of seconds greater than zero)"),
    ("spawn_delay", "-1", "invalid value for spawn_delay: '-1'"),
    ("hang_timeout", "nan", "invalid value for hang_timeout: 'nan'"),
    ("cpu_limit", "0", "invalid value for cpu_limit: '0'"),
    ("enable-coredumps", "yes", "invalid value for enable-coredumps: 'yes' (expected true or false)"),
    ("wait_timeout", "", "value for wait_timeout must be non-empty"),
])
def test_bad_values_are_errors_with_file_and_line(ld, attr, value, expected):
    e = ld.error('<launch>\n\n  <node name="n" pkg="tpkg" type="talker" respawn="true" %s="%s"/>\n</launch>'
                 % (attr, value))
    assert e.filename.endswith("main.launch") and e.line == 3
    assert "Invalid <node> tag: " + expected in e.message


def test_bad_scoped_value_names_its_element(ld):
    e = ld.error('<launch>\n  <group ns="g"\n    memory_limit="lots">\n    <node name="n" pkg="tpkg" type="talker"/>'
                 '\n  </group>\n</launch>')
    assert e.line == 2 and "Invalid <group> tag: invalid value for memory_limit: 'lots'" in e.message
    inc = ld.write("inc.launch", '<launch>\n<node name="n" pkg="tpkg" type="talker" respawn_on="x"/>\n</launch>')
    e = ld.error('<launch>\n<include file="%s"/>\n</launch>' % inc)
    assert e.filename == inc and e.line == 2 and e.include_chain[0][1] == 2


def test_two_spellings_of_one_setting_on_one_element(ld):
    e = ld.error('<launch><node name="n" pkg="tpkg" type="talker" memory_limit="1MB" rosmon-memory-limit="2MB"/>'
                 '</launch>')
    assert "both set memory_limit" in e.message


def test_respawn_settings_without_respawn_are_warned_about(ld):
    c = ld.load('<launch><group respawn_backoff="2"><node name="a" pkg="tpkg" type="talker"/></group>\n'
                '<node name="b" pkg="tpkg" type="talker" respawn_max_retries="3" memory_limit="1MB"/></launch>')
    assert len(c.warnings) == 1 and 'respawn_max_retries has no effect without respawn="true"' in c.warnings[0]


def test_test_tags_take_no_policy(ld):
    c = ld.load('<launch memory_limit="1MB"><test test-name="t" pkg="tpkg" type="talker" spawn_delay="1"/></launch>')
    assert c.tests[0].policy is None
    assert any("unknown <test> attribute 'spawn_delay'" in w for w in c.warnings)


def test_introspection_output_unchanged_by_extensions(ld):
    plain = ld.write("plain.launch", """
        <launch><group ns="g"><node name="n" pkg="tpkg" type="talker" respawn="true" args="-x">
          <param name="p" value="1"/></node></group></launch>""")
    extended = ld.write("extended.launch", """
        <launch memory_limit="1MB"><group ns="g" respawn_backoff="2"><node name="n" pkg="tpkg" type="talker"
          respawn="true" args="-x" spawn_delay="1" rosmon-cpu-limit="0.5"><param name="p" value="1"/></node></group>
        </launch>""")
    env = dict(ld.environ, PYTHONPATH=os.environ.get("PYTHONPATH", ""))

    def run(*argv):
        r = subprocess.run([sys.executable, "-m", "launcher", *argv], env=env, capture_output=True, text=True,
                           timeout=60)
        return r.returncode, r.stdout, r.stderr

    for option in (["--nodes"], ["--args", "/g/n"], ["--dump-params"]):
        a, b = run(*option, plain), run(*option, extended)
        assert a[0] == 0 and a == b, option
        assert not b[2]  # no warning about the extensions
