"""A node's last exit, as every reader of its changes keeps it: the fleet for its status, a view of the change
stream, a reader of the events file after the run. A run clears its exit fields when it starts and sets them
when it ends, so the last exit is not in a running node's fields: each reader keeps it by this one rule. Pure."""

from __future__ import annotations


def run_ended(before: tuple, after: tuple) -> bool:
    """Whether a node's (exit_code, exit_signal) going from `before` to `after` is a run's end: a run clears
    them when it starts, and its end sets them."""
    return after != (None, None) and after != before


def keep_last_exit(node: dict, change: dict) -> None:
    """A node's `last_exit_*` after a change of the stream or a line of the events file (which do not carry
    them: a run's end is where its exit fields are set), applied before the change's own fields."""
    before = (node.get("exit_code"), node.get("exit_signal"))
    after = (change.get("exit_code"), change.get("exit_signal"))
    if run_ended(before, after):
        node["last_exit_code"], node["last_exit_signal"] = after
        node["last_exit_at"] = change.get("time")
