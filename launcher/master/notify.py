"""Master -> node callbacks (publisherUpdate, paramUpdate, shutdown, and the getPid that precedes a shutdown) sent on the running loop.

What goes when is `launcher.master.outbox.Outbox`'s decision (per-node order,
coalescing, slots, back-off for failing nodes); this is the loop around it.
Every call has a deadline to connect and one to be answered, so a hung node
holds its one slot until then and no longer; new calls start a few at a time,
paced, so that a thousand at once never stall the master's own replies.

A node API this process serves itself (the built-in rosout's, `in_process`) is
called, not requested: each node's restart sends the rosout a publisherUpdate,
and over a loopback connection both ends of it were this process's work (a
tenth to a fifth of the launch's CPU in a crash loop, benchmarks/crash_loop.py).
The outbox's order and slots are the same for it.
"""

from __future__ import annotations

import asyncio
import collections.abc
import logging
import os
import socket
import time
from typing import Any, Callable

from launcher import compat
from launcher.master.masterlog import mlog  # master.log, in rosmaster's lines
from launcher.master.outbox import Callback, Outbox, Unreachable
from launcher.net import xmlrpc
from launcher.net.xmlrpc_codec import Fault
from launcher.net.http import split_uri
from launcher.net.open_files import callback_cap

log = logging.getLogger("launcher.master")


MASTER_CALLER_ID = "/master"

CONNECT_TIMEOUT_S = 3.0  # a SYN and its first retransmissions: a host that is up answers well within it
# A thousand calls at once cost the loop ~200 ms: they start BATCH at a time, a batch every PACE_S at most,
# so that the master's own clients are answered in between and the process is not busy enough throughout
# to wait for a CPU when one of them calls.
BATCH = 8
PACE_S = 0.002




def since_boot() -> float:
    """Now, on the clock /proc gives a process's start with."""
    return time.clock_gettime(time.CLOCK_BOOTTIME)


def process_started(pid: int) -> float | None:
    """When process `pid` of this machine started, since boot (None: no such process here)."""
    try:
        with open("/proc/%d/stat" % pid, "rb") as f:
            stat = f.read()
        return int(stat[stat.rindex(b")") + 2:].split()[19]) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return None


def replaced_process(pid: int | None, started: float | None, registered_at: float) -> str | None:
    """Why the process answering getPid at a replaced node's URI is not that node (None: it may be, and is
    told to shut down). `pid`: its answer (None: refused, unanswered or no pid: nobody is the node there);
    `started`: when that process started, if it is of this machine; `registered_at`: when the node first
    registered at that URI. A process that started after the node registered took its port since."""
    if pid is None:
        return "nothing there answers getPid with a pid"
    # (/proc gives a start in clock ticks, 10 ms, rounded down: the process that registered always started
    # before; another that took the port within the same tick of the registration is not told apart)
    if started is not None and started > registered_at:
        return "pid %d there started %.2f s after the node registered there (its port was taken since)" \
            % (pid, started - registered_at)
    return None


_own_addresses: list = []  # this machine's interface addresses, read at the first check (net.allow)


def is_this_host(api: str) -> bool:
    """Whether `api`'s host is this machine (loopback, this host's name or one of its addresses): only
    then does /proc say what a pid there is. No lookup by name: this runs on the master's loop."""
    host = split_uri(api).hostname or ""
    if host in ("localhost", socket.gethostname()):
        return True
    # (here: ipaddress is ~0.25 MB of a launch's memory, and this runs only when a node's name is taken over)
    import ipaddress
    from launcher.net.allow import own_addresses
    try:
        ip = ipaddress.ip_address(host.split("%", 1)[0])
    except ValueError:
        return False  # another name: not looked up
    if not _own_addresses:
        _own_addresses.extend(own_addresses())
    return ip.is_loopback or any(ip in net for net in _own_addresses)


_ARRAY_OR_STRUCT = (list, tuple, dict)


def _copied(value: Any) -> Any:
    """`value` as XML-RPC carries it: arrays (a tuple too) and structs copied, so that neither end holds the
    other's; the rest are immutable (and a publisherUpdate's array of URIs is one list copied)."""
    if isinstance(value, (list, tuple)):
        return [_copied(v) if isinstance(v, _ARRAY_OR_STRUCT) else v for v in value]
    if isinstance(value, dict):
        return {k: _copied(v) if isinstance(v, _ARRAY_OR_STRUCT) else v for k, v in value.items()}
    return value


