"""The `launcher` command: the operator's and CI's side of `launch` (`launch` stays the roslaunch/roscore drop-in).

Each subcommand lives in its own module and is imported only when it runs, so
that `launcher status` does not pay for the test runner. A subcommand is
`module` (its `main(argv) -> int`) or `module:function`; names starting with
`_` are hidden from the help (the completion script's helper).
"""

from __future__ import annotations

import importlib
import os
import sys

from launcher import __version__

# subcommand -> (module[:function], one line of help)
SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "completion": ("launcher.cli.completion", "print the bash or zsh completion script for launch and launcher"),
    "doctor": ("launcher.cli.doctor", "find set-up mistakes (host names, ROS_IP, master, package path, node executables)"),
    "__complete": ("launcher.cli.completion:complete_main", "(the completion script's helper)"),
    "status": ("launcher.operate.status", "every node's state, pid, uptime, restarts, last exit, CPU, RSS, host (after the "
               "end: the last run's)"),
    "start": ("launcher.operate.control:start", "start the nodes a name, glob or regex selects"),
    "stop": ("launcher.operate.control:stop", "stop the nodes a name, glob or regex selects (not respawned)"),
    "restart": ("launcher.operate.control:restart", "restart the nodes a name, glob or regex selects"),
    "reload": ("launcher.operate.reload", "read the launch's files again and apply only the difference "
               "(--dry-run prints it)"),
    "logs": ("launcher.operate.logs", "a node's output (-f follows it; after the end: the last run's)"),
    "events": ("launcher.operate.events", "the run's state changes (-f follows them; after the end: the last run's)"),
    "ui": ("launcher.operate.ui", "a live view of a running launch: states, CPU, RSS, output; start/stop/restart "
           "keys (q leaves it running)"),
    "web": ("launcher.operate.web", "the live view of a running launch as a web page ([ADDR:]PORT, loopback unless "
            "an address is given)"),
    "report": ("launcher.operate.report", "one .tar.gz of a run (the last one by default) for a bug report: logs, "
               "output, parameters, files, versions; secrets left out"),
    "check": ("launcher.cli.check", "check launch files without running them, over every if/unless branch"),
    "bag": ("launcher.bag.main", "record, play, inspect and reindex ROS 1 bags (rosbag's options; no ROS needed)"),
    "install": ("launcher.operate.install", "write a systemd unit that runs a launch at boot (--dry-run prints it)"),
    "uninstall": ("launcher.operate.install:uninstall", "remove a unit `launcher install` wrote"),
    "installed": ("launcher.operate.install:installed", "the units `launcher install` wrote: name, kind, state, "
                  "launch files"),
    "test": ("launcher.rostest.runner", "run a rostest file's <test> nodes, each on its own master (rostest)"),
}

USAGE = "usage: launcher <command> [options]\n\ncommands:\n%s\n\n'launcher <command> --help' tells more."


def usage() -> str:
    width = max((len(n) for n in SUBCOMMANDS), default=0)
    return USAGE % "\n".join("  %-*s  %s" % (width, name, text) for name, (_, text) in sorted(SUBCOMMANDS.items())
                              if not name.startswith("_"))


# The third-party packages launcher depends on (pyproject.toml), by their import names.
REQUIRED_PACKAGES = ("yaml", "psutil", "rosbags", "lxml", "prompt_toolkit", "prometheus_client")


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if not args or args[0] in ("-h", "--help", "help"):
        print(usage())
        return 0 if args else 2
    if args[0] == "--version":
        print(__version__)
        return 0
    entry = SUBCOMMANDS.get(args[0])
    if entry is None:
        print("launcher: unknown command '%s'\n\n%s" % (args[0], usage()), file=sys.stderr)
        return 2
    module_name, _, function = entry[0].partition(":")
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as e:
        if e.name not in REQUIRED_PACKAGES:
            raise
        # (an interpreter other than the one launcher was installed for: e.g. Debian's python3 with PYTHONPATH)
        print("launcher %s: this Python (%s) lacks %s, which launcher needs: run launcher with the Python it was "
              "installed for, or install its dependencies here (pip install ros1-launcher)"
              % (args[0], sys.executable, e.name), file=sys.stderr)
        return 1
    try:
        status = getattr(module, function or "main")(args[1:])
        sys.stdout.flush()  # (here, where a reader that left is caught, rather than at the interpreter's exit)
        return status
    except BrokenPipeError:
        # `launcher doctor | head`: the reader left, which is no error. What is still buffered goes nowhere, so
        # that the interpreter's own flush at exit has nothing to say either.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0


if __name__ == "__main__":
    sys.exit(main())
