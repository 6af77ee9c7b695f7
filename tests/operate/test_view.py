"""The live view's state without a terminal (launcher/operate/view.py): rows, selection, filter, mute, scrolling,
the change stream and the output pane, against a fake clock."""

from __future__ import annotations

from launcher.operate import columns
from launcher.operate.view import NODE_OUTPUT, ViewState

T0 = 1000.0


def node(name: str, state: str = "running", pid: int | None = 100, **kw) -> dict:
    d = {"name": name, "process": name[1:], "host": "localhost", "state": state, "pid": pid,
         "started_at": T0 if state == "running" else None, "uptime": None, "restarts": 0, "exit_code": None,
         "exit_signal": None, "cpu": None, "rss": None, "over_limit": {}}
    d.update(kw)
    return d


def view(*nodes: dict) -> ViewState:
    v = ViewState()
    v.load({"uri": "http://h:1/", "run_id": "r", "nodes": list(nodes)})
    return v


def test_rows_are_launcher_status_columns_with_uptime_from_the_clock():
    v = view(node("/a", cpu=0.25, rss=50 * 1000 * 1000), node("/b", "stopped", None, exit_code=0))
    rows = v.table_rows(10, T0 + 75)
    a = rows[0][0].split()
    assert a == [">", "/a", "running", "no", "100", "1m15s", "0", "-", "25%", "50MB", "localhost"]
    assert rows[0][1:] == ("green", True)
    assert rows[1][0].split() == ["/b", "stopped", "-", "-", "-", "0", "code", "0", "-", "-", "localhost"]
    assert rows[1][1:] == ("grey", False)
    # the same cells as `launcher status` gives for that node
    assert tuple(a[1:]) == columns.row(dict(v.nodes["/a"], uptime=75.0))
    assert v.table_header(T0).split() == list(columns.HEADER[:6]) + ["LAST", "EXIT"] + list(columns.HEADER[7:])


def test_a_change_updates_the_row_and_says_it_in_the_pane():
    v = view(node("/a"))
    v.changes([{"seq": 3, "time": T0 + 5, "node": "/a", "state": "respawning", "pid": 100, "exit_code": None,
                "exit_signal": 9, "restarts": 0},
               {"seq": 4, "time": T0 + 6, "node": "/a", "state": "running", "pid": 222, "restarts": 1}])
    assert v.seq == 4
    row = v.table_rows(5, T0 + 16)[0][0].split()
    assert row[2:7] == ["running", "no", "222", "10s", "1"]  # uptime from the new run's start
    # each change in the events file's words (`launcher events` without its time and node)
    assert v.output_rows(10) == ["[/a] respawning pid 100 signal 9 restarts 0", "[/a] running pid 222 restarts 1"]
    v.changes([{"seq": 5, "time": T0 + 6.5, "node": "/a", "state": "running", "pid": 222, "restarts": 1,
                "registered": True, "uri": "http://h:5/"}])
    assert v.table_rows(5, T0 + 16)[0][0].split()[2:4] == ["running", "yes"]
    assert v.output_rows(10)[-1] == "[/a] running pid 222 registered at http://h:5/ restarts 1"
    v.changes([{"seq": 6, "time": T0 + 7, "node": "/a", "state": "stopped", "pid": 222, "exit_code": 0,
                "registered": False, "uri": ""}])
    assert v.table_rows(5, T0 + 20)[0][0].split()[2:6] == ["stopped", "-", "-", "-"]
    v.changes([{"seq": 7, "time": T0, "node": "/unknown", "state": "running"}])  # (not in the status: ignored)
    assert list(v.nodes) == ["/a"]


def test_over_limit_is_marked():
    v = view(node("/a", over_limit={"memory_limit": 1e6}))
    text, style, _ = v.table_rows(3, T0)[0]
    assert "OVER memory_limit" in text and style == "red"


