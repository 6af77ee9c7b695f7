"""The launch server's calls for live views (launcher_output, launcher_samples) on real files, and the page server's
guards (operate/web.py), without a launch."""

from __future__ import annotations

import asyncio
import json
import socket
from types import SimpleNamespace

import pytest

from helpers import launch_server_setting_up
from launcher.net.xmlrpc import Fault
from launcher.services import server as server_mod
from launcher.services.rosouttail import RosoutTail
from launcher.services.server import LaunchServer
from launcher.services.servers import RosoutService, RunView
from launcher.operate.web import allowed_host, parse_address, round_sample
from launcher.fleet.state import Fleet


def make_server(tmp_path, names=("/a", "/b"), log_nodes=(), warnings=None, remote=()):
    fleet = Fleet()
    specs = {}
    for name in names:
        fleet.add(name)
        specs[name] = SimpleNamespace(stdout_path=str(tmp_path / ("%s-stdout.log" % name[1:])),
                                      output="log" if name in log_nodes else "screen")
    # (the run as the server reads it: through its supervisor here, through `nodes.spec` in the RunView that
    # main's runservices brings; both are given so that this test holds on either side of that merge)
    supervisor = SimpleNamespace(node=lambda n: SimpleNamespace(spec=specs[n]) if n in specs else None)
    nodes = SimpleNamespace(spec=specs.get, remote_names=lambda: list(remote))
    run = SimpleNamespace(fleet=fleet, supervisor=supervisor, remote=None, nodes=nodes, warnings=warnings)
    return LaunchServer(run, {"ROS_IP": "127.0.0.1"}), fleet


def output(server, offsets, timeout=0.0):
    code, _msg, text = asyncio.run(server.launcher_output(json.dumps(offsets), timeout))
    assert code == 1
    return json.loads(text)


def test_output_from_the_end_then_what_follows_and_the_last_bytes_on_request(tmp_path):
    server, _ = make_server(tmp_path)
    (tmp_path / "a-stdout.log").write_text("old line\n")
    first = output(server, {})
    assert first == {"offsets": {"/a": 9, "/b": 0}, "output": {}}  # (no file yet for /b)
    with open(tmp_path / "a-stdout.log", "a") as f:
        f.write("new line\n")
    (tmp_path / "b-stdout.log").write_text("bee\n")
    second = output(server, first["offsets"])
    assert second["output"] == {"/a": "new line\n", "/b": "bee\n"} and second["offsets"] == {"/a": 18, "/b": 4}
    assert output(server, {"/a": -9})["output"] == {"/a": "new line\n"}
    # rotated: shorter than the offset, read from its start
    (tmp_path / "a-stdout.log").write_text("fresh\n")
    assert output(server, {"/a": 18, "/b": 4})["output"] == {"/a": "fresh\n"}


def test_a_view_far_behind_gets_the_newest_output_from_a_line_start_and_how_much_was_passed_over(tmp_path):
    server, _ = make_server(tmp_path, ("/a", "/b"))
    lines = b"".join(b"line %04d\n" % i for i in range(1000))  # 10 bytes each
    (tmp_path / "a-stdout.log").write_bytes(lines)
    (tmp_path / "b-stdout.log").write_bytes(b"short\n")
    answer = output(server, {"/a": 0, "/b": 0, "@most": 95})
    # the newest 95 bytes begin inside line 990; it is passed over with the rest before it
    assert answer["output"] == {"/a": "".join("line %04d\n" % i for i in range(991, 1000)), "/b": "short\n"}
    assert answer["skipped"] == {"/a": 9910} and answer["offsets"] == {"/a": 10000, "/b": 6}
    # within the bound: every byte, nothing said passed over
    with open(tmp_path / "a-stdout.log", "ab") as f:
        f.write(b"one more\n")
    later = output(server, dict(answer["offsets"], **{"@most": 95}))
    assert later["output"] == {"/a": "one more\n"} and "skipped" not in later
    # a line longer than the bound: its newest bytes, from where they begin
    with open(tmp_path / "b-stdout.log", "ab") as f:
        f.write(b"x" * 200 + b"\n")
    long = output(server, {"/a": 10009, "/b": 6, "@most": 50})
    assert long["output"] == {"/b": "x" * 49 + "\n"} and long["skipped"] == {"/b": 151}
    # without "@most" (`launcher logs`, the recent output): every byte
    assert output(server, {"/a": 0})["output"]["/a"].startswith("line 0000\n")
    with pytest.raises(Fault):
        asyncio.run(server.launcher_output(json.dumps({"@most": -1}), 0))


