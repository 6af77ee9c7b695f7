"""Nodes on other machines: our `launch` as parent, Debian's roslaunch as child, on two test hosts (tests/testhosts.py).

The hosts are network namespaces with their own sshd; they share this
filesystem, so Debian's ROS runs "on" them. A node's host is checked by the
namespace its process lives in.
"""

from __future__ import annotations

import json
import os
import re
import signal
import socket
import subprocess
import sys
import time
import xmlrpc.client

import pytest

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from testhosts import TestHosts  # noqa: E402

from helpers import ROS_PATH, descendants, free_port, until  # noqa: E402
from running import Launcher  # noqa: E402

NO_ORPHAN_S = 5.0  # the bound: a machine's nodes are gone this long after the launcher or link is


@pytest.fixture(scope="module")
def hosts(ros_env, ros_part_missing):
    why = TestHosts.unavailable()
    if why:
        ros_part_missing(why)
    with TestHosts(2) as th:
        yield th


def our_child_loaders(tmp_path, hosts: TestHosts) -> list[str]:
    """env-loaders that put our launcher first on the host's PATH, as `launch` and as `roslaunch`."""
    bin_dir = os.path.join(str(tmp_path), "bin")
    os.makedirs(bin_dir, exist_ok=True)
    for name in ("launch", "roslaunch"):
        path = os.path.join(bin_dir, name)
        with open(path, "w") as f:
            f.write('#!/bin/sh\nPYTHONPATH=%s exec %s -m launcher "$@"\n' % (os.getcwd(), sys.executable))
        os.chmod(path, 0o755)
    loaders = []
    for host in hosts.hosts:
        with open(host.env_loader) as f:
            text = f.read().replace('exec "$@"', 'export PATH=%s:$PATH\nexec "$@"' % bin_dir)
        path = os.path.join(str(tmp_path), "ours-%d.sh" % host.index)
        with open(path, "w") as f:
            f.write(text)
        os.chmod(path, 0o755)
        loaders.append(path)
    return loaders


def launch_file(tmp_path, hosts: TestHosts, nodes: str, machines: str | None = None,
                loaders: list[str] | None = None) -> str:
    h1, h2 = hosts.hosts
    l1, l2 = loaders or (h1.env_loader, h2.env_loader)
    if machines is None:
        machines = ('  <machine name="one" address="%s" env-loader="%s"/>\n'
                    '  <machine name="two" address="%s" env-loader="%s"/>\n'
                    % (h1.address, l1, h2.address, l2))
    path = os.path.join(str(tmp_path), "robot.launch")
    with open(path, "w") as f:
        f.write("<launch>\n%s%s</launch>\n" % (machines, nodes))
    return path


def run_env(tmp_path, hosts: TestHosts, **extra: str) -> dict[str, str]:
    env = hosts.env(ROS_MASTER_URI="http://%s:%d/" % (hosts.gateway, free_port()), PATH=ROS_PATH,
                    ROS_HOME=os.path.join(str(tmp_path), "home"), ROS_LOG_DIR=os.path.join(str(tmp_path), "log"),
                    PYTHONPATH=os.getcwd())
    env.pop("ROS_NAMESPACE", None)
    env.update(extra)
    return env


def node_names(env: dict[str, str]) -> set[str]:
    r = subprocess.run(["rosnode", "list"], env=env, capture_output=True, text=True, timeout=30)
    return set(r.stdout.split())


def on_host(host, needle: str) -> list[int]:
    """pids of processes on the test host whose command line contains `needle`."""
    return [int(line.split()[0]) for line in host.process_lines() if needle in line]


TALKER = '<node machine="one" pkg="rostopic" type="rostopic" name="talker" args="pub /chatter std_msgs/String hello -r 10"%s/>\n'
LISTENER = '<node machine="two" pkg="rostopic" type="rostopic" name="listener" args="echo /chatter"%s/>\n'
LOCAL = '<node pkg="rostopic" type="rostopic" name="local_echo" args="echo /chatter"/>\n'


@pytest.fixture
def launched(tmp_path, hosts):
    started: list[Launcher] = []

    def start(nodes: str, machines: str | None = None, child: str = "debian",
              **env: str) -> tuple[Launcher, dict[str, str]]:
        loaders = None
        if child == "ours":  # our launch as the child, run by its own name
            loaders = our_child_loaders(tmp_path, hosts)
            env.setdefault("LAUNCHER_REMOTE_PROGRAM", "launch")
        e = run_env(tmp_path, hosts, **env)
        la = Launcher([launch_file(tmp_path, hosts, nodes, machines, loaders)], e, str(tmp_path))
        started.append(la)
        return la, e

    yield start
    for la in started:
        la.close()
    for host in hosts.hosts:  # what a test left running on a host must not leak into the next one
        for pid in host.pids():
            try:
                os.kill(pid, signal.SIGKILL)
            except OSError:
                pass


