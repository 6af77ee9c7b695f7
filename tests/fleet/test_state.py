

def test_over_limit_is_said_in_the_readmes_units():
    """The limit as the user wrote it (500MB is decimal, 512MiB binary), the measured use in decimal units: one
    formatter for `launcher status`'s OVER LIMIT column and /diagnostics (it once said 476.8 MB for 500MB)."""
    from launcher.fleet.state import over_limit_text
    assert over_limit_text({"memory_limit": 500_000_000}, None, 612_345_678) == "memory_limit 500MB (uses 612.3MB)"
    assert over_limit_text({"memory_limit": 512 << 20}, None, None) == "memory_limit 512MiB (uses ?)"
    assert over_limit_text({"cpu_limit": 0.5}, 0.75, None) == "cpu_limit 0.5 cores (uses 0.75)"


def test_the_fleet_steps_the_launchs_phase_from_its_nodes_and_carries_out_end_and_say():
    """The launch's phase is the fleet's: a node that ended by itself ends a launch on a master found running once
    every node has been started (roslaunch's words, `done`), a required node's end sets the exit status, and a
    runner's bug is said, not raised."""
    from launcher.fleet import launchphase as lp, lifecycle as m
    from launcher.fleet.state import Fleet
    said, warned = [], []

    def say(text, bold):
        said.append(text if not bold else "**%s**" % text)
    fleet = Fleet(clock=lambda: 0.0, say=say, warn=warned.append, exit_when_all_dead=True)
    for name in ("/a", "/b"):
        fleet.add(name)
        fleet.apply(name, m.Event(m.START))
        fleet.apply(name, m.Event(m.SPAWNED, pid=1))
    fleet.apply("/a", m.Event(m.PROCESS_EXITED, exit_code=0))
    assert fleet.launch.state == lp.STARTING and not said
    fleet.registrations_complete()
    assert fleet.launch.state == lp.RUNNING and not fleet.done.is_set()  # (/b runs)
    fleet.apply("/b", m.Event(m.PROCESS_EXITED, exit_code=0))
    assert said == [lp.ALL_DEAD_TEXT] and fleet.done.is_set() and fleet.exit_status == 0
    assert not fleet.starts_allowed and not fleet.stopping
    assert [a.kind for a in fleet.launch_step(lp.STOP)] == [lp.STOP_ALL] and fleet.stopping
    fleet.launch_step(lp.ALL_STOPPED)
    assert fleet.launch.state == lp.ENDED and not warned
    fleet.launch_step(lp.ALL_STOPPED)  # (a runner's bug)
    assert warned == ["WARNING: internal error: launch: event [all stopped] in phase [ended]"]

    fleet = Fleet(clock=lambda: 0.0, say=say)  # our own master: a required node ends it
    fleet.add("/vital", rules=m.Rules(required=True))
    fleet.apply("/vital", m.Event(m.START))
    fleet.apply("/vital", m.Event(m.SPAWNED, pid=1))
    fleet.registrations_complete()
    fleet.apply("/vital", m.Event(m.PROCESS_EXITED, exit_signal=9))
    assert fleet.done.is_set() and fleet.exit_status == 137 and fleet.launch.state == lp.ENDING
    fleet.not_started(required=True)  # (a later failure does not change the status)
    assert fleet.exit_status == 137


def test_a_launch_without_a_process_ends_on_a_master_found_running_as_roslaunchs():
    """roslaunch's "No processes to monitor" (its #556): a launch of parameters only, or whose every node could not
    be made, ends with status 0 on a master found running; on its own master (a process roslaunch would monitor)
    it runs on. A node of another machine is a process (its machine's roslaunch)."""
    from launcher.fleet import launchphase as lp, lifecycle as m
    from launcher.fleet.state import Fleet
    for unstarted in (0, 2):
        said = []
        fleet = Fleet(clock=lambda: 0.0, say=lambda text, bold: said.append((text, bold)), exit_when_all_dead=True)
        for _ in range(unstarted):
            fleet.not_started(required=False)
        fleet.registrations_complete()
        assert said == [(lp.NO_PROCESSES_TEXT, True)], unstarted  # (said once: not "all processes ... died" too)
        assert fleet.done.is_set() and fleet.exit_status == 0 and fleet.launch.reason == lp.NO_PROCESSES_TEXT

    said = []
    fleet = Fleet(clock=lambda: 0.0, say=lambda text, bold: said.append(text))  # our own master
    fleet.registrations_complete()
    assert not said and not fleet.done.is_set() and fleet.launch.state == lp.RUNNING

    fleet = Fleet(clock=lambda: 0.0, say=lambda text, bold: said.append(text), exit_when_all_dead=True)
    fleet.add("/far", host="robot2")
    fleet.registrations_complete()
    assert not said and not fleet.done.is_set()


def test_a_process_that_cannot_be_started_while_the_launch_starts_ends_roslaunchs_own_launch():
    """roslaunch's FatalProcessLaunch (a bad launch-prefix): its own launch ends with status 1 when a node's exec
    fails while it starts its nodes; not once they have all been started (a respawn's failure is the node's), not
    for another machine's node, and not in a remote child or a supervisor on its own."""
    from launcher.fleet import launchphase as lp, lifecycle as m
    from launcher.fleet.state import Fleet

    def failed_start(fleet, name, host=m.LOCAL_HOST):
        fleet.add(name, host=host)
        fleet.apply(name, m.Event(m.START))
        fleet.apply(name, m.Event(m.SPAWN_FAILED))

    fleet = Fleet(clock=lambda: 0.0)
    fleet.start_failure_ends_the_launch()
    failed_start(fleet, "/far", host="robot2")
    assert not fleet.done.is_set()
    failed_start(fleet, "/bad")
    assert fleet.done.is_set() and fleet.exit_status == 1 and not fleet.starts_allowed

    fleet = Fleet(clock=lambda: 0.0)
    fleet.start_failure_ends_the_launch()
    fleet.registrations_complete()  # (every node started: a later failure, a respawn's, is the node's business)
    failed_start(fleet, "/late")
    assert not fleet.done.is_set() and fleet.starts_allowed

    fleet = Fleet(clock=lambda: 0.0)  # a remote child, a supervisor on its own
    failed_start(fleet, "/bad")
    assert not fleet.done.is_set() and fleet.starts_allowed
