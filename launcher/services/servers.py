"""A run's servers, each one service with a start and a stop: roslaunch's API server, rosout, /diagnostics, the log-disk check; and `RunView`, what the API server sees of the run.

A server that cannot start says so and the launch goes on without it (its
stop is then nothing), as roslaunch goes on without a log collector.
"""

from __future__ import annotations

import asyncio
from typing import TYPE_CHECKING, Awaitable, Callable

from launcher import compat
from launcher.model.errors import LaunchError
from launcher.services.diagnostics import Diagnostics
from launcher.services.rosouttail import RosoutTail
from launcher.services.server import LaunchServer
from launcher.output import console
from launcher.output.logdir import watch_log_disk
from launcher.workspace.roshome import log_root

if TYPE_CHECKING:  # (annotations only)
    from launcher.fleet.state import Fleet
    from launcher.net.rosout import Rosout
    from launcher.output.runlog import RunLog
    from launcher.services.metrics import Exporter
    from launcher.services.service import MasterLink, RunNodes

SERVER_UNREGISTER_S = 3.0  # a master that outlives the run is told the server is gone, if it answers by then


class RunView:
    """The narrow view of a run that its API server reads: the nodes (the fleet, their control), the run's
    identity (run id, master URI, log directory, launch files), and the core processes it started."""

    def __init__(self, master: MasterLink, nodes: RunNodes, log: RunLog, rosout: RosoutService | None,
                 launch_files: tuple[str, ...]):
        self._master = master
        self.nodes = nodes
        self._log = log
        self._rosout = rosout  # RosoutService, or None
        self.launch_files = list(launch_files)
        # a reload of the run (run/reload.py: `async reload(args, dry_run) -> answer`), when it can have one
        self.reload: Callable[[list[str], bool], Awaitable[dict]] | None = None
        # what makes the run's metrics (services/metrics.Exporter: `async text()`) for `launcher_metrics`, once
        self.metrics_of: Callable[[], Exporter] | None = None
        self._metrics: Exporter | None = None

    @property
    def metrics(self) -> Exporter | None:
        """The run's metrics, made at the first call that reads them: a run nobody scrapes never imports them."""
        if self._metrics is None and self.metrics_of is not None:
            self._metrics = self.metrics_of()
        return self._metrics

    @property
    def fleet(self) -> Fleet | None:
        return self.nodes.fleet

    @property
    def starting(self) -> bool:
        """A launch still setting up: its nodes are made once its master is up and its parameters are set (a core
        makes none)."""
        return self.nodes.fleet is None and not self._master.core

    @property
    def run_id(self) -> str:
        return self._master.run_id

    @property
    def master_uri(self) -> str:
        return self._master.uri

    @property
    def log_dir(self) -> str:
        return self._log.run_dir or ""

    def core_processes(self) -> list[list]:
        """roslaunch (and roscore) lists the master it started and its rosout as processes; a launch that
        found a master running lists neither (it started neither)."""
        core = []
        if self._master.master is not None:
            core.append(["master", 1])
        if self._rosout is not None and self._rosout.rosout is not None:
            core.append(["rosout-1", 1])
        return core

    @property
    def warnings(self) -> RosoutTail | None:
        """The recent WARN/ERROR/FATAL lines of /rosout (services.rosouttail.RosoutTail), None without our rosout."""
        return self._rosout.warnings if self._rosout is not None else None

    def unresponsive(self) -> list[dict]:
        """The nodes our master cannot reach (its callbacks time out or are refused)."""
        master = self._master.master
        return [u._asdict() for u in master.unresponsive_nodes()] if master is not None else []