@pytest.mark.parametrize("child", ["debian", "ours"])
def test_nodes_on_three_hosts_register_and_talk(hosts, launched, child):
    la, env = launched(TALKER % "" + LISTENER % "" + LOCAL, child=child)
    until(lambda: {"/talker", "/listener", "/local_echo"} <= node_names(env), 60, period=0.5,
          what="nodes of all three hosts registered")
    h1, h2 = hosts.hosts
    assert on_host(h1, "__name:=talker") and not on_host(h1, "__name:=listener")
    assert on_host(h2, "__name:=listener") and not on_host(h2, "__name:=talker")
    r = subprocess.run(["rostopic", "echo", "-n", "1", "/chatter"], env=env, capture_output=True, text=True,
                       timeout=60)
    assert 'data: "hello"' in r.stdout
    # the remote listener hears the remote talker: its subscription is connected
    r = subprocess.run(["rosnode", "info", "/listener"], env=env, capture_output=True, text=True, timeout=60)
    assert re.search(r"topic: /chatter\s+\* to: /talker", r.stdout), r.stdout
    # one roslaunch server, as roslaunch's: a Debian child registers the URI of its parent as the launch's
    uris = xmlrpc.client.ServerProxy(env["ROS_MASTER_URI"]).getParam("/test", "/roslaunch/uris")[2]
    assert len(uris) == 1, uris
    # the events carry each node's host; `launcher events` names the host of a node on another machine
    def events(*args: str) -> str:
        r = subprocess.run([sys.executable, "-m", "launcher.cli.tool", "events"] + list(args), env=env,
                           capture_output=True, text=True, timeout=30)
        assert r.returncode == 0, r.stderr
        return r.stdout
    text = until(lambda: (lambda out: out if "/talker on %s running" % h1.address in out else None)(events()), 30,
                 0.5, what="the remote talker's events")
    assert re.search(r" /local_echo running pid \d+", text), text
    hosts_of = {e["node"]: e["host"] for e in map(json.loads, events("--json").splitlines())}
    assert hosts_of == {"/talker": h1.address, "/listener": h2.address, "/local_echo": "localhost"}


@pytest.mark.parametrize("child", ["debian", "ours"])
def test_remote_node_killed_is_reported_and_respawned(hosts, launched, child):
    la, env = launched(TALKER % ' respawn="true"', child=child)
    h1 = hosts.hosts[0]
    first = until(lambda: on_host(h1, "__name:=talker"), 60, what="talker on host one")[0]
    la.wait_output(r"\[talker-1\]: started with pid", 30)
    os.kill(first, signal.SIGKILL)
    la.wait_output(r"\[talker-1\] process has died \[pid %d, exit code -9" % first, 30, stream="stderr")
    again = until(lambda: [p for p in on_host(h1, "__name:=talker") if p != first], 30, what="talker respawned")
    assert again


def test_unreachable_host_and_refused_key_are_errors_while_local_nodes_run(tmp_path, hosts, launched):
    h1 = hosts.hosts[0]
    machines = ('  <machine name="gone" address="%s.99" env-loader="%s" timeout="3"/>\n'
                '  <machine name="one" address="%s" env-loader="%s"/>\n'
                % (hosts.subnet, h1.env_loader, h1.address, h1.env_loader))
    nodes = ('<node machine="gone" pkg="rostopic" type="rostopic" name="lost" args="echo /x"/>\n' + LOCAL)
    la, env = launched(nodes, machines)
    m = la.wait_output(r"robot\.launch:2: remote\[[^\]]+\]: failed to launch on machine \[gone\]:\s+unable to "
                       r"reach \[%s\.99:22\]" % re.escape(hosts.subnet), 60, stream="stderr")
    assert m
    assert "/local_echo" in node_names(env)
    assert la.proc.poll() is None

    nodes = TALKER % "" + LOCAL
    la2, env2 = launched(nodes, machines, LAUNCHER_SSH_COMMAND=hosts.ssh_command(key="other_key"))
    la2.wait_output(r"robot\.launch:3: remote\[[^\]]+\]: failed to launch on machine \[one\]:\s+authentication "
                    r"to remote computer \[%s:22\] failed: the key was refused" % re.escape(h1.address), 60,
                    stream="stderr")
    until(lambda: "/local_echo" in node_names(env2), 30, period=0.5, what="local node registered")
    assert la2.proc.poll() is None and not on_host(h1, "__name:=talker")


def test_unknown_host_key_is_an_error_unless_roslaunch_ssh_unknown(tmp_path, hosts, launched):
    empty = os.path.join(str(tmp_path), "known_hosts")
    open(empty, "w").close()
    la, env = launched(TALKER % "", LAUNCHER_SSH_COMMAND=hosts.ssh_command(known_hosts=empty))
    la.wait_output(r"failed to launch on machine \[one\]:\s+%s is not in your SSH known_hosts file"
                   % re.escape(hosts.hosts[0].address), 60, stream="stderr")
    la.close()
    la, env = launched(TALKER % "", LAUNCHER_SSH_COMMAND=hosts.ssh_command(known_hosts=empty),
                       ROSLAUNCH_SSH_UNKNOWN="1")
    until(lambda: "/talker" in node_names(env), 60, period=0.5, what="talker registered")


def test_password_and_loopback_master_are_clear_errors(tmp_path, hosts, launched):
    h1 = hosts.hosts[0]
    machines = '  <machine name="one" address="%s" env-loader="%s" password="secret"/>\n' % (h1.address,
                                                                                             h1.env_loader)
    la, _ = launched(TALKER % "", machines)
    assert la.wait(30) != 0
    assert re.search(r"robot\.launch:2: machine \[one\]: password=.* use a key", la.stderr), la.stderr
    la, _ = launched(TALKER % "", ROS_MASTER_URI="http://localhost:%d/" % free_port())
    assert la.wait(30) != 0
    assert re.search(r"robot\.launch:\d+: ROS_MASTER_URI \[http://localhost:\d+/\] is a loopback address",
                     la.stderr), la.stderr


def test_missing_env_loader_is_reported_by_machine(tmp_path, hosts, launched):
    h1 = hosts.hosts[0]
    machines = '  <machine name="one" address="%s" env-loader="/nonexistent/env.sh"/>\n' % h1.address
    la, _ = launched(TALKER % "" + LOCAL, machines)
    la.wait_output(r"robot\.launch:2: remote\[[^\]]+\]: failed to launch on machine \[one\]:\s+env-loader "
                   r"\[/nonexistent/env.sh\] not found on \[%s\]" % re.escape(h1.address), 60, stream="stderr")
    assert la.proc.poll() is None


