"""The parent side of roslaunch's remote protocol: one child per machine over ssh, and the parent's XML-RPC API.

For each machine that has nodes, the parent runs (over `launcher.remote.ssh`)
`env ROS_MASTER_URI=... ENV_LOADER roslaunch -c NAME -u PARENT_URI --run_id ID`.
The child (Debian's roslaunch, or our `launch -c`) starts an XML-RPC server and
calls the parent's `register(NAME, CHILD_URI)`; the parent then calls the
child's `launch(XML)` with that machine's nodes (parameters are the parent's
business: it has set them on the master already). While it runs, the child
reports with `log(NAME, LEVEL, TEXT)` and `process_died(PROCESS, EXIT_CODE)`,
and runs respawns itself. At the end the parent calls `shutdown()`, then
closes the ssh session (whose pty hangup stops a child that did not answer).
PARENT_URI is the launch's own roslaunch server (`launcher.operate.server`,
which hands these calls here), as roslaunch has one: a Debian child registers
PARENT_URI on the master as the launch's, and a second server would be listed
as a second launch.

A machine whose session ends while the launch runs (the link was cut, the host
rebooted) is tried again with a growing delay; when it answers, its nodes are
launched again (roslaunch gives up on it: PR #1345 was never merged).
"""

from __future__ import annotations

import asyncio
import collections
import os
import re
import signal
from typing import Any, Callable, Mapping

from launcher.config import Machine, Node
from launcher.errors import LaunchError
from launcher.names import ns_join
from launcher.net.xmlrpc import call
from launcher.net.xmlrpc_server import XmlRpcServer
from launcher.process import console, state
from launcher.remote import ssh
from launcher.remote.launch_xml import remote_launch_xml

# rosgraph_msgs/Log levels (the `level` of `log`)
LOG_ERROR = 8
# A dropped machine is tried again after 1, 2, 4 ... seconds, at most this long apart.
RETRY_MAX_S = 30.0
RETRY_FIRST_S = 1.0
# How long `launch(XML)` may take on the child (it starts every node before answering).
LAUNCH_CALL_TIMEOUT_S = 120.0
# At shutdown: the child's `shutdown()` stops its nodes (SIGINT, SIGTERM escalation) before it answers.
SSH_EXIT_GRACE_S = 2.0
OUTPUT_LINES_KEPT = 40
_STARTED = re.compile(r"process\[(?P<proc>[^\]]+)\]: started with pid \[(?P<pid>\d+)\]")


def machine_nodes(nodes: list[Node], machines: Mapping[str, Machine],
                  is_remote: Callable[[Node], bool]) -> dict[str, list[Node]]:
    """The remote nodes binned by machine name, in launch order."""
    binned: dict[str, list[Node]] = {}
    for node in nodes:
        if is_remote(node):
            binned.setdefault(machines[node.machine_name].name, []).append(node)
    return binned


def check_addresses(master_uri: str, advertised_host: str, machines: list[Machine]) -> None:
    """A remote host must reach the master and the parent: loopback addresses are an error (file:line)."""
    import urllib.parse
    host = urllib.parse.urlsplit(master_uri).hostname or ""
    for what, name, var in (("ROS_MASTER_URI", host, "ROS_MASTER_URI"),
                            ("this machine's ROS address", advertised_host, "ROS_IP or ROS_HOSTNAME")):
        if name in ("localhost", "::1", "ip6-localhost") or name.startswith("127."):
            m = machines[0]
            raise LaunchError("%s [%s] is a loopback address, which machine [%s] at [%s] cannot reach: set %s to "
                              "an address of this computer that the other machines can reach"
                              % (what, master_uri if var == "ROS_MASTER_URI" else name, m.name, m.address, var),
                              m.filename or None, m.line or None)


