"""The live terminal view of a launch: `launcher ui` (attached to a running launch) and `launch --ui` (a launch
run as a child process, with the view in front): the prompt_toolkit application around `operate/view.py`.

prompt_toolkit, because it is well kept, pure Python, draws only what changed
(usable over SSH), follows resizes and runs on asyncio; it costs ~0.12 s to
import, paid only here (`launch` without --ui never imports this module). The
view is its own process and reads the launch through the launch's server only:
the change stream (`launcher_changes`), the resource samples, the nodes'
output (`launcher_output`), and steers it with the run's token, as `launcher
start/stop/restart` do. A slow or paused terminal therefore never delays the
launch: the launch answers calls, it never waits on the view. Without a
terminal (or with TERM=dumb) the view says so and prints plain lines.
"""

from __future__ import annotations

import argparse
import ctypes
import ctypes.util
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from types import SimpleNamespace
from typing import Any, Callable

from launcher.net.xmlrpc import Fault, XmlRpcError, call_blocking
from launcher.operate import client, columns
from launcher.operate.errors import slow
from launcher.model import token as run_token
from launcher.operate.view import HELP, HISTORY, NODE_OUTPUT, Line, ViewState, cut_left
from launcher.workspace.roshome import log_root

POLL_WAIT_S = 20.0  # a long poll's wait (the call's own timeout is longer)
# A view asks for the nodes' output at most every OUTPUT_PERIOD_S, and gets at most VIEW_OUTPUT_BYTES of a node's
# newest output in one answer: a node flooding its screen (20 MB/s) is shown as a screen refreshes, with what was
# passed over said, instead of being read whole (which cost the view most of a core; `launcher logs` has it all).
OUTPUT_PERIOD_S = 0.1
VIEW_OUTPUT_BYTES = 32 * 1024
SAMPLE_PERIOD_S = 1.0  # the CPU/RSS columns' refresh
RECENT_OUTPUT_BYTES = 16 * 1024  # of the selected node's log, for `o`
CONTROL_TIMEOUT_S = 600.0  # a stop waits for the node's SIGINT -> SIGTERM -> SIGKILL escalation


def call(uri: str, method: str, *params: Any, timeout: float = 10.0) -> Any:
    """A read call of the launch's server: its value (a failed answer is an XmlRpcError)."""
    code, msg, value = call_blocking(uri, method, *params, timeout=timeout)
    if code != 1:
        raise XmlRpcError("%s: %s" % (method, msg))
    return value


def new_output(uri: str, offsets: dict[str, int]) -> tuple[dict[str, str], list[list[str]], dict[str, int]]:
    """The nodes' output after `offsets` (updated), waiting up to POLL_WAIT_S for some: (node -> text,
    [[node, level, text], ...] the WARN/ERROR/FATAL lines of output="log" nodes from /rosout, node -> the
    bytes passed over: of a node further behind than VIEW_OUTPUT_BYTES, only its newest come)."""
    asked = json.dumps(dict(offsets, **{"@most": VIEW_OUTPUT_BYTES}))
    answer = json.loads(call(uri, "launcher_output", asked, POLL_WAIT_S, timeout=POLL_WAIT_S + 10))
    offsets.update(answer["offsets"])
    return answer["output"], answer.get("log") or [], answer.get("skipped") or {}


def recent_output(uri: str, node: str) -> str:
    """The end of a node's output (its -stdout.log), as the launch's server reads it."""
    answer = json.loads(call(uri, "launcher_output", json.dumps({node: -RECENT_OUTPUT_BYTES}), 0))
    return answer["output"].get(node, "")


def past_samples(uri: str) -> dict[str, list]:
    """The samples the launch kept of each node ({node: [[time, cpu, rss], ...]}): a view attaching late
    starts its history with them. {} from a launch that keeps none (an older launcher)."""
    try:
        return json.loads(call(uri, "launcher_samples", True))
    except (OSError, XmlRpcError, Fault, ValueError):
        return {}


def terminal_ok() -> bool:
    return sys.stdin.isatty() and sys.stdout.isatty() and os.environ.get("TERM", "dumb") not in ("dumb", "")