def test_required_node_on_a_failed_machine_ends_the_launch_with_status_1(tmp_path, hosts, launched):
    machines = '  <machine name="gone" address="%s.99" env-loader="/x" timeout="3"/>\n' % hosts.subnet
    la, _ = launched('<node machine="gone" pkg="rostopic" type="rostopic" name="lost" args="echo /x" '
                     'required="true"/>\n' + LOCAL, machines)
    assert la.wait(60) == 1


@pytest.mark.parametrize("child", ["debian", "ours"])
def test_sigkill_of_the_launcher_leaves_no_process_on_the_hosts(hosts, launched, child):
    la, env = launched(TALKER % "" + LISTENER % "", child=child)
    h1, h2 = hosts.hosts
    until(lambda: on_host(h1, "__name:=talker") and on_host(h2, "__name:=listener"), 60, what="remote nodes")
    la.proc.kill()
    la.proc.wait()
    try:
        until(lambda: not h1.pids() and not h2.pids(), NO_ORPHAN_S, period=0.1, what="no process on the test hosts")
    except AssertionError as e:
        raise AssertionError("%s: %s" % (e, h1.process_lines() + h2.process_lines())) from None


# a node whose launch-prefix is a shell that leaves a background job in the node's session: a shell's
# background jobs ignore SIGINT, so only a signal to the node's whole group stops it
BACKGROUNDER = ('<node machine="one" pkg="rostopic" type="rostopic" name="talker" args="pub /chatter std_msgs/String '
                'hello -r 10" launch-prefix="sh -c \'sleep 1234 &amp; exec &quot;$0&quot; &quot;$@&quot;\'"/>\n')


@pytest.mark.parametrize("child", ["debian", "ours"])
@pytest.mark.parametrize("how", ["sigkill", "cut"])
def test_a_remote_nodes_whole_process_tree_is_stopped_when_the_launcher_or_the_link_goes(hosts, launched, child,
                                                                                         how):
    la, env = launched(BACKGROUNDER, child=child)
    h1 = hosts.hosts[0]
    until(lambda: on_host(h1, "sleep 1234") and on_host(h1, "__name:=talker"), 60, what="the node and its job")
    if how == "sigkill":
        la.proc.kill()
        la.proc.wait()
    else:
        h1.cut()
    try:
        until(lambda: not on_host(h1, "sleep 1234") and not on_host(h1, "__name:=talker"), NO_ORPHAN_S,
              period=0.1, what="the node and its background job gone from host one")
    except AssertionError as e:
        raise AssertionError("%s: %s" % (e, h1.process_lines())) from None
    finally:
        if how == "cut":
            h1.restore()


@pytest.mark.parametrize("child", ["debian", "ours"])
def test_a_cut_link_stops_that_hosts_nodes_and_they_start_again_when_it_returns(hosts, launched, child):
    la, env = launched(TALKER % "" + LISTENER % "", child=child)
    h1, h2 = hosts.hosts
    first = until(lambda: on_host(h1, "__name:=talker"), 60, what="talker on host one")[0]
    until(lambda: on_host(h2, "__name:=listener"), 60, what="listener on host two")
    h1.cut()
    try:
        # (the host's sshd keeps its half of the dead connection: only ssh's own processes may stay)
        try:
            until(lambda: not [line for line in h1.process_lines() if "sshd" not in line], NO_ORPHAN_S,
                  period=0.1, what="host one's nodes stopped after its link was cut")
        except AssertionError as e:
            raise AssertionError("%s: %s" % (e, h1.process_lines())) from None
        assert on_host(h2, "__name:=listener"), la.stdout + la.stderr  # the other machine carries on
        la.wait_output(r"machine \[one\] dropped; trying again", 30, stream="stderr")
    finally:
        h1.restore()
    try:
        again = until(lambda: on_host(h1, "__name:=talker"), 60, period=0.2, what="talker started again on host one")
    except AssertionError as e:
        raise AssertionError("%s\n%s%s" % (e, la.stdout, la.stderr)) from None
    assert again[0] != first
    until(lambda: "/talker" in node_names(env), 30, period=0.5, what="talker registered again")


def test_debian_roslaunch_parent_with_our_child(tmp_path, hosts, launched):
    """Debian's roslaunch runs `roslaunch -c` on the hosts, which there is our launcher."""
    loaders = our_child_loaders(tmp_path, hosts)
    env = run_env(tmp_path, hosts, HOME=hosts.home)  # (paramiko reads ~/.ssh)
    path = launch_file(tmp_path, hosts, TALKER % ' respawn="true"' + LISTENER % "" + LOCAL, loaders=loaders)
    out_path = os.path.join(str(tmp_path), "roslaunch.out")
    with open(out_path, "w") as out:
        la = subprocess.Popen(["roslaunch", path], env=env, stdout=out, stderr=subprocess.STDOUT,
                              start_new_session=True)
    h1, h2 = hosts.hosts
    local: set[int] = set()

    def parent_output() -> str:
        with open(out_path) as f:
            return f.read()

    try:
        until(lambda: {"/talker", "/listener", "/local_echo"} <= node_names(env), 90, period=0.5,
              what="nodes of all three hosts registered")
        assert [line for line in h1.process_lines() if "-m launcher -c" in line]  # our child runs there
        # the child's console lines reach Debian's parent (which prints them as "[child]: ..."), once each
        # and in order, also when several went in one system.multicall
        until(lambda: "... done launching nodes" in parent_output(), 30, what="the children's lines printed")
        text = re.sub(r"\x1b\[[0-9;]*m", "", parent_output())  # (it prints "started" lines in bold)
        for host in (h1, h2):
            lines = re.findall(r"^\[%s-\d+\]: (.*)$" % re.escape(host.address), text, re.M)
            assert lines[:3] == ["launching nodes...", lines[1], "... done launching nodes"], (host.address, text)
            assert re.fullmatch(r"process\[(talker|listener)-1\]: started with pid \[\d+\]", lines[1]), lines
        r = subprocess.run(["rostopic", "echo", "-n", "1", "/chatter"], env=env, capture_output=True, text=True,
                           timeout=60)
        assert 'data: "hello"' in r.stdout
        first = on_host(h1, "__name:=talker")[0]
        os.kill(first, signal.SIGKILL)
        until(lambda: [p for p in on_host(h1, "__name:=talker") if p != first], 30, what="talker respawned")
        # SIGKILL of Debian's roslaunch: its ssh channel closes, and our child stops the nodes
        local = descendants(la.pid)
        la.kill()
        la.wait()
        try:
            until(lambda: not h1.pids() and not h2.pids(), NO_ORPHAN_S, period=0.1, what="no process on the hosts")
        except AssertionError as e:
            raise AssertionError("%s: %s" % (e, h1.process_lines() + h2.process_lines())) from None
    finally:
        if la.poll() is None:
            local = descendants(la.pid)
            la.kill()
            la.wait()
        for pid in local:  # Debian's master and rosout, in sessions of their own
            try:
                os.kill(pid, signal.SIGKILL)
            except OSError:
                pass


