"""The bag fuzz's worker: `launcher bag` command lines run one after another in this process (started by the test
under a 2 GiB address-space limit), each as `python -m launcher.bag ARGV` would run it, with its output captured and
timed. A process per run would add only its start-up: what a run does is the same.

usage: fuzzworker.py JOBS.json RESULTS.json   (JOBS: [argv, ...]; RESULTS: [{argv, code, out, err, seconds,
exception}, ...], an exception being the traceback of anything that escaped the command)
"""

from __future__ import annotations

import contextlib
import gc
import io
import json
import signal
import sys
import time
import traceback

LIMIT_S = 10.0


class OverTime(BaseException):
    """A run past LIMIT_S (raised by SIGALRM wherever the run is)."""


def on_alarm(signum, frame):
    raise OverTime("over %g s" % LIMIT_S)


def run(argv: list[str]) -> dict:
    from launcher.bag.main import main

    out, err = io.StringIO(), io.StringIO()
    exception = None
    code = None
    began = time.monotonic()
    signal.setitimer(signal.ITIMER_REAL, LIMIT_S + 1.0)
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                code = main(argv)
            except SystemExit as exc:  # argparse's usage errors
                code = exc.code if isinstance(exc.code, int) else 2
            finally:
                gc.collect()  # (an unretrieved task's exception is logged when it is collected: within the run)
    except BaseException:  # noqa: B036 (anything at all escaping the command is what the fuzz looks for)
        exception = traceback.format_exc()
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
    return {"argv": argv, "code": code, "out": out.getvalue(), "err": err.getvalue(),
            "seconds": time.monotonic() - began, "exception": exception}


def main() -> None:
    with open(sys.argv[1]) as f:
        jobs = json.load(f)
    signal.signal(signal.SIGALRM, on_alarm)
    results = [run(argv) for argv in jobs]
    with open(sys.argv[2], "w") as f:
        json.dump(results, f)


if __name__ == "__main__":
    main()
