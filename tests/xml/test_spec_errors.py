"""Loader errors: a LaunchError naming the file and the line (and the include chain), never a traceback.

roslaunch reports most of these without a line number; we must give `file:line: message`.
Which inputs are errors at all is pinned by test_spec_cases.py against roslaunch itself.
"""

from __future__ import annotations

import os

import pytest

from launcher.model.errors import LaunchError

PKG = "spec_err_pkg"


@pytest.fixture
def tree(tmp_path):
    pkg = tmp_path / "pkgs" / PKG
    pkg.mkdir(parents=True)
    (pkg / "package.xml").write_text("<package><name>%s</name></package>" % PKG)
    env = {k: v for k, v in os.environ.items() if not k.startswith("ROS_") and k != "CMAKE_PREFIX_PATH"}
    env["ROS_PACKAGE_PATH"] = str(tmp_path / "pkgs")
    env["ROS_HOME"] = str(tmp_path / "home")

    class Tree:
        root = pkg

        def write(self, rel, text):
            path = pkg / rel
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(text)
            return str(path)

        def load(self, rel="main.launch", argv=()):
            from launcher.workspace.packages import PackageIndex
            from launcher.xml import load
            return load([str(pkg / rel)], list(argv), environ=env, packages=PackageIndex(env), core=False)

        def error(self, rel="main.launch", argv=()) -> LaunchError:
            try:
                self.load(rel, argv)
            except LaunchError as e:
                return e
            except Exception as e:  # anything else is a traceback for the user
                pytest.fail("not a LaunchError: %r" % e)
            pytest.fail("loaded without error")

    return Tree()


def at(err: LaunchError, filename: str, line: int) -> None:
    """The error points at filename:line, in its attributes and in the text the user sees."""
    text = str(err)
    assert "%s:%d:" % (filename, line) in text, text
    assert "Traceback" not in text


# line numbers below count from 1 at "<launch>"
ERROR_LINES = [
    ("bad_int", '<launch>\n  <param name="a" value="1"/>\n  <param name="b" type="int" value="x"/>\n</launch>', 3),
    ("bad_bool", '<launch>\n\n\n  <param name="b" type="bool" value="maybe"/>\n</launch>', 4),
    ("unknown_type", '<launch>\n  <param name="b" type="float" value="1"/>\n</launch>', 2),
    ("bad_yaml_param", '<launch>\n  <param name="b" type="yaml" value="[1"/>\n</launch>', 2),
    ("undefined_arg", '<launch>\n  <arg name="a" default="1"/>\n  <node pkg="p" type="t" name="$(arg b)"/>\n</launch>', 3),
    ("unknown_subst", '<launch>\n  <param name="p" value="$(nosuch x)"/>\n</launch>', 2),
    ("missing_pkg", '<launch>\n  <param name="p" value="$(find spec_no_such_pkg)/x"/>\n</launch>', 2),
    ("missing_env", '<launch>\n  <param name="p" value="$(env SPEC_ERR_UNSET_VAR)"/>\n</launch>', 2),
    ("missing_include", '<launch>\n  <arg name="a" default="1"/>\n  <include file="/nonexistent/x.launch"/>\n</launch>', 3),
    ("bad_if", '<launch>\n  <group if="perhaps">\n  </group>\n</launch>', 2),
    ("node_slash_name", '<launch>\n  <node pkg="p" type="t" name="a/b"/>\n</launch>', 2),
    ("node_no_pkg", '<launch>\n  <node type="t" name="n"/>\n</launch>', 2),
    ("node_bad_output", '<launch>\n\n  <node pkg="p" type="t" name="n" output="nowhere"/>\n</launch>', 3),
    ("dup_node", '<launch>\n  <node pkg="p" type="t" name="n"/>\n  <node pkg="p" type="t" name="n"/>\n</launch>', 3),
    ("remap_missing_to", '<launch>\n  <node pkg="p" type="t" name="n">\n    <remap from="a"/>\n  </node>\n</launch>', 3),
    ("arg_both", '<launch>\n  <arg name="a" value="1" default="2"/>\n</launch>', 2),
    ("eval_dunder", '<launch>\n  <param name="p" value="$(eval ().__class__)"/>\n</launch>', 2),
    ("eval_syntax", '<launch>\n  <param name="p" value="$(eval 1 +)"/>\n</launch>', 2),
    ("rosparam_scalar", '<launch>\n  <rosparam>\n    42\n  </rosparam>\n</launch>', 2),
    ("test_bad_limit", '<launch>\n  <test test-name="t" pkg="p" type="t" time-limit="soon"/>\n</launch>', 2),
    ("malformed", '<launch>\n  <param name="a" value="1">\n</launch>', 3),
    ("bad_attr_syntax", '<launch>\n  <param name="a" value=1/>\n</launch>', 2),
]


