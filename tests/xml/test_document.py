"""Reading launch XML as roslaunch does (expat, as minidom): what is accepted, refused, and where."""

from __future__ import annotations

import pytest

from launcher.model.errors import LaunchError
from launcher.xml.document import XmlSyntaxError, element_text, parse_xml, read_launch


def _read(tmp_path, text: str | bytes):
    path = tmp_path / "main.launch"
    path.write_bytes(text.encode() if isinstance(text, str) else text)
    return read_launch(str(path))


def _syntax_error(tmp_path, text: str | bytes) -> LaunchError:
    with pytest.raises(LaunchError) as err:
        _read(tmp_path, text)
    assert err.value.message.startswith("Invalid roslaunch XML syntax: ")
    return err.value


def test_elements_have_tag_attributes_children_and_the_line_where_the_tag_starts(tmp_path):
    doc = _read(tmp_path, '<launch>\n  <node\n    name="n" pkg="p"\n    type="t">\n'
                          '    <param name="x" value="1"/>\n  </node>\n  <!-- a comment -->\n'
                          '  <?pi data?>\n  <group/>\n</launch>\n')
    launch = doc.launch
    assert (launch.tag, launch.sourceline) == ("launch", 1)
    assert [(c.tag, c.sourceline) for c in launch] == [("node", 2), ("group", 9)]  # no comment, no PI
    node = launch[0]
    assert node.attrib == {"name": "n", "pkg": "p", "type": "t"}
    assert node.get("name") == "n" and node.get("missing") is None and node.get("missing", "d") == "d"
    assert [(c.tag, c.sourceline, c.get("value")) for c in node] == [("param", 5, "1")]
    assert doc.masters == []


def test_rosparam_text_is_its_own_text_and_cdata_with_entities_expanded(tmp_path):
    doc = _read(tmp_path, '<?xml version="1.0"?>\n<!DOCTYPE launch [<!ENTITY e "from entity">]>\n'
                          '<launch><rosparam>a: 1<!-- c -->\nb: <x>not mine</x>2\nc: <![CDATA[<raw>]]>\n'
                          'd: &e;&amp;</rosparam><node name="n" pkg="p" type="t">'
                          '<ROSPARAM>k: v</ROSPARAM></node></launch>')
    rosparam, node = doc.launch
    assert element_text(rosparam) == "a: 1\nb: 2\nc: <raw>\nd: from entity&"
    assert element_text(node[0]) == "k: v"  # a node's child tags are matched case-insensitively
    with pytest.raises(ValueError):
        element_text(node)  # text not recorded for tags whose text no one reads


def test_parse_xml_records_all_text_when_not_told_otherwise():
    root, watched = parse_xml(b"<package><name> pkg </name><version>1.2.3</version></package>")
    assert [(c.tag, element_text(c)) for c in root] == [("name", " pkg "), ("version", "1.2.3")]
    assert watched == []


def test_namespaced_names_are_qualified_names_and_declarations_are_not_attributes(tmp_path):
    doc = _read(tmp_path, '<launch xmlns:xacro="http://x">\n<xacro:foo xacro:a="1" b="2"/>\n'
                          '<inner xmlns="http://default"><param name="p"/></inner>\n</launch>')
    foo, inner = doc.launch
    assert doc.launch.attrib == {}
    assert (foo.tag, foo.attrib) == ("xacro:foo", {"xacro:a": "1", "b": "2"})
    assert (inner.tag, inner[0].tag, inner[0].attrib) == ("inner", "param", {"name": "p"})


def test_launch_may_be_wrapped_but_only_once_and_masters_inside_it_are_found(tmp_path):
    doc = _read(tmp_path, "<root>\n<master/>\n<launch>\n<group><master/></group>\n</launch>\n</root>")
    assert doc.launch.sourceline == 3
    assert [m.sourceline for m in doc.masters] == [4]
    e = _syntax_error(tmp_path, "<launch>\n<group>\n<launch/>\n</group>\n</launch>")
    assert e.line == 3 and "more than one <launch>" in e.message
    e = _syntax_error(tmp_path, "<root>\n<a/>\n</root>")
    assert "no root <launch> tag" in e.message


@pytest.mark.parametrize("text, line, words", [
    ("<launch>\n  <group>\n  </grop>\n</launch>", 3, "mismatched tag"),
    ('<launch>\n  <param name="a" value=1/>\n</launch>', 2, "not well-formed (invalid token)"),
    ('<launch>\n  <param name="a" value="1"/>\n', 3, "no element found"),
    ("<launch>\n</launch>\n<launch/>\n", 3, "junk after document element"),
    ('<launch a="1" a="2">\n</launch>', 1, "duplicate attribute"),
    ('<launch>\n  <param name="a" value="&undefined;"/>\n</launch>', 2, "undefined entity"),
    ("<launch>\n<x:foo/>\n</launch>", 2, "unbound prefix"),
    ('<?xml version="1.0" encoding="utf-16"?>\n<launch/>', 1, "encoding specified in XML declaration is incorrect"),
])
def test_syntax_errors_are_expats_words_at_the_line(tmp_path, text, line, words):
    # the words of roslaunch's own message (minidom's ExpatError), e.g. "mismatched tag: line 3, column 4"
    e = _syntax_error(tmp_path, text)
    assert e.line == line and words in e.message, e.message
    assert e.filename == str(tmp_path / "main.launch")