class ApiServer:
    """roslaunch's XML-RPC API (roscore's too): started first, as roslaunch's, registered on the master
    once /run_id is set, and unregistered from a master that outlives the run."""

    def __init__(self, view: RunView, master: MasterLink, environ: dict[str, str]):
        self.view = view
        self.master = master  # masterlink.MasterSession
        self.environ = environ
        self.server: LaunchServer | None = None

    @property
    def uri(self) -> str:
        return self.server.uri if self.server is not None else ""

    async def start(self) -> None:
        server = LaunchServer(self.view, self.environ)
        try:
            await server.start()
        except OSError as e:  # the launch runs on, without its operator's side
            console.printerrlog("could not start the roslaunch server: %s" % e)
            await server.stop()
            return
        self.server = server
        console.printlog_bold("started roslaunch server %s" % server.uri)

    async def register(self) -> None:
        """`/roslaunch/uris/host_<host>__<port>` on the master, as roslaunch sets it once /run_id is."""
        if self.server is None:
            return
        try:
            await self.master.params.set(self.server.param_key, self.server.uri)
        except LaunchError as e:  # not findable through the master; --uri still reaches it
            console.printerrlog("could not register the roslaunch server on the master: %s" % e)

    async def stop(self) -> None:
        if self.server is None:
            return
        if self.master.external and self.master.params is not None:
            # a master that outlives us must not list a launch that is gone
            try:
                await compat.wait_for(self.master.params.delete(self.server.param_key), SERVER_UNREGISTER_S)
            except (Exception, asyncio.TimeoutError):  # noqa: BLE001 - the master may be gone already
                pass
        await self.server.stop()


class RosoutService:
    """The built-in rosout, with a master of ours (roslaunch starts its core nodes only with its own master);
    roslaunch runs it as process "rosout-1", so the nodes' numbers (and log file names) start after it."""

    def __init__(self, master: MasterLink, log: RunLog, environ: dict[str, str]):
        self.master = master  # masterlink.MasterSession
        self.log = log
        self.environ = environ
        self.rosout: Rosout | None = None
        self.tail = RosoutTail()  # its warnings, for the live views (launcher_output)
        self.failed = False  # it could not start

    @property
    def warnings(self) -> RosoutTail | None:
        """Its tail of warnings from the start of a run whose master is ours, before rosout is up: a view that
        asks in between must already leave the output="log" nodes' files to it (it keeps following what it was
        first given). None with a master found running, or once our rosout could not start."""
        return None if self.master.external or self.failed else self.tail

    @property
    def processes(self) -> int:
        return 1 if self.rosout is not None else 0

    async def start(self) -> None:
        if self.master.master is None:
            return
        from launcher.net.rosout import Rosout  # (here: with a master found running, its own rosout logs)
        rosout = Rosout(self.master.uri, self.log.run_dir, environ=self.environ,
                        in_process=self.master.master.in_process_apis)  # (our master calls it, no request)
        try:
            await rosout.start()
        except Exception as e:  # noqa: BLE001 - the launch goes on without a log collector
            console.printerrlog("could not start the built-in rosout: %s" % e)
            self.failed = True
            try:
                await rosout.stop()
            except Exception:  # noqa: BLE001
                pass
            return
        rosout.warning_listeners.append(self.tail.add)
        self.rosout = rosout
        console.printlog("started core service [/rosout]")

    async def stop(self) -> None:
        if self.rosout is None:
            return
        if not self.master.core:
            console.printlog("[rosout-1] killing on exit")
        try:
            await self.rosout.stop()
        except Exception as e:  # noqa: BLE001 - the master must still stop
            console.printerrlog("error stopping rosout: %s" % e)


class DiagnosticsService:
    """/diagnostics of the nodes' health, published from the fleet."""

    def __init__(self, master: MasterLink, nodes: RunNodes, environ: dict[str, str]):
        self.master = master
        self.nodes = nodes
        self.environ = environ
        self.diagnostics: Diagnostics | None = None

    async def start(self) -> None:
        try:
            diagnostics = Diagnostics(self.master.uri, self.nodes.fleet, environ=self.environ,
                                      master=self.master.master)
            await diagnostics.start()
        except Exception as e:  # noqa: BLE001 - the launch goes on without /diagnostics
            console.printerrlog("could not publish /diagnostics: %s" % e)
            return
        self.diagnostics = diagnostics

    async def stop(self) -> None:
        if self.diagnostics is not None:
            await self.diagnostics.stop()


class LogDiskCheck:
    """roslaunch's check of the log directory's size (`--skip-log-check`, `--log-check-threshold`), in the
    background once start-up is over."""

    def __init__(self, environ: dict[str, str], threshold: int):
        self.environ = environ
        self.threshold = threshold
        self._task: asyncio.Future | None = None

    async def start(self) -> None:
        self._task = asyncio.ensure_future(watch_log_disk(log_root(self.environ), self.threshold))

    async def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()