@pytest.mark.parametrize("child", ["debian", "ours"])
def test_a_machine_whose_nodes_all_ended_is_not_started_again(hosts, launched, child):
    la, env = launched('<node machine="one" pkg="rostopic" type="rostopic" name="once" args="list"/>\n' + LOCAL,
                       child=child)
    h1 = hosts.hosts[0]
    la.wait_output(r"\[once-1\]: started with pid", 60)
    until(lambda: not h1.pids(), 30, period=0.1, what="the child on host one ended with its only node")
    until(lambda: "/local_echo" in node_names(env), 30, period=0.5, what="local node registered")
    la.signal(signal.SIGINT)
    la.wait(60)
    assert "dropped" not in la.stderr
    assert len(re.findall(r"process\[once-1\]: started with pid", la.stdout)) == 1


def test_debian_parent_cut_off_from_our_child_leaves_no_process_on_that_host(tmp_path, hosts, launched):
    """Debian's parent gives the child no pty: our child notices the silent parent by itself."""
    loaders = our_child_loaders(tmp_path, hosts)
    env = run_env(tmp_path, hosts, HOME=hosts.home)
    path = launch_file(tmp_path, hosts, TALKER % "" + LISTENER % "", loaders=loaders)
    la = subprocess.Popen(["roslaunch", path], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                          start_new_session=True)
    h1, h2 = hosts.hosts
    local: set[int] = set()
    try:
        until(lambda: on_host(h1, "__name:=talker") and on_host(h2, "__name:=listener"), 90, what="remote nodes")
        h1.cut()
        try:
            until(lambda: not [line for line in h1.process_lines() if "sshd" not in line], NO_ORPHAN_S,
                  period=0.1, what="host one's nodes stopped after its link was cut")
        except AssertionError as e:
            raise AssertionError("%s: %s" % (e, h1.process_lines())) from None
        finally:
            h1.restore()
        assert on_host(h2, "__name:=listener")
    finally:
        local = descendants(la.pid)
        la.kill()
        la.wait()
        for pid in local:
            try:
                os.kill(pid, signal.SIGKILL)
            except OSError:
                pass


def events(tmp_path, node: str) -> list[dict]:
    """The node's events in the run's events file (ROS_LOG_DIR/latest/launcher-events.jsonl)."""
    import json
    try:
        with open(os.path.join(str(tmp_path), "log", "latest", "launcher-events.jsonl")) as f:
            lines = f.read().splitlines()
    except OSError:
        return []
    return [e for e in (json.loads(line) for line in lines if line.endswith("}")) if e.get("node") == node]


POLICY_TALKER = ('<node machine="one" pkg="rostopic" type="rostopic" name="talker" respawn="true" '
                 'respawn_delay="0.3" respawn_backoff="2" respawn_min_uptime="60" respawn_max_retries="2" '
                 'args="pub /chatter std_msgs/String hello -r 10"/>\n')
KEEPER = '<node machine="one" pkg="rostopic" type="rostopic" name="keeper" args="echo /chatter"/>\n'


@pytest.mark.parametrize("child", ["debian", "ours"])
@pytest.mark.parametrize("alone", [False, True], ids=["beside-another-node", "alone"])
def test_restart_policy_of_a_remote_node_backoff_then_fatal(tmp_path, hosts, launched, child, alone):
    """The parent owns the restarts of a node with a policy: backoff after each kill, FATAL after the retries.

    Beside another node its child takes a second `launch` call; alone, the child ends with it (as
    roslaunch's children do) and the next start comes with a new session."""
    la, env = launched(POLICY_TALKER + ("" if alone else KEEPER), child=child)
    h1 = hosts.hosts[0]
    keeper = [] if alone else until(lambda: on_host(h1, "__name:=keeper"), 60, what="keeper on host one")
    started = r"process\[talker-\d+\]: started with pid"
    killed: list[int] = []
    for run in range(3):
        pid = until(lambda: [p for p in on_host(h1, "__name:=talker") if p not in killed], 60,
                    what="talker run %d on host one" % (run + 1))[0]
        until(lambda: len(re.findall(started, la.stdout)) == run + 1, 60, what="talker run %d reported" % (run + 1))
        os.kill(pid, signal.SIGKILL)
        killed.append(pid)
    la.wait_output(r"\[talker\] on machine \[one\] FATAL: failed 3 starts in a row \(respawn_max_retries=2\)", 60,
                   stream="stderr")
    # (said on stdout before that on stderr; the two are read apart, so it is waited for too)
    la.wait_output(re.escape("[talker] on machine [one] respawning in 0.6 s (2 failed starts in a row)"), 30)
    evs = events(tmp_path, "/talker")
    assert [e["state"] for e in evs] == ["waiting", "running", "respawning", "running", "respawning", "running",
                                         "fatal"][-len(evs):], evs
    assert [e["failures"] for e in evs if e["state"] in ("respawning", "fatal")] == [1, 2, 3]
    assert evs[-1]["exit_signal"] == 9 and "respawn_max_retries=2" in evs[-1]["reason"]
    if not alone:  # the other node of that machine ran on, in the same child, all along
        assert on_host(h1, "__name:=keeper") == keeper
    # the delays grow by the backoff (a new session adds its ssh and child start)
    runs = [e for e in evs if e["state"] in ("respawning", "running")]
    delays = [b["time"] - a["time"] for a, b in zip(runs, runs[1:]) if a["state"] == "respawning"]
    assert len(delays) == 2 and 0.28 <= delays[0] < 0.3 + 5 and 0.58 <= delays[1] < 0.6 + 5, delays
    la.signal(signal.SIGINT)
    assert la.wait(60) == 0, la.stderr
    # the child never respawned it on its own: three runs, none after the FATAL
    assert len(re.findall(started, la.stdout)) == 3, la.stdout