@pytest.mark.parametrize("name,xml,line", ERROR_LINES, ids=[c[0] for c in ERROR_LINES])
def test_error_names_file_and_line(tree, name, xml, line):
    path = tree.write("main.launch", xml)
    at(tree.error(), path, line)


def test_error_in_included_file_gives_include_chain(tree):
    main = tree.write("main.launch", '<launch>\n  <arg name="a" default="1"/>\n\n'
                                     '  <include file="$(dirname)/mid.launch"/>\n</launch>')
    mid = tree.write("mid.launch", '<launch>\n  <group ns="g">\n    <include file="$(dirname)/leaf.launch"/>\n'
                                   '  </group>\n</launch>')
    leaf = tree.write("leaf.launch", '<launch>\n  <param name="ok" value="1"/>\n'
                                     '  <param name="bad" type="int" value="1.5"/>\n</launch>')
    err = tree.error()
    text = str(err)
    at(err, leaf, 3)
    # the chain, innermost first: where leaf was included, then where mid was
    assert "%s:3" % mid in text and "%s:4" % main in text
    assert text.index("%s:3" % mid) < text.index("%s:4" % main)


def test_yaml_error_in_rosparam_file_points_into_the_yaml(tree):
    yaml_path = tree.write("config/bad.yaml", "a: 1\nb: 2\nc: [1, 2\nd: 4\n")
    tree.write("main.launch", '<launch>\n  <rosparam command="load" file="$(find %s)/config/bad.yaml"/>\n</launch>'
               % PKG)
    err = tree.error()
    text = str(err)
    assert yaml_path in text
    # PyYAML notices the unclosed flow sequence on line 4 ("d: 4")
    assert any("%s:%d" % (yaml_path, n) in text for n in (3, 4)), text


def test_inline_yaml_error_points_into_the_launch_file(tree):
    path = tree.write("main.launch", '<launch>\n  <param name="x" value="1"/>\n  <rosparam>\n    a: 1\n'
                                     '    b: : bad\n  </rosparam>\n</launch>')
    at(tree.error(), path, 5)


def test_bad_angle_in_rosparam_points_at_its_line(tree):
    path = tree.write("main.launch", '<launch>\n  <rosparam>\n    a: 1\n    b: !degrees ninety\n'
                                     '  </rosparam>\n</launch>')
    at(tree.error(), path, 4)


def test_missing_required_cli_arg_names_the_arg(tree):
    path = tree.write("main.launch", '<launch>\n  <arg name="robot"/>\n  <param name="p" value="$(arg robot)"/>\n'
                                     '</launch>')
    err = tree.error()
    assert path in str(err) and "robot" in str(err)


def test_unused_include_arg_names_the_arg_and_the_include(tree):
    main = tree.write("main.launch", '<launch>\n  <include file="$(dirname)/inc.launch">\n'
                                     '    <arg name="surplus" value="1"/>\n  </include>\n</launch>')
    tree.write("inc.launch", "<launch/>")
    err = tree.error()
    assert "surplus" in str(err) and main in str(err)


def test_failing_command_names_command_and_stderr(tree):
    path = tree.write("main.launch", '<launch>\n  <param name="p" command="sh -c \'echo oops-on-stderr 1>&amp;2; '
                                     'exit 3\'"/>\n</launch>')
    err = tree.error()
    text = str(err)
    at(err, path, 2)
    assert "oops-on-stderr" in text and "sh" in text


