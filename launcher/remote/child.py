"""The child side of roslaunch's remote protocol: `launch -c NAME -u PARENT_URI --run_id ID`.

A parent (Debian's roslaunch or our `launch`) runs this over ssh on a machine.
It starts the child's XML-RPC API (`launch`, `shutdown`, and the common
`list_processes`, `process_info`, `get_pid`, `get_node_names`, as
roslaunch.server.ROSLaunchChildHandler; and launcher's `stop_process`, which
`launcher stop` of a node on this machine needs), registers with the parent, and runs
the nodes of the launch XML it is given under our supervisor (respawn, stop
escalation, the no-orphans guard). It tells the parent every console line
(`log`) and every node death (`process_died`). It sets no parameters and
starts no master: that is the parent's business.

It ends when told to (`shutdown`, SIGINT), when every node has ended for good, as
roslaunch's child does, or when its session with the parent ends: SIGHUP when the ssh
session's pty hangs up, SIGTERM from sshd, the end of its stdin (Debian's parent gives it
no pty), or a parent that stopped answering. A session that ended stops the nodes on a
short clock (SIGINT, then SIGKILL of each node's whole process group after
SESSION_END_GRACE_S), whether or not a group's leader still runs: nobody is left to wait
for them, and a cut link's nodes must be gone within 5 s of the cut.
"""

from __future__ import annotations

import asyncio
import os
import stat
import tempfile
from typing import Any

from launcher import compat
from launcher.model.errors import LaunchError
from launcher.net.slave import default_host
from launcher.net.xmlrpc import Fault, call
from launcher.net.xmlrpc_server import XmlRpcServer
from launcher.fleet import processes
from launcher.output import console
from launcher.fleet import lifecycle, state
from launcher.fleet.state import Change, Fleet
from launcher.process.supervisor import Supervisor
from launcher.process.watchdog import Watchdog
from launcher.workspace.packages import PackageIndex
from launcher.output.runlog import RunLog
from launcher.model.runopts import RunOptions
from launcher.plan.relations import of as relations_of, without
from launcher.plan.specs import node_specs
from launcher.remote.ssh import NODE_GRACE_S
from launcher.xml import load

LOG_INFO, LOG_ERROR = 2, 8  # rosgraph_msgs/Log levels
REGISTER_TIMEOUT_S = 10.0
# The parent is asked for its pid every PARENT_CHECK_S; when none of its answers came for
# PARENT_SILENCE_S it is gone or cut off, and the nodes are stopped: Debian's parent runs us without
# a pty, so a cut link would otherwise leave them running (stopped within 5 s of the cut).
PARENT_CHECK_S = 0.5
PARENT_CALL_TIMEOUT_S = 0.75
PARENT_SILENCE_S = 2.0
# After its session with the parent ended, how long the nodes get to handle SIGINT before their process
# groups are SIGKILLed: the watch loop's grace (ssh.NODE_GRACE_S), which Debian's parent does not run.
SESSION_END_GRACE_S = NODE_GRACE_S


def run_child(opts: Any) -> int:
    """`launch -c NAME -u URI --run_id ID`: the exit status."""
    if not (opts.child_name and opts.server_uri and opts.run_id):
        raise LaunchError("child mode needs all of -c NAME, -u SERVER_URI and --run_id ID")
    watchdog = Watchdog.start()
    try:
        return asyncio.run(Child(opts, watchdog).main())
    finally:
        if watchdog is not None:
            watchdog.close()


