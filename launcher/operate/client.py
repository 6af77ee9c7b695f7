"""Finding a running launch and calling its API: what every `launcher` subcommand shares.

A launch registers its API on the master as `/roslaunch/uris/host_<host>__<port>`
(as roslaunch does, and so does roscore, a roslaunch run); `launcher` reads
that key on ROS_MASTER_URI's master. One entry is used as it is. Of several,
each is probed with `launcher_status` and a short timeout: an entry whose
launch is gone (roslaunch never removes its key; a launch of ours killed with
`kill -9` cannot) or does not answer, and one that answers with a fault
(roslaunch's or roscore's server), is no candidate; of ours, those that run
nodes are (one still starting, then a bare `launch --core`, only when no other is).
Only two candidates make `launcher` ask. `--uri` names a launch's API
directly; `--launch` picks one by its key, URI or pid.

Exit statuses a script can rely on: 0 done; 1 the request failed (no node
matches, a node unknown); 2 bad usage; 3 no launch of ours found, or it does
not answer; 4 refused (the run's token is missing or unreadable).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import threading
import time
from typing import Any, Callable, Mapping, NamedTuple

from launcher.net.xmlrpc import Fault, XmlRpcError, call_blocking
from launcher.model.suggest import did_you_mean
from launcher.operate.errors import (EXIT_FAILED, EXIT_NO_LAUNCH, EXIT_OK, EXIT_REFUSED, EXIT_USAGE,  # noqa: F401
                                     NoAnswer, NotOurs, ToolError, slow)

DEFAULT_MASTER_URI = "http://localhost:11311/"
PROBE_TIMEOUT_S = 2.0
# A launch of ours answers launcher_status at once (a cached text); one that does not, within this, is wedged
# or gone, and is no candidate (with several launches registered, each is probed so).
LAUNCH_PROBE_TIMEOUT_S = 1.0


def add_launch_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--uri", help="the launch's XML-RPC URI (default: found through ROS_MASTER_URI)")
    parser.add_argument("--launch", metavar="KEY", help="which launch, when several use the master: its "
                        "/roslaunch/uris key, URI or pid")
    parser.add_argument("--master-uri", dest="master_uri", help="the master to look on (default: ROS_MASTER_URI)")


class Registered(NamedTuple):
    """A launch registered on the master, as its probe found it."""

    key: str  # its /roslaunch/uris key
    uri: str
    kind: str  # OURS, ROSLAUNCH (it answers, but not launcher_status: Debian's roslaunch or roscore) or GONE
    info: dict[str, Any]  # its launcher_status (ours), else {}


OURS, ROSLAUNCH, GONE = "ours", "roslaunch", "gone"


def _registered(master_uri: str) -> dict[str, str]:
    """The master's /roslaunch/uris: key -> URI."""
    try:
        code, msg, value = call_blocking(master_uri, "getParam", "/launcher", "/roslaunch/uris",
                                         timeout=PROBE_TIMEOUT_S)
    except (OSError, XmlRpcError, Fault) as e:
        raise ToolError("cannot reach the master at %s: %s" % (master_uri, getattr(e, "strerror", None) or e),
                        EXIT_NO_LAUNCH) from None
    if code != 1 or not isinstance(value, dict):
        return {}
    return {k: v for k, v in value.items() if isinstance(v, str)}


def _probe(key: str, uri: str) -> Registered:
    """Ask a registered launch for launcher_status, which roslaunch's server answers with a fault."""
    try:
        code, _msg, text = call_blocking(uri, "launcher_status", timeout=LAUNCH_PROBE_TIMEOUT_S)
    except Fault:
        return Registered(key, uri, ROSLAUNCH, {})
    except (OSError, XmlRpcError, ValueError, TypeError):
        # (a launch that ended without removing its key: roslaunch never removes it, a `kill -9` of ours
        # cannot; or one that does not answer within the probe's time)
        return Registered(key, uri, GONE, {})
    try:
        info = json.loads(text) if code == 1 else {}
    except (TypeError, ValueError):
        info = {}
    return Registered(key, uri, OURS, info if isinstance(info, dict) else {})


def survey(registered: dict[str, str]) -> list[Registered]:
    """Every launch registered on the master (key -> URI), each probed (all at once: a stale key costs one
    timeout)."""
    entries = sorted(registered.items())
    found: list[Registered | None] = [None] * len(entries)

    def probe(i: int, key: str, uri: str) -> None:
        found[i] = _probe(key, uri)

    threads = [threading.Thread(target=probe, args=(i, key, uri), daemon=True)
               for i, (key, uri) in enumerate(entries)]
    for t in threads:
        t.start()
    deadline = time.monotonic() + 2 * LAUNCH_PROBE_TIMEOUT_S
    for t in threads:
        t.join(max(0.0, deadline - time.monotonic()))
    return [r if r is not None else Registered(key, uri, GONE, {}) for r, (key, uri) in zip(found, entries)]