def test_encodings_bom_and_bad_bytes(tmp_path):
    doc = _read(tmp_path, b'<?xml version="1.0" encoding="iso-8859-1"?>\n<launch><param value="caf\xe9"/></launch>')
    assert doc.launch[0].get("value") == "caf\u00e9"
    doc = _read(tmp_path, b'\xef\xbb\xbf<launch><param value="bom"/></launch>')
    assert doc.launch[0].get("value") == "bom"
    e = _syntax_error(tmp_path, b'<launch>\n<param value="\xff\xfe"/>\n</launch>')
    assert e.line == 2


@pytest.mark.parametrize("encoding, words", [
    ("x-no-such", "unknown encoding: x-no-such"),  # Python knows no such codec
    ("rot13", "is not a text encoding"),  # a codec, but not for text
    ("utf-7", "multi-byte encodings are not supported"),  # a codec expat cannot use
])
def test_an_encoding_that_cannot_be_used_is_a_syntax_error_at_the_declaration(tmp_path, encoding, words):
    # roslaunch: "Invalid roslaunch XML syntax: unknown encoding: x-no-such"
    e = _syntax_error(tmp_path, '<?xml version="1.0" encoding="%s"?><launch/>' % encoding)
    assert words in e.message and e.line == 1, e.message
    assert e.filename == str(tmp_path / "main.launch")


def test_external_entities_are_never_read(tmp_path):
    secret = tmp_path / "secret.txt"
    secret.write_text("TOP SECRET")
    doc = _read(tmp_path, '<?xml version="1.0"?>\n<!DOCTYPE launch [<!ENTITY x SYSTEM "file://%s">]>\n'
                          '<launch><rosparam param="r">&x;</rosparam></launch>' % secret)
    assert "TOP SECRET" not in element_text(doc.launch[0])
    e = _syntax_error(tmp_path, '<?xml version="1.0"?>\n<!DOCTYPE launch [<!ENTITY x SYSTEM "file://%s">]>\n'
                                '<launch><param name="p" value="&x;"/></launch>' % secret)
    assert e.line == 3 and "external entity" in e.message


def test_entity_expansion_bomb_is_refused(tmp_path):
    decls = '<!ENTITY a "%s">' % ("a" * 10)
    for prev, name in zip("abcdefg", "bcdefgh"):
        decls += '<!ENTITY %s "%s">' % (name, ("&%s;" % prev) * 10)
    e = _syntax_error(tmp_path, '<?xml version="1.0"?>\n<!DOCTYPE launch [%s]>\n<launch><param value="&h;"/></launch>'
                      % decls)
    assert e.line is not None


def test_parse_xml_raises_its_own_error_type():
    with pytest.raises(XmlSyntaxError) as err:
        parse_xml(b"<a>\n<b></a>")
    assert (err.value.line, err.value.message) == (2, "mismatched tag")


def test_nesting_deeper_than_python_recursion_is_a_clean_error(tmp_path):
    from launcher.xml import load
    n = 5000
    path = tmp_path / "deep.launch"
    path.write_text("<launch>%s<param name='p' value='1'/>%s</launch>" % ("<group>" * n, "</group>" * n))
    with pytest.raises(LaunchError) as err:
        load([str(path)], [], core=False)
    assert "nested too deeply" in err.value.message and err.value.filename == str(path)
    path.write_text("<launch>%s<param name='p' value='1'/>%s</launch>" % ("<group>" * 300, "</group>" * 300))
    assert load([str(path)], [], core=False).params["/p"].value == 1  # deeper than libxml2's 256 is fine


def test_iter_and_iterdescendants():
    root, _ = parse_xml(b"<a><b><c/><b/></b><c><b/></c></a>")
    assert [e.tag for e in root.iter()] == ["a", "b", "c", "b", "c", "b"]
    assert [e.tag for e in root.iterdescendants()] == ["b", "c", "b", "c", "b"]
    assert len(list(root.iterdescendants("b"))) == 3 and list(root.iterdescendants("a")) == []
    assert list(root[0][0].iterdescendants("master")) == []  # (found by the fuzzer: a leaf, nothing to find)


def test_masters_outside_a_wrapped_launch_are_not_its_own(tmp_path):
    doc = _read(tmp_path, "<root>\n<master/>\n<launch/>\n</root>")
    assert doc.masters == []


def test_a_parse_leaves_no_cycle_behind():
    # loads run with the cyclic GC off: a tree kept alive by a parser<->handler cycle would stay
    # in memory for the whole load (it did: ~5 MB on a 1000-node tree)
    import gc
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        gc.collect()
        root, _ = parse_xml(b"<launch><rosparam>a: 1</rosparam><node><param/></node></launch>",
                            lambda tag: tag == "rosparam", frozenset(("launch",)))
        assert element_text(root[0]) == "a: 1"
        del root
        assert gc.collect() == 0
    finally:
        if was_enabled:
            gc.enable()