class RemoteChild:
    """One machine's child roslaunch: its ssh session, its registration, its nodes."""

    def __init__(self, name: str, machine: Machine, nodes: list[Node]):
        self.name = name  # roslaunch's child name: "ADDRESS-COUNTER"
        self.machine = machine
        self.nodes = nodes
        self.uri: str | None = None
        self.registered: asyncio.Event = asyncio.Event()
        self.ssh: asyncio.subprocess.Process | None = None
        self.output: collections.deque[str] = collections.deque(maxlen=OUTPUT_LINES_KEPT)
        self.launched = False  # its nodes were handed to it (this session)
        self.ever_launched = False
        self.finished = False  # it ended after all its nodes had ended for good (nothing to start again)
        self.task: asyncio.Task | None = None

    def where(self) -> str:
        m = self.machine
        return "%s:%d" % (m.filename, m.line) if m.filename and m.line else m.filename or ""

    def node_for_process(self, process_name: str) -> Node | None:
        """The node a child's process name (`ns/name-N`) stands for."""
        base = re.sub(r"-\d+$", "", process_name)
        for node in self.nodes:
            if ns_join(node.namespace, node.name).lstrip("/") == base:
                return node
        return None


class RemoteParent:
    """The parent's XML-RPC server and every machine's child (see module docstring)."""

    def __init__(self, by_machine: dict[str, list[Node]], machines: Mapping[str, Machine], *, run_id: str,
                 master_uri: str, host: str, environ: Mapping[str, str], watchdog: Any = None, sigint_timeout: float = 15.0, sigterm_timeout: float = 2.0,
                 program: str | None = None):
        self.run_id = run_id
        self.master_uri = master_uri
        self.host = host
        self.environ = environ
        # set by attach(): the children are started before them (ssh and a remote roslaunch take
        # a second; that second overlaps the master's start and the parameters), but get their
        # nodes only once the parameters are set
        self.fleet: state.Fleet = None  # type: ignore[assignment]
        self.supervisor: Any = None
        self.attached = asyncio.Event()
        self.watchdog = watchdog
        self.sigint_timeout = sigint_timeout
        self.sigterm_timeout = sigterm_timeout
        # the program the remote side runs: Debian's roslaunch, unless LAUNCHER_REMOTE_PROGRAM names another
        self.program = program or environ.get("LAUNCHER_REMOTE_PROGRAM") or "roslaunch"
        self.children: dict[str, RemoteChild] = {}
        for counter, (mname, nodes) in enumerate(by_machine.items()):
            machine = machines[mname]
            child = RemoteChild("%s-%d" % (machine.address, counter), machine, nodes)
            self.children[child.name] = child
        self.server: XmlRpcServer | None = XmlRpcServer(self._dispatch, "0.0.0.0", 0)
        self.uri = ""
        self.stopping = False

    # ---- running ------------------------------------------------------------------------------------

    async def start(self, uri: str = "") -> None:
        """Start every child's session (the sessions go on on their own tasks), and the server, unless `uri`
        is the launch's own server, which hands PARENT_CALLS to `parent_call`: roslaunch has one server, and
        a Debian child registers the URI it is given on the master as the launch's."""
        if uri:
            self.server = None
            self.uri = uri
        else:
            await self.server.start()
            self.uri = "http://%s:%d/" % (self.host, self.server.port)
            console.printlog_bold("started roslaunch server %s" % self.uri)
        for child in self.children.values():
            child.task = asyncio.ensure_future(self._keep(child))

    def attach(self, fleet: state.Fleet, supervisor: Any) -> None:
        """The parameters are set: the nodes' states go to `fleet`, required ends to `supervisor`."""
        self.fleet, self.supervisor = fleet, supervisor
        for child in self.children.values():
            for node in child.nodes:
                fleet.add(node.full_name, process=node.full_name.lstrip("/"), host=child.machine.address)
        self.attached.set()

    async def _keep(self, child: RemoteChild) -> None:
        """Run the child; after a drop, try again with a growing delay while the launch runs."""
        delay = RETRY_FIRST_S
        while not self.stopping:
            await self._session(child)
            if self.stopping or child.finished:
                return
            if not child.ever_launched:
                await self.attached.wait()
                self._machine_failed(child)
                return
            console.printerrlog("remote[%s]: machine [%s] dropped; trying again in %.0f s"
                                % (child.name, child.machine.name, delay))
            await asyncio.sleep(delay)
            delay = min(RETRY_MAX_S, delay * 2)

    async def _session(self, child: RemoteChild) -> None:
        """One ssh session: start it, wait for `register`, hand over the nodes, run until it ends."""
        m = child.machine
        child.uri, child.launched = None, False
        child.registered.clear()
        child.output.clear()
        command = ssh.remote_command(m, self.program, child.name, self.uri, self.run_id, self.master_uri,
                                     self.sigint_timeout, self.sigterm_timeout)
        argv = ssh.ssh_argv(m, command, self.environ)
        console.printlog("remote[%s] starting roslaunch" % child.name)
        console.printlog("remote[%s]: creating ssh connection to %s:%s%s"
                         % (child.name, m.address, m.ssh_port, ", user[%s]" % m.user if m.user else ""))
        try:
            # its own session: a Ctrl-C on the terminal reaches the launcher only, which shuts the child down
            proc = await asyncio.create_subprocess_exec(*argv, stdin=asyncio.subprocess.PIPE,
                                                        stdout=asyncio.subprocess.PIPE,
                                                        stderr=asyncio.subprocess.STDOUT, start_new_session=True)
        except OSError as e:
            child.output.append("cannot run %s: %s" % (argv[0], e.strerror))
            return
        child.ssh = proc
        if self.watchdog is not None:
            self.watchdog.watch(proc.pid)  # a killed launcher takes ssh down, and the pty hangup the child
        reader = asyncio.ensure_future(self._read_output(child, proc))
        heartbeat = asyncio.ensure_future(self._heartbeat(proc))
        try:
            registered = asyncio.ensure_future(child.registered.wait())
            await asyncio.wait((registered, reader), timeout=m.timeout, return_when=asyncio.FIRST_COMPLETED)
            registered.cancel()
            if not child.registered.is_set():
                if not reader.done():
                    child.output.append("the remote roslaunch did not register within %s s (<machine timeout=...>)"
                                        % m.timeout)
                return
            await self.attached.wait()
            await self._launch_on(child)
            await reader  # the session runs until ssh ends
        finally:
            await self._end_ssh(child)
            if self.watchdog is not None:
                self.watchdog.forget(proc.pid)
            reader.cancel()
            heartbeat.cancel()
            child.ssh = None
            if child.launched and not self.stopping:
                if self._any_alive(child):
                    self._nodes_lost(child)
                else:
                    child.finished = True  # every node ended and was reported: the child's work is done

    async def _read_output(self, child: RemoteChild, proc: asyncio.subprocess.Process) -> None:
        assert proc.stdout is not None
        while True:
            line = await proc.stdout.readline()
            if not line:
                break
            text = line.decode("utf-8", "replace").rstrip("\r\n")
            if text:
                child.output.append(text)
        await proc.wait()

    async def _heartbeat(self, proc: asyncio.subprocess.Process) -> None:
        """A newline every HEARTBEAT_S through the session: the remote watch loop stops the child without it."""
        assert proc.stdin is not None
        try:
            while proc.returncode is None:
                proc.stdin.write(b"\n")  # (1 byte a second: a stalled ssh never fills the pipe)
                await asyncio.sleep(ssh.HEARTBEAT_S)
        except (OSError, RuntimeError):
            pass  # ssh is gone

    async def _launch_on(self, child: RemoteChild) -> None:
        console.printlog("remote[%s]: ssh connection created" % child.name)
        xml = remote_launch_xml(child.nodes)
        try:
            code, msg, val = await call(child.uri or "", "launch", xml, timeout=LAUNCH_CALL_TIMEOUT_S)
        except Exception as e:  # noqa: BLE001 - any failure of the call: the nodes most likely did not start
            code, msg, val = 0, str(e) or type(e).__name__, None
        child.launched = child.ever_launched = True
        if code != 1:
            console.printerrlog("error launching on [%s, uri %s]: %s" % (child.name, child.uri, msg))
            console.printerrlog("Launch of the following nodes most likely failed: %s"
                                % ", ".join("%s/%s" % (n.package, n.type) for n in child.nodes))
            return
        _succeeded, failed = val
        for name in failed:
            node = child.node_for_process(name) or next((n for n in child.nodes if "%s/%s" % (n.package, n.type)
                                                         == name), None)
            console.printerrlog("remote[%s]: node [%s] could not be started on [%s]"
                                % (child.name, node.full_name if node else name, child.machine.name))
            if node is not None:
                self.fleet.change(node.full_name, state.EXITED, reason="could not be started")
                if node.required:
                    self.supervisor.not_started(node.full_name, True)

    async def _end_ssh(self, child: RemoteChild) -> None:
        """Close the session: SIGTERM to ssh closes the connection, whose pty hangup stops the child."""
        proc = child.ssh
        if proc is None or proc.returncode is not None:
            return
        for sig, wait in ((signal.SIGTERM, SSH_EXIT_GRACE_S), (signal.SIGKILL, None)):
            try:
                os.killpg(proc.pid, sig)
            except OSError:
                pass
            try:
                await asyncio.wait_for(proc.wait(), wait)
                return
            except asyncio.TimeoutError:
                continue

    # ---- what happens to nodes ----------------------------------------------------------------------

    def _machine_failed(self, child: RemoteChild) -> None:
        """The child never ran: say why (machine, file:line), and what it means for its nodes."""
        proc = child.ssh
        status = proc.returncode if proc is not None else None
        reason = ssh.explain_failure(child.machine, "\n".join(child.output), status, self.program)
        where = child.where()
        console.printerrlog("%sremote[%s]: failed to launch on machine [%s]:\n\n%s\n"
                            % (where + ": " if where else "", child.name, child.machine.name, reason))
        for node in child.nodes:
            self.fleet.change(node.full_name, state.EXITED, reason="machine [%s] failed" % child.machine.name)
            self.supervisor.not_started(node.full_name, node.required)

    def _any_alive(self, child: RemoteChild) -> bool:
        """Is a node of the child running or due to respawn, as far as its reports say?"""
        for node in child.nodes:
            status = self.fleet.nodes.get(node.full_name)
            if status is None or status.state not in (state.EXITED, state.FATAL, state.STOPPED):
                return True
        return False

    def _nodes_lost(self, child: RemoteChild) -> None:
        for node in child.nodes:
            status = self.fleet.nodes.get(node.full_name)
            if status is not None and status.state in (state.RUNNING, state.RESPAWNING):
                self.fleet.change(node.full_name, state.EXITED, reason="machine [%s] dropped" % child.machine.name)
            if node.required:
                console.printerrlog("=" * 80 + "REQUIRED process [%s] was lost with machine [%s]!\n"
                                    "Initiating shutdown!\n" % (node.full_name, child.machine.name) + "=" * 80)
                self.supervisor.end(failed=True)

    def _process_died(self, process_name: str, exit_code: Any) -> None:
        if self.fleet is None:
            return
        for child in self.children.values():
            node = child.node_for_process(process_name)
            if node is None:
                continue
            code = exit_code if isinstance(exit_code, int) else None
            code_, sig = (None, -code) if code is not None and code < 0 else (code, None)
            if node.required:
                console.printerrlog("=" * 80 + "REQUIRED process [%s] on machine [%s] has died!\nexit code %s\n"
                                    "Initiating shutdown!\n" % (process_name, child.machine.name, exit_code)
                                    + "=" * 80)
                self.supervisor.end(failed=code != 0)
            self.fleet.change(node.full_name, state.RESPAWNING if node.respawn else state.EXITED,
                              exit_code=code_, exit_signal=sig)
            return

    # ---- the parent's XML-RPC API (roslaunch.server.ROSLaunchParentHandler) -------------------------

    PARENT_CALLS = ("register", "list_children", "process_died", "log")  # what only the children call

    def parent_call(self, method: str, params: list) -> Any:
        return self._dispatch(method, params)

    def _dispatch(self, method: str, params: list) -> Any:
        fn = self._API.get(method)
        if fn is None:
            from launcher.net.xmlrpc import Fault
            raise Fault(-1, "method [%s] is not supported" % method)
        return fn(self, *params)

    def register(self, client: str, uri: str) -> list:
        child = self.children.get(client)
        if child is None:
            return [-1, "unknown child [%s]" % client, 0]
        child.uri = uri
        child.registered.set()
        return [1, "registered", 1]

    def list_children(self) -> list:
        return [1, "roslaunch children", [c.uri for c in self.children.values() if c.uri is not None]]

    def process_died(self, process_name: str, exit_code: Any) -> list:
        self._process_died(process_name, exit_code)
        return [1, "", 0]

    def log(self, client: str, level: int, message: str) -> list:
        text = "[%s]: %s" % (client, message)
        if isinstance(level, int) and level >= LOG_ERROR:
            console.printerrlog(text)
        elif "started with pid" in message:
            console.printlog_bold(text)
            m = _STARTED.search(message)
            child = self.children.get(client)
            node = child.node_for_process(m.group("proc")) if m and child else None
            if node is not None and self.fleet is not None:
                self.fleet.change(node.full_name, state.RUNNING, pid=int(m.group("pid")))
        else:
            console.printlog(text)
        return [1, "", 1]

    def list_processes(self) -> list:
        active, dead = [], []
        for status in self.fleet or ():
            if status.host == "localhost":
                (active if status.state in (state.RUNNING, state.RESPAWNING) else dead).append(
                    [status.process, status.restarts + 1])
        return [1, "processes on parent machine", [active, dead]]

    def process_info(self, process_name: str) -> list:
        for status in self.fleet or ():
            if status.process == process_name and status.host == "localhost":
                return [1, "process info", {"name": status.process, "pid": status.pid or 0,
                                            "alive": status.state == state.RUNNING,
                                            "respawn_count": status.restarts}]
        return [-1, "no process by that name", {}]

    def get_pid(self) -> list:
        pid = os.getpid()
        return [1, str(pid), pid]

    def get_node_names(self) -> list:
        return [1, "node names", [s.name for s in self.fleet or () if s.host == "localhost" and s.state == state.RUNNING]]

    _API = {"register": register, "list_children": list_children, "process_died": process_died, "log": log,
            "list_processes": list_processes, "process_info": process_info, "get_pid": get_pid,
            "get_node_names": get_node_names}

    # ---- stopping -----------------------------------------------------------------------------------

    async def shutdown(self) -> None:
        """Ask every child to stop its nodes, then close the sessions."""
        self.stopping = True
        live = [c for c in self.children.values() if c.ssh is not None]
        for child in live:
            console.printlog("[%s] killing on exit" % child.name)

        async def stop(child: RemoteChild) -> None:
            if child.uri is not None:
                try:
                    await call(child.uri, "shutdown", timeout=self.sigint_timeout + self.sigterm_timeout + 5)
                except Exception:  # noqa: BLE001 - the hangup below stops it anyway
                    console.printerrlog("remote[%s]: unable to contact [%s] to shutdown remote processes!"
                                        % (child.name, child.machine.address))
            await self._end_ssh(child)

        await asyncio.gather(*(stop(c) for c in live))
        for child in self.children.values():
            if child.task is not None:
                child.task.cancel()
                try:
                    await child.task
                except BaseException:  # noqa: BLE001 - cancelled on purpose
                    pass
        if self.server is not None:
            await self.server.stop()