def test_selection_moves_and_the_table_scrolls_to_keep_it_visible():
    v = view(*(node("/n%02d" % i) for i in range(30)))
    assert v.selected == "/n00"
    v.move(-1)
    assert v.selected == "/n00"
    v.move(25)
    rows = v.table_rows(10, T0)
    assert len(rows) == 10 and rows[-1][2] and rows[-1][0].split()[1] == "/n25"
    assert rows[0][0].split()[0] == "/n16"
    v.move(100)
    assert v.selected == "/n29" and v.table_rows(10, T0)[-1][0].split()[1] == "/n29"
    v.move(-29)
    assert v.table_rows(10, T0)[0][0].split()[1] == "/n00"


def test_filter_narrows_rows_and_moves_the_selection_into_them():
    v = view(node("/cam/left"), node("/cam/right"), node("/driver"))
    v.move(2)
    v.set_filter("CAM")
    assert v.visible() == ["/cam/left", "/cam/right"] and v.selected == "/cam/left"
    assert "filter [CAM]: 2 shown" in v.title()
    v.set_filter("nothing")
    assert v.table_rows(5, T0) == [] and v.selected == ""
    v.set_filter("")
    assert len(v.table_rows(5, T0)) == 3


def test_output_lines_are_whole_tagged_and_muted_nodes_hidden():
    v = view(node("/a"), node("/b"))
    v.output("/a", "one\ntw")
    v.output("/b", "bee\r\n")
    assert v.output_rows(10) == ["[/a] one", "[/b] bee"]
    v.output("/a", "o\n")
    assert v.output_rows(10)[-1] == "[/a] two"
    v.toggle_mute()  # /a, selected
    assert v.output_rows(10) == ["[/b] bee"] and "(muted)" in v.table_rows(5, T0)[0][0]
    v.toggle_mute()
    assert len(v.output_rows(10)) == 3


def test_output_passed_over_is_said_in_its_place_with_the_line_it_cut():
    v = view(node("/a"), node("/b"))
    v.output("/a", "whole\nhalf a li")
    v.output("/b", "bee\n")
    v.skipped("/a", 1900000)  # (the launch gives the newest output of a flood, from a line's start)
    v.output("/a", "newest\n")
    assert v.output_rows(10) == ["[/a] whole", "[/b] bee",
                                 "[/a] ... 1.9MB of output passed over (`launcher logs /a` has every line)",
                                 "[/a] newest"]


def test_scrolling_back_holds_the_lines_in_place_while_output_comes():
    v = view(node("/a"))
    v.output("/a", "".join("line %d\n" % i for i in range(100)))
    assert v.output_rows(3) == ["[/a] line 97", "[/a] line 98", "[/a] line 99"]
    v.scroll_output(10)
    assert v.output_rows(3)[-1] == "[/a] line 89"
    v.output("/a", "new 1\nnew 2\n")
    assert v.output_rows(3)[-1] == "[/a] line 89"
    v.scroll_output(-1000)
    assert v.output_rows(1) == ["[/a] new 2"]
    v.scroll_output(10 ** 6)
    assert v.output_rows(1) == ["[/a] line 0"]


def test_a_nodes_recent_output_replaces_the_pane_until_asked_back():
    v = view(node("/a"))
    v.output("/a", "live\n")
    v.show_node_output("old 1\nold 2")
    assert v.mode == NODE_OUTPUT and v.output_rows(5) == ["old 1", "old 2"]
    v.show_node_output(None)
    assert v.output_rows(5) == ["[/a] live"]


def test_samples_fill_cpu_and_rss_of_running_nodes_only():
    v = view(node("/a"), node("/b"))
    v.samples({"/a": [0.5, 2 * 1000 * 1000]})
    rows = [r[0].split() for r in v.table_rows(5, T0)]
    assert rows[0][-3:-1] == ["50%", "2MB"] and rows[1][-3:-1] == ["-", "-"]


