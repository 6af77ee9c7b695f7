"""The restart policy: when a node's run has ended, whether and when it starts again.

One decision for every node, wherever it runs: the supervisor applies it to
the nodes of this machine, the remote parent (`launcher.remote.parent`) to the
nodes it sends to other machines. It reads the node's `respawn`,
`respawn_delay` and `NodePolicy` (whose defaults are roslaunch's behaviour):

- `respawn_on="failure"`: an exit code in `success_exit_codes` is not restarted;
- a run shorter than `respawn_min_uptime` (or a start that failed) is a failed
  start; the delay grows by `respawn_backoff` with each failed start in a row,
  up to `respawn_delay_max`;
- after `respawn_max_retries` restarts that failed in a row, the node is FATAL.

A crash loop is paced, never spun: a start follows the previous one by at
least MIN_RESPAWN_INTERVAL_S (roslaunch's 0.1 s monitor loop gives the same pace).
"""

from __future__ import annotations

from launcher.model.config import NodePolicy
from launcher.model.record import record

MIN_RESPAWN_INTERVAL_S = 0.1

STAY_DOWN = "stay down"
RESPAWN = "respawn"
FATAL = "fatal"


@record
class Decision:
    action: str  # STAY_DOWN, RESPAWN or FATAL
    failures: int  # failed starts in a row, this run counted
    delay: float = 0.0  # seconds from now until the next start (RESPAWN)
    reason: str = ""  # in words, for the state model and the console ("" when there is nothing to add)
    note: str = ""  # a console line that says what the policy decided ("" when roslaunch would say nothing)


def after_run(respawn: bool, respawn_delay: float, policy: NodePolicy, exit_code: int | None, started: bool,
              uptime: float, failures: int) -> Decision:
    """What comes after a run that lasted `uptime` seconds and ended with `exit_code` (None: by a signal),
    or that could not be started at all (`started` False); `failures`: failed starts in a row before it."""
    if not respawn:
        return Decision(STAY_DOWN, failures, reason="" if started else "could not be started")
    if policy.respawn_on == "failure" and exit_code in policy.success_exit_codes:
        why = "exit code %d counts as success (respawn_on=\"failure\")" % exit_code
        return Decision(STAY_DOWN, failures, reason=why, note="not restarted: " + why)
    # a failed start too: an executable briefly missing (a package being reinstalled) comes back
    failures = 0 if started and uptime >= policy.respawn_min_uptime else failures + 1
    retries = policy.respawn_max_retries
    if retries is not None and failures > retries:
        why = "failed %d starts in a row (respawn_max_retries=%d), not restarted" % (failures, retries)
        return Decision(FATAL, failures, reason=why, note="FATAL: " + why)
    delay = respawn_delay_after(respawn_delay, policy, failures, uptime)
    note = ""
    if policy.respawn_backoff != 1.0 or retries is not None:
        note = "respawning in %.3g s (%d failed start%s in a row)" % (delay, failures, "" if failures == 1 else "s")
    return Decision(RESPAWN, failures, delay, "" if started else "could not be started", note)


def respawn_delay_after(respawn_delay: float, policy: NodePolicy, failures: int, uptime: float) -> float:
    """respawn_delay, multiplied by respawn_backoff for each failed start in a row after the first,
    capped by respawn_delay_max (growing from 0 would stay 0: the backoff then starts from
    MIN_RESPAWN_INTERVAL_S). It counts from the death, as roslaunch's respawn_delay."""
    delay = respawn_delay
    if policy.respawn_backoff != 1.0 and failures > 1:
        delay = (delay or MIN_RESPAWN_INTERVAL_S) * policy.respawn_backoff ** (failures - 1)
    if policy.respawn_delay_max is not None:
        delay = min(delay, policy.respawn_delay_max)
    return max(0.0, delay, MIN_RESPAWN_INTERVAL_S - uptime)
