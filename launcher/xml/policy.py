"""The supervision extension attributes (`respawn_on`, `memory_limit`, ... and rosmon's spellings): names and values.

They are accepted on `<node>`, and on `<launch>`, `<group>` and `<include>` as
defaults for the nodes inside (the nearest one wins, attribute by attribute).
This module turns an element's attributes (already substituted) into a dict of
`NodePolicy` field -> value; the loader keeps the scoped dicts and builds
`Node.policy` from them. A bad value is a `PolicyError` whose message the loader
prefixes with file and line.

Units: times are seconds (a decimal number); sizes are bytes as `launcher.model.units`
reads them (`500MB`, `1.5GiB`, `200k`), as `--log-max-size` is. CPU is in cores
(`0.5` = half of one core; rosmon's `rosmon-cpu-limit` has the same unit).
"""

from __future__ import annotations

import math
import re

from launcher.model import units
from launcher.model.names import is_legal_name

TYPE_CHECKING = False  # (typing.TYPE_CHECKING without importing typing: ~3 ms a start; the annotations are text)
if TYPE_CHECKING:
    from typing import Any, Callable


class PolicyError(ValueError):
    """A bad extension attribute value; the loader adds file and line."""


WAIT_KINDS = ("topic", "service", "param", "node", "output")

def _size(text: str) -> int:
    """A size greater than zero, in bytes (`launcher.model.units.parse_size`)."""
    try:
        size = units.parse_size(text)
    except ValueError:
        raise PolicyError(units.SIZE_EXPECTED) from None
    if size <= 0:
        raise PolicyError("a size greater than zero")
    return size


