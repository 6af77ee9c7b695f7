"""`launcher reload [--dry-run] [--json] [name:=value ...]`: a running launch reads its files again and applies only the difference (issue 23).

The launch does the work (run/reload.py): it reads its own files, in its own
environment, with the args it was started with (those given here replace
theirs), and answers with the difference: each parameter to set or delete,
each node to stop, restart or start and why, each node whose supervision
settings alone change. `--dry-run` prints it and changes nothing; without it
the launch applies exactly that. Needs the run's token, like `launcher stop`.
A launch file that does not load changes nothing: its error (file:line) is
printed and the exit status is 1.
"""

from __future__ import annotations

import argparse
import json
import sys

from launcher.model import token as run_token
from launcher.net.xmlrpc_codec import Fault
from launcher.operate import client
from launcher.operate.control import CONTROL_TIMEOUT_S, read_token


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="launcher reload", description="read the running launch's files again and "
                                "apply only the difference: parameters set and deleted, changed nodes restarted, "
                                "new ones started, removed ones stopped")
    p.add_argument("args", nargs="*", metavar="name:=value", help="launch args that replace the run's")
    p.add_argument("--dry-run", action="store_true", help="print the difference; change nothing")
    p.add_argument("--json", action="store_true", help="print the launch's answer as JSON")
    p.add_argument("--token-file", dest="token_file", help="the run's token file (default: the one the launch "
                   "wrote in its log directory)")
    client.add_launch_options(p)
    return p


def main(argv: list[str]) -> int:
    return client.run_tool(_reload, argv)


def _reload(argv: list[str]) -> int:
    opts = _parser().parse_args(argv)
    bad = [a for a in opts.args if ":=" not in a]
    if bad:
        raise client.ToolError("reload takes name:=value args only, not %s" % ", ".join(bad), client.EXIT_USAGE)
    uri = client.find_launch(opts)
    token = read_token(opts, uri, client.status(uri), "reload")
    try:
        code, msg, text = client.call(uri, "launcher_reload", token, opts.args, opts.dry_run,
                                      timeout=CONTROL_TIMEOUT_S)
    except Fault as e:
        status = client.EXIT_REFUSED if e.faultCode == run_token.REFUSED else client.EXIT_FAILED
        raise client.ToolError(e.faultString, status) from None
    answer = json.loads(text)
    if opts.json:
        sys.stdout.write(json.dumps(answer, indent=2, default=str) + "\n")
        return client.EXIT_OK if code == 1 else client.EXIT_FAILED
    for warning in answer.get("warnings", ()):
        sys.stderr.write("WARNING: %s\n" % warning)
    for line in answer.get("lines", ()):
        sys.stdout.write(("would %s\n" if opts.dry_run else "%s\n") % line)
    if code != 1:
        sys.stdout.flush()
        raise client.ToolError("reload refused, nothing changed: %s" % msg)
    if not answer.get("lines"):
        sys.stdout.write("nothing changed\n")
    return client.EXIT_OK