def candidates(found: list[Registered]) -> list[Registered]:
    """The launches an operator can mean: ours that run nodes; else ours of a launch file that has none yet (in
    its first moments, beside a `launch --core`); else ours with neither (a bare `launch --core`)."""
    ours = [r for r in found if r.kind == OURS]
    return [r for r in ours if r.info.get("nodes")] or [r for r in ours if r.info.get("launch_files")] or ours


def launches(master_uri: str) -> dict[str, str]:
    """The launches of ours on the master an operator can mean (see `candidates`): key -> URI."""
    registered = _registered(master_uri)
    if len(registered) == 1:
        # the usual case: no probe (the call that follows says it if that launch is gone or is not ours)
        return registered
    return {r.key: r.uri for r in candidates(survey(registered))}


def find_launch(opts: argparse.Namespace, environ: dict[str, str] | None = None) -> str:
    """The URI of the launch the options name; ToolError when there is none or the choice is ambiguous."""
    if opts.uri:
        return opts.uri
    env = os.environ if environ is None else environ
    master_uri = opts.master_uri or env.get("ROS_MASTER_URI") or DEFAULT_MASTER_URI
    registered = _registered(master_uri)
    if not registered:
        raise ToolError("no launch is running on the master at %s" % master_uri, EXIT_NO_LAUNCH)
    if len(registered) == 1 and not opts.launch:
        return next(iter(registered.values()))  # (no probe: the call that follows says what is wrong with it)
    found = survey(registered)
    if opts.launch:
        answering = [r for r in found if r.kind != GONE]
        chosen = [r for r in answering if opts.launch in (r.key, r.uri, r.key.rsplit("/", 1)[-1])]
        if not chosen and opts.launch.isdigit():
            chosen = [r for r in answering if _pid(r) == int(opts.launch)]
        if len(chosen) != 1:
            raise ToolError("no launch [%s] on the master at %s; running:\n%s"
                            % (opts.launch, master_uri, _listing(answering)), EXIT_USAGE)
        return chosen[0].uri
    choice = candidates(found)
    if not choice:
        others = [r for r in found if r.kind == ROSLAUNCH]
        raise ToolError("no launch of `launch` is running on the master at %s%s" % (master_uri, (
            " (roslaunch's, which `launcher` cannot read: %s)" % ", ".join(r.uri for r in others)) if others else ""),
            EXIT_NO_LAUNCH)
    if len(choice) > 1:
        if sys.stdin.isatty() and sys.stderr.isatty():
            return _ask(choice)
        raise ToolError("%d launches use the master at %s; choose one with --launch KEY:\n%s"
                        % (len(choice), master_uri, _listing(choice)), EXIT_USAGE)
    return choice[0].uri


def _ask(found: list[Registered]) -> str:
    """At a terminal: list the launches and ask which (a script gets exit status 2 instead)."""
    sys.stderr.write("several launches use this master:\n%s\n" % "\n".join(
        "  %d) %s" % (i + 1, line.strip()) for i, line in enumerate(_listing(found).split("\n"))))
    sys.stderr.write("which one? [1-%d] " % len(found))
    sys.stderr.flush()
    answer = sys.stdin.readline().strip()
    if not answer.isdigit() or not 1 <= int(answer) <= len(found):
        raise ToolError("no launch chosen (next time, --launch KEY picks one)", EXIT_USAGE)
    return found[int(answer) - 1].uri


def _pid(r: Registered) -> int | None:
    if r.info.get("pid") is not None:
        return r.info["pid"]
    try:
        return call_blocking(r.uri, "get_pid", timeout=PROBE_TIMEOUT_S)[2]
    except (OSError, XmlRpcError, Fault, IndexError, TypeError):
        return None


def _listing(found: list[Registered]) -> str:
    lines = []
    for r in found:
        line = "  %s  %s  (pid %s)" % (r.key.rsplit("/", 1)[-1], r.uri, _pid(r))
        if r.kind == OURS:
            nodes = len(r.info.get("nodes") or ())
            line += "  %s, %d node%s" % (" ".join(os.path.basename(f) for f in r.info.get("launch_files") or ())
                                         or "no launch file", nodes, "" if nodes == 1 else "s")
        elif r.kind == ROSLAUNCH:
            line += "  roslaunch's"
        lines.append(line)
    return "\n".join(lines)