def test_a_waiting_output_call_answers_when_a_node_writes(tmp_path, monkeypatch):
    monkeypatch.setattr(server_mod, "OUTPUT_CHECK_S", 0.01)
    server, _ = make_server(tmp_path, ("/a",))
    (tmp_path / "a-stdout.log").write_text("before\n")

    async def scenario():
        call = asyncio.ensure_future(server.launcher_output("{}", 30))
        await asyncio.sleep(0.05)
        assert not call.done()
        with open(tmp_path / "a-stdout.log", "a") as f:
            f.write("after\n")
        return await asyncio.wait_for(call, 5)
    code, _msg, text = asyncio.run(scenario())
    assert json.loads(text)["output"] == {"/a": "after\n"}  # (what came after the call, not before)


def test_log_nodes_give_their_rosout_warnings_not_their_file(tmp_path):
    tail = RosoutTail()
    server, _ = make_server(tmp_path, ("/screen", "/quiet"), log_nodes=("/quiet",), warnings=tail,
                            remote=("/far",))
    (tmp_path / "quiet-stdout.log").write_text("info line\n")
    tail.add(4, "/quiet", "before the reader came")
    first = output(server, {})
    assert first == {"offsets": {"/screen": 0, "@rosout": 1}, "output": {}, "log": []}
    with open(tmp_path / "quiet-stdout.log", "a") as f:
        f.write("[INFO] more info\n[WARN] careful\n")
    tail.add(4, "/quiet", "careful")
    tail.add(8, "/quiet", "broken")
    tail.add(16, "/screen", "its own file has it")  # (a screen node's lines are in its output already)
    tail.add(4, "/elsewhere", "a node of another launch")
    tail.add(8, "/far", "on another machine")  # (its file is there: /rosout is how its warnings come)
    second = output(server, first["offsets"])
    assert second["log"] == [["/quiet", "WARN", "careful"], ["/quiet", "ERROR", "broken"],
                             ["/far", "ERROR", "on another machine"]]
    assert second["output"] == {} and second["offsets"]["@rosout"] == 6
    # its file on request (the view's recent output): read as any node's
    assert output(server, {"/quiet": -15})["output"] == {"/quiet": "[WARN] careful\n"}


def test_a_view_asking_before_our_rosout_is_up_leaves_the_log_nodes_files_to_it(tmp_path):
    """The live view may ask as soon as the API server is up, before rosout is: a run whose master is ours gives
    its output="log" nodes' warnings from the start (a view keeps following what it was first given: had it been
    given their files, their INFO lines would show for the whole run). A master found running, or a rosout
    that could not start, gives their files."""
    def first_offsets(external: bool, failed: bool = False) -> dict:
        server, fleet = make_server(tmp_path, ("/screen", "/quiet"), log_nodes=("/quiet",))
        master = SimpleNamespace(external=external, master=None, core=False)
        rosout = RosoutService(master, SimpleNamespace(run_dir=str(tmp_path)), {})
        rosout.failed = failed
        nodes = SimpleNamespace(fleet=fleet, spec=server.run.nodes.spec, remote_names=lambda: [])
        server.run = RunView(master, nodes, SimpleNamespace(run_dir=str(tmp_path)), rosout, ())
        return output(server, {})["offsets"]
    assert first_offsets(external=False) == {"/screen": 0, "@rosout": 0}
    assert first_offsets(external=True) == {"/screen": 0, "/quiet": 0}
    assert first_offsets(external=False, failed=True) == {"/screen": 0, "/quiet": 0}


def test_a_waiting_output_call_answers_when_a_warning_comes(tmp_path, monkeypatch):
    monkeypatch.setattr(server_mod, "OUTPUT_CHECK_S", 0.01)
    tail = RosoutTail()
    server, _ = make_server(tmp_path, ("/a",), log_nodes=("/a",), warnings=tail)

    async def scenario():
        call = asyncio.ensure_future(server.launcher_output("{}", 30))
        await asyncio.sleep(0.05)
        assert not call.done()
        tail.add(8, "/a", "oops")
        return await asyncio.wait_for(call, 5)
    code, _msg, text = asyncio.run(scenario())
    assert json.loads(text)["log"] == [["/a", "ERROR", "oops"]]


