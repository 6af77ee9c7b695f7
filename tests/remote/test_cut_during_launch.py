"""A machine's session ends while its `launch` call is under way: the node is queued once for the next session.

Deterministic, with no network: `LAUNCHER_SSH_COMMAND` is a stand-in for ssh that runs the remote command
here (the real watch loop of `remote.ssh`), and the child is a script that speaks
roslaunch's child protocol to the real `RemoteParent`: it registers, and holds its first `launch` call
until the test ends that session. The second session's `launch` must hold the node once: the old parent
queued it twice (once when the session was lost, once when the cancelled call gave its batch back), and
a child then refuses "multiple nodes named [/talker]" for ever.
"""

from __future__ import annotations

import asyncio
import os
import signal
import sys
import textwrap

from helpers import until_async
from launcher.model.config import Machine, Node
from launcher.model.graph import Graph
from launcher.fleet import lifecycle as m
from launcher.fleet.state import Fleet
from launcher.remote import parent as remote_parent

FAKE_SSH = textwrap.dedent("""\
    #!%s
    # ssh's stand-in: the command after `-- ADDRESS` runs here, its stdin the session's
    import os, sys
    argv = sys.argv[1:]
    command = argv[argv.index("--") + 2]
    os.execvp("sh", ["sh", "-c", command])
    """) % sys.executable

CHILD = textwrap.dedent("""\
    #!%s
    # a roslaunch child: `CHILD -c NAME -u PARENT_URI --run_id ID ...`; every launch call is appended to the log
    import os, sys, time, threading, xmlrpc.client
    from xmlrpc.server import SimpleXMLRPCServer
    argv = sys.argv[1:]
    name, parent = argv[argv.index("-c") + 1], argv[argv.index("-u") + 1]
    log = os.environ["CHILD_LOG"]
    session = sum(1 for line in open(log) if line.startswith("session")) + 1 if os.path.exists(log) else 1
    with open(log, "a") as f:
        f.write("session %%d %%d\\n" %% (session, os.getpid()))
    # off the session's output: when the session goes (the link is cut), this child lives on, its call
    # unanswered, as a child beyond a cut link does
    devnull = os.open(os.devnull, os.O_RDWR)
    for fd in (0, 1, 2):
        os.dup2(devnull, fd)
    server = SimpleXMLRPCServer(("127.0.0.1", 0), logRequests=False, allow_none=True)
    def launch(xml):
        with open(log, "a") as f:
            f.write("launch %%d %%d\\n" %% (session, xml.count('name="talker"')))
        if session == 1:
            time.sleep(3600)  # held: the test ends this session meanwhile
        xmlrpc.client.ServerProxy(parent).log(name, 2, "process[talker-%%d]: started with pid [%%d]" %% (session, os.getpid()))
        return [1, "launched", [["talker-%%d" %% session], []]]
    server.register_function(launch)
    server.register_function(lambda: [1, "", 1], "shutdown")
    threading.Thread(target=server.serve_forever, daemon=True).start()
    xmlrpc.client.ServerProxy(parent).register(name, "http://127.0.0.1:%%d/" %% server.server_address[1])
    time.sleep(3600)
    """) % sys.executable


def script(path, text: str) -> str:
    with open(path, "w") as f:
        f.write(text)
    os.chmod(path, 0o755)
    return str(path)


def launches(log: str) -> list[tuple[int, int]]:
    """(session, how many times the talker was in it) of each launch call the child got."""
    if not os.path.exists(log):
        return []
    with open(log) as f:
        return [(int(w[1]), int(w[2])) for w in (line.split() for line in f) if w[0] == "launch"]


def children(log: str) -> list[int]:
    with open(log) as f:
        return [int(w[2]) for w in (line.split() for line in f) if w[0] == "session"]


def test_a_session_cut_during_a_launch_call_queues_the_node_once(tmp_path, monkeypatch):
    log = str(tmp_path / "child.log")
    monkeypatch.setenv("CHILD_LOG", log)
    environ = dict(os.environ, LAUNCHER_SSH_COMMAND=script(tmp_path / "ssh", FAKE_SSH))
    machine = Machine("m1", "somewhere", env_loader="env")
    talker = Node("rostopic", "rostopic", "talker", machine_name="m1")

    async def main() -> tuple[list, str, int]:
        parent = remote_parent.RemoteParent({"m1": [talker]}, {"m1": machine}, run_id="r", master_uri="http://x:1/",
                                            host="127.0.0.1", environ=environ,
                                            program=script(tmp_path / "child", CHILD))
        fleet = Fleet()
        await parent.start()
        parent.attach(fleet, Graph())
        try:
            child = next(iter(parent.children.values()))
            await until_async(lambda: launches(log) == [(1, 1)], 20, what="the first launch call under way")
            assert fleet.records["/talker"].state == m.LAUNCHING
            # the session ends (ssh's process) with the call under way and unanswered: as when the link is cut
            os.kill(child.ssh.pid, signal.SIGKILL)
            await until_async(lambda: len(launches(log)) >= 2, 20, what="the next session's launch call")
            await until_async(lambda: fleet.records["/talker"].state == m.RUNNING, 20, what="talker on the child")
            return launches(log), fleet.records["/talker"].process, fleet.records["/talker"].spawn_count
        finally:
            await parent.shutdown()
            for pid in children(log):
                try:
                    os.kill(pid, signal.SIGKILL)
                except OSError:
                    pass

    calls, process, spawn_count = asyncio.run(main())
    assert calls == [(1, 1), (2, 1)], calls  # the talker once in each call, and no third call
    assert (process, spawn_count) == ("talker-2", 1)
