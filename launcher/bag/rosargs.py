"""A bag node's ROS arguments (`__name:=`, `__ns:=`, `from:=to`), split from its own options as roscpp does, and its
wait for the master."""

from __future__ import annotations

import asyncio
import os
import sys
from collections.abc import Mapping
from typing import NamedTuple

from launcher.model import names
from launcher.net.xmlrpc import call

# roscpp's special keys: each read here or, for the log file and addresses, harmless to a bag node.
_SPECIAL = ("__name", "__ns", "__master", "__log", "__ip", "__hostname")


class RosArgs(NamedTuple):
    args: list[str]               # the command's own options and operands
    name: str                     # the node's resolved name
    namespace: str                # the node's namespace, ending in '/'
    master_uri: str
    remaps: dict[str, str]        # resolved from -> resolved to
    host: str | None              # __ip / __hostname


def split(argv: list[str], default_name: str, environ: Mapping[str, str] | None = None) -> RosArgs:
    """The node's identity and remaps from `argv` and the environment; `default_name` is made anonymous."""
    env = os.environ if environ is None else environ
    special: dict[str, str] = {}
    pairs: list[tuple[str, str]] = []
    args: list[str] = []
    for token in argv:
        key, sep, value = token.partition(":=")
        if not sep or not key or token.startswith("-"):
            args.append(token)
        elif key in _SPECIAL:
            special[key] = value
        elif key.startswith("_") and not key.startswith("__"):
            args.append(token)  # a private parameter: no bag option takes one; main refuses it by name
        else:
            pairs.append((key, value))
    ns = names.make_global_ns(special.get("__ns") or env.get("ROS_NAMESPACE") or "/")
    base = special.get("__name") or names.anonymous_name(default_name)
    name = names.canonicalize_name(names.ns_join(ns, base))
    remaps = {names.resolve_name(a, name): names.resolve_name(b, name) for a, b in pairs}
    master = special.get("__master") or env.get("ROS_MASTER_URI") or "http://localhost:11311/"
    host = special.get("__hostname") or special.get("__ip")
    return RosArgs(args, name, ns, master, remaps, host)


async def wait_for_master(uri: str, caller_id: str, period: float = 0.5) -> None:
    """Return once the master at `uri` answers; as roscpp nodes do, wait for it (saying so once)."""
    said = False
    while True:
        try:
            await call(uri, "getPid", caller_id, timeout=5.0)
            return
        except (OSError, asyncio.TimeoutError, ValueError) as exc:
            if not said:
                print("[ WARN] waiting for the ROS master at %s (%s)" % (uri, exc), file=sys.stderr, flush=True)
                said = True
        await asyncio.sleep(period)
