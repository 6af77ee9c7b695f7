"""A run's options, typed: what `launch`'s command line, `launcher test` and a roslaunch child give a run.

One record with roslaunch's defaults, so that a run reads fields, not an
argparse namespace it has to guess at, and every front-end builds the same
thing (`from_args` for the command line's namespace; `launcher test` names
the few it sets).
"""

from __future__ import annotations

from launcher.model.record import record

TYPE_CHECKING = False  # (typing.TYPE_CHECKING without importing typing: the annotations are text)
if TYPE_CHECKING:
    from typing import Any


@record
class RunOptions:
    positional: tuple[str, ...] = ()  # launch files (or a package and a file) and name:=value args
    core: bool = False  # `launch --core`: a master, parameter server and rosout only
    port: int | None = None  # the master's port (-p)
    run_id: str | None = None
    wait: bool = False  # wait for a master instead of starting one
    local: bool = False  # run no node on another machine
    screen: bool = False  # every node's output to the screen
    log: bool = False  # every node's output to its log file
    required: bool = False  # every node required
    no_summary: bool = False
    skip_log_check: bool = False
    log_check_threshold: str = "1GiB"  # roslaunch's 1 GB check of the log directory, as 2^30 bytes
    log_max_size: str = "100MB"  # node output logs are rotated past this
    log_backups: int = 4
    sigint_timeout: float = 15.0  # the stop escalation: SIGINT, then SIGTERM after this ...
    sigterm_timeout: float = 2.0  # ... then SIGKILL after this
    monitor_period: float = 1.0  # CPU and memory samples of the nodes
    ready_timeout: float = 60.0  # under systemd: READY=1 at the latest after this, naming the nodes not up
    pid_fn: str | None = None  # write the launcher's pid to this file
    no_start: bool = False  # start no node: an operator does (`launcher start`)
    no_diagnostics: bool = False  # publish no /diagnostics
    master_allow: tuple[str, ...] = ()  # networks (CIDR) the master started here answers
    metrics: str | None = None  # [ADDR:]PORT where Prometheus metrics are served (services/metrics.py)
    verbose: bool = False  # -v: a bug's traceback, not one line

    @classmethod
    def from_args(cls, ns: Any) -> RunOptions:
        """The options of `launch`'s parsed command line (an argparse namespace)."""
        values = {name: getattr(ns, name) for name in cls._fields if getattr(ns, name, None) is not None}
        values["positional"] = tuple(values.get("positional", ()))
        values["master_allow"] = tuple(values.get("master_allow", ()))
        return cls(**values)