def test_rows_fit_80_columns_with_every_column_and_follow_the_width():
    long = "/a_rather_long_namespace/and_a_long_node_name"
    v = view(node(long, pid=4194301, cpu=1.25, rss=1_500_000_000, restarts=12),
             node("/b", "respawning", None, exit_signal=9, host="robot-arm-controller.example.org"))
    rows = v.table_rows(10, T0 + 86399, 80)
    header = v.table_header(T0)
    assert all(len(text) <= 80 for text, _, _ in rows) and len(header) <= 80
    assert header.split() == ["NODE", "STATE", "REG", "PID", "UP", "RST", "EXIT", "CPU", "RSS", "HOST"]
    a, b = rows[0][0].split(), rows[1][0].split()
    assert a[1].startswith("\u2026") and long.endswith(a[1][1:]) and len(a[1]) >= 10  # (the name's end)
    assert a[2:] == ["running", "no", "4194301", "23h59m", "12", "-", "125%", "1.5GB", "localhost"]
    assert b[:7] == ["/b", "respawning", "-", "-", "-", "0", "SIGKILL"]
    assert b[-1].startswith("robot-arm-") and b[-1].endswith("\u2026")  # (a long host cut, still there)
    # wide enough: nothing shortened, the header's own words
    rows = v.table_rows(10, T0 + 86399, 200)
    assert rows[0][0].split()[1] == long and "robot-arm-controller.example.org" in rows[1][0]
    assert "RESTARTS" in v.table_header(T0)


def test_a_late_view_starts_its_sparkline_with_the_samples_the_launch_kept():
    v = view(node("/a"), node("/b"))
    assert v.spark("/a", 20) == ""
    v.past_samples({"/a": [[T0 + i, 0.1 * i, 1000] for i in range(10)], "/gone": [[T0, 0.5, 1]]})
    v.samples({"/a": [1.0, 1000]})  # (then the view's own)
    line = v.spark("/a", 20)
    assert len(line) == 11 and line[0] == "\u2581" and line[-1] == "\u2588"
    assert list(line[:10]) == sorted(line[:10])  # (rising as the samples did)
    assert v.spark("/a", 4) == line[-4:] and v.spark("/b", 20) == " "  # (/b: no sample, not running)
    assert "/gone" not in v.history


def test_the_title_leaves_out_the_run_id_when_narrow():
    v = ViewState()
    v.load({"uri": "http://127.0.0.1:35315/", "run_id": "147fb780-e92a-11f1-9e20-02fc00000001",
            "nodes": [node("/a"), node("/b", "stopped", None)]})
    assert v.title() == "launch http://127.0.0.1:35315/  run 147fb780-e92a-11f1-9e20-02fc00000001  1/2 running"
    assert v.title(80) == "launch http://127.0.0.1:35315/  1/2 running"
    assert v.title(120) == v.title()


def test_the_pane_has_one_line_per_change_of_the_events_file_and_the_filter_applies_to_it():
    """A restart by an operator: the steps the events file leaves out (the long poll marks them internal:
    running -> stopping, stopped -> starting) give no line; the others one each, in `launcher events`' words."""
    v = view(node("/r2/talker", pid=21006), node("/r2/sub", pid=300))
    base = {"node": "/r2/talker", "host": "localhost", "exit_code": None, "exit_signal": None, "failures": 0,
            "over_limit": {}, "next_start": None}
    v.changes([dict(base, seq=1, time=T0, state="running", phase="stopping", pid=21006, restarts=0, reason="",
                    internal=True),
               dict(base, seq=2, time=T0 + 1, state="stopped", phase="stopped", pid=21006, exit_code=0, restarts=0,
                    reason="stopped by operator"),
               dict(base, seq=3, time=T0 + 1, state="waiting", phase="starting", pid=21006, exit_code=0, restarts=0,
                    reason="started by operator", internal=True),
               dict(base, seq=4, time=T0 + 2, state="running", phase="running", pid=21010, restarts=1, reason=""),
               dict(base, seq=5, time=T0 + 2, node="/r2/sub", state="stopped", phase="stopped", pid=300,
                    restarts=0, reason="stopped by operator")])
    assert v.output_rows(10) == ["[/r2/talker] stopped pid 21006 exit code 0 restarts 0 (stopped by operator)",
                                 "[/r2/talker] running pid 21010 restarts 1",
                                 "[/r2/sub] stopped pid 300 restarts 0 (stopped by operator)"]
    v.output("/r2/sub", "a line of sub's\n")
    v.output("/r2/talker", "hello\n")
    v.set_filter("SUB")
    assert v.output_rows(10) == ["[/r2/sub] stopped pid 300 restarts 0 (stopped by operator)",
                                 "[/r2/sub] a line of sub's"]
    v.set_filter("")
    assert len(v.output_rows(10)) == 5


