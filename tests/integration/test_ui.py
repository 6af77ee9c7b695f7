"""The live terminal view in a real terminal: tmux (Debian's) runs `launch --ui` and `launcher ui` on launches of
real rospy nodes; `capture-pane` reads what the operator sees, `send-keys` types."""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import signal
import subprocess
import sys

import pytest

from helpers import free_port, pid_alive, until
from running import Launcher, make_package, ros_env, write_launch

pytestmark = pytest.mark.integration

Ticker = """#!/usr/bin/python3
import rospy
rospy.init_node("ticker")
n = 0
while not rospy.is_shutdown():
    n += 1
    rospy.loginfo("tick %d", n)
    rospy.sleep(0.3)
"""
Sleeper = "#!/bin/sh\nexec sleep 1000\n"
Warner = """#!/usr/bin/python3
import rospy
rospy.init_node("warner")
n = 0
while not rospy.is_shutdown():
    n += 1
    rospy.loginfo("tick %d", n)
    rospy.logwarn("careful %d", n)
    rospy.logerr("broken %d", n)
    rospy.sleep(0.3)
"""


@pytest.fixture
def tmux(tmp_path):
    if shutil.which("tmux") is None:
        if os.environ.get("REQUIRE_ROS"):
            pytest.fail("tmux is missing (.ci/run installs it)")
        pytest.skip("tmux is missing")
    # (a server of its own per test: `kill-server` returns before the last test's server has gone, and a
    # session started on its socket meanwhile fails)
    t = Tmux("launcher-ui-%d-%s" % (os.getpid(), os.path.basename(tmp_path)))
    yield t
    t.close()


class Tmux:
    """A tmux server of the test's own (its own socket), one session."""

    def __init__(self, socket: str):
        self.base = ["tmux", "-L", socket]

    def start(self, argv: list[str], env: dict[str, str], cols: int = 80, rows: int = 24) -> None:
        command = "env -i %s %s" % (" ".join(shlex.quote("%s=%s" % kv) for kv in env.items()),
                                    " ".join(shlex.quote(a) for a in argv))
        # (remain-on-exit set before the session starts: a command that ends at once still leaves its pane)
        done = subprocess.run(self.base + ["start-server", ";", "set-option", "-g", "remain-on-exit", "on", ";",
                                           "new-session", "-d", "-s", "t", "-x", str(cols), "-y", str(rows), command],
                              capture_output=True, text=True)
        assert done.returncode == 0, "tmux new-session: exit %d: %s" % (done.returncode, done.stderr)

    def screen(self, joined: bool = False, escapes: bool = False) -> str:
        """What the pane shows (`joined`: a line the terminal wrapped is one line; `escapes`: with colours)."""
        return subprocess.run(self.base + ["capture-pane", "-p", "-t", "t"] + (["-J"] if joined else []) +
                              (["-e"] if escapes else []), capture_output=True, text=True, check=True).stdout

    def keys(self, *keys: str) -> None:
        subprocess.run(self.base + ["send-keys", "-t", "t"] + list(keys), check=True)

    def resize(self, cols: int, rows: int) -> None:
        subprocess.run(self.base + ["resize-window", "-t", "t", "-x", str(cols), "-y", str(rows)], check=True)

    def pane_pid(self) -> int:
        return int(subprocess.run(self.base + ["display-message", "-p", "-t", "t", "#{pane_pid}"], capture_output=True,
                                  text=True, check=True).stdout)

    def pane_dead(self) -> bool:
        out = subprocess.run(self.base + ["display-message", "-p", "-t", "t", "#{pane_dead}"], capture_output=True,
                             text=True).stdout.strip()
        return out == "1"

    def wait_screen(self, cond, what: str, timeout: float = 60.0):
        last = [""]

        def check():
            last[0] = self.screen()
            return last[0] if cond(last[0]) else None
        try:
            return until(check, timeout, 0.1, what=what)  # (the screen that met it)
        except Exception:
            raise AssertionError("%s; the screen:\n%s" % (what, last[0])) from None

    def close(self) -> None:
        subprocess.run(self.base + ["kill-server"], capture_output=True)


