"""Reading XML the way roslaunch does (expat, as xml.dom.minidom), into small element objects with line numbers.

roslaunch parses launch files with minidom, i.e. expat with namespace
processing: we use the same parser, so the same documents are accepted and
refused (unbound prefixes, external entities in attributes, ...), and build
only what the loader reads: tag, attributes, children, the line of the start
tag and, for the elements whose text matters, their text. Comments and
processing instructions are dropped. No external entity or DTD is ever read
(expat only reads one when asked to, and we never ask) and expat refuses
entity expansion bombs (billion laughs, since expat 2.4; refused up front on
an older expat).
"""

from __future__ import annotations

import pyexpat
import sys

from launcher.model.errors import LaunchError

TYPE_CHECKING = False  # (typing.TYPE_CHECKING without importing typing: ~3 ms a start; the annotations are text)
if TYPE_CHECKING:
    from typing import Callable, Iterator

# namespace processing as minidom does it: names arrive as "uri local prefix", which we turn
# back into the qualified name minidom reports (`xacro:arg`); xmlns declarations are not attributes
_NS_SEP = " "
_OLD_EXPAT = pyexpat.version_info < (2, 4, 0)


class Element(list):
    """One XML element; its children are the list's items, in document order.

    `attrib` is a plain dict (name -> value), `sourceline` the line of the start tag,
    `text` the list of its own character data chunks when they were recorded (else None).
    """

    __slots__ = ("tag", "attrib", "sourceline")
    text: list[str] | None = None  # (the few elements that record their text are _TextElements)
    __hash__ = object.__hash__  # an element is one place in one document, not a value
    __eq__ = object.__eq__  # type: ignore[assignment]
    __ne__ = object.__ne__  # type: ignore[assignment]

    def get(self, key: str, default: str | None = None) -> str | None:
        return self.attrib.get(key, default)

    def keys(self):  # noqa: ANN201 - dict keys view
        return self.attrib.keys()

    def iter(self, tag: str | None = None) -> Iterator[Element]:
        """This element and its descendants, in document order (those named `tag` if given)."""
        stack = [self]
        while stack:
            el = stack.pop()
            if tag is None or el.tag == tag:
                yield el
            stack.extend(reversed(el))

    def iterdescendants(self, tag: str | None = None) -> Iterator[Element]:
        """The element's descendants (not itself), in document order (those named `tag` if given)."""
        for child in self:
            yield from child.iter(tag)

    def __repr__(self) -> str:
        return "<Element %s at line %s>" % (self.tag, self.sourceline)


class _TextElement(Element):
    __slots__ = ("text",)


def element_text(el: Element) -> str:
    """The element's own text (text and CDATA children, not its children's text), as roslaunch's _get_text."""
    if el.text is None:
        raise ValueError("the text of <%s> was not recorded" % el.tag)
    return "".join(el.text)


class XmlSyntaxError(Exception):
    """The document is not well-formed XML (expat's message, without its position) at `line`."""

    def __init__(self, message: str, line: int | None, column: int | None):
        super().__init__(message)
        self.message = message
        self.line = line
        self.column = column


_new = list.__new__


def _qualified(name: str) -> str:
    """expat's "uri local prefix" (or "uri local" for a default namespace) -> minidom's qualified name."""
    parts = name.split(_NS_SEP)
    if len(parts) == 3:
        return parts[2] + ":" + parts[1]
    return parts[-1]


