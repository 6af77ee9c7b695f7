"""The restart policy as one pure decision (the supervisor and the remote parent both apply it)."""

from __future__ import annotations

from launcher.model.config import NodePolicy
from launcher.fleet import restart

ROSLAUNCH = NodePolicy()


def test_no_respawn_stays_down_and_a_failed_start_says_so():
    assert restart.after_run(False, 0.0, ROSLAUNCH, 3, True, 5.0, 0) == restart.Decision(restart.STAY_DOWN, 0)
    d = restart.after_run(False, 0.0, ROSLAUNCH, None, False, 0.0, 0)
    assert d.action == restart.STAY_DOWN and d.reason == "could not be started"


def test_roslaunchs_respawn_after_respawn_delay_without_a_word():
    d = restart.after_run(True, 2.0, ROSLAUNCH, 1, True, 5.0, 0)
    assert (d.action, d.delay, d.failures, d.note) == (restart.RESPAWN, 2.0, 0, "")


def test_a_crash_loop_is_paced():
    d = restart.after_run(True, 0.0, ROSLAUNCH, 1, True, 0.02, 0)
    assert abs(d.delay - (restart.MIN_RESPAWN_INTERVAL_S - 0.02)) < 1e-9 and d.failures == 1


def test_success_exit_code_is_not_restarted_with_respawn_on_failure():
    policy = NodePolicy(respawn_on="failure", success_exit_codes=frozenset({0, 3}))
    d = restart.after_run(True, 0.0, policy, 3, True, 5.0, 0)
    assert d.action == restart.STAY_DOWN and "exit code 3 counts as success" in d.note
    assert restart.after_run(True, 0.0, policy, None, True, 5.0, 0).action == restart.RESPAWN  # killed by a signal


def test_backoff_grows_to_its_cap_and_fatal_after_the_retries():
    policy = NodePolicy(respawn_backoff=2.0, respawn_delay_max=3.0, respawn_max_retries=3)
    delays, failures = [], 0
    for _ in range(3):
        d = restart.after_run(True, 1.0, policy, 1, True, 0.5, failures)
        assert d.action == restart.RESPAWN and "respawning in" in d.note
        delays.append(d.delay)
        failures = d.failures
    assert delays == [1.0, 2.0, 3.0]
    d = restart.after_run(True, 1.0, policy, 1, True, 0.5, failures)
    assert d.action == restart.FATAL and d.failures == 4 and "respawn_max_retries=3" in d.reason
    # a run that lasted respawn_min_uptime starts the count again
    assert restart.after_run(True, 1.0, policy, 1, True, 1.0, 3).failures == 0