def row(screen: str, name: str) -> list[str] | None:
    """A node's row on the screen, split (the selection marker left out)."""
    for line in screen.splitlines():
        cells = line.split()
        if cells and cells[0] == ">":
            cells = cells[1:]
        if cells and cells[0] == name and len(cells) >= 4:
            return cells
    return None


def tool(env: dict, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "launcher.cli.tool"] + list(args), env=env, capture_output=True,
                          text=True, timeout=60)


def status(env: dict) -> dict:
    r = tool(env, "status", "--json")
    return {n["name"]: n for n in json.loads(r.stdout)["nodes"]} if r.returncode == 0 else {}


@pytest.fixture
def env(tmp_path):
    make_package(str(tmp_path / "pkgs"), "ui_tests", {"ticker": Ticker, "sleeper": Sleeper, "warner": Warner})
    e = ros_env(str(tmp_path), free_port(), str(tmp_path / "pkgs"))
    return e


THREE = """
  <node pkg="ui_tests" type="ticker" name="alpha" output="screen" respawn="true"/>
  <node pkg="ui_tests" type="warner" name="beta"/>
  <group ns="g"><node pkg="ui_tests" type="ticker" name="gamma" respawn="true"/></group>
"""


def running_pid(screen: str, name: str) -> int | None:
    r = row(screen, name)
    # (cells: name, state, REG, pid, ...)
    return int(r[3]) if r and r[1] == "running" and r[2] in ("yes", "no") and r[3].isdigit() else None


def steer_and_watch(tmux: Tmux, env: dict) -> None:
    """What both views must do: every row, stop and start by keys, a respawn after an outside kill."""
    names = ["/alpha", "/beta", "/g/gamma"]
    screen = tmux.wait_screen(lambda s: all(running_pid(s, n) for n in names), "every node running")
    st = until(lambda: (lambda s: s if all(s.get(n, {}).get("state") == "running" for n in names) else None)(
        status(env)), 30, 0.2, what="status")
    for n in names:
        assert running_pid(screen, n) == st[n]["pid"]
    # the output pane: a screen node's lines, and an output="log" node's WARN and ERROR lines from /rosout
    # (its INFO lines stay in its log file, as under roslaunch), each tagged with the node and the level
    screen = tmux.wait_screen(lambda s: re.search(r"\[/alpha\] .*tick \d+", s) and re.search(
        r"^\[/beta\] WARN careful \d+", s, re.M) and re.search(r"^\[/beta\] ERROR broken \d+", s, re.M),
        "tagged output of both nodes")
    assert not re.search(r"\[/beta\].*tick", screen)
    # in the level's colour (tmux's escapes: 33 yellow, 31 red)
    coloured = tmux.screen(escapes=True)
    assert re.search(r"\x1b\[[0-9;]*33[0-9;]*m\[/beta\] WARN careful", coloured)
    assert re.search(r"\x1b\[[0-9;]*31[0-9;]*m\[/beta\] ERROR broken", coloured)
    # select /beta (the second row) and stop it, then start it: a new pid
    tmux.keys("j")
    tmux.wait_screen(lambda s: any(line.split()[:2] == [">", "/beta"] for line in s.splitlines() if line.split()),
                     "/beta selected")
    old = st["/beta"]["pid"]
    tmux.keys("s")
    tmux.wait_screen(lambda s: (row(s, "/beta") or [""])[1:2] == ["stopped"], "/beta stopped")
    assert not pid_alive(old)
    tmux.keys("t")
    screen = tmux.wait_screen(lambda s: running_pid(s, "/beta") not in (None, old), "/beta running again")
    new = running_pid(screen, "/beta")
    assert until(lambda: status(env)["/beta"]["pid"] == new, 10, 0.2, what="status agrees")
    # killed from outside: respawned, the pane shows the new pid
    gamma = running_pid(screen, "/g/gamma")
    os.kill(gamma, signal.SIGKILL)
    screen = tmux.wait_screen(lambda s: running_pid(s, "/g/gamma") not in (None, gamma), "/g/gamma respawned")
    assert (row(screen, "/g/gamma") or [])[5] == "1"  # restarts
    assert "[/g/gamma] running pid %d" % running_pid(screen, "/g/gamma") in screen