class Feed:
    """The launch's side of the view: threads doing blocking long polls (the view's loop never waits on the
    network), each handing what it got to `post`, which runs it on the view's loop."""

    def __init__(self, uri: str, state: ViewState, post: Callable[[Callable[[], None]], None]):
        self.uri = uri
        self.state = state
        self.post = post
        self.ended = threading.Event()
        self.gone = ""  # why the launch stopped answering

    def start(self) -> None:
        for target in (self._changes, self._samples, self._output):
            threading.Thread(target=target, daemon=True).start()

    def _call(self, method: str, *params: Any, timeout: float = 10.0) -> Any:
        return call(self.uri, method, *params, timeout=timeout)

    def _loop(self, body: Callable[[], None]) -> None:
        while not self.ended.is_set():
            try:
                body()
            except (OSError, XmlRpcError, Fault, ValueError) as e:
                why = "the launch at %s does not answer: %s" % (self.uri, getattr(e, "strerror", None) or e)
                if slow(e):  # (busy, or out of reach a while: said, and asked again; not the launch's end)
                    self.post(lambda: setattr(self.state, "message", why))
                elif not self.gone:
                    self.gone = why
                    self.post(lambda: setattr(self.state, "message", why))
                self.ended.wait(1.0)

    def _changes(self) -> None:
        def body() -> None:
            answer = json.loads(self._call("launcher_changes", self.state.seq, POLL_WAIT_S, timeout=POLL_WAIT_S + 10))
            if self.state.stale(answer):  # (changes dropped, or the launch has made its nodes since): the status
                info = json.loads(self._call("launcher_status"))
                self.post(lambda: self.state.load(info))
            self.post(lambda: self.state.changes(answer["changes"]))
            # (the next poll asks after the last change it got, whether or not the loop applied them yet)
            self.state.seq = max(self.state.seq, answer["seq"])
        self._loop(body)

    def _samples(self) -> None:
        def body() -> None:
            samples = json.loads(self._call("launcher_samples"))
            self.post(lambda: self.state.samples(samples))
            self.ended.wait(SAMPLE_PERIOD_S)
        self._loop(body)

    def _output(self) -> None:
        offsets: dict[str, int] = {}

        def body() -> None:
            output, log, skipped = new_output(self.uri, offsets)
            if output or log or skipped:
                def show() -> None:
                    for node, size in skipped.items():
                        self.state.skipped(node, size)
                    for node, text in output.items():
                        self.state.output(node, text)
                    for node, level, text in log:
                        self.state.warning(node, level, text)
                self.post(show)
                self.ended.wait(OUTPUT_PERIOD_S)  # (what comes meanwhile is in the next answer)
        self._loop(body)


def read_token(info: dict[str, Any], path: str | None = None) -> str:
    """The run's token: from `path`, else from the file the launch names (on its own machine)."""
    path = path or info.get("token_file") or ""
    if not path:
        raise client.ToolError("the launch has no token file: start/stop/restart are refused", client.EXIT_REFUSED)
    try:
        return run_token.read(path)
    except OSError as e:
        raise client.ToolError("cannot read the run's token [%s]: %s" % (path, e.strerror), client.EXIT_REFUSED) \
            from None


