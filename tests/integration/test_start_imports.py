"""A plain `launch file.launch` imports only what its run needs (issue 36: the launcher's memory at start).

Each module a run imports costs memory for as long as the launch runs (a robot's computer shares it with
the nodes); what a run does not use is imported where it is used (the views, bag, remote machinery, the
metrics server, rostest, rosbags for rosout). The test runs a real launch under `python -X importtime`,
which names every module as it is imported, lazy ones included, and reads what was imported by the time
its roscpp node is registered, its log line is in rosout.log and the log-disk check has run.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import xmlrpc.client

from helpers import free_port, until

from running import compile_roscpp, make_package, master_proxy, ros_env, stop_group, write_launch

# A plain launch of local nodes, with no parameters, no --metrics, no view attached: none of these.
NOT_NEEDED = (
    "rosbags", "numpy",  # rosout decodes rosgraph_msgs/Log itself (net/rosout.decode_log)
    "yaml",  # no <rosparam>, no parameter PyYAML must write
    "prometheus_client", "launcher.services.metrics_server",
    "psutil",  # /proc is read directly (health/resources), the free disk space with statvfs (output/logdir)
    "shutil", "bz2", "lzma",  # (shutil imports its compressors: the log check finds `du` itself)
    "launcher.remote",  # no node on another machine
    "launcher.operate", "launcher.bag", "launcher.rostest", "launcher.cli.introspect", "launcher.cli.check",
    "launcher.xml.sandbox",  # no $(eval)
    "launcher.net.topic_watch",  # no watch_topic: the stall check imports its TCPROS client at its first watch
    "http.server", "xmlrpc.server", "lxml", "prompt_toolkit", "argparse", "email",
    "_ssl", "_hashlib", "hmac",  # libcrypto: asyncio imported without ssl (its attempt is listed), token by hand
    "datetime", "dataclasses", "uuid", "platform", "urllib", "ipaddress", "base64",
    "concurrent.futures.thread",  # no worker thread: the run record is written at once (services/nodeservice)
)
IMPORTED = re.compile(r"^import time:\s+\d+ \|\s+\d+ \|\s*(\S+)\s*$", re.M)


def _unneeded(modules: set[str]) -> list[str]:
    return sorted(m for m in modules if any(m == n or m.startswith(n + ".") for n in NOT_NEEDED))


def _one_roscpp_node(tmp: str) -> tuple[str, int, dict]:
    """A launch of one roscpp node (it logs "tick N" five times a second) in `tmp`, a free master port, its
    environment."""
    pkgs = os.path.join(tmp, "pkgs")
    make_package(pkgs, "lean_pkg", {})
    compile_roscpp("info_node.cpp", os.path.join(pkgs, "lean_pkg", "info_cpp"))
    launch = write_launch(tmp, '<node pkg="lean_pkg" type="info_cpp" name="talker"/>')
    port = free_port()
    return launch, port, ros_env(tmp, port, pkgs)


def test_a_plain_launch_imports_only_what_it_runs(tmp_path):
    tmp = str(tmp_path)
    launch, port, env = _one_roscpp_node(tmp)
    err_path = os.path.join(tmp, "importtime.err")
    with open(err_path, "wb") as err:
        proc = subprocess.Popen([sys.executable, "-X", "importtime", "-m", "launcher", launch], env=env,
                                stdout=subprocess.DEVNULL, stderr=err, stdin=subprocess.DEVNULL,
                                start_new_session=True)
    try:
        def registered() -> bool:
            try:
                return proc.poll() is None and master_proxy(port).lookupNode("/t", "/talker")[0] == 1
            except OSError:
                return False
        until(registered, 60, 0.05, what="the node registered")
        log_dir = os.path.join(tmp, "log", "latest")
        rosout_log = os.path.join(log_dir, "rosout.log")

        def logged() -> bool:  # (rosout has decoded one of the node's Log messages)
            return os.path.exists(rosout_log) and "tick" in open(rosout_log, errors="replace").read()
        until(logged, 30, 0.05, what="the node's line in rosout.log")

        def disk_checked() -> bool:  # (the log-disk check, which runs seconds after the start, has run too)
            return any("Done checking log file disk usage" in open(os.path.join(log_dir, name), errors="replace").read()
                       for name in os.listdir(log_dir) if name.startswith("roslaunch-"))
        until(disk_checked, 30, 0.1, what="the log-disk check in the launch log")
        with open(err_path, errors="replace") as f:
            modules = set(IMPORTED.findall(f.read()))
        assert "launcher.run.runtime" in modules and "launcher.net.rosout" in modules  # (what a run does import)
        assert _unneeded(modules) == []
        assert "launcher.services.metrics" not in modules and "launcher.run.reload" not in modules
        # what is made when first asked for still answers: the run's metrics through its API server
        uris = master_proxy(port).getParam("/t", "/roslaunch/uris")[2]
        code, _msg, text = xmlrpc.client.ServerProxy(list(uris.values())[0]).launcher_metrics()
        assert code == 1 and 'node="/talker"' in text
        proc.send_signal(signal.SIGINT)
        assert proc.wait(30) == 0
    finally:
        stop_group(proc, 10)


def test_a_launch_with_a_master_found_running_imports_none_of_our_masters_code(tmp_path):
    """A robot's launches beside its roscore (or a second launch): the master and rosout are another process's,
    so none of `launcher.master` nor the built-in rosout is this launch's memory."""
    tmp = str(tmp_path)
    launch, port, env = _one_roscpp_node(tmp)
    core = subprocess.Popen([sys.executable, "-m", "launcher", "--core", "-p", str(port)], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, stdin=subprocess.DEVNULL,
                            start_new_session=True)
    proc = None
    try:
        def master_up() -> bool:
            try:
                return master_proxy(port).getPid("/t")[0] == 1
            except OSError:
                return False
        until(master_up, 60, 0.05, what="the core's master")
        err_path = os.path.join(tmp, "importtime.err")
        with open(err_path, "wb") as err:
            proc = subprocess.Popen([sys.executable, "-X", "importtime", "-m", "launcher", launch], env=env,
                                    stdout=subprocess.DEVNULL, stderr=err, stdin=subprocess.DEVNULL,
                                    start_new_session=True)

        def registered() -> bool:
            return proc.poll() is None and master_proxy(port).lookupNode("/t", "/talker")[0] == 1
        until(registered, 60, 0.05, what="the node registered")
        with open(err_path, errors="replace") as f:
            modules = set(IMPORTED.findall(f.read()))
        assert "launcher.run.runtime" in modules and "launcher.services.masterwatch" in modules  # (it runs)
        assert sorted(m for m in modules if m.startswith("launcher.master")) == []
        assert "launcher.net.rosout" not in modules  # (the core's rosout logs: roslaunch starts none here)
        proc.send_signal(signal.SIGINT)
        assert proc.wait(30) == 0
    finally:
        if proc is not None:
            stop_group(proc, 10)
        stop_group(core, 10)