def test_launch_ui_shows_steers_and_stops_a_launch_of_rospy_nodes(tmp_path, tmux, env):
    launch = write_launch(str(tmp_path), THREE)
    tmux.start([sys.executable, "-m", "launcher", "--ui", launch], dict(env, TERM="xterm"))
    steer_and_watch(tmux, env)
    # a resize is followed: the rule under the table spans the new width
    tmux.resize(100, 30)
    tmux.wait_screen(lambda s: any(line.startswith("\u2500\u2500 output") and len(line.rstrip()) == 100
                                   for line in s.splitlines()), "the view redrawn at 100 columns")
    pids = [n["pid"] for n in status(env).values()]
    log_dir = json.loads(tool(env, "status", "--json").stdout)["log_dir"]
    console = os.path.join(log_dir, "launch-console.log")
    assert os.path.exists(console)  # (the launch's console, in its run's log directory)
    tmux.keys("q")  # = Ctrl-C: the launch's orderly stop
    tmux.wait_screen(lambda s: tmux.pane_dead(), "the launch ended")
    assert not any(pid_alive(p) for p in pids)
    # the view said where the console is; it holds the launch's lines, to its end
    assert "the launch's console: %s" % console in tmux.screen(joined=True)
    text = open(console).read()
    assert "started roslaunch server" in text and "shutting down processing monitor" in text


def test_launcher_ui_attaches_to_a_running_launch_and_leaves_it_running(tmp_path, tmux, env):
    lp = Launcher([write_launch(str(tmp_path), THREE)], env, str(tmp_path))
    try:
        lp.wait_output(r"process\[g/gamma-\d+\]: started", 60)
        tmux.start([sys.executable, "-m", "launcher.cli.tool", "ui"], dict(env, TERM="xterm"))
        steer_and_watch(tmux, env)
        pids = {n: s["pid"] for n, s in status(env).items()}
        tmux.keys("q")
        tmux.wait_screen(lambda s: tmux.pane_dead(), "the view ended")
        assert lp.proc.poll() is None and all(pid_alive(p) for p in pids.values())
        assert {n: s["pid"] for n, s in status(env).items()} == pids
    finally:
        lp.close()


def test_thirty_nodes_scroll_in_80x24_with_every_column_and_follow_resizes(tmp_path, tmux, env):
    long = "/a_rather_long_namespace/and_a_long_node_name"
    launch = write_launch(str(tmp_path), "".join(
        '<node pkg="ui_tests" type="sleeper" name="n%02d"/>\n' % i for i in range(30)) +
        '<group ns="%s"><node pkg="ui_tests" type="sleeper" name="%s"/></group>' % tuple(long[1:].split("/")))
    tmux.start([sys.executable, "-m", "launcher", "--ui", launch], dict(env, TERM="xterm"), 80, 24)
    screen = tmux.wait_screen(lambda s: running_pid(s, "/n00"), "the first rows")
    assert row(screen, "/n29") is None  # (not all fit)
    assert all(len(line) <= 80 for line in screen.splitlines()) and len(screen.splitlines()) <= 24

    def every_column(screen: str, names: list[str]) -> bool:
        # name state pid uptime restarts last-exit cpu rss host: nine cells, the host last
        rows = [row(screen, n) for n in names]
        return all(r and len(r) == 10 and r[-1] == "localhost" for r in rows)
    header = next(line for line in screen.splitlines() if line.split()[:2] == ["NODE", "STATE"])
    assert header.split()[-1] == "HOST"
    tmux.wait_screen(lambda s: every_column(s, ["/n%02d" % i for i in range(5)]), "every column of the rows")
    tmux.keys(*["j"] * 30)

    def abbreviated(s: str) -> str | None:
        return next((c[0] for line in s.splitlines() for c in [line.split()[1:] if line.startswith(">") else []]
                     if c and c[0].startswith("\u2026") and long.endswith(c[0][1:])), None)
    screen = tmux.wait_screen(lambda s: running_pid(s, "/n29") and abbreviated(s), "the last rows scrolled into view")
    assert row(screen, "/n00") is None
    assert every_column(screen, ["/n29", abbreviated(screen)])
    tmux.resize(150, 24)  # the whole name, the long headers
    tmux.wait_screen(lambda s: running_pid(s, long) and "RESTARTS" in s, "the full name at 150 columns")
    tmux.resize(80, 24)
    tmux.wait_screen(lambda s: abbreviated(s) and "RESTARTS" not in s and every_column(s, ["/n29"]),
                     "abbreviated again at 80 columns")
    tmux.keys("C-c")
    tmux.wait_screen(lambda s: tmux.pane_dead(), "the launch ended")