class Panes:
    """The view's panes from top to bottom (title, table header, table, rule, output, help line), each drawn from
    the state and the terminal's size (`size()`: rows, columns) whenever prompt_toolkit redraws; `filtering`: the
    operator is typing a filter (`/`), which the help line shows."""

    def __init__(self, state: ViewState, size: Callable[[], tuple[int, int]]):
        self.state = state
        self.size = size
        self.filtering = False

    def table_height(self) -> int:
        rows, _ = self.size()
        # the table takes what it needs up to half the screen; the output pane the rest (title, header,
        # rule and help line take 4)
        return max(1, min(len(self.state.visible()) or 1, (rows - 4) // 2))

    def title(self) -> list:
        cols = self.size()[1]
        return [("class:title", self.state.title(cols).ljust(cols))]

    def _fitted_rows(self) -> list:
        return self.state.table_rows(self.table_height(), time.time(), self.size()[1])

    def header(self) -> list:
        self._fitted_rows()  # (the header is drawn first: it takes the widths the rows are fitted to now)
        return [("class:header", self.state.table_header(time.time())[:self.size()[1]])]

    def table(self) -> list:
        out: list = []
        rows = self._fitted_rows()
        for i, (text, style, selected) in enumerate(rows):
            cls = "class:state.%s" % style if style else ""
            if selected:
                cls += " reverse"
            out.append((cls, text))
            if i < len(rows) - 1:
                out.append(("", "\n"))
        if not rows:
            state = self.state
            if state.filter:
                out.append(("class:dim", "no node matches the filter [%s]" % state.filter))
            else:  # (a launch still setting up has made no node yet)
                out.append(("class:dim", columns.STARTING if state.starting else "no nodes"))
        return out

    def rule(self) -> list:
        state = self.state
        what = ("recent output of %s (o: back)" % state.selected if state.mode == NODE_OUTPUT
                else "output%s" % (" (%d muted)" % len(state.muted) if state.muted else ""))
        if state.scroll:
            what += "  [scrolled back %d lines; End follows]" % state.scroll
        cols = self.size()[1]
        left = "\u2500\u2500 %s " % what
        # the selected node's CPU over the last minute, at the right end (when there is room)
        spark = state.spark(state.selected, min(HISTORY, cols // 4)) if state.selected else ""
        right = " %s cpu %s \u2500\u2500" % (cut_left(state.selected, 16), spark) if spark else ""
        if len(left) + len(right) > cols:
            right = ""
        return [("class:rule", left.ljust(cols - len(right), "\u2500") + right)]

    def output(self) -> list:
        rows, cols = self.size()
        height = max(1, rows - 4 - self.table_height())
        entries = self.state.output_entries(height)
        return [("class:level.%s" % style if style else "", line[:cols] + ("\n" if i < len(entries) - 1 else ""))
                for i, (line, style) in enumerate(entries)]

    def help_line(self) -> list:
        if self.filtering:
            return [("class:title", "filter: %s\u2588  (Enter keeps it, Esc clears it)" % self.state.filter)]
        if self.state.message:
            return [("class:message", self.state.message[:self.size()[1]])]
        return [("class:help", HELP[:self.size()[1]])]

    def layout(self) -> Any:
        from prompt_toolkit.layout import HSplit, Layout, Window
        from prompt_toolkit.layout.controls import FormattedTextControl
        from prompt_toolkit.layout.dimension import Dimension
        return Layout(HSplit([
            Window(FormattedTextControl(self.title), height=1),
            Window(FormattedTextControl(self.header), height=1, style="class:header"),
            Window(FormattedTextControl(self.table), height=lambda: Dimension.exact(self.table_height())),
            Window(FormattedTextControl(self.rule), height=1),
            Window(FormattedTextControl(self.output), wrap_lines=False),
            Window(FormattedTextControl(self.help_line), height=1),
        ]))


STYLE = {"title": "reverse bold", "header": "bold", "rule": "ansiblue", "help": "ansicyan",
         "message": "ansiyellow bold", "dim": "ansibrightblack",
         "state.green": "ansigreen", "state.yellow": "ansiyellow", "state.red": "ansired bold",
         "state.grey": "ansibrightblack", "level.warn": "ansiyellow", "level.error": "ansired",
         "level.fatal": "ansired bold reverse"}


class Steering:
    """What the operator asks of the launch from the view (start, stop, restart, reload, a node's recent output):
    each call made off the view's thread (the view never waits on the network), its answer handed to `post`."""

    def __init__(self, uri: str, info: dict[str, Any], token_file: str | None, state: ViewState,
                 post: Callable[[Callable[[], None]], None]):
        self.uri = uri
        self.info = info
        self.token_file = token_file
        self.state = state
        self.post = post

    def control(self, verb: str, every: bool = False) -> None:
        """`verb` (start, stop, restart) of the selected node, or of every node."""
        pattern = "*" if every else self.state.selected
        if not pattern:
            return
        self.state.message = "%s %s ..." % (verb, pattern)
        self._steer(verb, lambda: call_blocking(self.uri, "%s_nodes" % verb, self._token(), pattern,
                                                timeout=CONTROL_TIMEOUT_S)[1])

    def reload(self) -> None:
        """`launcher reload`: the launch reads its files again and applies the difference."""
        self.state.message = "reload ..."

        def answer() -> str:
            code, msg, text = call_blocking(self.uri, "launcher_reload", self._token(), [], False,
                                            timeout=CONTROL_TIMEOUT_S)
            lines = json.loads(text).get("lines", [])
            if code != 1:
                return "reload refused, nothing changed: %s" % msg
            if lines:  # (nodes added and removed: the whole status again)
                status = json.loads(call_blocking(self.uri, "launcher_status")[2])
                self.post(lambda: self.state.load(status))
            return "reloaded: %s" % "; ".join(lines) if lines else "reload: nothing changed"
        self._steer("reload", answer)

    def node_output(self) -> None:
        """The end of the selected node's output in the output pane, or back to every node's (`o`)."""
        state = self.state
        if state.mode == NODE_OUTPUT or not state.selected:
            state.show_node_output(None)
            return
        node = state.selected

        def work() -> None:
            try:
                text = recent_output(self.uri, node)
            except (OSError, XmlRpcError, Fault, ValueError) as e:
                text = "cannot read the output of %s: %s" % (node, e)
            self.post(lambda: state.show_node_output(text or "(%s has written nothing)" % node))
        threading.Thread(target=work, daemon=True).start()

    def _token(self) -> str:
        return read_token(self.info, self.token_file)

    def _steer(self, verb: str, call: Callable[[], str]) -> None:
        """Make the call off the view's thread; its answer (or why not) becomes the message."""
        def work() -> None:
            try:
                text = call()
            except client.ToolError as e:
                text = str(e)
            except Fault as e:
                text = e.faultString
            except (OSError, XmlRpcError) as e:
                text = "%s: the launch does not answer: %s" % (verb, e)
            self.post(lambda: setattr(self.state, "message", text))
        threading.Thread(target=work, daemon=True).start()


def key_bindings(state: ViewState, panes: Panes, steering: Steering) -> Any:
    """The keys (view.HELP names them): while a filter is typed (`/`), keys go to it; else they move, steer and
    quit. `q` and Ctrl-C leave the view (under `launch --ui`, stopping the launch)."""
    from prompt_toolkit.key_binding import KeyBindings

    def half_page() -> int:
        return max(1, panes.size()[0] // 2)

    def start_filter(event: Any) -> None:
        panes.filtering = True

    def type_filter(event: Any) -> None:
        if event.data.isprintable():
            state.set_filter(state.filter + event.data)

    def keep_filter(event: Any) -> None:
        panes.filtering = False

    def clear_filter(event: Any) -> None:
        panes.filtering = False
        state.set_filter("")

    def quit_view(event: Any) -> None:
        event.app.exit()

    browsing: list[tuple[str, Callable[[Any], Any]]] = [
        ("up", lambda e: state.move(-1)), ("k", lambda e: state.move(-1)),
        ("down", lambda e: state.move(1)), ("j", lambda e: state.move(1)),
        ("home", lambda e: state.move(-len(state.nodes))),
        ("pageup", lambda e: state.scroll_output(half_page())),
        ("pagedown", lambda e: state.scroll_output(-half_page())),
        ("end", lambda e: setattr(state, "scroll", 0)),
        ("s", lambda e: steering.control("stop")), ("t", lambda e: steering.control("start")),
        ("r", lambda e: steering.control("restart")),
        ("S", lambda e: steering.control("stop", every=True)), ("T", lambda e: steering.control("start", every=True)),
        ("R", lambda e: steering.reload()),
        ("m", lambda e: state.toggle_mute()),
        ("o", lambda e: steering.node_output()),
        ("/", start_filter),
        ("q", quit_view),
    ]
    typing = [("<any>", type_filter), ("backspace", lambda e: state.set_filter(state.filter[:-1])),
              ("enter", keep_filter), ("escape", clear_filter)]
    kb = KeyBindings()
    for keys, when in ((browsing, _Cond(lambda: not panes.filtering)), (typing, _Cond(lambda: panes.filtering))):
        for key, handler in keys:
            kb.add(key, filter=when)(handler)
    kb.add("c-c")(quit_view)
    return kb


def _post(app: Any, fn: Callable[[], None]) -> None:
    """Run `fn` on the view's loop (from a feed's or a call's thread), then redraw; nothing once the view ended."""
    loop = getattr(app, "loop", None)
    if loop is None or loop.is_closed():
        return

    def run() -> None:
        fn()
        app.invalidate()
    try:
        loop.call_soon_threadsafe(run)
    except RuntimeError:  # (the loop ended meanwhile)
        pass


def run_view(uri: str, on_quit: Callable[[], None] | None = None,
             launch_proc: subprocess.Popen | None = None, token_file: str | None = None, note: str = "") -> None:
    """The full-screen view of the launch at `uri` until the operator quits (or `launch_proc` ends); `note`
    is the output pane's first lines."""
    try:
        from prompt_toolkit.application import Application
    except ModuleNotFoundError:  # (an interpreter other than the one launcher was installed for)
        raise client.ToolError("the live view needs prompt_toolkit, which this Python (%s) lacks: pip install "
                               "prompt_toolkit, or run launcher with the Python it was installed for"
                               % sys.executable) from None
    from prompt_toolkit.styles import Style

    state = ViewState()
    info = client.status(uri)
    state.load(info)
    state.past_samples(past_samples(uri))
    for line in note.splitlines():
        state.lines.append(Line("launch", line, "state"))

    def size() -> tuple[int, int]:
        s = app.output.get_size()
        return s.rows, s.columns

    def post(fn: Callable[[], None]) -> None:
        _post(app, fn)

    panes = Panes(state, size)
    steering = Steering(uri, info, token_file, state, post)
    # (refresh_interval: the uptimes tick; mouse off: the terminal's own selection keeps working)
    app: Any = Application(layout=panes.layout(), key_bindings=key_bindings(state, panes, steering),
                           style=Style.from_dict(STYLE), full_screen=True, refresh_interval=1.0)
    feed = Feed(uri, state, post)

    def pre_run() -> None:
        feed.start()
        if launch_proc is not None:
            def watch() -> None:
                launch_proc.wait()
                post(lambda: app.exit() if app.is_running else None)
            threading.Thread(target=watch, daemon=True).start()

    try:
        app.run(pre_run=pre_run, handle_sigint=False)
    finally:
        feed.ended.set()
    if on_quit is not None:
        on_quit()


class _Cond:
    """A prompt_toolkit filter of a plain function (imported lazily, as the rest)."""

    def __new__(cls, fn: Callable[[], bool]) -> Any:
        from prompt_toolkit.filters import Condition
        return Condition(fn)


# ---- without a terminal ------------------------------------------------------------------------------------

def plain(uri: str) -> int:
    """Without a terminal: the table once, then each change and each output line as it comes, until Ctrl-C."""
    state = ViewState()
    info = client.status(uri)
    state.load(info)
    from launcher.operate.status import table
    sys.stdout.write(table(info) + "\n")
    sys.stdout.flush()
    lock = threading.Lock()

    def post(fn: Callable[[], None]) -> None:
        with lock:
            before = len(state.lines)
            fn()
            # (deque: the newest lines are at the end)
            new = list(state.lines)[before:] if len(state.lines) > before else []
            for line in new:
                sys.stdout.write(("[%s] %s\n" % (line.node, line.text)))
            sys.stdout.flush()

    feed = Feed(uri, state, post)
    feed.start()
    try:
        while not feed.gone:
            time.sleep(0.5)
    except KeyboardInterrupt:
        return client.EXIT_OK
    sys.stderr.write("launcher ui: %s\n" % feed.gone)
    return client.EXIT_NO_LAUNCH


# ---- `launcher ui` -----------------------------------------------------------------------------------------

def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="launcher ui", description="a live view of a running launch: every node's "
                                "state, CPU and RSS, their output; start, stop and restart nodes (q leaves the "
                                "launch running)")
    p.add_argument("--token-file", dest="token_file", help="the run's token file (default: the one the launch "
                   "wrote in its log directory; from another machine, a copy of it)")
    client.add_launch_options(p)
    return p


def _main(argv: list[str]) -> int:
    opts = parser().parse_args(argv)
    uri = client.find_launch(opts)
    if not terminal_ok():
        sys.stderr.write("launcher ui: no terminal (or TERM=dumb): plain lines follow\n")
        return plain(uri)
    run_view(uri, token_file=opts.token_file)
    return client.EXIT_OK


def main(argv: list[str]) -> int:
    return client.run_tool(_main, argv)


# ---- `launch --ui` -----------------------------------------------------------------------------------------

PR_SET_PDEATHSIG = 1
CONSOLE_NAME = "launch-console.log"  # the launch's console under --ui, in its run's log directory


def _stop_with_parent() -> Callable[[], None]:
    """A preexec_fn: the child gets SIGINT (its orderly stop, as at Ctrl-C) when the view that started it dies,
    SIGKILL included; else a launch would run on with nobody in front of it and no terminal to stop it from."""
    libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)  # (loaded before the fork)
    parent = os.getpid()

    def preexec() -> None:
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGINT, 0, 0, 0)
        if os.getppid() != parent:  # (the view died before the line above: nothing has started yet)
            os._exit(1)
    return preexec


def launch_with_view(args: list[str], master_uri: str) -> int:
    """`launch ARGS` as a child process (its console to a file that ends up in the run's log directory), the
    view in front; quitting the view stops the launch as Ctrl-C does and waits for its end, and so does the
    view's death (SIGKILL too). Returns the launch's exit status."""
    # the console's file starts in the log root (the run's directory is named once the launch has its run id)
    # so that moving it there is a rename on the same file system, which the launch writing it does not notice
    root = log_root(os.environ)
    try:
        os.makedirs(root, exist_ok=True)
        fd, console_path = tempfile.mkstemp(prefix="launch-ui-", suffix=".log", dir=root)
    except OSError:
        fd, console_path = tempfile.mkstemp(prefix="launch-ui-", suffix=".log")
    kept = False  # whether the console's file is in the run's log directory (else it is removed at the end)
    env = dict(os.environ, ROS_MASTER_URI=master_uri)
    # its own session: the terminal's signals are the view's, which passes the stop on (one Ctrl-C, not two)
    with os.fdopen(fd, "wb") as out:
        proc = subprocess.Popen([sys.executable, "-m", "launcher"] + args, stdout=out, stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL, env=env, start_new_session=True,
                                preexec_fn=_stop_with_parent())

    def stop_launch() -> None:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)

    # the terminal closed, or the view was told to end: the launch stops as at Ctrl-C, and the view ends with it
    old = {sig: signal.signal(sig, lambda *_: stop_launch()) for sig in (signal.SIGHUP, signal.SIGTERM)}
    uri = None
    try:
        uri = _wait_for_launch(proc, master_uri)
        if uri is not None:
            try:
                info = client.status(uri)
                if info.get("log_dir"):
                    moved = os.path.join(info["log_dir"], CONSOLE_NAME)
                    try:
                        os.rename(console_path, moved)
                        console_path, kept = moved, True
                    except OSError:  # (another file system: the file stays where it is until the end)
                        pass
                # (the directory on a line of its own: an 80-column pane shows it whole)
                where = (os.path.dirname(console_path) + os.sep, os.path.basename(console_path))
                run_view(uri, launch_proc=proc, note="q stops the launch; its console is %s in\n%s" % where[::-1])
            except client.ToolError as e:
                sys.stderr.write("launch --ui: %s\n" % e)
            except KeyboardInterrupt:  # (a SIGINT from outside the terminal's keys: the same stop)
                pass
            if proc.poll() is None:
                sys.stderr.write("stopping the launch (its console: %s) ...\n" % console_path)
                sys.stderr.flush()
                stop_launch()
        while True:
            try:
                status = proc.wait()
                break
            except KeyboardInterrupt:  # a second Ctrl-C: the launch's own second-Ctrl-C rule
                stop_launch()
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)
    # the launch's last words (all of them when it ended before the view could attach: a load error)
    sys.stdout.write(_tail(console_path, 20 if uri is not None else None))
    if kept:
        sys.stdout.write("the launch's console: %s\n" % console_path)
    else:
        try:
            os.unlink(console_path)
        except OSError:
            pass
    sys.stdout.flush()
    return status if status >= 0 else 128 - status


def _wait_for_launch(proc: subprocess.Popen, master_uri: str) -> str | None:
    """The URI of the launch `proc` runs, once its server is registered on the master (None: it ended first)."""
    opts = SimpleNamespace(uri=None, launch=str(proc.pid), master_uri=master_uri)
    while proc.poll() is None:
        try:
            return client.find_launch(opts)  # type: ignore[arg-type]
        except client.ToolError:
            time.sleep(0.1)
        except KeyboardInterrupt:
            proc.send_signal(signal.SIGINT)
    return None


def _tail(path: str, lines: int | None) -> str:
    try:
        with open(path, "rb") as f:
            data = f.read()
    except OSError:
        return ""
    text = data.decode("utf-8", "replace")
    kept = text.splitlines(keepends=True)
    return "".join(kept[-lines:] if lines else kept)

