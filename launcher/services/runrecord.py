"""What a launch keeps of itself in its run's log directory, for after the run: `launcher-run.json` (its launch files,
the YAML files they loaded, its command line, the environment that matters to ROS, the packages of its nodes,
versions) and `launcher-params.yaml` (the parameters it set, as `--dump-params` writes them).

The parameters live in the master only while it runs; `launcher report` reads
both files, so a run's archive holds them after the launch has ended. Written
once the nodes are started (in a worker thread when the parameters' YAML is yet
to be made: a launch of thousands of parameters must not hold its loop for it),
as the user's own files: the secrets in them are left out only where they leave
the machine, by the report.
"""

from __future__ import annotations

import json
import os
import sys
import time
from typing import Any

from launcher import __version__
from launcher.workspace.roshome import PARAMS_FILE, RUN_RECORD_FILE, ros_environment


def record(config: Any, run_id: str, environ: dict[str, str], packages: dict[str, str], argv: list[str]) -> dict:
    """The run's record (`launcher-run.json`)."""
    return {"run_id": run_id, "time": round(time.time(), 3), "pid": os.getpid(), "argv": list(argv),
            "launcher": __version__, "python": sys.version.split()[0], "platform": " ".join(os.uname()[i] for i in (0, 2, 3, 4)),
            "launch_files": list(config.files), "yaml_files": list(config.yaml_files),
            "packages": sorted({p for p in packages.values() if p}), "environment": ros_environment(environ)}


def params_text(config: Any) -> str:
    """The parameters the launch set, as `--dump-params` writes them (a flat map of keys to values)."""
    # (imported here: a launch gets this text with its plan, made apart, and never needs the writer itself)
    from launcher.params.dump import dump_yaml
    return dump_yaml({k: p.value for k, p in config.params.items()}) + "\n"


def write(run_dir: str, run: dict, config: Any, params: str | None = None) -> str:
    """Both files into `run_dir` (`params`: the parameters' text, if it was made with the plan: run/apart.py); what
    went wrong, in words ("" when nothing did)."""
    problems = []
    for name, make in ((RUN_RECORD_FILE, lambda: json.dumps(run, indent=1, default=str) + "\n"),
                       (PARAMS_FILE, lambda: params_text(config) if params is None else params)):
        path = os.path.join(run_dir, name)
        try:
            text = make()
            with open(path + ".tmp", "w", encoding="utf-8") as f:
                f.write(text)
            os.replace(path + ".tmp", path)
        except OSError as e:
            problems.append("cannot write %s: %s" % (path, e.strerror))
        except Exception as e:  # noqa: BLE001 - a value YAML cannot hold: the report says the file is missing
            problems.append("cannot write %s: %s: %s" % (path, type(e).__name__, e))
    return "; ".join(problems)