def test_without_a_terminal_both_say_so_and_print_plain_lines(tmp_path, env, tmux):
    lp = Launcher(["--ui", write_launch(str(tmp_path), THREE)], env, str(tmp_path))
    try:
        lp.wait_output("no terminal", 30, stream="stderr")
        lp.wait_output(r"process\[alpha-\d+\]: started with pid", 60)
        out = open(tmp_path / "ui.out", "wb")
        ui = subprocess.Popen([sys.executable, "-m", "launcher.cli.tool", "ui"], env=env, stdout=out,
                              stderr=subprocess.PIPE, stdin=subprocess.DEVNULL)
        try:
            until(lambda: re.search(r"\[/alpha\] .*tick \d+", (tmp_path / "ui.out").read_text()), 30,
                  what="plain output lines")
            text = (tmp_path / "ui.out").read_text()
            assert re.search(r"^/g/gamma +(waiting|running)", text, re.M)
            assert "\x1b" not in text
        finally:
            ui.send_signal(signal.SIGINT)
            ui.wait(10)
            out.close()
        assert b"no terminal" in ui.stderr.read()
        # a terminal that cannot draw (TERM=dumb): the same plain lines
        tmux.start([sys.executable, "-m", "launcher.cli.tool", "ui"], dict(env, TERM="dumb"))
        screen = tmux.wait_screen(lambda s: "TERM=dumb" in s and re.search(r"\[/beta\] ERROR broken \d+", s),
                                  "plain lines under TERM=dumb")
        assert "\u2500\u2500 output" not in screen  # (no full-screen view)
    finally:
        lp.close()


def test_a_closed_terminal_stops_the_launch_as_ctrl_c_does(tmp_path, tmux, env):
    launch = write_launch(str(tmp_path), '<node pkg="ui_tests" type="sleeper" name="s"/>')
    tmux.start([sys.executable, "-m", "launcher", "--ui", launch], dict(env, TERM="xterm"))
    screen = tmux.wait_screen(lambda s: running_pid(s, "/s"), "/s running")
    pid = running_pid(screen, "/s")
    tmux.close()  # (the terminal's end: SIGHUP to the view; the launch runs in a session of its own)
    until(lambda: not pid_alive(pid), 30, 0.1, what="the node stopped with the launch")
    assert not status(env)


def test_the_reload_key_applies_the_changed_files(tmp_path, tmux, env):
    path = write_launch(str(tmp_path), THREE)
    lp = Launcher([path], env, str(tmp_path))
    try:
        lp.wait_output(r"process\[g/gamma-\d+\]: started", 60)
        tmux.start([sys.executable, "-m", "launcher.cli.tool", "ui"], dict(env, TERM="xterm"))
        screen = tmux.wait_screen(lambda s: all(running_pid(s, n) for n in ("/alpha", "/beta", "/g/gamma")),
                                  "every node running")
        before = {n: running_pid(screen, n) for n in ("/alpha", "/beta", "/g/gamma")}
        with open(path) as f:
            text = f.read()
        with open(path, "w") as f:
            f.write(text.replace('name="beta"/>', 'name="beta" args="--changed"/>\n'
                                                  '<node pkg="ui_tests" type="ticker" name="delta"/>'))
        tmux.keys("R")
        tmux.wait_screen(lambda s: "reloaded: restart /beta: args" in s, "the reload's answer")
        tmux.wait_screen(lambda s: running_pid(s, "/delta"), "the node added in the table")
        screen = tmux.wait_screen(lambda s: running_pid(s, "/beta") not in (None, before["/beta"]),
                                  "/beta running anew")
        assert running_pid(screen, "/alpha") == before["/alpha"] and running_pid(screen, "/g/gamma") == before["/g/gamma"]
    finally:
        lp.close()