def parse_xml(data: bytes, keeps_text: Callable[[str], bool] | None = None,
              watch: frozenset[str] = frozenset()) -> tuple[Element, list[Element]]:
    """(root element, the elements whose tag is in `watch`, in document order).

    Text is recorded for the elements for which `keeps_text(tag)` is true (all if None):
    a launch file only needs it for a few tags, and recording it costs a call per chunk.
    Raises XmlSyntaxError.
    """
    p = pyexpat.ParserCreate(None, _NS_SEP)
    p.buffer_text = True
    p.namespace_prefixes = True
    top = _new(Element)
    stack: list[Element] = [top]
    push = stack.append
    pop = stack.pop
    watched: list[Element] = []
    kinds = _TagKinds(keeps_text, watch)
    text_depth = 0  # > 0 while inside an element whose text is recorded

    def chars(data: str) -> None:
        t = stack[-1].text
        if t is not None:
            t.append(data)

    def start(tag: str, attrib: dict[str, str]) -> None:
        kind = kinds[tag]
        if kind:  # (rare) records its text, or is watched
            start_special(tag, attrib, kind)
            return
        el = _new(Element)
        el.tag = tag
        el.attrib = attrib
        el.sourceline = p.CurrentLineNumber
        stack[-1].append(el)
        push(el)

    def start_special(tag: str, attrib: dict[str, str], kind: int) -> None:
        nonlocal text_depth
        if kind & _KEEPS_TEXT:
            el = _new(_TextElement)
            el.text = []
            if text_depth == 0:
                p.CharacterDataHandler = chars
                p.EndElementHandler = end_text
            text_depth += 1
        else:
            el = _new(Element)
        el.tag = tag
        el.attrib = attrib
        el.sourceline = p.CurrentLineNumber
        stack[-1].append(el)
        push(el)
        if kind & _WATCHED:
            watched.append(el)

    def end(tag: str) -> None:
        pop()

    def end_text(tag: str) -> None:
        nonlocal text_depth
        if pop().text is not None:
            text_depth -= 1
            if text_depth == 0 and keeps_text is not None:
                p.CharacterDataHandler = None
                p.EndElementHandler = end

    def start_ns(tag: str, attrib: dict[str, str]) -> None:
        if _NS_SEP in tag:
            tag = _qualified(tag)
        if attrib and any(_NS_SEP in k for k in attrib):
            attrib = {(_qualified(k) if _NS_SEP in k else k): v for k, v in attrib.items()}
        start(tag, attrib)

    def namespace_declared(prefix: str | None, uri: str) -> None:
        # the rare document that uses namespaces: qualify names from here on
        p.StartElementHandler = start_ns
        p.StartNamespaceDeclHandler = None

    p.StartElementHandler = start
    p.EndElementHandler = end
    p.StartNamespaceDeclHandler = namespace_declared
    if _OLD_EXPAT:
        p.EntityDeclHandler = _refuse_nested_entities
    try:
        p.Parse(data, True)
    except pyexpat.ExpatError as e:
        raise XmlSyntaxError(pyexpat.ErrorString(e.code), e.lineno or None, e.offset) from None
    except _EntityRefused as e:
        raise XmlSyntaxError(str(e), p.CurrentLineNumber, None) from None
    except LookupError as e:
        # the XML declaration names an encoding Python does not know (expat asks Python's codecs)
        raise XmlSyntaxError(str(e), p.CurrentLineNumber, None) from None
    except ValueError as e:
        # or one expat cannot use ("multi-byte encodings are not supported"); only the declaration,
        # before any element, can cause that: a ValueError later is a bug of ours, not bad input
        if len(top) or len(stack) > 1:
            raise
        raise XmlSyntaxError(str(e), p.CurrentLineNumber, None) from None
    finally:
        # the parser holds the handlers, whose closures hold the parser (and the whole tree): a
        # cycle, which a load (the cyclic GC off) would keep until the end. Break it.
        p.StartElementHandler = p.EndElementHandler = p.CharacterDataHandler = None
        p.StartNamespaceDeclHandler = p.EntityDeclHandler = None
    if not top:
        raise XmlSyntaxError("no element found", p.CurrentLineNumber, None)
    return top[0], watched


_KEEPS_TEXT = 1
_WATCHED = 2


class _TagKinds(dict):
    """tag -> what parse_xml does with such an element beyond building it (_KEEPS_TEXT | _WATCHED), worked out
    once per tag name in a document."""

    def __init__(self, keeps_text: Callable[[str], bool] | None, watch: frozenset[str]):
        self.keeps_text = keeps_text
        self.watch = watch

    def __missing__(self, tag: str) -> int:
        kind = ((_KEEPS_TEXT if self.keeps_text is None or self.keeps_text(tag) else 0)
                | (_WATCHED if tag in self.watch else 0))
        self[tag] = kind
        return kind


class _EntityRefused(Exception):
    pass


def _refuse_nested_entities(name: str, is_parameter: int, value: str | None, *rest: object) -> None:
    # An expat older than 2.4 has no protection against exponential entity expansion; entities
    # defined through other entities are what makes it exponential, and no launch file needs them.
    if value is not None and "&" in value:
        raise _EntityRefused("entity '%s' is defined through other entities, which is refused" % name)


# ------------------------------------------------------------------------------------ launch files

# the tags whose text a launch file means (roslaunch matches a node's child tags case-insensitively)
_TEXT_TAGS = frozenset(("rosparam",))


def _launch_keeps_text(tag: str) -> bool:
    return tag.lower() in _TEXT_TAGS


class LaunchDocument:
    """A parsed launch file: its one `<launch>` element and the `<master>` tags inside it."""

    __slots__ = ("launch", "masters")

    def __init__(self, launch: Element, masters: list[Element]):
        self.launch = launch
        self.masters = masters


_LAUNCH_WATCH = frozenset(("launch", "master"))


def read_launch(filename: str, include_chain: tuple[tuple[str, int], ...] = ()) -> LaunchDocument:
    """The `<launch>` element of `filename` (which may be anywhere in the document, but only once)."""
    try:
        if filename == "-":  # roslaunch reads launch XML from stdin for '-'
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
        root, watched = parse_xml(data, _launch_keeps_text, _LAUNCH_WATCH)
    except XmlSyntaxError as e:
        msg = e.message if e.column is None else "%s (column %d)" % (e.message, e.column)
        raise LaunchError("Invalid roslaunch XML syntax: %s" % msg, filename, e.line, include_chain) from None
    launches = [e for e in watched if e.tag == "launch"]
    if len(launches) != 1:
        if not launches:
            raise LaunchError("Invalid roslaunch XML syntax: no root <launch> tag", filename,
                              root.sourceline, include_chain)
        raise LaunchError("Invalid roslaunch XML syntax: more than one <launch> tag in the document",
                          filename, launches[1].sourceline, include_chain)
    launch = launches[0]
    masters = [e for e in watched if e.tag == "master"]
    if masters and launch is not root:  # only those inside <launch> count (rare: a wrapped <launch>)
        inside = set(map(id, launch.iterdescendants("master")))
        masters = [m for m in masters if id(m) in inside]
    return LaunchDocument(launch, masters)