def _pid_of(result: Any) -> int | None:
    """The pid in a getPid answer (code 1, an int), else None."""
    if isinstance(result, (list, tuple)) and len(result) == 3 and result[0] == 1 and type(result[2]) is int:
        return result[2]
    return None


class Notifier:
    """Queues callbacks per node API and sends them on the running loop.

    `timeout` bounds the answer to each call, `connect_timeout` the connection;
    `max_in_flight` caps the calls in flight (by default from the open-file
    limit), a sixteenth of them for nodes whose last call failed;
    `in_process`: the node APIs this process serves, URI -> the dispatch its
    XML-RPC server calls (kept by their nodes as they start and stop).
    """

    def __init__(self, *, timeout: float = 10.0, connect_timeout: float = CONNECT_TIMEOUT_S,
                 max_in_flight: int | None = None, max_queued_per_api: int = 10000,
                 in_process: dict[str, Callable[[str, list], Any]] | None = None):
        self.timeout = timeout
        self.in_process = {} if in_process is None else in_process
        self.connect_timeout = connect_timeout
        cap = callback_cap() if max_in_flight is None else max_in_flight
        self._outbox = Outbox(max_in_flight=cap, max_failing=max(4, cap // 16), max_queued=max_queued_per_api)
        self._tasks: set[asyncio.Task] = set()
        self._pump_handle: asyncio.Handle | None = None  # the next _pump, soon or at a back-off's end
        self._pump_at: float | None = None  # when it runs (None: at the next loop turn)
        self._paced_until = 0.0  # after a full batch, the next starts no sooner
        self._closed = False

    # -- what the master queues --------------------------------------------------
    def publisher_update(self, api: str, topic: str, pub_uris: list[str]) -> None:
        self._put(api, Callback("publisherUpdate", [MASTER_CALLER_ID, topic, pub_uris], None,
                                ("publisherUpdate", topic)))

    def param_update(self, api: str, key: str, value: Any, on_result: Callable[[Any], None] | None = None) -> None:
        self._put(api, Callback("paramUpdate", [MASTER_CALLER_ID, key, value], on_result, ("paramUpdate", key)))

    def shutdown_node(self, api: str, caller_id: str, reason: str, registered_at: float) -> None:
        """The node at `api` has been replaced: it is told once, never retried, and only if the process there
        may be the one that registered (`replaced_process`): asked for its pid first, as its `shutdown` would
        otherwise reach whoever took its port (ros/ros_comm#2241, #2018). rosmaster calls a node only to
        update or stop it: the pid is asked here, of a node about to be stopped, never at registration."""
        message = "[%s] Reason: %s" % (caller_id, reason)

        def checked(result: Any) -> None:
            pid = _pid_of(result)
            started = process_started(pid) if pid is not None and is_this_host(api) else None
            why = replaced_process(pid, started, registered_at)
            if why is None:
                self._put(api, Callback("shutdown", [MASTER_CALLER_ID, message], once=True))
                return
            log.info("no shutdown sent to %s (%s): %s", api, message, why)
            mlog.info("shutdown of %s not sent: %s", api, why)
        self._put(api, Callback("getPid", [MASTER_CALLER_ID], checked, once=True))

    def forget(self, api: str) -> None:
        """`api` is no longer any registered node's: what it is still owed is dropped."""
        self._outbox.forget(api)

    def unreachable(self) -> list[Unreachable]:
        """The nodes whose last callback failed (retried with back-off while they stay registered)."""
        return self._outbox.unreachable()

    # -- machinery ----------------------------------------------------------------
    def _put(self, api: str, cb: Callback) -> None:
        if self._closed or not api.startswith("http://"):
            return  # rosrpc:// APIs cannot take XML-RPC calls
        self._outbox.put(api, cb)
        self._kick()

    def _kick(self) -> None:
        """Something may be sent: pump at the next loop turn, or when the pace allows."""
        paced = self._paced_until
        self._wake(paced if paced > asyncio.get_running_loop().time() else None)

    def _wake(self, at: float | None) -> None:
        """Have _pump run at the next loop turn (`at` None) or at loop time `at`, whichever is first."""
        if self._pump_handle is not None:
            if self._pump_at is None or (at is not None and self._pump_at <= at):
                return
            self._pump_handle.cancel()
        loop = asyncio.get_running_loop()
        self._pump_at = at
        self._pump_handle = loop.call_soon(self._pump) if at is None else loop.call_at(at, self._pump)

    def _pump(self) -> None:
        self._pump_handle = None
        if self._closed:
            return
        loop = asyncio.get_running_loop()
        outbox = self._outbox
        now = loop.time()
        calls = outbox.take(now, BATCH)
        for api, cb in calls:
            task = loop.create_task(self._send(api, cb))
            self._tasks.add(task)
            task.add_done_callback(self._tasks.discard)
        self._paced_until = now + PACE_S if len(calls) == BATCH else 0.0
        if outbox.can_take():
            self._wake(self._paced_until)
        else:
            at = outbox.next_wakeup()
            if at is not None:
                self._wake(at)

    async def _send(self, api: str, cb: Callback) -> None:
        loop = asyncio.get_running_loop()
        if cb.method == "paramUpdate":
            mlog.info("paramUpdate[%s]", cb.params[1])
        logged = cb.method == "publisherUpdate" and mlog.enabled
        if logged:
            what = "publisherUpdate[%s] -> %s %s" % (cb.params[1], api, cb.params[2])
            mlog.info(what)
        started = loop.time()
        error = None
        hung = False
        dispatch = self.in_process.get(api)
        try:
            if dispatch is not None:
                result = await self._call_in_process(dispatch, cb)
            else:
                result = await xmlrpc.call(api, cb.method, *cb.params, timeout=self.timeout,
                                           connect_timeout=self.connect_timeout)
            if logged:
                mlog.info("%s: sec=%0.2f, result=%s", what, loop.time() - started, result)
        except asyncio.CancelledError:
            raise
        except (OSError, asyncio.TimeoutError) as e:  # the node is not there, or does not answer
            error = str(e) or "no answer within %g s" % self.timeout
            hung = isinstance(e, (TimeoutError, asyncio.TimeoutError))
            log.info("%s to %s failed: %s", cb.method, api, error)
            if logged:
                mlog.info("%s: sec=%0.2f, exception=%s", what, loop.time() - started, error)
        except Exception as e:  # noqa: BLE001 - it answered, with garbage or a fault: sending again won't help
            log.info("%s to %s: %s", cb.method, api, e)
            if logged:
                mlog.info("%s: sec=%0.2f, exception=%s", what, loop.time() - started, e)
        else:
            if cb.on_result is not None:
                try:
                    cb.on_result(result)
                except Exception:  # noqa: BLE001
                    log.exception("handling the reply of %s from %s", cb.method, api)
        if self._closed:
            return
        if self._outbox.done(api, cb, loop.time(), error, hung) == 1 and hung:
            # (a refused one is a node gone without unregistering: common; master.log has its publisherUpdates)
            log.warning("the node at %s does not answer the master (%s): its callbacks are kept and sent "
                        "again with back-off", api, error)
        self._kick()

    async def _call_in_process(self, dispatch: Callable[[str, list], Any], cb: Callback) -> Any:
        """`cb` as the API's XML-RPC server would run it: the values copied, as a request carries them; the
        answer awaited within `timeout`; what the handler raises, the fault the server would answer with."""
        try:
            result = dispatch(cb.method, _copied(cb.params))
            if isinstance(result, collections.abc.Awaitable):
                result = await compat.wait_for(result, self.timeout)
        except (asyncio.CancelledError, asyncio.TimeoutError):
            raise
        except Exception as e:  # noqa: BLE001 - a request's handler that raises is answered with a fault
            raise Fault(1, "%s:%s" % (type(e), e)) from None
        return _copied(result)

    def pending(self) -> int:
        """Callbacks queued or in flight (for tests and shutdown)."""
        return self._outbox.queued()

    async def close(self) -> None:
        """Cancel everything still queued or in flight."""
        self._closed = True
        if self._pump_handle is not None:
            self._pump_handle.cancel()
            self._pump_handle = None
        tasks = list(self._tasks)
        for t in tasks:
            t.cancel()
        if tasks:
            await asyncio.gather(*tasks, return_exceptions=True)
        self._outbox.clear()