def test_a_killed_view_stops_its_launch_and_an_attached_one_does_not(tmp_path, tmux, env):
    """`launch --ui`'s launch is the view's child: the view's death (SIGKILL: nothing could pass a stop on)
    stops it as Ctrl-C does. `launcher ui` only looks at a launch: its death changes nothing."""
    launch = write_launch(str(tmp_path), '<node pkg="ui_tests" type="sleeper" name="s"/>')
    # (wide: the test's log directory is a long path; ~/.ros/log/RUN_ID/ fits in 80 columns)
    tmux.start([sys.executable, "-m", "launcher", "--ui", launch], dict(env, TERM="xterm"), 160, 24)
    screen = tmux.wait_screen(lambda s: running_pid(s, "/s"), "/s running")
    info = json.loads(tool(env, "status", "--json").stdout)
    pid, launch_pid = running_pid(screen, "/s"), info["pid"]
    # where the launch's console goes
    assert "[launch] q stops the launch; its console is launch-console.log in\n[launch] %s/\n" % info["log_dir"] \
        in screen, screen
    os.kill(tmux.pane_pid(), signal.SIGKILL)
    until(lambda: not pid_alive(pid) and not pid_alive(launch_pid), 30, 0.1, what="the launch stopped in order")
    assert not status(env)
    tmux.close()

    lp = Launcher([launch], env, str(tmp_path))
    try:
        lp.wait_output(r"process\[s-\d+\]: started", 60)
        pid = until(lambda: status(env).get("/s", {}).get("pid"), 30, 0.2, what="/s running")
        tmux.start([sys.executable, "-m", "launcher.cli.tool", "ui"], dict(env, TERM="xterm"))
        tmux.wait_screen(lambda s: running_pid(s, "/s") == pid, "/s running in the attached view")
        os.kill(tmux.pane_pid(), signal.SIGKILL)
        tmux.wait_screen(lambda s: tmux.pane_dead(), "the view ended")
        assert lp.proc.poll() is None and pid_alive(pid) and status(env)["/s"]["pid"] == pid
    finally:
        lp.close()


def kept_samples(env: dict, name: str) -> int:
    """How many samples of `name` the launch keeps (launcher_samples(true), through its server)."""
    import xmlrpc.client
    # (no "uri" before the launch answers: the status is then the last run's)
    uri = json.loads(tool(env, "status", "--json").stdout or "{}").get("uri")
    if not uri:
        return 0
    code, _msg, text = xmlrpc.client.ServerProxy(uri).launcher_samples(True)
    return len(json.loads(text).get(name, [])) if code == 1 else 0


def test_launcher_ui_attached_late_shows_the_cpu_history_at_once(tmp_path, tmux, env):
    lp = Launcher([write_launch(str(tmp_path), '<node pkg="ui_tests" type="ticker" name="alpha"/>')], env,
                  str(tmp_path))
    try:
        until(lambda: kept_samples(env, "/alpha") >= 8, 60, 0.5, what="8 samples kept by the launch")
        tmux.start([sys.executable, "-m", "launcher.cli.tool", "ui"], dict(env, TERM="xterm"))
        # the first screen with the selected node's sparkline: the launch's samples, not only the view's own
        screen = tmux.wait_screen(lambda s: re.search(r"/alpha cpu [\u2581-\u2588 ]+ \u2500", s), "the sparkline")
        bars = re.search(r"/alpha cpu ([\u2581-\u2588 ]+) \u2500", screen).group(1)
        assert len(bars) >= 8, screen
        tmux.keys("q")
        tmux.wait_screen(lambda s: tmux.pane_dead(), "the view ended")
    finally:
        lp.close()


