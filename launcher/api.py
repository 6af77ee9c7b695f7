"""The Python API: run a launch from Python code and tests (`with Launch(...) as launch:`), and leave nothing behind.

A `Launch` runs `launch` itself, in a child process of its own with its own
master on a free port (unless `master_uri` names a running one), and talks to
it over the master's XML-RPC API. So the caller's process gets no thread, no
socket and no signal handler from it; when the context ends, the launcher is
stopped as a user would (SIGINT: nodes are stopped in order), then its process
group is killed if it has not finished within `stop_timeout`, and it is reaped.
roslaunch's own API (`ROSLaunchParent`, `scriptapi.ROSLaunch`) runs in the
caller's process and leaks a busy thread after shutdown (ros_comm#2238).

    with Launch("my_pkg", "demo.launch", "sim:=true") as launch:
        launch.wait_for_publisher("/chatter")
        assert launch.status()["/talker"] == "running"
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
import uuid
import xmlrpc.client
from typing import Any, Mapping

from launcher.operate import lastrun
from launcher.workspace.roshome import log_root

CALLER_ID = "/launcher_api"
POLL_S = 0.05  # how often a wait asks the master again
PORT_ATTEMPTS = 3  # free ports tried for our own master
CALL_TIMEOUT_S = 5.0  # one XML-RPC call to the master (something else on the port may never answer)


class LaunchFailed(RuntimeError):
    """The launcher exited, or did not come up: the message holds the end of its output."""


class _Transport(xmlrpc.client.Transport):
    """xmlrpc.client's transport, with a time-out on every connection."""

    def make_connection(self, host: Any) -> Any:
        conn = super().make_connection(host)
        conn.timeout = CALL_TIMEOUT_S
        return conn


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Launch:
    """One launch: `words` are what `launch` takes (`[pkg] file.launch ... name:=value ...`).

    `env` replaces os.environ for the launch (ROS_MASTER_URI is set by the Launch); `master_uri` uses
    a running master instead of starting one; `screen` shows the nodes' output on this process's
    stdout/stderr (else everything goes to `output_path`).
    """

    def __init__(self, *words: str, env: Mapping[str, str] | None = None, master_uri: str | None = None,
                 screen: bool = False, start_timeout: float = 30.0, stop_timeout: float = 20.0):
        self.words = list(words)
        self.env = dict(os.environ if env is None else env)
        self.own_master = master_uri is None
        self.port = _free_port() if master_uri is None else None
        self.master_uri = master_uri or "http://127.0.0.1:%d/" % self.port
        self.screen = screen
        self.start_timeout = start_timeout
        self.stop_timeout = stop_timeout
        self.run_id = "launcher-api-%s" % uuid.uuid4()
        self.process: subprocess.Popen | None = None
        self._dir: tempfile.TemporaryDirectory | None = None
        self.output_path = ""

    # ---- life ------------------------------------------------------------------------------------------

    def start(self) -> Launch:
        """Start the launcher and wait until its master answers (LaunchFailed if it exits first)."""
        if self.process is not None:
            raise RuntimeError("this Launch was already started")
        for attempt in range(PORT_ATTEMPTS):
            try:
                self._start()
                return self
            except LaunchFailed as e:
                # the free port was taken between our look and the launcher's bind: another one
                if not self.own_master or "unable to start the master" not in str(e) or attempt + 1 == PORT_ATTEMPTS:
                    raise
                self.process = None
                self.port = _free_port()
                self.master_uri = "http://127.0.0.1:%d/" % self.port
        return self

    def _start(self) -> None:
        self._dir = tempfile.TemporaryDirectory(prefix="launcher-api-")
        self.output_path = os.path.join(self._dir.name, "launch.out")
        env = dict(self.env)
        env["ROS_MASTER_URI"] = self.master_uri
        # the launcher this module belongs to, whatever the child's sys.path would find first
        here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
        env["PYTHONPATH"] = here + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
        argv = [sys.executable, "-m", "launcher", "--run_id", self.run_id]
        if self.own_master:
            argv += ["-p", str(self.port)]
        if self.screen:
            argv.append("--screen")
        out = None if self.screen else open(self.output_path, "wb")
        try:
            self.process = subprocess.Popen(argv + self.words, env=env, stdin=subprocess.DEVNULL, stdout=out,
                                            stderr=subprocess.STDOUT if out else None, start_new_session=True)
        finally:
            if out is not None:
                out.close()
        try:
            self._wait(self._master_up, self.start_timeout, "the master at %s" % self.master_uri)
        except BaseException:
            self.stop()
            raise

    def stop(self) -> int | None:
        """Stop the launch (SIGINT, then SIGKILL of its process group after `stop_timeout`); its exit status."""
        proc = self.process
        status = None
        if proc is not None:
            if proc.poll() is None:
                try:
                    os.killpg(proc.pid, signal.SIGINT)
                except OSError:
                    pass
                try:
                    proc.wait(self.stop_timeout)
                except subprocess.TimeoutExpired:
                    try:
                        os.killpg(proc.pid, signal.SIGKILL)
                    except OSError:
                        pass
                    proc.wait()
            status = proc.returncode
        if self._dir is not None:
            self._last_output = self.output()
            self._dir.cleanup()
            self._dir = None
        return status

    def __enter__(self) -> Launch:
        return self.start()

    def __exit__(self, *exc: Any) -> None:
        self.stop()

    # ---- looking -----------------------------------------------------------------------------------------

    @property
    def running(self) -> bool:
        return self.process is not None and self.process.poll() is None

    def output(self) -> str:
        """What the launcher printed so far (empty with `screen`)."""
        if self._dir is None:
            return getattr(self, "_last_output", "")
        try:
            with open(self.output_path, errors="replace") as f:
                return f.read()
        except OSError:
            return ""

    def master(self) -> xmlrpc.client.ServerProxy:
        return xmlrpc.client.ServerProxy(self.master_uri, transport=_Transport())

    def system_state(self) -> tuple[list, list, list]:
        """The master's (publishers, subscribers, services): [[name, [node, ...]], ...] each."""
        code, msg, state = self.master().getSystemState(CALLER_ID)
        if code != 1:
            raise LaunchFailed("getSystemState: %s" % msg)
        return state

    def nodes(self) -> set[str]:
        """The nodes registered with the master (with a publication, subscription or service)."""
        names: set[str] = set()
        for kind in self.system_state():
            for _topic, members in kind:
                names.update(members)
        return names

    def publishers(self, topic: str) -> list[str]:
        for name, members in self.system_state()[0]:
            if name == topic:
                return list(members)
        return []

    def status(self) -> dict[str, str]:
        """Each node's state as the supervisor last recorded it (`running`, `stopped`, `respawning`, ...: fleet.state)."""
        path = os.path.join(log_root(self.env), self.run_id, lastrun.EVENTS_FILE)
        try:
            events = lastrun.read_events(path)
        except OSError:
            events = []
        return {name: event["state"] for name, event in lastrun.final_states(events).items()}

    # ---- waiting -----------------------------------------------------------------------------------------

    def wait_for_nodes(self, *names: str, timeout: float = 30.0) -> None:
        """Until every node of `names` (global names) is registered with the master."""
        self._wait(lambda: set(names) <= self.nodes(), timeout, "nodes %s" % ", ".join(names))

    def wait_for_publisher(self, topic: str, timeout: float = 30.0) -> list[str]:
        """Until `topic` has a publisher; its publishers."""
        return self._wait(lambda: self.publishers(topic), timeout, "a publisher of %s" % topic)

    def _master_up(self) -> bool:
        try:
            return self.master().getPid(CALLER_ID)[0] == 1
        except (OSError, xmlrpc.client.Error):
            return False

    def _wait(self, condition: Any, timeout: float, what: str) -> Any:
        deadline = time.monotonic() + timeout
        while True:
            if self.process is None or self.process.poll() is not None:
                raise LaunchFailed("the launcher exited (status %s) before %s:\n%s"
                                   % (self.process.returncode if self.process else None, what, self.output()[-4000:]))
            try:
                value = condition()
            except (OSError, xmlrpc.client.Error):
                value = None
            if value:
                return value
            if time.monotonic() > deadline:
                raise TimeoutError("%s: not within %.1f s" % (what, timeout))
            time.sleep(POLL_S)