def test_the_tail_keeps_the_newest():
    tail = RosoutTail(kept=3)
    for i in range(5):
        tail.add(4, "/a", str(i))
    assert tail.since(0) == [("/a", "WARN", "2"), ("/a", "WARN", "3"), ("/a", "WARN", "4")]
    assert tail.since(3) == [("/a", "WARN", "3"), ("/a", "WARN", "4")] and tail.since(5) == []


def test_bad_output_arguments_are_a_fault(tmp_path):
    server, _ = make_server(tmp_path)
    for args in (("[]", 0), ("{}", -1), ("not json", 0), (5, 0)):
        with pytest.raises(Fault):
            server.launcher_output(*args)


def test_samples_are_the_running_nodes_cpu_and_rss(tmp_path):
    server, fleet = make_server(tmp_path)
    fleet.nodes["/a"].cpu, fleet.nodes["/a"].rss = 0.5, 1000
    code, _msg, text = server.launcher_samples()
    assert code == 1 and json.loads(text) == {"/a": [0.5, 1000]}


def test_the_page_answers_only_hosts_that_name_it():
    assert allowed_host("127.0.0.1:8080", 8080, "127.0.0.1")
    assert allowed_host("localhost:8080", 8080, "127.0.0.1")
    assert allowed_host("[::1]:8080", 8080, "::1")
    assert allowed_host("%s:8080" % socket.gethostname(), 8080, "0.0.0.0")
    assert not allowed_host("127.0.0.1:8081", 8080, "127.0.0.1")  # another port
    assert not allowed_host("evil.example:8080", 8080, "127.0.0.1")  # DNS rebinding: a name resolving here
    assert not allowed_host("127.0.0.1", 8080, "127.0.0.1")
    assert not allowed_host("", 8080, "127.0.0.1")


def test_address_is_loopback_unless_given_and_samples_round_to_what_shows():
    assert parse_address("8080") == ("127.0.0.1", 8080)
    assert parse_address("0.0.0.0:8080") == ("0.0.0.0", 8080)
    assert parse_address("[::1]:8080") == ("::1", 8080)
    assert round_sample(0.01234, 33_345_678) == [0.012, 33_300_000]
    assert round_sample(None, None) == [None, None]


def test_samples_with_history_are_what_the_fleet_kept(tmp_path):
    server, fleet = make_server(tmp_path)
    fleet.nodes["/a"].state = "running"
    for i in range(3):
        fleet.sample("/a", 0.1 * i, 1000 + i)
    code, _msg, text = server.launcher_samples(True)
    kept = json.loads(text)
    assert code == 1 and list(kept) == ["/a"] and [s[1:] for s in kept["/a"]] == [[0.0, 1000], [0.1, 1001],
                                                                                  [0.2, 1002]]
    assert json.loads(server.launcher_samples()[2]) == {"/a": [0.2, 1002]}  # (without: the last sample only)


def test_a_status_read_before_the_nodes_were_made_is_not_kept_for_after(tmp_path):
    # (the cached status may be half a second old, but not older than the fleet: a view attached during the
    # start read "no nodes" again when it asked at the first change, and kept that for good)
    from launcher.net.xmlrpc_codec import dumps_response, loads_response

    def status_nodes():  # (as a caller gets it: the server keeps the status XML-encoded)
        return [n["name"] for n in json.loads(loads_response(dumps_response(server.launcher_status()))[2])["nodes"]]
    server, make_nodes = launch_server_setting_up()
    assert status_nodes() == []
    make_nodes()
    assert status_nodes() == ["/a"]


def test_a_status_read_before_the_nodes_were_made_says_the_launch_is_starting(tmp_path):
    """`launcher status` during a long start (a master waited for, many parameters) said "no nodes"."""
    from launcher.operate.status import table
    server, make_nodes = launch_server_setting_up()
    info = json.loads(server._build_status())
    assert info["starting"] is True and info["nodes"] == []
    assert table(info).splitlines()[1].startswith("starting: its nodes start once the master is up")
    make_nodes()
    info = json.loads(server._build_status())
    assert info["starting"] is False and table(info).splitlines()[1].split()[0] == "NODE"
    assert table(dict(info, nodes=[])).splitlines()[1] == "no nodes"  # (a launch of none, or a core)