def test_the_output_pane_says_each_change_once_in_the_events_words_and_the_filter_applies(tmp_path, tmux, env):
    """A node restarted by an operator (the `r` key): the pane has exactly one line for each change the events
    file has of it, in `launcher events`' words, however many internal steps the launch went through; with the
    filter `/sub`, no line of another node (state or output) is left in the pane."""
    # (sub says a line every 2 s: the pane keeps every line of the test in view)
    make_package(str(tmp_path / "pkgs"), "pane_tests",
                 {"greeter": "#!/bin/sh\nwhile true; do echo hello from sub; sleep 2; done\n"})
    lp = Launcher([write_launch(str(tmp_path), '<group ns="r2"><node pkg="ui_tests" type="sleeper" name="talker"/>'
                                '<node pkg="pane_tests" type="greeter" name="sub" output="screen"/></group>')],
                  env, str(tmp_path))
    try:
        lp.wait_output(r"process\[r2/sub-\d+\]: started", 60)
        tmux.start([sys.executable, "-m", "launcher.cli.tool", "ui"], dict(env, TERM="xterm"), 160, 40)
        screen = tmux.wait_screen(lambda s: running_pid(s, "/r2/talker") and "[/r2/sub] hello from sub" in s,
                                  "both nodes running, sub's output")
        old = running_pid(screen, "/r2/talker")
        assert row(screen, "/r2/talker")[0] == "/r2/talker"  # (the first row: selected)
        tmux.keys("r")
        screen = tmux.wait_screen(lambda s: running_pid(s, "/r2/talker") not in (None, old), "/r2/talker restarted")
        new = running_pid(screen, "/r2/talker")

        def talker_lines(s: str) -> list[str]:
            return [line.rstrip() for line in s.splitlines() if line.startswith("[/r2/talker] ")]

        def said() -> list[str]:  # what `launcher events` says of the node, its time left out
            out = tool(env, "events").stdout.splitlines()
            return ["[/r2/talker] " + line.split(" /r2/talker ", 1)[1] for line in out if " /r2/talker " in line]
        expected = said()
        # its first run, its stop by the operator, its run again: each once (the sleeper writes no output)
        assert len(expected) == 3 and expected[-1].startswith("[/r2/talker] running pid %d " % new), expected
        assert expected[1].startswith("[/r2/talker] stopped pid %d " % old) and expected[1].endswith(
            "(stopped by operator)"), expected
        screen = tmux.wait_screen(lambda s: talker_lines(s) == expected, "one line per change of the events file")
        assert row(screen, "/r2/talker")[6] == "SIGINT"  # (LAST EXIT: how its last run ended, while it runs again)
        # the filter applies to every line of the pane: no other node's, state or output
        tmux.keys("/", "s", "u", "b", "Enter")
        screen = tmux.wait_screen(lambda s: "filter [sub]" in s and not talker_lines(s), "only /r2/sub's lines")
        pane = screen.split("\u2500\u2500 output", 1)[1].splitlines()[1:-1]
        assert pane and all(line.startswith("[/r2/sub] ") for line in pane if line.strip()), screen
        assert any(re.match(r"\[/r2/sub\] running pid \d+ restarts 0$", line.rstrip()) for line in pane), screen
        assert "[/r2/sub] hello from sub" in pane
        tmux.keys("q")
        tmux.wait_screen(lambda s: tmux.pane_dead(), "the view ended")
    finally:
        lp.close()