class Child:
    def __init__(self, opts: Any, watchdog: Any):
        self.opts = RunOptions.from_args(opts)  # (the node options: --screen, --log, --required, timeouts)
        self.name = opts.child_name
        self.parent_uri = opts.server_uri
        self.run_id = opts.run_id
        self.watchdog = watchdog
        self.environ = dict(os.environ)
        self.server = XmlRpcServer(self._dispatch, "0.0.0.0", 0)
        self.uri = ""
        self.log = RunLog(self.environ)
        self.fleet: Fleet | None = None
        self.supervisor: Supervisor | None = None
        self.stop = compat.Event()
        self.session_ended = False  # the parent is gone (see SESSION_END_GRACE_S)
        self._stopping: asyncio.Future | None = None  # the nodes' stop, once begun
        self._kill_timer: asyncio.TimerHandle | None = None
        self._to_parent: asyncio.Queue = compat.Queue()
        self._number = 0  # process numbering, as a roslaunch child's: talker-1, listener-2, ...

    async def main(self) -> int:
        loop = asyncio.get_running_loop()
        loop.add_signal_handler(2, self.stop.set)  # SIGINT
        for sig in (15, 1):  # SIGTERM (sshd ended the session), SIGHUP (the ssh session's pty hung up)
            loop.add_signal_handler(sig, self._session_end)
        self._watch_session(loop)
        run_dir = self.log.open(self.run_id)
        events = state.EVENTS_FILE.replace(".jsonl", "-%s.jsonl" % self.name)
        self.fleet = Fleet(os.path.join(run_dir, events) if run_dir else None, warn=console.printerrlog)
        self.fleet.listeners.append(self._node_changed)
        self.supervisor = Supervisor(sigint_timeout=self.opts.sigint_timeout,
                                     sigterm_timeout=self.opts.sigterm_timeout, exit_when_all_dead=True,
                                     watchdog=self.watchdog, fleet=self.fleet)
        await self.server.start()
        self.uri = "http://%s:%d/" % (default_host(self.environ), self.server.port)
        sender = asyncio.ensure_future(self._send_to_parent())
        try:
            code, msg, _ = await call(self.parent_uri, "register", self.name, self.uri, timeout=REGISTER_TIMEOUT_S)
        except Exception as e:  # noqa: BLE001 - any failure to reach the parent ends the child
            console.printerrlog("unable to register with roslaunch parent [%s]: %s" % (self.parent_uri, e))
            await self.server.stop()
            return 1
        if code != 1:
            console.printerrlog("unable to register with roslaunch server: %s" % msg)
            await self.server.stop()
            return 1
        # from now on the parent hears every console line (roslaunch's child does the same)
        console.add_level_handler(self._forward_log)
        parent_gone = asyncio.ensure_future(self._watch_parent())
        waiters = [asyncio.ensure_future(self.stop.wait()), asyncio.ensure_future(self.supervisor.done.wait()),
                   parent_gone]
        await asyncio.wait(waiters, return_when=asyncio.FIRST_COMPLETED)
        for w in waiters:
            w.cancel()
        if parent_gone.done() and not parent_gone.cancelled():
            self._session_end()
        await self._shutdown()
        console.remove_level_handler(self._forward_log)
        if parent_gone.done() and not parent_gone.cancelled():
            sender.cancel()  # nobody to tell
        else:
            await self._flush_to_parent(sender)
        await self.server.stop()
        self.fleet.close()
        return 0

    async def _watch_parent(self) -> None:
        """Return when the parent has not answered for PARENT_SILENCE_S (not later: a call under way
        then is given up)."""
        loop = asyncio.get_running_loop()
        last_answer = loop.time()

        async def asked() -> None:
            await asyncio.sleep(PARENT_CHECK_S)
            await call(self.parent_uri, "get_pid", timeout=PARENT_CALL_TIMEOUT_S)

        while True:
            left = last_answer + PARENT_SILENCE_S - loop.time()
            if left <= 0:
                break
            try:
                await compat.wait_for(asked(), left)
                last_answer = loop.time()
            except Exception:  # noqa: BLE001 - unreachable, refused, timed out: all mean not answering
                pass
        console.printerrlog("the roslaunch parent [%s] does not answer: stopping" % self.parent_uri)

    def _watch_session(self, loop: asyncio.AbstractEventLoop) -> None:
        """Stop when the ssh session closes, if stdin is that session's channel.

        Debian's roslaunch parent (paramiko) runs the child without a pty, so no SIGHUP comes when
        the parent dies; but the channel, our stdin, then ends. (Under our parent stdin is the
        watch loop's /dev/null, and the pty's hangup does it.)
        """
        try:
            mode = os.fstat(0).st_mode
        except OSError:
            return
        if not (stat.S_ISFIFO(mode) or stat.S_ISSOCK(mode)):
            return

        def readable() -> None:
            try:
                data = os.read(0, 4096)
            except BlockingIOError:
                return
            except OSError:
                data = b""
            if not data:
                loop.remove_reader(0)
                console.printerrlog("the ssh session to the parent closed: stopping")
                self._session_end()

        os.set_blocking(0, False)
        loop.add_reader(0, readable)

    def _session_end(self) -> None:
        """The session with the parent ended: the nodes are stopped on the short clock, also if their stop
        (a `shutdown` call's, or at the end of the last node) was under way already."""
        self.session_ended = True
        self.stop.set()
        if self._stopping is not None:
            self._arm_kill()

    def _arm_kill(self) -> None:
        if self._kill_timer is None and self.supervisor is not None:
            # SIGKILL to every node's group still stopping: that of a leader gone at SIGINT too, whose
            # group the supervisor still waits for (a shell script's background jobs ignore SIGINT)
            self._kill_timer = asyncio.get_running_loop().call_later(SESSION_END_GRACE_S, self.supervisor.kill_now)

    async def _shutdown(self) -> None:
        if self.supervisor is None:
            return
        if self._stopping is None:
            self._stopping = asyncio.ensure_future(self._stop_nodes())
        if self.session_ended:
            self._arm_kill()
        await asyncio.shield(self._stopping)

    async def _stop_nodes(self) -> None:
        try:
            await self.supervisor.shutdown()
        finally:
            if self._kill_timer is not None:
                self._kill_timer.cancel()
            self.supervisor.close()

    # ---- talking to the parent ----------------------------------------------------------------------

    def _forward_log(self, msg: str, error: bool) -> None:
        self._to_parent.put_nowait(("log", self.name, LOG_ERROR if error else LOG_INFO, msg))

    def _node_changed(self, change: Change) -> None:
        """A run that ended by itself is told to the parent (roslaunch's `process_died`; a stop the parent
        asked for is answered by `stop_process` instead)."""
        new = change.new
        if change.event.kind == lifecycle.PROCESS_EXITED and change.old.state in (lifecycle.RUNNING, lifecycle.HUNG):
            code = new.exit_code if new.exit_code is not None else -(new.exit_signal or 0)
            self._to_parent.put_nowait(("process_died", new.process, code))

    async def _send_to_parent(self) -> None:
        """One call at a time, in order (a log line before the death it explains).

        What queued up while a call was under way goes in one `system.multicall` (roslaunch's
        server has it too): when a machine's nodes stop together, their lines and deaths are a
        few calls rather than one connection each, on CPUs the exiting nodes need.
        """
        while True:
            batch = [await self._to_parent.get()]
            while not self._to_parent.empty():
                batch.append(self._to_parent.get_nowait())
            try:
                if len(batch) == 1:
                    await call(self.parent_uri, batch[0][0], *batch[0][1:], timeout=5.0)
                else:
                    await call(self.parent_uri, "system.multicall",
                               [{"methodName": item[0], "params": list(item[1:])} for item in batch], timeout=5.0)
            except Exception:  # noqa: BLE001 - a parent gone or slow must not stop the nodes' supervision
                pass
            for _ in batch:
                self._to_parent.task_done()

    async def _flush_to_parent(self, sender: asyncio.Future) -> None:
        try:
            await compat.wait_for(self._to_parent.join(), 3.0)
        except asyncio.TimeoutError:
            pass
        sender.cancel()

    # ---- the child's XML-RPC API ----------------------------------------------------------------------

    def _dispatch(self, method: str, params: list) -> Any:
        fn = self._API.get(method)
        if fn is None:
            raise Fault(-1, "method [%s] is not supported" % method)
        return fn(self, *params)

    def launch(self, launch_xml: str) -> Any:
        return self._launch(launch_xml)

    async def _launch(self, launch_xml: str) -> list:
        if self.supervisor is None or self.supervisor.shutting_down:
            return [0, "uninitialized", -1]
        warn = lambda msg: console.printerrlog("WARNING: %s" % msg)  # noqa: E731
        packages = PackageIndex(self.environ, warn=warn)
        with tempfile.NamedTemporaryFile("w", suffix=".launch", prefix="child-", encoding="utf-8") as f:
            f.write(launch_xml)
            f.flush()
            try:
                config = load([f.name], [], environ=self.environ, packages=packages, warn=warn)
            except LaunchError as e:
                return [-1, "ERROR: %s" % e, [[], []]]
        console.printlog("launching nodes...")
        master_uri = self.environ.get("ROS_MASTER_URI", "http://localhost:11311/")
        # (the parent sends a child only its own machine's nodes, without `machine`: every one runs here)
        specs, failed = node_specs(config, master_uri, self.environ, packages, lambda node: False,
                                   opts=self.opts, run_dir=self.log.run_dir, first_number=self._number,
                                   log=console.printlog, log_error=console.printerrlog)
        self._number += len(specs) + len(failed)
        # each call's nodes add their relations to those of the calls before (a node given again: its new ones)
        fleet, given = self.supervisor.fleet, [(n.full_name, n.policy) for n in config.nodes]
        fleet.relate(relations_of(given, without(fleet.relations, (name for name, _ in given))))
        succeeded = []
        for spec in specs:
            if self.supervisor.start(spec) is not None:
                succeeded.append(spec.name)
            else:
                failed.append((spec.name, spec.required))
        for name, required in failed:
            self.supervisor.not_started(name, required)
        self.supervisor.registrations_complete()
        console.printlog("... done launching nodes")
        return [1, "launched", [succeeded, [name for name, _ in failed]]]

    def shutdown(self) -> Any:
        async def stop() -> list:
            await self._shutdown()
            self.stop.set()
            return [1, "success", 1]
        return stop()

    def stop_process(self, process_name: str) -> Any:
        """launcher's extension (roslaunch's child has no such call): stop one process as a local
        `launcher stop` does (SIGINT, escalation) and keep it stopped, its respawn="true" too; the
        answer comes once it has exited: [1, "stopped", exit code (-signal, as process_died)]. The
        parent starts it again, if asked to, with a `launch` call."""
        procs = self.supervisor.procs if self.supervisor is not None else []
        # the latest record of that name: a node given again by a later `launch` has a record per call
        proc = next((p for p in reversed(procs) if p.spec.name == process_name), None)
        if proc is None or self.supervisor.shutting_down:
            return [-1, "no process by that name", 0]
        stopping = self.supervisor.stop_process(proc)

        async def stopped() -> list:
            if stopping is not None:
                await stopping
            return [1, "stopped", proc.exit_code if proc.exit_code is not None else 0]
        return stopped()

    def list_processes(self) -> list:
        return processes.list_processes(self.fleet or ())

    def process_info(self, process_name: str) -> list:
        return processes.process_info(self.fleet or (), process_name)

    def get_pid(self) -> list:
        pid = os.getpid()
        return [1, str(pid), pid]

    def get_node_names(self) -> list:
        if self.fleet is None:
            return [0, "uninitialized", []]
        return processes.node_names(self.fleet)

    _API = {"launch": launch, "shutdown": shutdown, "list_processes": list_processes, "process_info": process_info,
            "get_pid": get_pid, "get_node_names": get_node_names, "stop_process": stop_process}
