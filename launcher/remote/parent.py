"""The parent side of roslaunch's remote protocol: the other machines' runner, `RemoteParent`.

One child per machine that has nodes, kept over ssh while the launch runs
(`remote.link`: its session, its `launch` calls, its retries); the calls the
children make to the parent (`register`, `log`, `process_died`: `remote.handler`)
go to the launch's own roslaunch server (`launcher.services.server`, which hands
them here), as roslaunch has one: a Debian child registers PARENT_URI on the
master as the launch's, and a second server would be listed as a second launch.
At the end the parent calls each child's `shutdown()`, then closes its session
(whose pty hangup stops a child that did not answer).

Restarts: a node without supervision extensions is respawned by the child
itself, as roslaunch does. A node with a `NodePolicy` is the parent's: the
child gets it with respawn="false", and when it dies the parent applies the
same restart policy as to a local node (`launcher.fleet.restart`: backoff,
respawn_max_retries and FATAL, respawn_on="failure" ...), then starts it again
by a second `launch` call holding just that node (both Debian's child and ours
take more than one, and number the new process anew: talker-3). spawn_delay
and wait_for (master-side conditions) hold the node's first `launch` call. A
child whose last node ended exits (roslaunch's children do), so a node started
again then gets a new session. What a child cannot be told (limits, core dumps,
hang probes, per-node stop timeouts, log rotation) is warned about at load
(`plan.remote`).

What happens to each node is decided by its state machine
(`launcher.fleet.lifecycle`, kept by the fleet), as for a local node, with the
remote states: pending (queued for its machine's child), launching (in a
`launch` call), lost (its machine dropped). The nodes queued for a machine are
those in pending or lost, so a node cannot be queued twice. The parent tells
the fleet what its children report (`tell`) and carries out the actions
(`fleet.actions.ActionRunner`).

Operators (`launcher start|stop|restart`, launcher.services.server) steer a
remote node through `stop_node`/`start_node`: a stop is kept by the state
machine (no restart on its death or its machine's return) and done by the
child (`stop_process`, an extension of our child: roslaunch's child has none,
and the stop is refused); a start is a `launch` call holding it, as a restart
under a NodePolicy. A reload (run/reload.py) goes through the same calls.
"""

from __future__ import annotations

import asyncio
import os
from typing import Any, Mapping

from launcher import compat
from launcher.model.config import Machine, Node
from launcher.net.xmlrpc_server import XmlRpcServer
from launcher.output import console
from launcher.fleet import launchphase, lifecycle, state
from launcher.fleet.actions import carry_out
from launcher.fleet.lifecycle import Event
from launcher.health.readiness import Readiness
from launcher.model.graph import Graph
from launcher.plan.remote import same_host
from launcher.remote import handler, session
from launcher.remote.link import DEFAULT_POLICY, RemoteChild, RemoteNode