def test_every_key_of_the_help_line_moves_shows_mutes_scrolls_filters_and_steers_all(tmp_path, tmux, env):
    """The keys the tests above do not press: k and Home move back, o shows the selected node's log and back,
    PageUp scrolls the pane and End follows again, m mutes and unmutes, a filter typed and taken back with
    Backspace and Esc, S stops every node and T starts every one."""
    lp = Launcher([write_launch(str(tmp_path), '<node pkg="ui_tests" type="ticker" name="a" output="screen"/>'
                                '<node pkg="ui_tests" type="sleeper" name="b"/>')], env, str(tmp_path))
    try:
        lp.wait_output(r"process\[b-\d+\]: started", 60)
        tmux.start([sys.executable, "-m", "launcher.cli.tool", "ui"], dict(env, TERM="xterm"), 160, 40)
        screen = tmux.wait_screen(lambda s: running_pid(s, "/a") and running_pid(s, "/b") and
                                  re.search(r"^\[/a\] .*tick \d+", s, re.M), "both running, /a's output")
        pids = {n: running_pid(screen, n) for n in ("/a", "/b")}

        def selected(s: str) -> str:
            return next((line.split()[1] for line in s.splitlines() if line.startswith("> ")), "")

        def rule(s: str) -> str:
            return next((line for line in s.splitlines() if line.startswith("\u2500\u2500 ")), "")

        def pane(s: str) -> list[str]:
            return s.split(rule(s), 1)[1].splitlines()[1:-1] if rule(s) else []
        for keys, name in ((["j"], "/b"), (["k"], "/a"), (["Down"], "/b"), (["Up"], "/a"), (["j", "Home"], "/a")):
            tmux.keys(*keys)
            tmux.wait_screen(lambda s: selected(s) == name, "%s: %s selected" % (keys, name))
        tmux.keys("o")
        screen = tmux.wait_screen(lambda s: rule(s).startswith("\u2500\u2500 recent output of /a (o: back)"),
                                  "/a's recent output")
        assert any(re.search(r"tick \d+", line) for line in pane(screen)) and not any(
            line.startswith("[/") for line in pane(screen)), screen  # (its log's own lines, untagged)
        tmux.keys("o")
        tmux.wait_screen(lambda s: rule(s).startswith("\u2500\u2500 output \u2500"), "every node's output again")
        tmux.keys("PageUp")
        tmux.wait_screen(lambda s: "[scrolled back " in rule(s) and "End follows]" in rule(s), "scrolled back")
        tmux.keys("End")
        tmux.wait_screen(lambda s: "scrolled back" not in rule(s), "following again")
        tmux.keys("m")
        screen = tmux.wait_screen(lambda s: rule(s).startswith("\u2500\u2500 output (1 muted)") and
                                  "/a muted: its output is not shown" in s, "/a muted")
        assert not any(line.startswith("[/a] ") for line in pane(screen)), screen
        tmux.keys("m")
        tmux.wait_screen(lambda s: "/a unmuted" in s and rule(s).startswith("\u2500\u2500 output \u2500") and
                         any(line.startswith("[/a] ") for line in pane(s)), "/a unmuted")
        tmux.keys("/", "z")
        tmux.wait_screen(lambda s: "filter: z\u2588" in s and "no node matches the filter [z]" in s, "filter z")
        tmux.keys("BSpace")
        screen = tmux.wait_screen(lambda s: "filter: \u2588" in s and running_pid(s, "/a"), "the filter emptied")
        tmux.keys("b", "Escape")
        tmux.wait_screen(lambda s: "filter [" not in s and "filter:" not in s and running_pid(s, "/a") and
                         running_pid(s, "/b"), "the filter cleared")
        tmux.keys("S")
        tmux.wait_screen(lambda s: all((row(s, n) or [""])[1:2] == ["stopped"] for n in pids), "every node stopped")
        assert not any(pid_alive(p) for p in pids.values())
        tmux.keys("T")
        tmux.wait_screen(lambda s: all(running_pid(s, n) not in (None, pids[n]) for n in pids),
                         "every node running anew")
        tmux.keys("q")
        tmux.wait_screen(lambda s: tmux.pane_dead(), "the view ended")
        assert lp.proc.poll() is None
    finally:
        lp.close()
