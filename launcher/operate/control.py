"""`launcher start|stop|restart PATTERN`: steer the nodes a node name, glob or regex selects (as rosmon).

Needs the run's token (launcher.model.token), read from the file the
launch wrote in its log directory: only the user who started the launch can.
Prints each node it changed; no node matching is an error naming the pattern,
and so is each node that could not be changed (exit status 1).
"""

from __future__ import annotations

import argparse
import re
import sys

from launcher.net.xmlrpc_codec import Fault
from launcher.operate import client
from launcher.model import token as run_token
from launcher.model.suggest import did_you_mean

# a stop waits for the node's SIGINT -> SIGTERM -> SIGKILL escalation (15 s + 2 s by default)
CONTROL_TIMEOUT_S = 600.0
PLAIN_NAME = re.compile(r"[\w/~]+")  # a node name as a user writes it, neither glob nor regular expression


def _parser(verb: str) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="launcher %s" % verb, description="%s the nodes PATTERN selects: a node "
                                "name (/ns/name, or name), a glob (/ns/*) or a regular expression" % verb)
    p.add_argument("pattern", metavar="PATTERN")
    p.add_argument("--token-file", dest="token_file", help="the run's token file (default: the one the launch "
                   "wrote in its log directory)")
    client.add_launch_options(p)
    return p


def read_token(opts: argparse.Namespace, uri: str, info: dict, verb: str) -> str:
    """The run's token (--token-file, else the file the launch names in its status); refused in words."""
    path = opts.token_file or info.get("token_file") or ""
    if not path:
        raise client.ToolError("the launch at %s has no token file: %s is refused" % (uri, verb),
                               client.EXIT_REFUSED)
    try:
        return run_token.read(path)
    except OSError as e:
        raise client.ToolError("cannot read the run's token [%s]: %s (only the user who started the launch may "
                               "start, stop, restart or reload its nodes)" % (path, e.strerror),
                               client.EXIT_REFUSED) from None


def _control(verb: str, argv: list[str]) -> int:
    opts = _parser(verb).parse_args(argv)
    uri = client.find_launch(opts)
    info = client.status(uri)
    token = read_token(opts, uri, info, verb)
    try:
        code, msg, names = client.call(uri, "%s_nodes" % verb, token, opts.pattern, timeout=CONTROL_TIMEOUT_S)
    except Fault as e:
        status = client.EXIT_REFUSED if e.faultCode == run_token.REFUSED else client.EXIT_FAILED
        raise client.ToolError(e.faultString, status) from None
    if code not in (0, 1):
        # a name that selects nothing is usually one almost right (`talker` for /r2/talker); a glob or a
        # regular expression gets no guess
        hint = did_you_mean(opts.pattern, [n["name"] for n in info["nodes"]]) if PLAIN_NAME.fullmatch(
            opts.pattern) else ""
        raise client.ToolError(msg + ("; " + hint if hint else ""))
    past = {"start": "started", "stop": "stopped", "restart": "restarted"}[verb]
    for name in names:
        sys.stdout.write("%s %s\n" % (past, name))
    if code == 0:  # some nodes could not be (a node on another machine whose roslaunch child cannot stop it)
        sys.stdout.flush()
        raise client.ToolError(msg)
    return client.EXIT_OK


def start(argv: list[str]) -> int:
    return client.run_tool(lambda a: _control("start", a), argv)


def stop(argv: list[str]) -> int:
    return client.run_tool(lambda a: _control("stop", a), argv)


def restart(argv: list[str]) -> int:
    return client.run_tool(lambda a: _control("restart", a), argv)


# (offered by `launcher __complete` for this subcommand's node argument)
complete_node_names = client.complete_node_names
