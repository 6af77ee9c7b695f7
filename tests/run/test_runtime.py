"""runtime: roslaunch's summary block and value shortening, where a launch's master can be started, the start's
steps as one list, and the stop signal's guard of them."""

from __future__ import annotations

from launcher.model.config import LaunchConfig, Machine, Node, Param
from launcher.services.masterlink import is_local_host as _is_local_host
from launcher.output.runlog import summary, summary_value as _summary_value


def test_summary_matches_roslaunch_layout():
    config = LaunchConfig(
        nodes=(Node("refpkg", "quick.sh", "quitter"), Node("refpkg", "sleeper.sh", "n1", namespace="/robot/"),
               Node("refpkg", "nothere", "missing")),
        params={"/s": Param("/s", "hello"), "/a": Param("/a", 1)},
        clear_params=("/robot/",))
    text = summary(config, {"/s": "hello", "/a": 1, "/rosdistro": "Debian\n"})
    # recorded from `roslaunch` 1.15.15 (same launch), plus the CLEAR PARAMETERS block of config.summary()
    assert text == ("\nSUMMARY\n========\n\nCLEAR PARAMETERS\n * /robot/\n\nPARAMETERS\n * /a: 1\n"
                    " * /rosdistro: Debian\n * /s: hello\n\nNODES\n  /\n    missing (refpkg/nothere)\n"
                    "    quitter (refpkg/quick.sh)\n  /robot/\n    n1 (refpkg/sleeper.sh)\n")


def test_summary_without_params():
    assert summary(LaunchConfig(), {}) == "\nSUMMARY\n========\n\nNODES\n"


def test_summary_of_a_run_with_other_machines_lists_them_and_every_node_else_only_this_machines():
    far = Node("refpkg", "sleeper.sh", "far", machine_name="robot2")
    config = LaunchConfig(nodes=(Node("refpkg", "quick.sh", "here"), far),
                          machines={"robot2": Machine("robot2", "192.0.2.10"), "base": Machine("base", "192.0.2.11")})
    remote = lambda n: n.machine_name == "robot2"  # noqa: E731
    # as roslaunch's ROSLaunchConfig.summary(local=False) when it runs remote children
    assert summary(config, {}, remote=remote, machines=True) == (
        "\nSUMMARY\n========\n\nMACHINES\n * base\n * robot2\n\nNODES\n  /\n    far (refpkg/sleeper.sh)\n"
        "    here (refpkg/quick.sh)\n")
    # --local (summary(local=True)): the other machine's node is not listed
    assert summary(config, {}, remote=remote) == "\nSUMMARY\n========\n\nNODES\n  /\n    here (refpkg/quick.sh)\n"


def test_summary_value_shortening_as_roslaunch():
    assert _summary_value("a" * 20) == "a" * 20
    assert _summary_value("a" * 21) == "a" * 17 + "..."
    assert _summary_value(2.5) == "2.5"
    assert _summary_value(True) == "True"
    assert _summary_value("1.15.15\n") == "1.15.15"  # trailing whitespace of command output
    assert _summary_value("line1\nline2") == "<...>"
    assert _summary_value("caf\u00e9") == "<...>"
    assert _summary_value({"a": 1}) == "{'a': 1}"


def test_local_hosts():
    env = {"ROS_HOSTNAME": "myrobot"}
    assert _is_local_host("localhost", env) and _is_local_host("127.0.0.1", env)
    assert _is_local_host("myrobot", env)
    assert not _is_local_host("192.0.2.77", env)  # TEST-NET-1: never a local address


def test_malformed_master_host_is_not_local_and_not_a_crash(tmp_path):
    assert not _is_local_host("a..b", {})
    import os
    import subprocess
    import sys
    launch = tmp_path / "a.launch"
    launch.write_text("<launch/>")
    env = dict(os.environ, ROS_MASTER_URI="http://a..b:11311/", ROS_HOME=str(tmp_path))
    out = subprocess.run([sys.executable, "-m", "launcher", str(launch)], env=env, capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 1
    assert "unable to contact ROS master at [http://a..b:11311/]" in out.stderr and "internal error" not in out.stderr


def test_a_step_guarded_after_the_stop_signal_is_closed_not_left_unawaited():
    """A SIGINT during the start: the steps after it are never begun, and Python must not warn at exit that a
    coroutine was never awaited (a launch printed `coroutine 'LogDiskCheck.start' was never awaited`)."""
    import asyncio
    import gc
    import warnings

    from launcher.run.runtime import Stopped, StopSignals
    began = []

    async def step() -> None:
        began.append(True)

    async def go() -> str:
        signals = StopSignals()
        assert await signals.guard(step()) is None and began == [True]  # (not stopped: it runs)
        signals.event.set()
        try:
            await signals.guard(step())
        except Stopped:
            return "stopped"
        return "ran"
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        assert asyncio.run(go()) == "stopped"
        gc.collect()
    assert began == [True]
    assert [str(w.message) for w in seen if "never awaited" in str(w.message)] == []


def _step_names(run, external: bool = False) -> list[tuple[str, str, bool]]:
    """The run's start as its steps say it (their service's class, the step's name, guarded), walked without
    running them (the master's `find` would say whether it found one: `external` says it here)."""
    run.master.external = external
    out = []
    for service, step, guarded in run._steps():
        name = getattr(step, "__name__", "?")
        out.append((type(service).__name__ if service is not None else "", name, guarded))
    return out


def test_the_start_is_one_list_of_steps_in_roslaunchs_order():
    """`Run._steps`: roscore's start, a launch's with our master, and with a master found running (a watch of
    it, and the nodes exit when all are dead), each service counted up at its first step."""
    from launcher.model.runopts import RunOptions
    from launcher.plan.plan import Plan
    from launcher.run.runtime import Run
    core = Run(RunOptions(core=True), Plan(LaunchConfig(), "", {}, core=True, core_port=11311))
    assert _step_names(core) == [
        ("MasterSession", "find", True), ("", "_open_log", True), ("ApiServer", "start", True),
        ("", "_say_version", True), ("", "_say_summary", True), ("", "_start_master", False),
        ("", "register", True), ("RosoutService", "start", True), ("", "_note_master", True),
        ("", "set_parameters", True), ("", "_note_parameters", True), ("NodeService", "_start_nodes", True),
        ("", "_started_all", True)]
    launch = Run(RunOptions(no_summary=True), Plan(LaunchConfig(), "http://localhost:11311/", {}))
    ours = _step_names(launch)
    assert [s for s in ours if s[0]] == [
        ("MasterSession", "find", True), ("ApiServer", "start", True), ("NodeService", "_prepare_nodes", False),
        ("RosoutService", "start", True), ("NodeService", "_start_nodes", True),
        ("DiagnosticsService", "start", True), ("LogDiskCheck", "start", True)]
    assert "_say_summary" not in [name for _, name, _ in ours] and launch.master_watch is None
    found = _step_names(launch, external=True)
    assert [s for s in found if s[0] == "MasterWatch"] == [("MasterWatch", "start", True)]
    assert found.index(("MasterWatch", "start", True)) == found.index(("NodeService", "_start_nodes", True)) + 1
