"""The launch XML a parent sends a child for one machine's nodes (roslaunch's `Node.to_remote_xml`)."""

from __future__ import annotations

from typing import Iterable

from launcher.model.config import Node


def _attr(value: object) -> str:
    """An attribute value in double quotes. (Not xml.sax.saxutils.escape: it imports urllib.request,
    ~25 ms of every start of the parent and of our child, for four replacements.)"""
    return (str(value).replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")
            .replace('"', "&quot;"))


def node_xml(node: Node) -> str:
    """One `<node>` without parameters or `machine` (the parent sets parameters; the child runs it locally).

    Values are written as roslaunch writes them (Python's str of the value: `True`, `0.0`), which both
    roslaunch's loader and ours read back.
    """
    attrs = [("pkg", node.package), ("type", node.type), ("ns", node.namespace), ("args", node.args),
             ("output", node.output), ("cwd", node.cwd), ("respawn", node.respawn),
             ("respawn_delay", node.respawn_delay), ("name", node.name), ("launch-prefix", node.launch_prefix),
             ("required", node.required)]
    text = "<node %s>\n" % " ".join('%s="%s"' % (k, _attr(v)) for k, v in attrs if v is not None)
    text += "".join('  <remap from="%s" to="%s" />\n' % (_attr(a), _attr(b)) for a, b in node.remap_args)
    text += "".join('  <env name="%s" value="%s" />\n' % (_attr(a), _attr(b)) for a, b in node.env_args)
    return text + "</node>"


def remote_launch_xml(nodes: Iterable[Node]) -> str:
    body = "\n".join(node_xml(n) for n in nodes)
    return '<?xml version="1.0" encoding="utf-8"?>\n<launch>\n%s</launch>' % body