def _number(text: str, what: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise PolicyError(what) from None
    if not math.isfinite(value):
        raise PolicyError(what)
    return value


def _seconds(positive: bool) -> Callable[[str], float]:
    what = "a number of seconds greater than zero" if positive else "a number of seconds (0 or more)"

    def parse(text: str) -> float:
        value = _number(text, what)
        if value < 0 or (positive and value == 0):
            raise PolicyError(what)
        return value
    return parse


def _backoff(text: str) -> float:
    value = _number(text, "a factor of 1 or more")
    if value < 1:
        raise PolicyError("a factor of 1 or more")
    return value


def _cores(text: str) -> float:
    value = _number(text, "a number of cores greater than zero (0.5 = half of one core)")
    if value <= 0:
        raise PolicyError("a number of cores greater than zero (0.5 = half of one core)")
    return value


def _count(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise PolicyError("a whole number (0 or more)") from None
    if value < 0:
        raise PolicyError("a whole number (0 or more)")
    return value


def _exit_codes(text: str) -> frozenset[int]:
    codes = set()
    for word in text.replace(",", " ").split():
        try:
            code = int(word)
        except ValueError:
            code = -1
        if not 0 <= code <= 255:
            raise PolicyError("exit codes from 0 to 255, separated by spaces")
        codes.add(code)
    if not codes:
        raise PolicyError("exit codes from 0 to 255, separated by spaces")
    return frozenset(codes)


def _bool(text: str) -> bool:
    low = text.lower()
    if low in ("true", "1"):
        return True
    if low in ("false", "0"):
        return False
    raise PolicyError("true or false")


def _choice(*choices: str) -> Callable[[str], str]:
    def parse(text: str) -> str:
        if text not in choices:
            raise PolicyError(" or ".join(choices))
        return text
    return parse


# a wait_for item: unquoted runs and quoted parts ('...' or "..."), up to a space outside quotes; group 1: a
# quote left open. (Patterns, compiled by `re` at their first use: every launch imports this module, few
# use wait_for.)
_WAIT_ITEM = r"""(?:[^\s'"]+|'[^']*'|"[^"]*")+|(['"].*)"""
_QUOTED = r"'([^']*)'|\"([^\"]*)\""


def parse_wait_for(text: str) -> tuple[tuple[str, str], ...]:
    """`topic:/scan service:static_map` -> (("topic", "/scan"), ("service", "static_map")); names as written.

    `output:NODE:PATTERN`: a line of NODE's output matches PATTERN (a Python regular expression, searched
    in each line); the item is ("output", "NODE:PATTERN"). Items are separated by spaces; a part in single or
    double quotes keeps its spaces (`output:driver:'ready to go'`). There are no escapes: a backslash is
    the pattern's (`output:driver:'port \\d+'`)."""
    words = []
    for m in re.finditer(_WAIT_ITEM, text, re.S):
        if m.group(1) is not None:
            raise PolicyError("kind:name items, a pattern with spaces in quotes (an unclosed quote: %s)"
                              % m.group(1))
        words.append(re.sub(_QUOTED, lambda q: q.group(1) if q.group(1) is not None else q.group(2), m.group(0)))
    out = []
    for word in words:
        kind, sep, name = word.partition(":")
        if not sep or kind not in WAIT_KINDS:
            raise PolicyError("kind:name items with a kind of %s (got '%s')" % (", ".join(WAIT_KINDS), word))
        if kind == "output":
            name = _output_condition(word, name)
        elif not name or not is_legal_name(name):
            raise PolicyError("kind:name items with a valid ROS name (got '%s')" % word)
        out.append((kind, name))
    if not out:
        raise PolicyError("kind:name items, e.g. topic:/scan service:/static_map")
    return tuple(out)


def _output_condition(word: str, rest: str) -> str:
    node, sep, pattern = rest.partition(":")
    if not sep or not node or not is_legal_name(node) or not pattern:
        raise PolicyError("output:NODE:PATTERN with a node name and a pattern (got '%s')" % word)
    try:
        re.compile(pattern)
    except re.error as e:
        raise PolicyError("output:NODE:PATTERN with a Python regular expression (got '%s': %s)" % (word, e)) \
            from None
    return rest


def _topics(text: str) -> tuple[str, ...]:
    """`/camera/image camera_info` -> the names as written (resolved later, as the node resolves them)."""
    names = tuple(text.split())
    for name in names:
        if not is_legal_name(name):
            raise PolicyError("topic names separated by spaces (got '%s')" % name)
    return names


def _node_name(text: str) -> str:
    if len(text.split()) != 1 or not is_legal_name(text):
        raise PolicyError("one node name")
    return text


def _rate(text: str) -> float:
    value = _number(text, "a rate in Hz greater than zero")
    if value <= 0:
        raise PolicyError("a rate in Hz greater than zero")
    return value


# attribute -> (NodePolicy field, parser of its substituted text)
POLICY_ATTRS: dict[str, tuple[str, Callable[[str], Any]]] = {
    "respawn_on": ("respawn_on", _choice("always", "failure")),
    "success_exit_codes": ("success_exit_codes", _exit_codes),
    "respawn_backoff": ("respawn_backoff", _backoff),
    "respawn_delay_max": ("respawn_delay_max", _seconds(positive=False)),
    "respawn_min_uptime": ("respawn_min_uptime", _seconds(positive=False)),
    "respawn_max_retries": ("respawn_max_retries", _count),
    "on_fatal": ("on_fatal", _choice("none", "shutdown")),
    "restart_warn_threshold": ("restart_warn_threshold", _count),
    "sigint_timeout": ("sigint_timeout", _seconds(positive=True)),
    "sigterm_timeout": ("sigterm_timeout", _seconds(positive=True)),
    "spawn_delay": ("spawn_delay", _seconds(positive=False)),
    "wait_for": ("wait_for", parse_wait_for),
    "wait_timeout": ("wait_timeout", _seconds(positive=True)),
    "hang_timeout": ("hang_timeout", _seconds(positive=True)),
    "memory_limit": ("memory_limit", _size),
    "cpu_limit": ("cpu_limit", _cores),
    "on_limit": ("on_limit", _choice("warn", "restart")),
    "enable_coredumps": ("enable_coredumps", _bool),
    "log_max_size": ("log_max_size", _size),
    "log_backups": ("log_backups", _count),
    "watch_topic": ("watch_topics", _topics),
    "watch_timeout": ("watch_timeout", _seconds(positive=True)),
    "watch_min_rate": ("watch_min_rate", _rate),
    "watch_window": ("watch_window", _seconds(positive=True)),
    "on_stall": ("on_stall", _choice("restart", "warn")),
    "bind_to": ("bind_to", _node_name),
    # registers="false": a program that is no ROS node (a shell script, a tool that never calls the master) is up
    # once it runs; any other node once it has registered (systemd's READY=1 waits for that, up to --ready-timeout)
    "registers": ("registers", _bool),
    # rosmon's spellings. rosmon stops a node with SIGINT, then SIGKILL after its stop timeout: that is
    # our sigint_timeout (the SIGTERM step after it stays the default).
    "rosmon-stop-timeout": ("sigint_timeout", _seconds(positive=True)),
    "rosmon-memory-limit": ("memory_limit", _size),
    "rosmon-cpu-limit": ("cpu_limit", _cores),
    "rosmon-spawn-delay": ("spawn_delay", _seconds(positive=False)),
    "rosmon-restart-warn-threshold": ("restart_warn_threshold", _count),
    "enable-coredumps": ("enable_coredumps", _bool),
}
POLICY_ATTR_NAMES = frozenset(POLICY_ATTRS)
# the attributes that only matter for a node that respawns (a <node> that sets one without
# respawn="true" is warned about, as roslaunch does for respawn_delay)
RESPAWN_ONLY = frozenset(("respawn_on", "success_exit_codes", "respawn_backoff", "respawn_delay_max",
                          "respawn_min_uptime", "respawn_max_retries", "on_fatal", "restart_warn_threshold",
                          "rosmon-restart-warn-threshold"))


def read_policy(attrib: Any, substitute: Callable[[str], str]) -> dict[str, Any]:
    """The policy fields an element's attributes set ({} if none). `substitute` resolves `$(...)`.

    Raises PolicyError naming the attribute; two spellings of one field on one element are an error.
    """
    fields: dict[str, Any] = {}
    given: dict[str, str] = {}
    for attr, text in attrib.items():
        entry = POLICY_ATTRS.get(attr)
        if entry is None:
            continue
        field, parse = entry
        if field in given:
            raise PolicyError("'%s' and '%s' both set %s: use one" % (given[field], attr, field))
        given[field] = attr
        value = substitute(text) if "$" in text else text
        if not value.strip():
            raise PolicyError("value for %s must be non-empty" % attr)
        try:
            fields[field] = parse(value.strip())
        except PolicyError as e:
            raise PolicyError("invalid value for %s: '%s' (expected %s)" % (attr, value, e)) from None
    return fields


def resolve_wait_names(wait_for: tuple[tuple[str, str], ...], namespace: str,
                       node_name: str) -> tuple[tuple[str, str], ...]:
    """wait_for names resolved as the node itself would: relative to its namespace, `~x` under its name (an
    output condition's node name, its pattern kept)."""
    out = []
    for kind, name in wait_for:
        pattern = ""
        if kind == "output":
            name, _, pattern = name.partition(":")
            pattern = ":" + pattern
        if name.startswith("~"):
            name = node_name.rstrip("/") + "/" + name[1:].lstrip("/")
        elif not name.startswith("/"):
            name = namespace.rstrip("/") + "/" + name
        out.append((kind, name + pattern))
    return tuple(out)


def resolve_watch_topics(topics: tuple[str, ...], namespace: str, node_name: str,
                         remaps: tuple[tuple[str, str], ...]) -> tuple[str, ...]:
    """The watched topics as the node publishes them: resolved in its namespace (`~x` under its name), then
    through its own remaps (`from:=to`, both resolved the same way), as the node's client library does."""
    def resolve(name: str) -> str:
        if name.startswith("~"):
            return node_name.rstrip("/") + "/" + name[1:].lstrip("/")
        return name if name.startswith("/") else namespace.rstrip("/") + "/" + name
    mapping = {resolve(a): resolve(b) for a, b in remaps}
    return tuple(mapping.get(resolve(t), resolve(t)) for t in topics)
