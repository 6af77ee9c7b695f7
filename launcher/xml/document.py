"""Reading a launch file: safe XML parsing (no DTD, entities or network) and finding its one `<launch>`."""

from __future__ import annotations

import re

from lxml import etree

from launcher.errors import LaunchError

_PARSER = None
_LXML_POSITION = re.compile(r"(, line \d+, column \d+|\s*\([^()]*, line \d+\))$")


def _parser() -> etree.XMLParser:
    global _PARSER
    if _PARSER is None:
        # no external entities, no DTD loading, no network: a launch file cannot make us read other files
        _PARSER = etree.XMLParser(resolve_entities=False, no_network=True, load_dtd=False,
                                  huge_tree=False, remove_blank_text=False)
    return _PARSER


def read_launch(filename: str, include_chain: tuple[tuple[str, int], ...] = ()) -> etree._Element:
    """The `<launch>` element of `filename` (which may be anywhere in the document, but only once)."""
    try:
        if filename == "-":  # roslaunch reads launch XML from stdin for '-'
            import sys
            data = sys.stdin.buffer.read()
        else:
            with open(filename, "rb") as f:
                data = f.read()
    except OSError as e:
        raise LaunchError("cannot read launch file [%s]: %s" % (filename, e.strerror or e),
                          include_chain=include_chain) from None
    if not data.strip():
        raise LaunchError("Invalid roslaunch XML syntax: the file is empty", filename, None, include_chain)
    try:
        root = etree.fromstring(data, _parser(), base_url=None if filename == "-" else filename)
    except etree.XMLSyntaxError as e:
        msg = e.msg or str(e)
        # lxml appends ", line N, column M" (or "(<file>, line N)"); we print file:line ourselves
        msg = _LXML_POSITION.sub("", msg)
        raise LaunchError("Invalid roslaunch XML syntax: %s" % msg, filename, e.lineno or None,
                          include_chain) from None
    launches = [root] if root.tag == "launch" else []
    launches += [e for e in root.iterdescendants("launch")]
    if len(launches) != 1:
        if not launches:
            raise LaunchError("Invalid roslaunch XML syntax: no root <launch> tag", filename,
                              root.sourceline, include_chain)
        raise LaunchError("Invalid roslaunch XML syntax: more than one <launch> tag in the document",
                          filename, launches[1].sourceline, include_chain)
    return launches[0]


def element_text(el: etree._Element) -> str:
    """The element's own text (text and CDATA children, not its children's text), as DOM gives it."""
    parts = [el.text or ""]
    for child in el:
        if child.tail:
            parts.append(child.tail)
    return "".join(parts)