def test_changes_asked_before_the_nodes_were_made_are_answered_when_they_are(tmp_path):
    server, make_nodes = launch_server_setting_up()

    async def go():
        asked = asyncio.ensure_future(server.launcher_changes(0, 30.0))
        await asyncio.sleep(0.05)
        assert not asked.done()  # (a long poll, not an empty answer at once that its reader asks again and again)
        make_nodes()
        return await asyncio.wait_for(asked, 5.0)
    code, _msg, text = asyncio.run(go())
    answer = json.loads(text)
    assert code == 1 and answer["seq"] >= 1 and [c["node"] for c in answer["changes"]] == ["/a"]


def test_changes_asked_while_a_launch_sets_up_end_at_their_timeout_saying_it_is_starting(tmp_path):
    server, _ = launch_server_setting_up()
    code, _msg, text = asyncio.run(server.launcher_changes(0, 0.05))
    assert code == 1 and json.loads(text) == {"seq": 0, "complete": True, "starting": True, "changes": []}
    core, _ = launch_server_setting_up(core=True)  # (launch --core: no node is ever made)
    code, _msg, text = asyncio.run(core.launcher_changes(0, 0.05))
    assert code == 1 and json.loads(text) == {"seq": 0, "complete": True, "starting": False, "changes": []}


def test_changes_asked_of_a_launch_that_makes_no_node_are_answered_once_it_has_set_up(tmp_path):
    """A launch of parameters alone has no change to say it is set up by: a view that attached while it set up
    said "starting" for good."""
    from launcher.operate.view import ViewState
    server, make_nodes = launch_server_setting_up(names=())
    view = ViewState()
    view.load(json.loads(server._build_status()))
    assert view.starting

    async def go():
        asked = asyncio.ensure_future(server.launcher_changes(0, 30.0))
        await asyncio.sleep(0.05)
        assert not asked.done()
        make_nodes()
        return await asyncio.wait_for(asked, 1.0)  # (at once: not at the end of the long poll)
    code, _msg, text = asyncio.run(go())
    answer = json.loads(text)
    assert code == 1 and answer == {"seq": 0, "complete": True, "starting": False, "changes": []}
    assert view.stale(answer)  # (its reader reads the status again: no node, and no longer starting)
    view.load(json.loads(server._build_status()))
    assert not view.starting and not view.stale(answer)


def test_a_page_attached_while_the_launch_sets_up_says_so_until_the_launch_has_made_its_nodes(tmp_path):
    """The page's table was empty, without a word, while the terminal view and `launcher status` said "starting".
    Its hub reads a real launch server over XML-RPC here."""
    from launcher.operate import web
    from launcher.operate.columns import STARTING
    server, make_nodes = launch_server_setting_up(names=("/a", "/b"))
    events = []

    class Page:  # (a page's event stream, as the hub hands it each event)
        def send(self, data: bytes) -> bool:
            events.append(json.loads(data.decode()[len("data: "):]))
            return True

    async def go():
        await server.start()
        try:
            hub = web.Hub(server.uri, json.loads(server._build_status()), {})
            reply = hub.subscribe()
            reply.attach(Page())
            events.append(json.loads(reply.first.decode()[len("data: "):]))
            reading = asyncio.ensure_future(hub._changes())
            await asyncio.sleep(0.1)
            make_nodes()
            await asyncio.wait_for(reading, 10)
            late = json.loads(hub.subscribe().first.decode()[len("data: "):])  # (a page that comes after)
            return late
        finally:
            await server.stop()
    late = asyncio.run(go())
    assert [e["type"] for e in events] == ["snapshot", "started", "changes"]
    assert events[0]["starting"] == STARTING and events[0]["nodes"] == []
    assert [c["node"] for c in events[2]["changes"]] == ["/a", "/b"]
    assert late["starting"] == "" and [n["name"] for n in late["nodes"]] == ["/a", "/b"]