def test_missing_command_executable(tree):
    path = tree.write("main.launch", '<launch>\n  <param name="p" command="spec-no-such-program --x"/>\n</launch>')
    err = tree.error()
    at(err, path, 2)
    assert "spec-no-such-program" in str(err)


def test_missing_textfile_names_the_file(tree):
    path = tree.write("main.launch", '<launch>\n  <param name="p" textfile="/nonexistent/spec.txt"/>\n</launch>')
    err = tree.error()
    at(err, path, 2)
    assert "/nonexistent/spec.txt" in str(err)


def test_missing_launch_file():
    from launcher.xml import load
    with pytest.raises(LaunchError) as err:
        load(["/nonexistent/spec_main.launch"], [], core=False)
    assert "/nonexistent/spec_main.launch" in str(err.value)


def test_not_utf8_file_is_a_clean_error(tree):
    path = tree.root / "main.launch"
    path.write_bytes(b'<?xml version="1.0" encoding="utf-8"?>\n<launch>\n  <param name="p" value="\xff\xfe"/>\n'
                     b'</launch>')
    err = tree.error()
    assert str(path) in str(err)


def test_entity_expansion_is_refused_or_harmless(tree):
    bomb = ('<?xml version="1.0"?>\n<!DOCTYPE launch [\n <!ENTITY a "aaaaaaaaaa">\n <!ENTITY b "&a;&a;&a;&a;&a;&a;&a;'
            '&a;&a;&a;">\n <!ENTITY c "&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;">\n <!ENTITY d "&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;">\n'
            ' <!ENTITY e "&d;&d;&d;&d;&d;&d;&d;&d;&d;&d;">\n <!ENTITY f "&e;&e;&e;&e;&e;&e;&e;&e;&e;&e;">\n'
            ' <!ENTITY g "&f;&f;&f;&f;&f;&f;&f;&f;&f;&f;">\n]>\n<launch><param name="p" value="&g;"/></launch>')
    tree.write("main.launch", bomb)
    try:
        config = tree.load()
    except LaunchError:
        return
    assert len(str(config.params["/p"].value)) < 10 ** 6


def test_external_entity_is_not_read(tree):
    secret = tree.write("secret.txt", "SPEC-SECRET-CONTENT")
    tree.write("main.launch", '<?xml version="1.0"?>\n<!DOCTYPE launch [<!ENTITY x SYSTEM "file://%s">]>\n'
                              '<launch><param name="p" value="&x;"/></launch>' % secret)
    try:
        config = tree.load()
    except LaunchError:
        return
    assert "SPEC-SECRET-CONTENT" not in repr(config.params)


# -- warnings for what roslaunch silently ignores ----------------------------------------------

def test_unknown_tag_and_attribute_are_warned_with_line(tree):
    path = tree.write("main.launch", '<launch>\n  <param name="a" value="1"/>\n  <frobnicate/>\n'
                                     '  <node pkg="p" type="t" name="n" colour="red"/>\n</launch>')
    config = tree.load()
    assert config.params["/a"].value == 1
    warnings = "\n".join(config.warnings)
    assert "%s:3" % path in warnings and "frobnicate" in warnings
    assert "%s:4" % path in warnings and "colour" in warnings


def test_param_and_child_param_are_kept_and_warned(tree):
    path = tree.write("main.launch", '<launch>\n  <param name="a" value="1"/>\n  <param name="a/b" value="2"/>\n'
                                     '</launch>')
    config = tree.load()
    assert config.params["/a"].value == 1 and config.params["/a/b"].value == 2
    assert any(path in w for w in config.warnings), config.warnings


def test_params_remember_where_they_were_set(tree):
    path = tree.write("main.launch", '<launch>\n\n  <param name="a" value="1"/>\n</launch>')
    p = tree.load().params["/a"]
    assert p.filename == path and p.line == 3


def test_nodes_remember_where_they_were_declared(tree):
    path = tree.write("main.launch", '<launch>\n  <group ns="g">\n    <node pkg="p" type="t" name="n"/>\n'
                                     '  </group>\n</launch>')
    n = tree.load().nodes[0]
    assert n.filename == path and n.line == 3