def call(uri: str, method: str, *params: Any, timeout: float = 10.0) -> Any:
    """Call the launch; ToolError for a launch that is gone, or one that is not ours (plain roslaunch)."""
    try:
        return call_blocking(uri, method, *params, timeout=timeout)
    except Fault as e:
        if "is not supported" in e.faultString:  # (no launch of ours: status 3, as for none at all)
            raise ToolError("the launch at %s is roslaunch's or roscore's, not one of `launch`: it does not serve %s"
                            % (uri, method), EXIT_NO_LAUNCH) from None
        raise
    except (OSError, XmlRpcError) as e:
        why = "the launch at %s does not answer: %s" % (uri, getattr(e, "strerror", None) or e)
        if slow(e):
            raise NoAnswer(why) from None
        raise ToolError(why, EXIT_NO_LAUNCH) from None


def status_text(uri: str) -> str:
    """The run and its nodes as the launch sends them: one JSON object (launcher_status)."""
    code, msg, text = call(uri, "launcher_status")
    if code != 1:
        raise ToolError("status: %s" % msg)
    return text


def status(uri: str) -> dict[str, Any]:
    """The run and its nodes (launcher_status)."""
    return json.loads(status_text(uri))


# A long poll of the change stream waits this long on the launch's side (the server's cap is longer).
CHANGES_WAIT_S = 1.0
ANSWER_MARGIN_S = 10.0  # a long poll's answer is awaited this long past its wait, before the call counts as slow
LAST_SEQ = (1 << 31) - 1  # (since the last change: the answer is the stream's number now, and no change)


def changes(uri: str, since: int, wait: float = CHANGES_WAIT_S) -> dict[str, Any]:
    """The launch's changes after `since` (launcher_changes: a long poll of up to `wait` s): {"seq", "complete",
    "changes"}. ToolError (EXIT_NO_LAUNCH) once the launch is gone."""
    code, msg, text = call(uri, "launcher_changes", since, wait, timeout=wait + ANSWER_MARGIN_S)
    if code != 1:
        raise ToolError("changes: %s" % msg)
    return json.loads(text)


def follow_changes(uri: str, since: int, on_answer: Callable[[dict[str, Any]], None],
                   wait: float = CHANGES_WAIT_S) -> int:
    """Hand each answer of the change stream after `since` to `on_answer` (one at least every `wait` s, changes
    or none) while the launch runs; the last sequence number handed over, once it is gone. A launch slow to
    answer (NoAnswer: busy, or out of reach a while) is asked again: a follower ends with its launch, not with
    the launch's busiest moment."""
    while True:
        try:
            answer = changes(uri, since, wait)
        except NoAnswer:
            continue
        except ToolError as e:
            if e.status != EXIT_NO_LAUNCH:
                raise
            return since
        since = answer["seq"]
        on_answer(answer)


def find_node(info: dict[str, Any], name: str) -> dict[str, Any]:
    """A node of the status by node name (leading / optional) or process name; ToolError naming it."""
    wanted = name if name.startswith("/") else "/" + name
    for node in info["nodes"]:
        if node["name"] == wanted or node.get("process") == name:
            return node
    hint = did_you_mean(wanted, [node["name"] for node in info["nodes"]])
    raise ToolError("unknown node [%s]: not part of the launch at %s%s"
                    % (name, info.get("uri", "?"), "; " + hint if hint else ""))


def add_run_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--run", metavar="RUN_ID", help="read this finished run from its log directory (default: "
                        "the running launch; when none answers, the last run, $ROS_HOME/log/latest)")


def live_or_last(opts: argparse.Namespace, fetch: Callable[[str], Any],
                 environ: Mapping[str, str] | None = None) -> tuple[Any, Any]:
    """(fetch(the running launch's URI), None); or, when no launch of ours answers and --uri or --launch
    named none, (None, the last run: a lastrun.LastRun). Stderr says why the launch was not read only when
    that matters: the last run's launch still runs (its master does not answer, say); a launch that has
    ended needs no master (what the caller prints says how it ended). `--run` reads that run; a roslaunch
    run is NotOurs."""
    env = os.environ if environ is None else environ
    why = None
    if not opts.run:
        try:
            return fetch(find_launch(opts, dict(env))), None
        except ToolError as e:
            if e.status != EXIT_NO_LAUNCH or opts.uri or opts.launch:
                raise
            why = e
    # (lastrun costs ~1 ms to import, measured with -X importtime: only a run that has ended needs it)
    from launcher.operate import lastrun
    try:
        last = lastrun.read(lastrun.find_run(env, opts.run), latest=not opts.run)
    except NotOurs:
        if why is not None:  # (whether that run ended cannot be told: what was tried, then what it is)
            sys.stderr.write("launcher: %s\n" % why)
            sys.stderr.flush()
        raise
    except ToolError as e:
        if why is None:
            raise
        raise ToolError("%s\n%s" % (why, e), why.status) from None
    if why is not None and last.still_running:
        sys.stderr.write("launcher: %s\n" % why)
        sys.stderr.flush()
    return None, last


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