def test_on_fatal_shutdown_of_a_remote_node_ends_the_launch_with_status_1(tmp_path, hosts, launched):
    nodes = ('<node machine="one" pkg="rostopic" type="rostopic" name="bad" respawn="true" respawn_delay="0.1" '
             'respawn_max_retries="1" on_fatal="shutdown" args="pub /x no_such_pkg/NoType 1"/>\n' + LOCAL)
    la, env = launched(nodes, child="ours")
    assert la.wait(90) == 1, la.stdout + la.stderr
    assert re.search(r"FATAL process \[bad\] has failed \(on_fatal=\"shutdown\"\)", la.stderr), la.stderr


def test_spawn_delay_and_wait_for_hold_a_remote_nodes_start(tmp_path, hosts, launched):
    nodes = ('<node machine="one" pkg="rostopic" type="rostopic" name="talker" spawn_delay="1.5" '
             'args="pub /chatter std_msgs/String hello -r 10"/>\n'
             '<node machine="two" pkg="rostopic" type="rostopic" name="listener" wait_for="topic:/chatter" '
             'args="echo /chatter"/>\n')
    la, env = launched(nodes)
    la.wait_output(r"process\[listener-\d+\]: started with pid", 90)
    talker, listener = events(tmp_path, "/talker"), events(tmp_path, "/listener")
    t_run = next(e["time"] for e in talker if e["state"] == "running")
    l_run = next(e["time"] for e in listener if e["state"] == "running")
    assert any("spawn_delay 1.5" in e["reason"] for e in talker if e["state"] == "waiting"), talker
    assert any("waiting for topic:/chatter" in e["reason"] for e in listener if e["state"] == "waiting"), listener
    assert l_run > t_run  # the listener's start waited for the talker's topic
    start = min(e["time"] for e in talker)
    assert t_run - start >= 1.5


def test_policies_a_remote_child_cannot_apply_are_warned_about_at_load(tmp_path, hosts, launched):
    nodes = ('<node machine="one" pkg="rostopic" type="rostopic" name="talker" memory_limit="1GB" '
             'enable_coredumps="true" args="pub /chatter std_msgs/String hello -r 10"/>\n')
    la, env = launched(nodes)
    m = la.wait_output(r"WARNING: .*robot\.launch:4: node \[/talker\] runs on machine \[one\] \(%s\): resource "
                       r"limits \(memory_limit\) cannot be applied there" % re.escape(hosts.hosts[0].address), 30,
                       stream="stderr")
    # (the next warning is waited for too: on a loaded machine it may not be read yet when the first is)
    assert m and la.wait_output(r"core dumps \(enable_coredumps\)", 30, stream="stderr")


def tool(env: dict[str, str], *args: str) -> subprocess.CompletedProcess:
    """`launcher ARGS` against the launch of `env` (its master)."""
    return subprocess.run([sys.executable, "-m", "launcher.cli.tool"] + list(args), env=env, capture_output=True,
                          text=True, timeout=120)


def node_status(env: dict[str, str]) -> dict[str, dict]:
    r = tool(env, "status", "--json")
    assert r.returncode == 0, r.stderr
    return {n["name"]: n for n in json.loads(r.stdout)["nodes"]}


def pid_of_registered(env: dict[str, str], name: str) -> int | None:
    """The pid the node registered at the master answers with (getPid on its own API), or None."""
    try:
        code, _, uri = xmlrpc.client.ServerProxy(env["ROS_MASTER_URI"]).lookupNode("/test", name)
        return xmlrpc.client.ServerProxy(uri).getPid("/test")[2] if code == 1 else None
    except (OSError, xmlrpc.client.Error):
        return None


