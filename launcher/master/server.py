"""The embedded ROS master's server: Master API + Parameter Server API over XML-RPC, on the caller's event loop."""

from __future__ import annotations

import asyncio
import os
from typing import Any, Mapping, NamedTuple

from launcher import compat
from launcher.master.api import MasterApi, unsendable
from launcher.master.callstats import CallStats
from launcher.master.masterlog import mlog
from launcher.master.notify import Notifier
from launcher.model.graph import Graph
from launcher.model.names import resolve_name
from launcher.net.hostname import advertised_host, bind_address
from launcher.net.xmlrpc import call
from launcher.net.xmlrpc_server import XmlRpcServer
from launcher.params.tree import ParamTree, copy_tree

DEFAULT_MASTER_PORT = 11311


# How long a process that ended may take to answer getPid at its URI before it counts as gone (a dead
# process's port refuses at once; one that answers is another process that took the port).
PURGE_PROBE_S = 1.0

class UnresponsiveNode(NamedTuple):
    """A registered node whose last callback from the master failed (it is sent again after a back-off)."""

    names: list[str]  # the node names registered with this API
    api: str
    failures: int  # consecutive failed calls
    failing_s: float  # since the first of them
    last_error: str
    queued: int  # callbacks waiting for it


class Master:
    """A ROS master on the running asyncio loop.

    `host` is the bind address (default: rosgraph's rule from ROS_IP /
    ROS_HOSTNAME); `port` 0 picks a free one. The advertised URI uses the
    host name as rosmaster does, or `uri_host` when given.
    """

    def __init__(self, host: str | None = None, port: int = DEFAULT_MASTER_PORT, *,
                 uri_host: str | None = None, environ: Mapping[str, str] | None = None,
                 notify_timeout: float = 10.0, allow: Any = None):
        self._allow = allow  # a launcher.net.allow.AllowList: clients from elsewhere are refused
        self._environ = os.environ if environ is None else environ
        self.host = host if host is not None else bind_address(self._environ)
        self.port = port
        self._uri_host = uri_host
        self._notify_timeout = notify_timeout
        self.uri: str = ""
        self.shutdown_requested = compat.Event()
        self.shutdown_reason = ""  # the message of the `shutdown` call that set shutdown_requested
        self._server: Any = None
        self._notifier: Any = None
        # the node APIs served in this process (the built-in rosout's): URI -> their dispatch; the master's
        # callbacks to them are calls, not requests over loopback (notify.Notifier)
        self.in_process_apis: dict[str, Any] = {}
        self._api: Any = None
        self._tree = ParamTree()
        self._purges: set[asyncio.Task] = set()  # (process_ended's checks under way)
        self.calls = CallStats()  # its calls by method and their latency (launch --metrics)
        # what is registered, told as it changes: the launch listens here rather than asking over XML-RPC
        self.graph = Graph()

    @property
    def params(self) -> ParamTree:
        return self._tree

    @property
    def api(self) -> Any:
        """The MasterApi (registrations, topic types); None before start()."""
        return self._api

    async def start(self) -> None:
        """Listen and serve; OSError if the port is taken."""

        self._notifier = Notifier(timeout=self._notify_timeout, in_process=self.in_process_apis)
        self._api = MasterApi(self._notifier, self._tree, graph=self.graph)
        self._api.on_shutdown = self._on_shutdown
        self.calls = CallStats(list(self._api.methods) + ["system.multicall"])
        self._server = XmlRpcServer(self._api.dispatch, self.host, self.port, multicall=True,
                                    allow=self._allow.allows if self._allow is not None else None,
                                    on_call=self.calls.observe)
        try:
            await self._server.start()
        except OSError:
            await self._notifier.close()
            self._server = None
            raise
        self.port = self._server.port
        host = self._uri_host or advertised_host(self._environ)
        if ":" in host and not host.startswith("["):
            host = "[%s]" % host  # an IPv6 literal in a URI
        self.uri = "http://%s:%d/" % (host, self.port)
        self._api.uri = self.uri

    def open_log(self, path: str) -> None:
        """Write master.log as rosmaster does (master/masterlog.py); an unwritable file only costs the log."""
        if mlog.open(path):
            mlog.info("initialization complete, waiting for shutdown", logger="rosmaster.main")
            mlog.info("Starting ROS Master Node", logger="rosmaster.main")
            mlog.info("Master initialized: port[%s], uri[%s]", self.port, self.uri)

    def _close_log(self) -> None:
        if mlog.enabled:
            mlog.info("stopping master...", logger="rosmaster.main")
            mlog.close()

    def _on_shutdown(self, reason: str) -> None:
        self.shutdown_reason = reason
        self.shutdown_requested.set()

    def set_param(self, key: str, value: Any) -> None:
        """Set a parameter in-process; parameter subscribers are notified.

        Raises ValueError for a value no client could read back (an int outside 32 bits, a
        None), as setParam refuses it: stored, it would break getParam('/') for everyone.
        """
        self._require_started()
        key = resolve_name(key, "/")
        problem = unsendable(value)
        if problem:
            raise ValueError("parameter [%s] is not set: %s" % (key, problem))
        self._api.set_param(key, copy_tree(value))

    def delete_param(self, key: str) -> None:
        """Delete a parameter in-process (KeyError if not set); subscribers get `{}`."""
        self._require_started()
        self._api.delete_param(resolve_name(key, "/"))

    def unresponsive_nodes(self) -> list[UnresponsiveNode]:
        """The registered nodes the master cannot reach (timed out, refused), longest failing first."""
        if self._api is None:
            return []
        now = asyncio.get_running_loop().time()
        names: dict[str, list[str]] = {}
        for node in self._api.registry.nodes.values():
            names.setdefault(node.api, []).append(node.id)
        return [UnresponsiveNode(names.get(u.api, []), u.api, u.failures, now - u.since, u.last_error, u.queued)
                for u in self._notifier.unreachable()]

    def process_ended(self, node_name: str, pid: int) -> None:
        """A node's process (`pid`) ended, as its launcher saw: what that process registered goes at once,
        so that subscribers stop dialing a dead address and `rosnode list` tells the truth (no `rosnode
        cleanup`). Only if the URI registered under the name is that process's: a new run of the node
        may have registered already, and it answers getPid with its own pid."""
        if self._api is None:
            return
        node = self._api.registry.get_node(node_name)
        if node is not None:
            task = asyncio.get_running_loop().create_task(self._purge_if_gone(node_name, node.api, pid))
            self._purges.add(task)
            task.add_done_callback(self._purges.discard)

    async def _purge_if_gone(self, node_name: str, api: str, pid: int) -> None:
        try:
            code, _msg, answer = await call(api, "getPid", "/master", timeout=PURGE_PROBE_S)
            if code == 1 and answer != pid:
                return  # another process answers there now: that is its registration
        except Exception:  # noqa: BLE001 - refused, reset, timed out: nobody is the node there
            pass
        if self._api is not None and self._api.unregister_process(node_name, api):
            mlog.info("%s (pid %d) ended: its registrations under %s removed", node_name, pid, api)

    def _require_started(self) -> None:
        if self._api is None:
            raise RuntimeError("Master.start() has not been called")

    async def stop(self) -> None:
        """Stop serving and drop queued callbacks."""
        self._close_log()
        if self._server is not None:
            await self._server.stop()
            self._server = None
        if self._notifier is not None:
            await self._notifier.close()
