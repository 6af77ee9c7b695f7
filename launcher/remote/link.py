"""One machine's roslaunch child as the parent keeps it: its nodes, and its ssh session over the launch's life.

For each machine that has nodes, the parent runs (over `launcher.remote.ssh`)
`env ROS_MASTER_URI=... ENV_LOADER roslaunch -c NAME -u PARENT_URI --run_id ID`.
The child (Debian's roslaunch, or our `launch -c`) starts an XML-RPC server and
calls the parent's `register(NAME, CHILD_URI)` (`remote.handler`); once the
launch's parameters are set, the link hands the machine's queued nodes to the
child's `launch(XML)`, one call at a time. A newline goes through the session
every `ssh.HEARTBEAT_S`: without it the remote watch loop stops the child.

The session is kept while the launch runs: a machine never reached fails once
(said with its `<machine>`'s file and line), one that drops is tried again with
a growing delay and its nodes are launched again when it answers (roslaunch
gives up on it: PR #1345 was never merged), and a child that ended with its
last node gets a new session when a node is to start there again. What comes
after a session is `remote.session`'s decision; the link carries it out and
tells the parent (`Parent`) what happened to the nodes, which the parent tells
the fleet.
"""

from __future__ import annotations

import asyncio
import collections
import os
import signal
from typing import Any, Mapping, NamedTuple, Optional, Protocol

from launcher import compat
from launcher.fleet import lifecycle
from launcher.fleet.lifecycle import Event
from launcher.model.config import Machine, Node, NodePolicy
from launcher.net.xmlrpc import Fault, call
from launcher.output import console
from launcher.remote import session, ssh
from launcher.remote.launch_xml import remote_launch_xml

# How long `launch(XML)` may take on the child (it starts every node before answering).
LAUNCH_CALL_TIMEOUT_S = 120.0
# At shutdown: the child's `shutdown()` stops its nodes (SIGINT, SIGTERM escalation) before it answers.
SSH_EXIT_GRACE_S = 2.0
OUTPUT_LINES_KEPT = 40
DEFAULT_POLICY = NodePolicy()


class RemoteSpec(NamedTuple):
    """What `health.readiness` reads of a held node (as of a NodeProcess's spec)."""

    name: str
    node_name: str
    policy: NodePolicy


class RemoteNode:
    """One node of a machine, as the parent hands it over (its state is the fleet's record)."""

    def __init__(self, node: Node, child: RemoteChild):
        self.child = child
        self.timer: asyncio.TimerHandle | None = None  # a DUE to come: spawn_delay or a respawn's delay
        self.renew(node)

    def renew(self, node: Node) -> None:
        """The node as the launch file (now) says it."""
        self.node = node
        # the parent applies its restart policy; the child runs it with respawn="false"
        self.owned = node.policy is not None
        self.spec = RemoteSpec(node.full_name.lstrip("/"), node.full_name, node.policy or DEFAULT_POLICY)

    @property
    def name(self) -> str:
        return self.spec.node_name

    def rules(self) -> lifecycle.Rules:
        n = self.node
        return lifecycle.Rules(required=n.required, respawn=n.respawn, respawn_delay=n.respawn_delay,
                             policy=self.spec.policy, remote=True, owned=self.owned, machine=self.child.machine.name)

    def sent(self) -> Node:
        """The node as the child gets it."""
        return self.node._replace(respawn=False, respawn_delay=0.0) if self.owned else self.node


class Parent(Protocol):
    """What a machine's link reads of the parent (`remote.parent.RemoteParent`), and tells it of the nodes."""

    uri: str  # the parent's XML-RPC server, which the child registers with
    run_id: str
    master_uri: str
    environ: Mapping[str, str]
    program: str  # what the remote side runs: roslaunch, or ours
    watchdog: Any  # (process.watchdog.Watchdog: a killed launcher takes ssh down)
    sigint_timeout: float
    sigterm_timeout: float
    attached: asyncio.Event  # the launch's parameters are set: nodes may be handed over

    @property
    def stopping(self) -> bool: ...

    def tell(self, rn: RemoteNode, event: Event) -> list[lifecycle.Action]: ...

    def node_state(self, rn: RemoteNode) -> str: ...


