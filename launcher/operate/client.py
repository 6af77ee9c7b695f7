"""Finding a running launch and calling its API: what every `launcher` subcommand shares.

A launch registers its API on the master as `/roslaunch/uris/host_<host>__<port>`
(as roslaunch does); `launcher` reads that key on ROS_MASTER_URI's master,
drops entries whose launch is gone, and uses the one left. `--uri` names a
launch's API directly; with several launches on one master, `--launch` picks
one by its key, URI or pid.

Exit statuses a script can rely on: 0 done; 1 the request failed (no node
matches, a node unknown); 2 bad usage; 3 no launch found or it does not
answer; 4 refused (the run's token is missing or unreadable).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from typing import Any

from launcher.net.xmlrpc import Fault, XmlRpcError, call_blocking

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_NO_LAUNCH, EXIT_REFUSED = 0, 1, 2, 3, 4
DEFAULT_MASTER_URI = "http://localhost:11311/"
PROBE_TIMEOUT_S = 2.0


class ToolError(Exception):
    """A message for the user and the exit status that goes with it."""

    def __init__(self, message: str, status: int = EXIT_FAILED):
        super().__init__(message)
        self.status = status


def add_launch_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--uri", help="the launch's XML-RPC URI (default: found through ROS_MASTER_URI)")
    parser.add_argument("--launch", metavar="KEY", help="which launch, when several use the master: its "
                        "/roslaunch/uris key, URI or pid")
    parser.add_argument("--master-uri", dest="master_uri", help="the master to look on (default: ROS_MASTER_URI)")


def launches(master_uri: str) -> dict[str, str]:
    """The launches registered on the master that still answer: key -> URI."""
    try:
        code, msg, value = call_blocking(master_uri, "getParam", "/launcher", "/roslaunch/uris",
                                         timeout=PROBE_TIMEOUT_S)
    except (OSError, XmlRpcError, Fault) as e:
        raise ToolError("cannot reach the master at %s: %s" % (master_uri, getattr(e, "strerror", None) or e),
                        EXIT_NO_LAUNCH) from None
    if code != 1 or not isinstance(value, dict):
        return {}
    if len(value) == 1:
        # the usual case: no probe (the call that follows says it if that launch is gone)
        return {k: v for k, v in value.items() if isinstance(v, str)}
    alive = {}
    for key, uri in sorted(value.items()):
        if not isinstance(uri, str):
            continue
        try:
            call_blocking(uri, "get_pid", timeout=PROBE_TIMEOUT_S)
        except (OSError, XmlRpcError, Fault):
            continue  # a launch that ended without removing its key (roslaunch never removes it)
        alive[key] = uri
    return alive


def find_launch(opts: argparse.Namespace, environ: dict[str, str] | None = None) -> str:
    """The URI of the launch the options name; ToolError when there is none or the choice is ambiguous."""
    if opts.uri:
        return opts.uri
    env = os.environ if environ is None else environ
    master_uri = opts.master_uri or env.get("ROS_MASTER_URI") or DEFAULT_MASTER_URI
    found = launches(master_uri)
    if not found:
        raise ToolError("no launch is running on the master at %s" % master_uri, EXIT_NO_LAUNCH)
    if opts.launch:
        chosen = [uri for key, uri in found.items() if opts.launch in (key, uri, key.rsplit("/", 1)[-1])]
        if not chosen and opts.launch.isdigit():
            chosen = [uri for uri in found.values() if _pid(uri) == int(opts.launch)]
        if len(chosen) != 1:
            raise ToolError("no launch [%s] on the master at %s; running:\n%s"
                            % (opts.launch, master_uri, _listing(found)), EXIT_USAGE)
        return chosen[0]
    if len(found) > 1:
        if sys.stdin.isatty() and sys.stderr.isatty():
            return _ask(found)
        raise ToolError("%d launches use the master at %s; choose one with --launch KEY:\n%s"
                        % (len(found), master_uri, _listing(found)), EXIT_USAGE)
    return next(iter(found.values()))


def _ask(found: dict[str, str]) -> str:
    """At a terminal: list the launches and ask which (a script gets exit status 2 instead)."""
    uris = list(found.values())
    sys.stderr.write("several launches use this master:\n%s\n" % "\n".join(
        "  %d) %s" % (i + 1, line.strip()) for i, line in enumerate(_listing(found).split("\n"))))
    sys.stderr.write("which one? [1-%d] " % len(uris))
    sys.stderr.flush()
    answer = sys.stdin.readline().strip()
    if not answer.isdigit() or not 1 <= int(answer) <= len(uris):
        raise ToolError("no launch chosen (next time, --launch KEY picks one)", EXIT_USAGE)
    return uris[int(answer) - 1]


def _pid(uri: str) -> int | None:
    try:
        return call_blocking(uri, "get_pid", timeout=PROBE_TIMEOUT_S)[2]
    except (OSError, XmlRpcError, Fault, IndexError, TypeError):
        return None


def _listing(found: dict[str, str]) -> str:
    return "\n".join("  %s  %s  (pid %s)" % (key.rsplit("/", 1)[-1], uri, _pid(uri)) for key, uri in found.items())


def call(uri: str, method: str, *params: Any, timeout: float = 10.0) -> Any:
    """Call the launch; ToolError for a launch that is gone, or one that is not ours (plain roslaunch)."""
    try:
        return call_blocking(uri, method, *params, timeout=timeout)
    except Fault as e:
        if "is not supported" in e.faultString:
            raise ToolError("the launch at %s does not serve %s (is it roslaunch rather than `launch`?)"
                            % (uri, method), EXIT_FAILED) from None
        raise
    except (OSError, XmlRpcError) as e:
        raise ToolError("the launch at %s does not answer: %s" % (uri, getattr(e, "strerror", None) or e),
                        EXIT_NO_LAUNCH) from None


def status_text(uri: str) -> str:
    """The run and its nodes as the launch sends them: one JSON object (launcher_status)."""
    code, msg, text = call(uri, "launcher_status")
    if code != 1:
        raise ToolError("status: %s" % msg)
    return text


def status(uri: str) -> dict[str, Any]:
    """The run and its nodes (launcher_status)."""
    return json.loads(status_text(uri))


def find_node(info: dict[str, Any], name: str) -> dict[str, Any]:
    """A node of the status by node name (leading / optional) or process name; ToolError naming it."""
    wanted = name if name.startswith("/") else "/" + name
    for node in info["nodes"]:
        if node["name"] == wanted or node.get("process") == name:
            return node
    raise ToolError("unknown node [%s]: not part of the launch at %s" % (name, info.get("uri", "?")))


def run_tool(main_body: Any, argv: list[str]) -> int:
    """Run a subcommand body: ToolError becomes its message on stderr and its status; Ctrl-C ends quietly."""
    try:
        return main_body(argv)
    except ToolError as e:
        print("launcher: %s" % e, file=sys.stderr)
        return e.status
    except KeyboardInterrupt:
        return EXIT_OK
    except BrokenPipeError:
        return EXIT_OK


def complete_node_names(environ: dict[str, str]) -> list[str]:
    """The node names of the one launch on ROS_MASTER_URI, for shell completion (none when it is not clear which)."""
    try:
        master_uri = environ.get("ROS_MASTER_URI") or DEFAULT_MASTER_URI
        found = launches(master_uri)
        if len(found) != 1:
            return []
        return [node["name"] for node in status(next(iter(found.values())))["nodes"]]
    except (ToolError, OSError, ValueError, KeyError, TypeError):
        return []