def stays(cond, seconds: float, what: str) -> None:
    """`cond()` holds at every look for `seconds` (a respawn that should not come: it has had its time)."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        assert cond(), what
        time.sleep(0.1)


RESPAWN_DELAY_S = 1.0
RESPAWNING_TALKER = TALKER % (' respawn="true" respawn_delay="%g"' % RESPAWN_DELAY_S)


def test_operator_stop_start_restart_of_a_remote_node_with_our_child(tmp_path, hosts, launched):
    la, env = launched(RESPAWNING_TALKER + LOCAL, child="ours")
    h1 = hosts.hosts[0]
    first = until(lambda: on_host(h1, "__name:=talker"), 60, what="talker on host one")[0]
    until(lambda: pid_of_registered(env, "/talker") == first, 60, period=0.2, what="talker registered")
    until(lambda: node_status(env)["/talker"]["state"] == "running", 30, period=0.2, what="talker running")

    r = tool(env, "stop", "/talker")
    assert r.returncode == 0 and r.stdout == "stopped /talker\n", r.stdout + r.stderr
    # the answer comes once the process has exited; its child does not respawn it (respawn="true"), nor
    # does the parent
    until(lambda: not on_host(h1, "__name:=talker"), 10, what="talker gone from host one")
    stays(lambda: not on_host(h1, "__name:=talker"), 2.5 * RESPAWN_DELAY_S, "the stopped talker was respawned")
    st = node_status(env)
    assert st["/talker"]["state"] == "stopped" and st["/talker"]["reason"] == "stopped by operator", st["/talker"]
    assert st["/talker"]["host"] == h1.address and st["/local_echo"]["state"] == "running"
    assert [e["state"] for e in events(tmp_path, "/talker")][-1] == "stopped"

    r = tool(env, "start", "talker")
    assert r.returncode == 0 and r.stdout == "started /talker\n", r.stdout + r.stderr
    second = until(lambda: on_host(h1, "__name:=talker"), 60, what="talker started again on host one")[0]
    assert second != first
    until(lambda: pid_of_registered(env, "/talker") == second, 60, period=0.2, what="the new talker registered")
    until(lambda: (lambda s: s["state"] == "running" and s["pid"] == second)(node_status(env)["/talker"]), 30,
          period=0.2, what="talker running again in the status")

    # local and remote nodes in one call, one answer
    local_first = node_status(env)["/local_echo"]["pid"]
    r = tool(env, "restart", "/(talker|local_echo)")
    assert r.returncode == 0 and sorted(r.stdout.splitlines()) == ["restarted /local_echo", "restarted /talker"], \
        r.stdout + r.stderr
    third = until(lambda: [p for p in on_host(h1, "__name:=talker") if p != second], 60, what="talker restarted")[0]
    until(lambda: pid_of_registered(env, "/talker") == third, 60, period=0.2, what="the restarted talker registered")
    st = until(lambda: (lambda s: s if s["/talker"]["pid"] == third and s["/talker"]["state"] == "running"
                       and s["/local_echo"]["state"] == "running" else None)(node_status(env)), 30, period=0.2,
               what="both running again")
    assert st["/local_echo"]["pid"] != local_first
    states = [e["state"] for e in events(tmp_path, "/talker")]
    states = [s for i, s in enumerate(states) if i == 0 or s != states[i - 1]]  # (its registrations: lines too)
    assert states[-4:] == ["stopped", "running", "stopped", "running"] and states.count("stopped") == 2, states
    la.signal(signal.SIGINT)
    assert la.wait(60) == 0, la.stderr


def test_operator_stop_of_a_node_under_debians_child_is_refused_and_it_runs_on(tmp_path, hosts, launched):
    once = '<node machine="two" pkg="rostopic" type="rostopic" name="once" args="list"/>\n'
    la, env = launched(RESPAWNING_TALKER + LOCAL + once)
    h1, h2 = hosts.hosts
    first = until(lambda: on_host(h1, "__name:=talker"), 60, what="talker on host one")[0]
    until(lambda: node_status(env)["/talker"]["state"] == "running", 30, period=0.2, what="talker running")

    for verb in ("stop", "restart"):
        r = tool(env, verb, "/talker")
        assert r.returncode == 1 and r.stdout == "", r.stdout + r.stderr
        assert ("cannot stop [/talker] on machine [one] (%s): its roslaunch child cannot stop one process"
                % h1.address) in r.stderr, r.stderr
    # with a local node in the same call: that one is stopped, the remote one refused
    r = tool(env, "stop", "/(talker|local_echo)")
    assert r.returncode == 1 and r.stdout == "stopped /local_echo\n", r.stdout + r.stderr
    assert "cannot stop [/talker] on machine [one]" in r.stderr, r.stderr
    st = node_status(env)
    assert st["/talker"]["state"] == "running" and st["/talker"]["pid"] == first
    assert st["/local_echo"]["state"] == "stopped"
    assert on_host(h1, "__name:=talker") == [first]

    # a remote node that ended is started again by a `launch` call, also by Debian's child
    until(lambda: node_status(env)["/once"]["state"] == "exited", 60, period=0.2, what="once ended on host two")
    r = tool(env, "start", "/once")
    assert r.returncode == 0 and r.stdout == "started /once\n", r.stdout + r.stderr
    la.wait_output(r"process\[once-\d+\]: started with pid(.|\n)*process\[once-\d+\]: started with pid", 60)
    until(lambda: [e["state"] for e in events(tmp_path, "/once")].count("running") == 2, 30, period=0.2,
          what="once running a second time")


def test_a_remote_node_stopped_by_the_operator_stays_stopped_when_its_machine_comes_back(tmp_path, hosts, launched):
    la, env = launched(RESPAWNING_TALKER + KEEPER, child="ours")
    h1 = hosts.hosts[0]
    until(lambda: on_host(h1, "__name:=talker") and on_host(h1, "__name:=keeper"), 60, what="nodes on host one")
    until(lambda: node_status(env)["/talker"]["state"] == "running", 30, period=0.2, what="talker running")
    r = tool(env, "stop", "/talker")
    assert r.returncode == 0, r.stderr
    keeper = on_host(h1, "__name:=keeper")
    h1.cut()
    try:
        la.wait_output(r"machine \[one\] dropped; trying again", 30, stream="stderr")
    finally:
        h1.restore()
    until(lambda: [p for p in on_host(h1, "__name:=keeper") if p not in keeper], 60, period=0.2,
          what="keeper started again on host one")
    until(lambda: node_status(env)["/keeper"]["state"] == "running", 30, period=0.2, what="keeper running again")
    stays(lambda: not on_host(h1, "__name:=talker"), 2.5 * RESPAWN_DELAY_S, "the stopped talker came back")
    assert node_status(env)["/talker"]["state"] == "stopped"


def reload_json(env: dict[str, str], *args: str) -> dict:
    r = tool(env, "reload", "--json", *args)
    assert r.stdout, r.stderr
    return json.loads(r.stdout)


def test_a_reload_changes_adds_and_removes_nodes_of_other_machines_with_our_child(tmp_path, hosts, launched):
    la, env = launched(TALKER % "" + KEEPER + LOCAL, child="ours")
    h1, h2 = hosts.hosts
    talker = until(lambda: on_host(h1, "__name:=talker"), 60, what="talker on host one")[0]
    keeper = until(lambda: on_host(h1, "__name:=keeper"), 60, what="keeper on host one")[0]
    until(lambda: pid_of_registered(env, "/talker") == talker, 60, period=0.2, what="talker registered")
    local = until(lambda: (lambda s: s.get("/local_echo", {}).get("pid"))(node_status(env)), 30, period=0.2,
                  what="local_echo running")
    path = os.path.join(str(tmp_path), "robot.launch")
    with open(path) as f:
        text = f.read()
    text = text.replace("hello -r 10", "hello -r 5").replace(KEEPER, LISTENER % "")
    with open(path, "w") as f:
        f.write(text)
    answer = reload_json(env)
    assert answer["ok"], answer.get("error")
    assert list(answer["difference"]["restart"]) == ["/talker"] and list(answer["difference"]["stop"]) == ["/keeper"]
    assert list(answer["difference"]["start"]) == ["/listener"]
    new_talker = until(lambda: [p for p in on_host(h1, "__name:=talker") if p != talker], 60,
                       what="talker started anew on host one")[0]
    with open("/proc/%d/cmdline" % new_talker, "rb") as f:
        assert b"-r\x005" in f.read()
    until(lambda: not on_host(h1, "__name:=keeper"), 30, what="keeper gone from host one")
    until(lambda: on_host(h2, "__name:=listener"), 60, what="listener on host two")
    st = node_status(env)
    assert "/keeper" not in st and st["/local_echo"]["pid"] == local
    assert on_host(h1, "__name:=talker") == [new_talker] and keeper not in on_host(h1, "__name:=")


def test_a_reload_that_must_stop_a_node_under_debians_child_is_refused_by_name(tmp_path, hosts, launched):
    la, env = launched(TALKER % "" + LOCAL)
    h1 = hosts.hosts[0]
    talker = until(lambda: on_host(h1, "__name:=talker"), 60, what="talker on host one")[0]
    until(lambda: node_status(env)["/talker"]["state"] == "running", 30, period=0.2, what="talker running")
    path = os.path.join(str(tmp_path), "robot.launch")
    with open(path) as f:
        text = f.read()
    with open(path, "w") as f:
        f.write(text.replace("hello -r 10", "hello -r 5").replace('name="local_echo"', 'name="local_echo2"'))
    dry = tool(env, "reload", "--dry-run")
    assert dry.returncode == 1 and "would restart /talker" in dry.stdout, dry.stdout + dry.stderr
    assert ("node [/talker] runs under Debian's roslaunch child on machine [one], which cannot stop one node: "
            "the launch needs a full restart") in dry.stderr
    r = tool(env, "reload")
    assert r.returncode == 1 and "reload refused, nothing changed" in r.stderr, r.stderr
    st = node_status(env)
    assert set(st) == {"/talker", "/local_echo"} and on_host(h1, "__name:=talker") == [talker]



# A node that is a shell script (its launch-prefix; the node's own command only gives it its name): at
# SIGINT its leader, sh, exits at once and leaves its two background jobs, which ignore SIGINT, in the
# node's process group. Only a stop that knows the group without its leader ends them. Beside it, one
# whose leader has exited already (a script that starts its jobs and ends), leaving its group behind.
JOBS_SCRIPT = "sleep %d & sleep %d & wait\n"
DAEMON_SCRIPT = "sleep %d & sleep %d &\n"
JOBS_SLEEP_S, DAEMON_SLEEP_S = 1000, 2000  # + the host's index: each node's jobs told apart by their command line
# who runs the nodes of the other machines: (the parent, the child)
PARENT_AND_CHILD = [("ours", "ours"), ("ours", "debian"), ("debian", "ours")]
CUT_RUNS = 20  # cuts in a row (each pass cuts every host of four_hosts)


def jobs_left(host) -> list[str]:
    """What is left on the host of its shell-script nodes: the scripts' shells, their sleeps."""
    needles = ("__name:=jobs%d" % host.index, "__name:=daemon%d" % host.index,
               "sleep %d" % (JOBS_SLEEP_S + host.index), "sleep %d" % (DAEMON_SLEEP_S + host.index))
    return [line for line in host.process_lines() if any(n in line for n in needles)]