class RemoteParent:
    """The parent's XML-RPC server and every machine's child (see module docstring)."""

    def __init__(self, by_machine: dict[str, list[Node]], machines: Mapping[str, Machine], *, run_id: str,
                 master_uri: str, host: str, environ: Mapping[str, str], watchdog: Any = None, sigint_timeout: float = 15.0, sigterm_timeout: float = 2.0,
                 program: str | None = None):
        self.run_id = run_id
        self.master_uri = master_uri
        self.host = host
        self.environ = environ
        # set by attach(): the children are started before it (ssh and a remote roslaunch take
        # a second; that second overlaps the master's start and the parameters), but get their
        # nodes only once the parameters are set
        self.fleet: state.Fleet = None  # type: ignore[assignment]
        self.attached = compat.Event()
        self.watchdog = watchdog
        self.sigint_timeout = sigint_timeout
        self.sigterm_timeout = sigterm_timeout
        # the program the remote side runs: Debian's roslaunch, unless LAUNCHER_REMOTE_PROGRAM names another
        self.program = program or environ.get("LAUNCHER_REMOTE_PROGRAM") or "roslaunch"
        self.children: dict[str, RemoteChild] = {}
        for counter, (mname, nodes) in enumerate(by_machine.items()):
            machine = machines[mname]
            child = RemoteChild("%s-%d" % (machine.address, counter), machine, nodes, self)
            self.children[child.name] = child
        self.handler = handler.ParentHandler(self)
        self.server: XmlRpcServer | None = XmlRpcServer(self.handler.call, "0.0.0.0", 0)
        self.uri = ""
        self._shut = False  # shutdown() began (before attach() too: a stop signal during the start-up)
        self.readiness: Readiness | None = None  # holds the first start of nodes with wait_for (set by attach)

    @property
    def stopping(self) -> bool:
        """The launch's nodes are being stopped: its phase says (fleet.launchphase), as the supervisor's; before
        the fleet is attached, this parent's shutdown."""
        return self._shut or (self.fleet is not None and self.fleet.stopping)

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
            child.start()

    def attach(self, fleet: state.Fleet, graph: Graph) -> None:
        """The parameters are set: the nodes' records go to `fleet` (which keeps the launch's outcome too),
        and they start (those with wait_for once `graph`, the master's registrations, has what they wait for)."""
        self.fleet = fleet
        self.readiness = Readiness(self.master_uri, self, graph, fleet)
        for child in self.children.values():
            for rn in child.nodes:
                fleet.add(rn.name, process=rn.spec.name, host=child.machine.address, rules=rn.rules())
            for rn in child.nodes:
                self.tell(rn, Event(lifecycle.START))
        self.attached.set()

    # ---- telling the fleet, and doing what it says ----------------------------------------------------

    def tell(self, rn: RemoteNode, event: Event) -> list[lifecycle.Action]:
        actions = self.fleet.apply(rn.name, event)
        carry_out(self, rn, actions)
        return actions

    # ---- the node table's actions (fleet.actions.ActionRunner) ------------------------------------------

    def launch(self, rn: RemoteNode) -> None:
        rn.child.want()

    def schedule(self, rn: RemoteNode, delay: float) -> None:
        rn.timer = asyncio.get_running_loop().call_later(delay, self._due, rn)

    def cancel(self, rn: RemoteNode) -> None:
        if rn.timer is not None:
            rn.timer.cancel()
            rn.timer = None
        if self.readiness is not None:
            self.readiness.drop(rn)

    def hold(self, rn: RemoteNode) -> None:
        self.readiness.hold(rn)

    def begin_stop(self, rn: RemoteNode) -> None:
        """(The caller, an operator's stop or the shutdown, asks the child: it waits for the answer.)"""

    def spawn(self, rn: RemoteNode) -> None:
        """(SPAWN is for a node of this machine: its child spawns a remote one.)"""

    def kill(self, rn: RemoteNode) -> None:
        """(KILL follows a hang, stall or limit verdict: the health watchers watch this machine's nodes.)"""

    def node_state(self, rn: RemoteNode) -> str:
        return self.fleet.records[rn.name].state

    def _due(self, rn: RemoteNode) -> None:
        rn.timer = None
        if not self.stopping:
            self.tell(rn, Event(lifecycle.DUE))

    # (health/readiness calls these, as it calls the supervisor's for local nodes)
    @staticmethod
    def output_path(node_name: str) -> None:
        """No output file here for an `output:` condition: those of a node of another machine are there (the
        plan refuses such a condition, plan.order.check_output_waits)."""
        return None

    def release(self, rn: RemoteNode) -> None:
        if not self.stopping:
            self.tell(rn, Event(lifecycle.READY))

    def give_up_waiting(self, rn: RemoteNode, why: str) -> None:
        self.tell(rn, Event(lifecycle.NOT_READY, reason=why))

    # ---- operator control: `launcher start|stop|restart` of a node on another machine -----------------

    def node_names(self) -> list[str]:
        return [rn.name for child in self.children.values() for rn in child.nodes]

    def _node(self, name: str) -> RemoteNode | None:
        for child in self.children.values():
            for rn in child.nodes:
                if rn.name == name:
                    return rn
        return None

    async def stop_node(self, name: str, reload: str = "") -> str:
        """Stop the node and keep it stopped, as a local `launcher stop`: '' once done, else why not.

        From the STOP on, the state machine keeps it stopped: neither the death its child reports, nor
        its machine dropping and answering again, starts it; only `start_node` does. The child is asked
        to stop that one process (`stop_process`, our child's extension); roslaunch's child has no
        such call, and the node is then left running. With `reload` (why), a reload stops it (it is
        then removed, or renewed)."""
        rn = self._node(name)
        if rn is None or self.stopping or self.fleet is None:
            return ""
        child, machine_ = rn.child, rn.child.machine
        # handed to the child by a `launch` call still under way: its process name comes with the answer
        while self.node_state(rn) == lifecycle.LAUNCHING and child.launching is not None and not child.launching.done():
            await asyncio.wait([child.launching])
        event = Event(lifecycle.RELOAD_STOP, reason=reload) if reload else Event(lifecycle.STOP)
        if lifecycle.BEGIN_STOP not in {a.kind for a in self.tell(rn, event)}:
            return ""  # stopped before its next start; or stopped, being stopped, or down for good
        refusal, exit_code = await child.stop_process(self.fleet.records[rn.name].process)
        if self.node_state(rn) != lifecycle.STOPPING:
            return ""  # gone meanwhile (its machine dropped): it stays stopped all the same
        if refusal:
            self.tell(rn, Event(lifecycle.STOP_REFUSED, reason="stop refused: " + refusal))
            return "cannot stop [%s] on machine [%s] (%s): %s" % (rn.name, machine_.name, machine_.address, refusal)
        code, sig = session.died(exit_code)
        self.tell(rn, Event(lifecycle.DOWN, exit_code=code, exit_signal=sig))
        return ""

    def start_node(self, name: str) -> str:
        """Start a node that is not running, as a local `launcher start` (a pending start happens now),
        by a `launch` call holding it: '' when asked for, else why not."""
        rn = self._node(name)
        if rn is None or self.stopping or self.fleet is None:
            return ""
        child, machine_ = rn.child, rn.child.machine
        if child.task is None or child.task.done():
            return "cannot start [%s]: machine [%s] (%s) could not be reached at launch" % (rn.name, machine_.name,
                                                                                        machine_.address)
        self.tell(rn, Event(lifecycle.OPERATOR_START))  # (it runs, or starts as soon as its machine answers)
        return ""

    async def restart_node(self, name: str) -> str:
        return await self.stop_node(name) or self.start_node(name)

    # ---- a reload (run/reload.py): nodes of the machines changed, added and removed --------------------

    @property
    def children_stop_nodes(self) -> bool:
        """Can the children stop one node? Ours can (`stop_process`); Debian's roslaunch cannot."""
        return os.path.basename(self.program) != "roslaunch"

    def _child_for(self, node: Node, machines: Mapping[str, Machine]) -> RemoteChild | None:
        """The child of the node's machine, if this launch has one for that machine as it is now."""
        wanted = machines.get(node.machine_name or "")
        for child in self.children.values():
            if wanted is not None and same_host(child.machine, wanted):
                return child
        return None

    def reload_refusals(self, stop: list[tuple[str, str]], start: list[Node],
                        machines: Mapping[str, Machine]) -> list[str]:
        """Why a reload cannot stop (`stop`: (name, machine name)) or start (`start`: new, or restarted) these
        nodes of other machines, by name ([] when it can)."""
        refusals = []
        if not self.children_stop_nodes:
            refusals += ["node [%s] runs under Debian's roslaunch child on machine [%s], which cannot stop one node: "
                         "the launch needs a full restart for this change" % (name, m) for name, m in stop]
        for n in start:
            rn = self._node(n.full_name)
            if rn is not None and self._child_for(n, machines) is not rn.child:
                refusals.append("node [%s] moves to another machine (machine [%s]: its address, user, port or "
                                "env-loader changed): the launch needs a full restart for this change"
                                % (n.full_name, n.machine_name))
        return refusals

    async def reload(self, stop: dict[str, str], renew: dict[str, tuple[Node, str]], start: list[Node],
                     rules: dict[str, tuple[Node, str]], machines: Mapping[str, Machine]) -> list[str]:
        """Apply a reload to the nodes of the machines: `stop` (name -> why: removed), `renew` (name -> (its
        new node, why): stopped, then launched as new), `start` (new nodes), `rules` (name -> (node, why): new
        supervision settings only). The refusals of the children, by name (checked before: there should be
        none)."""
        refusals = await asyncio.gather(*(self.stop_node(name, "reload: " + why) for name, why in
                                          list(stop.items()) + [(n, why) for n, (_node, why) in renew.items()]))
        for name in stop:
            rn = self._node(name)
            if rn is not None and self.fleet.records[name].state not in lifecycle.ALIVE:
                rn.child.nodes.remove(rn)
                self.fleet.remove(name)
        for name, (node, why) in renew.items():
            rn = self._node(name)
            if rn is None or self.fleet.records[name].state in lifecycle.ALIVE:
                continue
            rn.renew(node)
            self.tell(rn, Event(lifecycle.RENEW, rules=rn.rules(), reason="reload: " + why))
            self.tell(rn, Event(lifecycle.START))
        for node in start:
            child = self._child_for(node, machines)
            if child is None:  # a machine none of the launch's nodes used so far: its child starts
                machine_ = machines[node.machine_name or ""]
                child = RemoteChild("%s-%d" % (machine_.address, len(self.children)), machine_, [], self)
                self.children[child.name] = child
                child.start()
            rn = RemoteNode(node, child)
            child.nodes.append(rn)
            self.fleet.add(rn.name, process=rn.spec.name, host=child.machine.address, rules=rn.rules())
            self.tell(rn, Event(lifecycle.START))
        for name, (node, why) in rules.items():
            rn = self._node(name)
            if rn is not None:
                rn.node = node
                rn.spec = rn.spec._replace(policy=node.policy or DEFAULT_POLICY)
                self.tell(rn, Event(lifecycle.RULES, rules=rn.rules(), reason="reload: " + why))
        return [r for r in refusals if r]

    # ---- the parent's XML-RPC API (remote.handler) --------------------------------------------------

    PARENT_CALLS = handler.PARENT_CALLS  # what only the children call

    def parent_call(self, method: str, params: list) -> Any:
        """A child's call that the launch's own server hands here (PARENT_CALLS)."""
        return self.handler.call(method, params)

    # ---- stopping -----------------------------------------------------------------------------------

    async def shutdown(self) -> None:
        """Ask every child to stop its nodes, then close the sessions (the launch's runner has stepped its phase
        to stopping; a parent that is its launch's runner, in a test, steps it here)."""
        own = self.fleet is not None and not self.fleet.stopping
        if own:
            self.fleet.launch_step(launchphase.STOP)
        self._shut = True
        if self.fleet is not None:
            for child in self.children.values():
                for rn in child.nodes:
                    self.tell(rn, Event(lifecycle.SHUTDOWN))  # (a start to come is called off)
        if self.readiness is not None:
            self.readiness.close()
        live = [c for c in self.children.values() if c.ssh is not None]
        for child in live:
            console.printlog("[%s] killing on exit" % child.name)
        await asyncio.gather(*(c.shut_down() for c in live))
        if self.fleet is not None:  # what ran there is stopped with its child's shutdown, or its session's end
            for child in self.children.values():
                for rn in child.nodes:
                    if self.node_state(rn) == lifecycle.STOPPING:
                        self.tell(rn, Event(lifecycle.DOWN))
        for child in self.children.values():
            if child.task is not None:
                child.task.cancel()
                try:
                    await child.task
                except BaseException:  # noqa: BLE001 - cancelled on purpose
                    pass
        if self.server is not None:
            await self.server.stop()
        if own:
            self.fleet.launch_step(launchphase.ALL_STOPPED)