def test_a_launch_with_rosparam_keeps_neither_pyyaml_nor_the_xml_loader(tmp_path):
    """A robot's launch loads YAML (`<rosparam>`): reading it takes PyYAML and libyaml (about 2 MB) and the XML
    loader; the launch reads its files in a child of its own (run/apart.py) and keeps none of them, for as long as
    it runs. Its launcher-params.yaml (which PyYAML writes) is made there too, and says what `--dump-params` says.
    The child is forked before the launch imports asyncio and the run, and reads while they are imported."""
    tmp = str(tmp_path)
    launch, port, env = _one_roscpp_node(tmp)
    with open(os.path.join(tmp, "params.yaml"), "w") as f:
        f.write("gains: {p: 1.5, i: [0.1, 0.2]}\nplugins:\n  - {name: obstacles, type: 'costmap_2d::ObstacleLayer'}\n"
                "frame: base_link\n")
    with open(launch) as f:
        text = f.read()
    with open(launch, "w") as f:
        # (the command runs in the reader of the launch's files: whether that process holds asyncio)
        f.write(text.replace("<launch>", '<launch>\n<rosparam command="load" file="%s" ns="ctl"/>\n'
                             '<param name="reader_maps_asyncio" command="sh -c \'grep -c _asyncio /proc/$PPID/maps '
                             '|| true\'"/>' % os.path.join(tmp, "params.yaml")))
    proc = subprocess.Popen([sys.executable, "-m", "launcher", launch], env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, stdin=subprocess.DEVNULL, start_new_session=True)
    try:
        until(lambda: proc.poll() is None and master_proxy(port).lookupNode("/t", "/talker")[0] == 1, 60, 0.05,
              what="the node registered", errors=(OSError,))
        assert master_proxy(port).getParam("/t", "/ctl/gains/i") == [1, "Parameter [/ctl/gains/i]", [0.1, 0.2]]
        kept = os.path.join(tmp, "log", "latest", "launcher-params.yaml")
        until(lambda: os.path.exists(kept), 30, 0.05, what="launcher-params.yaml written")
        dumped = subprocess.run([sys.executable, "-m", "launcher", "--dump-params", launch], env=env,
                                capture_output=True, text=True, timeout=60).stdout
        with open(kept) as f:
            assert f.read() == dumped and "costmap_2d::ObstacleLayer" in dumped
        with open("/proc/%d/maps" % proc.pid) as f:
            mapped = {line.split()[-1] for line in f if "/" in line}
        assert [m for m in mapped if os.path.basename(m).startswith(("_yaml.", "libyaml"))] == []
        # the files were read by a child forked before the launch imported asyncio (which the launch maps: the
        # Pythons this runs on build `_asyncio` as a module of its own), beside those imports
        assert any(os.path.basename(m).startswith("_asyncio.") for m in mapped)
        assert master_proxy(port).getParam("/t", "/reader_maps_asyncio")[2] == 0
        proc.send_signal(signal.SIGINT)
        assert proc.wait(30) == 0
    finally:
        stop_group(proc, 10)