def start_jobs(tmp_path, hosts: TestHosts, parent: str, child: str, args: tuple[str, ...] = ()):
    """A launch with the two shell-script nodes on each host, under `parent` and `child` (given `args`), once
    their jobs run and the daemon's leader has gone: a function that kills the parent (SIGKILL, or the signal
    given) and what it started here."""
    machines, nodes = "", ""
    loaders = our_child_loaders(tmp_path, hosts) if child == "ours" else [h.env_loader for h in hosts.hosts]
    for host, loader in zip(hosts.hosts, loaders):
        # (four children start at once, 20 runs in a row: on a loaded machine one can take more than roslaunch's
        # default 10 s to register; what is tested here is what a cut link leaves)
        machines += '  <machine name="m%d" address="%s" env-loader="%s" timeout="30"/>\n' % (
            host.index, host.address, loader)
        for name, text, sleep in (("jobs", JOBS_SCRIPT, JOBS_SLEEP_S), ("daemon", DAEMON_SCRIPT, DAEMON_SLEEP_S)):
            script = os.path.join(str(tmp_path), "%s-%d.sh" % (name, host.index))
            with open(script, "w") as f:
                f.write(text % (sleep + host.index, sleep + host.index))
            nodes += ('<node machine="m%d" pkg="rostopic" type="rostopic" name="%s%d" args="list" '
                      'launch-prefix="sh %s"/>\n' % (host.index, name, host.index, script))
    path = os.path.join(str(tmp_path), "jobs.launch")
    with open(path, "w") as f:
        f.write("<launch>\n%s%s</launch>\n" % (machines, nodes))
    output = lambda: ""  # noqa: E731
    if parent == "ours":
        env = run_env(tmp_path, hosts, **({"LAUNCHER_REMOTE_PROGRAM": "launch"} if child == "ours" else {}))
        la = Launcher([path, *args], env, str(tmp_path))
        proc = la.proc
        output = lambda: la.stdout + la.stderr  # noqa: E731
    else:
        env = run_env(tmp_path, hosts, HOME=hosts.home)  # (paramiko reads ~/.ssh)
        proc = subprocess.Popen(["roslaunch", path, *args], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                start_new_session=True)

    def kill(sig: int = signal.SIGKILL) -> None:
        local = descendants(proc.pid) if parent == "debian" else set()  # Debian's master and rosout
        proc.send_signal(sig)
        try:
            proc.wait(60)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
            raise AssertionError("the %s parent did not end within 60 s of signal %d" % (parent, sig)) from None
        finally:
            for pid in local:
                try:
                    os.kill(pid, signal.SIGKILL)
                except OSError:
                    pass
            if parent == "ours":
                la.close()

    def running(host) -> bool:
        jobs, daemon = "sleep %d" % (JOBS_SLEEP_S + host.index), "sleep %d" % (DAEMON_SLEEP_S + host.index)
        return len(on_host(host, jobs)) == 2 and len(on_host(host, daemon)) == 2 and \
            not on_host(host, "__name:=daemon%d" % host.index)
    try:
        for host in hosts.hosts:
            until(lambda: running(host), 90, period=0.1, what="the nodes' jobs on %s" % host.address)
    except AssertionError as e:
        kill()
        raise AssertionError("%s\n%s" % (e, output())) from None
    except BaseException:
        kill()
        raise
    return kill