class RemoteChild:
    """One machine's child roslaunch: its ssh session, kept while the launch runs, its registration, its nodes."""

    def __init__(self, name: str, machine: Machine, nodes: list[Node], parent: Parent):
        self.name = name  # roslaunch's child name: "ADDRESS-COUNTER"
        self.machine = machine
        self.parent = parent
        self.nodes = [RemoteNode(n, self) for n in nodes]
        self.uri: str | None = None
        self.registered: asyncio.Event = compat.Event()
        self.ssh: asyncio.subprocess.Process | None = None
        self.output: collections.deque[str] = collections.deque(maxlen=OUTPUT_LINES_KEPT)
        self.wanted = compat.Event()  # a node is queued (pending or lost): a session is needed
        self.session = session.Session()  # this machine's session with its child (remote.session)
        self.launching: asyncio.Task | None = None
        self.task: asyncio.Task | None = None

    @property
    def accepting(self) -> bool:
        """This session's child takes `launch` calls."""
        return self.session.phase == session.ACCEPTING

    def where(self) -> str:
        m = self.machine
        return "%s:%d" % (m.filename, m.line) if m.filename and m.line else m.filename or ""

    def node_for_process(self, process_name: str) -> Optional[RemoteNode]:
        """The node a child's process name (`ns/name-N`) stands for."""
        base = session.node_of_process(process_name)
        for rn in self.nodes:
            if rn.spec.name == base:
                return rn
        return None

    def queued(self) -> list[RemoteNode]:
        """The nodes to hand to the child at the next opportunity: the machine's records say which."""
        state = self.parent.node_state
        return [rn for rn in self.nodes if state(rn) in session.QUEUED]

    def want(self) -> None:
        """A node is queued for the machine: now if its child takes nodes, else with the next session."""
        self.wanted.set()
        if self.accepting and (self.launching is None or self.launching.done()):
            self.launching = asyncio.ensure_future(self._launch_queued())

    def process_died(self) -> None:
        """A node of this child died: a child whose last node died exits (remote.session.child_ends), and
        nothing more is sent to it."""
        state = self.parent.node_state
        if session.child_ends(self.session, ((state(rn), rn.owned) for rn in self.nodes)):
            self.session = session.ending(self.session)

    # ---- the session, kept while the launch runs ------------------------------------------------------

    def start(self) -> None:
        """Keep the machine's session on a task of its own, from now until the launch stops."""
        self.task = asyncio.ensure_future(self._keep())

    async def _keep(self) -> None:
        """Run the child while the launch runs: again after a drop (with a growing delay), and again
        when a node is to start after the child ended with its last node (remote.session decides)."""
        parent = self.parent
        while not parent.stopping:
            registered, lost = await self._session()
            if parent.stopping:
                return
            self.session, after = session.after_session(self.session, registered=registered, lost=lost,
                                                        queued=bool(self.queued()))
            if after.what == session.GIVE_UP:
                await parent.attached.wait()
                self._failed()
                return
            if after.what == session.RETRY:
                if after.dropped:
                    console.printerrlog("remote[%s]: machine [%s] dropped; trying again in %.0f s"
                                        % (self.name, self.machine.name, after.delay))
                await asyncio.sleep(after.delay)
                continue
            # the child ended with its last node (as roslaunch's children do): a new session when a
            # node is to start there again (a respawn the parent owns), else never
            self.wanted.clear()
            await self.wanted.wait()

    async def _session(self) -> tuple[bool, bool]:
        """One ssh session: start it, wait for `register`, hand over the nodes, run until it ends.

        (did the child register, were nodes lost with it)."""
        parent, m = self.parent, self.machine
        self.uri = None
        self.session = session.started(self.session)
        self.registered.clear()
        self.output.clear()
        command = ssh.remote_command(m, parent.program, self.name, parent.uri, parent.run_id, parent.master_uri,
                                     parent.sigint_timeout, parent.sigterm_timeout)
        argv = ssh.ssh_argv(m, command, parent.environ)
        console.printlog("remote[%s] starting roslaunch" % self.name)
        console.printlog("remote[%s]: creating ssh connection to %s:%s%s"
                         % (self.name, m.address, m.ssh_port, ", user[%s]" % m.user if m.user else ""))
        try:
            # its own session: a Ctrl-C on the terminal reaches the launcher only, which shuts the child down
            proc = await asyncio.create_subprocess_exec(*argv, stdin=asyncio.subprocess.PIPE,
                                                        stdout=asyncio.subprocess.PIPE,
                                                        stderr=asyncio.subprocess.STDOUT, start_new_session=True)
        except OSError as e:
            self.output.append("cannot run %s: %s" % (argv[0], e.strerror))
            return False, False
        self.ssh = proc
        watchdog = parent.watchdog
        if watchdog is not None:
            watchdog.watch(proc.pid)  # a killed launcher takes ssh down, and the pty hangup the child
        reader = asyncio.ensure_future(self._read_output(proc))
        heartbeat = asyncio.ensure_future(_heartbeat(proc))
        try:
            registered = asyncio.ensure_future(self.registered.wait())
            await asyncio.wait((registered, reader), timeout=m.timeout, return_when=asyncio.FIRST_COMPLETED)
            registered.cancel()
            if not self.registered.is_set():
                if not reader.done():
                    self.output.append("the remote roslaunch did not register within %s s (<machine timeout=...>)"
                                       % m.timeout)
                return False, False
            await parent.attached.wait()
            console.printlog("remote[%s]: ssh connection created" % self.name)
            self.session = session.accepting(self.session)
            if self.queued():
                self.launching = asyncio.ensure_future(self._launch_queued())
            await reader  # the session runs until ssh ends
        finally:
            self.session = session.ending(self.session)
            if self.launching is not None:
                # (the nodes of a call under way are lost with the session, below: the record says
                # so, and they are queued once, whatever the cancelled call does next)
                self.launching.cancel()
                self.launching = None
            await self.end_ssh()
            if watchdog is not None:
                watchdog.forget(proc.pid)
            reader.cancel()
            heartbeat.cancel()
            self.ssh = None
        return True, (not parent.stopping and self._nodes_lost())

    async def _read_output(self, proc: asyncio.subprocess.Process) -> None:
        assert proc.stdout is not None
        while True:
            line = await proc.stdout.readline()
            if not line:
                break
            text = line.decode("utf-8", "replace").rstrip("\r\n")
            if text:
                self.output.append(text)
        await proc.wait()

    async def _launch_queued(self) -> None:
        """Hand the queued nodes to this session's child, one `launch` call at a time."""
        tell = self.parent.tell
        while self.accepting:
            batch = self.queued()
            if not batch:
                return
            for rn in batch:
                tell(rn, Event(lifecycle.LAUNCH_SENT))
            xml = remote_launch_xml(rn.sent() for rn in batch)
            try:
                code, msg, val = await call(self.uri or "", "launch", xml, timeout=LAUNCH_CALL_TIMEOUT_S)
            except asyncio.CancelledError:
                raise  # the session ended during the call: its end has said the nodes are lost
            except Exception as e:  # noqa: BLE001 - any failure of the call: the nodes most likely did not start
                code, msg, val = 0, str(e) or type(e).__name__, None
            if code != 1:
                # a child that refuses a launch (it is ending, or broken) gets no more: the nodes wait for
                # the next session, and this one is ended so that there is a next one (a child whose starts
                # all failed would otherwise live on with nothing, and the nodes wait for ever)
                console.printerrlog("error launching on [%s, uri %s]: %s" % (self.name, self.uri, msg))
                console.printerrlog("Launch of the following nodes most likely failed: %s"
                                    % ", ".join("%s/%s" % (rn.node.package, rn.node.type) for rn in batch))
                self.session = session.ending(self.session)
                for rn in batch:
                    tell(rn, Event(lifecycle.LAUNCH_REFUSED, reason="its machine's child refused it: %s" % msg))
                if self.ssh is not None and self.ssh.returncode is None:
                    self.ssh.terminate()
                return
            self.session = session.launched(self.session)
            succeeded, failed = val
            for name in succeeded:
                rn = self.node_for_process(name)
                if rn is not None:
                    tell(rn, Event(lifecycle.LAUNCHED, process=name))
            for name in failed:
                rn = self.node_for_process(name) or next((r for r in batch if "%s/%s" % (r.node.package, r.node.type)
                                                          == name), None)
                console.printerrlog("remote[%s]: node [%s] could not be started on [%s]"
                                    % (self.name, rn.name if rn else name, self.machine.name))
                if rn is not None:
                    tell(rn, Event(lifecycle.SPAWN_FAILED))

    async def stop_process(self, process: str) -> tuple[str, Any]:
        """Ask the child to stop one of its processes (`stop_process`, our child's extension; roslaunch's child
        has none): (why it did not, '' when it did; the exit code it reports)."""
        parent = self.parent
        try:
            code, msg, exit_code = await call(self.uri or "", "stop_process", process,
                                              timeout=parent.sigint_timeout + parent.sigterm_timeout + 5)
            return ("" if code == 1 else msg), exit_code
        except Fault as e:
            return session.stop_refusal(e.faultString), None
        except Exception as e:  # noqa: BLE001 - unreachable, timed out: the node was not stopped
            return str(e) or type(e).__name__, None

    # ---- its end ------------------------------------------------------------------------------------

    async def shut_down(self) -> None:
        """The launch stops: ask the child to stop its nodes (`shutdown()`), then close the session."""
        orderly = False
        if self.uri is not None:
            try:
                code, _msg, _val = await call(self.uri, "shutdown",
                                              timeout=self.parent.sigint_timeout + self.parent.sigterm_timeout + 5)
                orderly = code == 1
            except Exception:  # noqa: BLE001 - the hangup below stops it anyway
                console.printerrlog("remote[%s]: unable to contact [%s] to shutdown remote processes!"
                                    % (self.name, self.machine.address))
        await self.end_ssh(orderly)

    async def end_ssh(self, orderly: bool = False) -> None:
        """Close the session: SIGTERM to ssh closes the connection, whose pty hangup stops the child.

        `orderly`: the child was shut down and ends by itself; the session is let end with it
        (ssh.ORDERLY_END), which is sooner than a hangup's stop of the remote side."""
        proc = self.ssh
        if proc is None or proc.returncode is not None:
            return
        if orderly and proc.stdin is not None:
            try:
                proc.stdin.write(ssh.ORDERLY_END)
                await compat.wait_for(proc.wait(), SSH_EXIT_GRACE_S)
                return
            except (OSError, RuntimeError, asyncio.TimeoutError):
                pass  # then as any other end
        for sig, wait in ((signal.SIGTERM, SSH_EXIT_GRACE_S), (signal.SIGKILL, None)):
            try:
                os.killpg(proc.pid, sig)
            except OSError:
                pass
            try:
                await compat.wait_for(proc.wait(), wait)
                return
            except asyncio.TimeoutError:
                continue

    # ---- what its end means for its nodes -------------------------------------------------------------

    def _failed(self) -> None:
        """The child never ran: say why (machine, file:line), and what it means for its nodes."""
        proc = self.ssh
        status = proc.returncode if proc is not None else None
        reason = ssh.explain_failure(self.machine, "\n".join(self.output), status, self.parent.program)
        where = self.where()
        console.printerrlog("%sremote[%s]: failed to launch on machine [%s]:\n\n%s\n"
                            % (where + ": " if where else "", self.name, self.machine.name, reason))
        for rn in self.nodes:
            self.parent.tell(rn, Event(lifecycle.MACHINE_FAILED, reason="machine [%s] failed" % self.machine.name))

    def _nodes_lost(self) -> bool:
        """The session ended: the nodes it ran, or was being handed, are lost with it (and queued for the
        next one). Were any?"""
        lost = False
        for rn in self.nodes:
            self.parent.tell(rn, Event(lifecycle.LINK_LOST, reason="machine [%s] dropped" % self.machine.name))
            lost = lost or self.parent.node_state(rn) == lifecycle.LOST
        return lost


async def _heartbeat(proc: asyncio.subprocess.Process) -> None:
    """A newline every HEARTBEAT_S through the session: the remote watch loop stops the child without it."""
    assert proc.stdin is not None
    try:
        while proc.returncode is None:
            proc.stdin.write(b"\n")  # (1 byte a second: a stalled ssh never fills the pipe)
            await asyncio.sleep(ssh.HEARTBEAT_S)
    except (OSError, RuntimeError):
        pass  # ssh is gone
