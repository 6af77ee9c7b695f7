"""The console's words about nodes: roslaunch's lines (and ours beyond it) for each change of the fleet.

A fleet listener. What a node's state machine decided is said here and
nowhere else, so a line and the change it tells of cannot part: a death and
what follows it (respawn, FATAL, the launch ending), a start held or let go,
an operator's stop and start. What only a runner knows is said by the runner
before it tells the fleet: a spawn's pid or its failure
(`process.spawn`), the stop escalation's signals, a machine's ssh session.
"""

from __future__ import annotations

from typing import Callable

from launcher.output import console
from launcher.fleet import lifecycle as m
from launcher.fleet.state import Change, Fleet

BAR = "=" * 80


ERROR, INFO, BOLD = "error", "info", "bold"


def lines(change: Change) -> list[tuple[str, str]]:
    """(ERROR, INFO or BOLD, text) for each console line the change calls for."""
    old, new, event = change.old, change.new, change.event
    rules = new.rules
    # a remote node is named as in its launch file, but for what its child named: a process
    proc = new.name.lstrip("/") if rules.remote else new.process
    on = " on machine [%s]" % rules.machine if rules.remote else ""
    kind = event.kind
    out: list[tuple[str, str]] = []
    notes = [a.text for a in change.actions if a.kind == m.NOTE]
    ends = any(a.kind == m.END_LAUNCH for a in change.actions)

    if kind in (m.PROCESS_EXITED, m.SPAWN_FAILED) and old.state in (m.RUNNING, m.HUNG, m.STARTING, m.LAUNCHING):
        started = kind == m.PROCESS_EXITED
        if started and old.restart_reason:
            return out  # (said when the restart was asked for)
        if rules.required:
            if not started:
                why = "failed to start: " + event.reason if event.reason else "could not be started"
                out.append((ERROR, BAR + "REQUIRED process [%s] %s!\nInitiating shutdown!\n" % (proc, why) + BAR))
            elif rules.remote:
                out.append((ERROR, BAR + "REQUIRED process [%s]%s has died!\nexit code %s\nInitiating shutdown!\n"
                            % (new.process, on, _code(new)) + BAR))
            else:
                out.append((ERROR, BAR + "REQUIRED process [%s] has died!\n%s\nInitiating shutdown!\n"
                            % (proc, event.detail) + BAR))
            return out
        if started and event.detail:
            failed = new.exit_code != 0 or new.exit_signal is not None
            out.append((ERROR if failed else BOLD, "[%s] %s" % (proc, event.detail)))
        for note in notes:
            out.append((ERROR if new.state == m.FATAL else INFO, "[%s]%s %s" % (proc, on, note)))
        if new.state == m.FATAL and ends:
            out.append((ERROR, BAR + "FATAL process [%s] has failed (on_fatal=\"shutdown\")!\nInitiating shutdown!\n"
                        % proc + BAR))
        return out
    if kind == m.START and new.state == m.DELAYED:
        out.append((INFO, "[%s] waiting %g s before starting%s (spawn_delay)"
                    % (proc, rules.policy.spawn_delay, on)))
    elif kind == m.NOT_READY:
        if rules.required:
            out.append((ERROR, BAR + "REQUIRED process [%s] failed to start: %s!\nInitiating shutdown!\n"
                        % (proc, event.reason) + BAR))
        else:
            out.append((ERROR, "[%s] failed to start%s: %s" % (proc, on, event.reason)))
    elif kind == m.DUE and old.state == m.RESPAWNING:
        out.append((INFO, "[%s] restarting process%s" % (proc, on)))
        if new.restart_warned and not old.restart_warned:
            out.append((ERROR, "[%s] WARNING: restarted %d times, more than its restart_warn_threshold (%d)"
                        % (proc, new.respawns, rules.policy.restart_warn_threshold)))
    elif kind == m.OPERATOR_START:
        out.append((INFO, "[%s] starting process%s (operator)" % (proc, on)))
    elif kind == m.STOP and new.state == m.STOPPING:
        out.append((INFO, "[%s] stopping process%s (operator)" % (new.process, on)))
    elif kind == m.SHUTDOWN and new.state == m.STOPPING and not rules.remote:
        out.append((INFO, "[%s] killing on exit" % proc))
    elif kind == m.HANG:
        out.append((ERROR, "[%s] is hung (%s): killing process group %s" % (proc, event.reason, new.pid)))
    elif kind == m.STALL:
        kill = "" if rules.policy.on_stall == "warn" else ": killing process group %s" % new.pid
        out.append((ERROR, "[%s] is stalled (%s)%s" % (proc, event.reason, kill)))
    elif kind == m.UNSTALL:
        out.append((INFO, "[%s] is no longer stalled: %s" % (proc, event.reason)))
    elif kind == m.RESTART:
        out.append((ERROR, "[%s] restarting: %s" % (proc, event.reason)))
    elif kind == m.LIMIT:
        crossed = dict(new.over_limit).keys() - dict(old.over_limit).keys()
        out.append((ERROR if crossed else INFO, "[%s] %s" % (proc, event.detail)))
    elif kind == m.BOUND_ENDED:
        out.append((INFO, "[%s] %s: %s" % (proc, "stopping process" if new.state == m.STOPPING else "not restarted",
                                           event.reason)))
    elif kind == m.BOUND_STARTED:
        out.append((INFO, "[%s] restarting process after [%s] (bound to it)" % (proc, rules.policy.bind_to)))
    elif kind == m.LINK_LOST and ends:
        out.append((ERROR, BAR + "REQUIRED process [%s] was lost with machine [%s]!\nInitiating shutdown!\n"
                    % (new.name, rules.machine) + BAR))
    elif kind == m.MACHINE_FAILED and ends:
        out.append((ERROR, BAR + "REQUIRED process [%s] could not be started!\nInitiating shutdown!\n" % proc + BAR))
    return out


def _code(r: m.Record) -> object:
    return -r.exit_signal if r.exit_signal is not None else r.exit_code


class Narrator:
    """A fleet listener that prints `lines` through the console's channels."""

    def __init__(self, info: Callable[[str], None], error: Callable[[str], None], bold: Callable[[str], None]):
        self.say = {INFO: info, ERROR: error, BOLD: bold}

    def __call__(self, change: Change) -> None:
        for level, text in lines(change):
            self.say[level](text)


def attach(fleet: Fleet) -> Fleet:
    """Have the fleet's changes and outcome told on the console (and so in the launch log); once."""
    if not any(isinstance(listener, Narrator) for listener in fleet.listeners):
        fleet.listeners.insert(0, Narrator(console.printlog, console.printerrlog, console.printlog_bold))
    if fleet.say is None:
        fleet.say = _say
    return fleet


def _say(text: str, bold: bool) -> None:
    (console.printlog_bold if bold else console.printlog)(text)