def test_the_last_exit_stays_while_the_node_runs_again():
    """LAST EXIT is the last run that ended, not the current one: a crash loop shows its code between crashes."""
    v = view(node("/crasher", last_exit_code=None, last_exit_signal=None, last_exit_at=None))
    for i, (t, state, code) in enumerate([(1, "respawning", 3), (2, "running", None), (3, "respawning", 3),
                                          (4, "running", None)]):
        v.changes([{"seq": i + 1, "time": T0 + t, "node": "/crasher", "state": state, "pid": 100 + i,
                    "exit_code": code, "exit_signal": None, "restarts": i // 2}])
        n = v.nodes["/crasher"]
        assert (n["exit_code"], n["last_exit_code"], n["last_exit_at"]) == (code, 3, T0 + 1 + i // 2 * 2)
        assert v.table_rows(1, T0 + 5)[0][0].split()[7:9] == ["code", "3"]
    v.changes([{"seq": 9, "time": T0 + 9, "node": "/crasher", "state": "respawning", "pid": None, "exit_code": None,
                "exit_signal": 11}])
    assert columns.last_exit(v.nodes["/crasher"]) == "SIGSEGV" and v.nodes["/crasher"]["last_exit_at"] == T0 + 9


def test_a_change_of_a_node_the_status_lacked_asks_for_the_status_again():
    """A view that read the status while the launch was still making its nodes (none yet) is told, by the first
    change of one, to read the status again (its readers do: ui.Feed, web.Hub); the launch's own lines are no
    node's."""
    v = ViewState()
    v.load({"nodes": []})
    assert v.unknown([{"seq": 1, "node": "/s", "state": "running"}])
    assert not v.unknown([{"seq": 2, "event": "reload", "reason": "x"}])
    v.load({"nodes": [{"name": "/s", "state": "running"}]})
    assert not v.unknown([{"seq": 3, "node": "/s", "state": "stopped"}])


def test_the_terminal_views_table_says_a_launch_is_starting_until_its_nodes_are_made():
    from launcher.operate.ui import Panes
    state = ViewState()
    panes = Panes(state, lambda: (24, 80))
    state.load({"nodes": [], "starting": True})
    assert panes.table() == [("class:dim", "starting: its nodes start once the master is up and the parameters are set")]
    state.load({"nodes": [], "starting": False})
    assert panes.table() == [("class:dim", "no nodes")]
    state.filter = "cam"
    assert panes.table() == [("class:dim", "no node matches the filter [cam]")]


def test_the_status_is_read_again_when_changes_were_dropped_or_a_launch_has_made_its_nodes_since():
    state = ViewState()
    state.load({"nodes": [{"name": "/a", "state": "running"}], "starting": False})
    quiet = {"seq": 3, "complete": True, "starting": False, "changes": []}
    assert not state.stale(quiet)
    assert state.stale(dict(quiet, complete=False))
    assert state.stale(dict(quiet, changes=[{"seq": 4, "node": "/new", "state": "running"}]))
    assert not state.stale(dict(quiet, changes=[{"seq": 4, "node": "/a", "state": "stopped"}]))
    # read while the launch set up: no node, "starting"; it stays so while the launch says it is
    state.load({"nodes": [], "starting": True})
    assert state.starting
    assert not state.stale(dict(quiet, starting=True))
    assert state.stale(quiet)  # (a launch of no node: no change says it has set up, the answer does)
    assert state.stale({"seq": 0, "complete": True, "changes": []})  # (a launch of before: no "starting")
    state.load({"nodes": [{"name": "/a", "state": "running"}], "starting": True})  # (a status made as it set up)
    assert not state.starting and not state.stale(quiet)