def all_gone_within(hosts: TestHosts, seconds: float, what: str) -> float:
    """Wait until nothing of the shell-script nodes is left on any host: how long it took."""
    start = time.monotonic()
    try:
        until(lambda: not any(jobs_left(h) for h in hosts.hosts), seconds, period=0.05, what=what)
    except AssertionError as e:
        raise AssertionError("%s: %s" % (e, [line for h in hosts.hosts for line in h.process_lines()])) from None
    return time.monotonic() - start


def reachable(address: str) -> bool:
    try:
        socket.create_connection((address, 22), timeout=0.5).close()
        return True
    except OSError:
        return False


def restore_hosts(hosts: TestHosts) -> None:
    """Between runs: the links up and the hosts' sshd answering again (the parent's address lookups during the
    cut failed, and this machine remembers that for a while), and sshd's half of each cut connection, which
    lingers, gone: the next run starts alone."""
    for host in hosts.hosts:
        host.restore()
    subprocess.run(["ip", "neigh", "flush", "dev", hosts.bridge], capture_output=True, timeout=30)
    for host in hosts.hosts:
        until(lambda: reachable(host.address), 30, period=0.1, what="%s reachable again" % host.address)
        for pid in host.pids():
            try:
                os.kill(pid, signal.SIGKILL)
            except OSError:
                pass


@pytest.fixture(scope="module")
def four_hosts(ros_env, ros_part_missing):
    """More hosts for the cuts in a row: each pass cuts all of them (their sessions are apart)."""
    why = TestHosts.unavailable()
    if why:
        ros_part_missing(why)
    with TestHosts(4) as th:
        yield th


@pytest.mark.parametrize("parent, child", PARENT_AND_CHILD)
def test_sigkill_of_the_parent_leaves_nothing_of_a_shell_script_node(tmp_path, hosts, parent, child):
    try:
        kill = start_jobs(tmp_path, hosts, parent, child)
        kill()
        all_gone_within(hosts, NO_ORPHAN_S, "nothing of the nodes left %g s after their parent's SIGKILL"
                        % NO_ORPHAN_S)
    finally:
        restore_hosts(hosts)


@pytest.mark.parametrize("parent, child", PARENT_AND_CHILD)
def test_an_orderly_stop_leaves_nothing_of_a_shell_script_node(tmp_path, hosts, parent, child):
    """Ctrl-C of the parent: the child's stop (SIGINT, SIGTERM after --sigint-timeout to a group whose leader
    is gone too) under ours; under Debian's child, which waits for each node's leader only, the watch loop's
    sweep after the child's end."""
    try:
        kill = start_jobs(tmp_path, hosts, parent, child, ("--sigint-timeout", "1", "--sigterm-timeout", "1"))
        kill(signal.SIGINT)
        all_gone_within(hosts, NO_ORPHAN_S, "nothing of the nodes left %g s after their parent's orderly end"
                        % NO_ORPHAN_S)
    finally:
        restore_hosts(hosts)


@pytest.mark.parametrize("parent, child", PARENT_AND_CHILD)
def test_a_cut_link_leaves_nothing_of_a_shell_script_node_20_runs_in_a_row(tmp_path, four_hosts, parent, child):
    hosts = four_hosts
    took = []
    for run in range(0, CUT_RUNS, len(hosts.hosts)):
        kill = start_jobs(tmp_path, hosts, parent, child)
        try:
            for host in hosts.hosts:
                host.cut()
            took.append(all_gone_within(hosts, NO_ORPHAN_S, "runs %d-%d: nothing of the nodes left %g s after "
                                        "the cut" % (run + 1, run + len(hosts.hosts), NO_ORPHAN_S)))
        finally:
            kill()
            restore_hosts(hosts)
    print("%s parent, %s child: the nodes gone %.2f-%.2f s after the cut" % (parent, child, min(took), max(took)))

