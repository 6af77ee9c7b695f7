"""The `launch` command: roslaunch's options, dispatch, exit codes.

Launch semantics live elsewhere: introspection in `launcher.cli.introspect`,
a run (`--core` is a run with an empty launch) in `launcher.run.runtime`.
"""

from __future__ import annotations

import gc
import os
import sys
from types import SimpleNamespace

TYPE_CHECKING = False  # (typing.TYPE_CHECKING without importing typing: ~3 ms a start; the annotations are text)
if TYPE_CHECKING:
    import argparse

from launcher import __version__
from launcher.model.errors import LaunchError, UsageError
from launcher.model.runopts import RunOptions

USAGE = ("launch [options] [package] <filename> [arg_name:=value...]\n"
         "       launch [options] <filename> [<filename>...] [arg_name:=value...]\n"
         "       launch [options] - [arg_name:=value...]     (the launch XML from standard input)\n"
         "       launch --core [-p PORT]")

EPILOG = """examples:
  launch my_robot bringup.launch sim:=true       a package's launch file, with an argument
  launch robot.launch sensors.launch              several files as one launch
  launch --nodes my_robot bringup.launch          list its nodes (also --args NODE, --dump-params, --files)
  launch --core -p 11312                          a master, parameter server and rosout, as roscore
  launch --wait my_robot bringup.launch           wait for a master started elsewhere (e.g. roscore)

environment:
  ROS_MASTER_URI     the master to use; a launch starts one there if none answers (default http://localhost:11311/)
  ROS_IP, ROS_HOSTNAME   the address the master and nodes advertise
  ROS_PACKAGE_PATH, CMAKE_PREFIX_PATH   where packages and node executables are found
  ROS_HOME           default ~/.ros: node working directory, the package crawl cache
  ROS_LOG_DIR        default $ROS_HOME/log: each run's logs in <run_id>/, and a latest link
  ROS_NAMESPACE      the namespace of the launch's nodes

exit status:
  0  the launch ended normally (Ctrl-C, all nodes done, a required node exited 0)
  N  a required node ended the launch with exit code N (128 + S when signal S killed it)
  1  bad input (the error names file and line), a master problem, a required node that could
     not start, or a FATAL node with on_fatal="shutdown"
  2  bad command line, or an internal error (please report it)
  130  interrupted before the launch started

shell completion:  eval "$(launcher completion bash)"   (or zsh); the operator's command is `launcher`."""

_RUN = RunOptions._field_defaults  # (one set of defaults for the command line and every other front-end)


def build_parser() -> argparse.ArgumentParser:
    import argparse
    p = argparse.ArgumentParser(prog="launch", usage=USAGE, allow_abbrev=False, epilog=EPILOG,
                                formatter_class=argparse.RawDescriptionHelpFormatter,
                                description="Launch ROS 1 nodes from launch XML, with a built-in master "
                                            "(roslaunch's options and behaviour; roscore with --core).")
    # introspection (print and exit), as roslaunch
    p.add_argument("--files", action="store_true", help="print the launch files loaded, including included ones")
    p.add_argument("--args", dest="node_args", metavar="NODE_NAME", help="print the command line of a node")
    p.add_argument("--nodes", action="store_true", help="print the names of the nodes in the launch")
    p.add_argument("--find-node", dest="find_node", metavar="NODE_NAME", help="print the launch file a node is defined in")
    p.add_argument("--dump-params", dest="dump_params", action="store_true", help="print the launch's parameters as YAML")
    p.add_argument("--ros-args", dest="ros_args", action="store_true", help="print the <arg>s the launch file accepts")
    # running
    p.add_argument("--core", action="store_true", help="run the core only: master, parameter server, rosout")
    p.add_argument("-p", "--port", type=int, help="master port (only when the master is started here)")
    p.add_argument("--screen", action="store_true", help="force output of all nodes to the screen")
    p.add_argument("--log", action="store_true", help="force output of all nodes to log files")
    p.add_argument("--required", action="store_true", help="make every node required")
    p.add_argument("--wait", action="store_true", help="wait for a master to come up instead of starting one")
    p.add_argument("--local", action="store_true", help="do not launch nodes on other machines")
    p.add_argument("--no-summary", dest="no_summary", action="store_true", help="do not print the summary")
    p.add_argument("--skip-log-check", dest="skip_log_check", action="store_true", help="do not check the log directory's size")
    p.add_argument("--log-check-threshold", dest="log_check_threshold", default=_RUN["log_check_threshold"], metavar="SIZE",
                   help="warn when the log directory is larger than this (default 1GiB, roslaunch's)")
    p.add_argument("--log-max-size", dest="log_max_size", default=_RUN["log_max_size"], metavar="SIZE",
                   help="rotate a node's output log past this size (default 100MB; 0: never)")
    p.add_argument("--log-backups", dest="log_backups", type=int, default=_RUN["log_backups"], metavar="N",
                   help="rotated copies of a node's output log to keep (default 4)")
    p.add_argument("--sigint-timeout", dest="sigint_timeout", type=float, default=_RUN["sigint_timeout"], metavar="SECONDS",
                   help="seconds from SIGINT to SIGTERM when stopping a node (default 15)")
    p.add_argument("--sigterm-timeout", dest="sigterm_timeout", type=float, default=_RUN["sigterm_timeout"], metavar="SECONDS",
                   help="seconds from SIGTERM to SIGKILL when stopping a node (default 2)")
    p.add_argument("--monitor-period", dest="monitor_period", type=float, default=_RUN["monitor_period"], metavar="SECONDS",
                   help="seconds between two samples of the nodes' CPU and memory (default 1)")
    p.add_argument("--ready-timeout", dest="ready_timeout", type=float, default=_RUN["ready_timeout"], metavar="SECONDS",
                   help="under systemd (NOTIFY_SOCKET): tell it READY=1 at the latest after this, naming the nodes "
                        "not up (default 60)")
    # operating a running launch (the `launcher` command)
    p.add_argument("--no-start", dest="no_start", action="store_true",
                   help="load and set the parameters but start no node (start them with `launcher start`)")
    p.add_argument("--no-diagnostics", dest="no_diagnostics", action="store_true",
                   help="do not publish the nodes' states on /diagnostics")
    p.add_argument("--ui", action="store_true", help="a live view of the launch in the terminal: every node's "
                   "state, CPU, RSS and output; keys start, stop and restart nodes (q or Ctrl-C stops the launch)")
    p.add_argument("--web", metavar="[ADDR:]PORT", help="the live view as a web page at this address (loopback "
                   "unless an address is given; start/stop/restart need the run's token)")
    p.add_argument("--metrics", metavar="[ADDR:]PORT", help="serve Prometheus metrics at http://ADDR:PORT/metrics "
                   "(loopback unless an address is given)")
    p.add_argument("--master-allow", "--allow", dest="master_allow", action="append", metavar="CIDR",
                   help="the master started here answers only clients from these networks (repeat the "
                        "option or separate with commas), loopback and this machine's addresses")
    p.add_argument("--pid", dest="pid_fn", metavar="PID_FN", help="write launch's pid to this file")
    p.add_argument("--run_id", dest="run_id", help="run_id of the session")
    p.add_argument("-v", dest="verbose", action="store_true", help="verbose printing")
    p.add_argument("--disable-title", dest="disable_title", action="store_true", help="accepted for roslaunch compatibility")
    p.add_argument("-w", "--numworkers", dest="num_workers", type=int, help="accepted for roslaunch compatibility")
    p.add_argument("-t", "--timeout", dest="timeout", type=float, help="socket time-out of the core, in seconds")
    p.add_argument("--master-logger-level", dest="master_logger_level", help="accepted for roslaunch compatibility")
    p.add_argument("-c", "--child", dest="child_name", help="roslaunch child mode: the child's name")
    p.add_argument("-u", "--server_uri", dest="server_uri", help="roslaunch child mode: the parent's XML-RPC URI")
    p.add_argument("--version", action="version", version="launch " + __version__)
    p.add_argument("positional", nargs="*", metavar="ARG", help="[package] file.launch ... name:=value ...")
    return p


# The store_true options, and what every option is when not given (build_parser's defaults;
# tests/cli/test_cli.py checks both against argparse). A command line made only of these and of
# positionals is read without argparse, which with gettext and locale costs ~4 ms to import and
# set up: a tenth of a big `--nodes`. Anything else (values, -h, errors, ...) goes to argparse.
_FLAGS = {"--files": "files", "--nodes": "nodes", "--dump-params": "dump_params", "--ros-args": "ros_args",
          "--core": "core", "--screen": "screen", "--log": "log", "--required": "required", "--wait": "wait",
          "--local": "local", "--no-summary": "no_summary", "--skip-log-check": "skip_log_check",
          "-v": "verbose", "--disable-title": "disable_title", "--no-start": "no_start",
          "--no-diagnostics": "no_diagnostics", "--ui": "ui"}
# what build_parser() gives for an argv of flags and positionals: a run's defaults are RunOptions' own
_DEFAULTS: dict[str, object] = dict(
    {dest: False for dest in _FLAGS.values()}, **{k: v for k, v in _RUN.items() if k not in ("positional", "master_allow")},
    node_args=None, find_node=None, num_workers=None, timeout=None, master_logger_level=None, child_name=None,
    server_uri=None, master_allow=None, web=None)


def parse_simple_args(args: list[str]) -> SimpleNamespace | None:
    """`args` as build_parser() parses them, when they are only flags of _FLAGS and positionals; else None."""
    values = dict(_DEFAULTS)
    positional = []
    for a in args:
        if a[:1] == "-" and a != "-":
            dest = _FLAGS.get(a)
            if dest is None:
                return None
            values[dest] = True
        else:
            positional.append(a)
    values["positional"] = positional
    return SimpleNamespace(**values)


def _end_process(status: int) -> None:
    """End a real command line's process once its output is out, without Python's teardown."""
    # (the console, and its writer thread's `threading`, is imported by what writes through it: a
    # run, an error; an introspection's output goes to stdout and needs neither)
    console = sys.modules.get("launcher.output.console")
    if console is not None:
        console.flush()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(status)


def _start_web(address: str, port: int | None) -> None:
    """`launch --web`: the page's server, `launcher web`, a process apart that reads this launch through its
    server once it is registered on the master, and ends with it."""
    import subprocess
    master_uri = "http://localhost:%d/" % port if port else os.environ.get("ROS_MASTER_URI") or "http://localhost:11311/"
    pid = str(os.getpid())
    subprocess.Popen([sys.executable, "-m", "launcher.cli.tool", "web", address, "--parent", pid, "--launch", pid,
                      "--master-uri", master_uri], stdin=subprocess.DEVNULL, start_new_session=True)


def _import_asyncio_without_tls() -> None:
    """Import asyncio without the ssl module it imports when it can.

    ssl loads libssl and libcrypto: ~4 MB of a launch's memory for as long as it runs (a third of its own), for
    TLS that nothing of a run uses. asyncio takes a missing ssl as "no TLS here"; ssl stays importable after.
    """
    if "asyncio" in sys.modules or "ssl" in sys.modules:
        return
    sys.modules["ssl"] = None  # type: ignore[assignment]  # (None there: `import ssl` raises ImportError)
    try:
        import asyncio  # noqa: F401
    finally:
        del sys.modules["ssl"]


def _pause_collector() -> bool:
    """Pause the cyclic garbage collector; whether it ran (to resume it only then: `launch` may run in a test).

    Imports, and a launch's loading, make objects that live as long as the process and leave next to no
    cyclic garbage: the collector would only go over them again and again. A run's ~250 modules cost ~40
    collections on their way in; imported with it paused, and then frozen (`gc.freeze`: no later
    collection goes over them either), a 100-node start takes ~6 ms less CPU (~5%) for ~0.1 MB more
    memory (the little garbage the imports left). A big `--dump-params`: ~10 ms."""
    running = gc.isenabled()
    gc.disable()
    return running


def _imports_done(collecting: bool) -> None:
    """Resume the collector paused for a run's imports (`_pause_collector`), what they made frozen first."""
    if collecting:
        gc.freeze()
        gc.enable()


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    opts = parse_simple_args(args)
    if opts is None:
        parser = build_parser()
        opts = parser.parse_intermixed_args(args)
    try:
        if opts.sigint_timeout <= 0 or opts.sigterm_timeout <= 0:
            raise LaunchError("--sigint-timeout and --sigterm-timeout must be greater than zero")
        if not opts.monitor_period > 0:
            raise LaunchError("--monitor-period must be greater than zero")
        if not opts.ready_timeout > 0:
            raise LaunchError("--ready-timeout must be greater than zero")
        if opts.child_name or opts.server_uri:
            collecting = _pause_collector()
            try:
                _import_asyncio_without_tls()
                from launcher.remote.child import run_child  # a roslaunch child on another machine
            finally:
                _imports_done(collecting)
            status = run_child(opts)
            if argv is None:
                # the parent's ssh session ends when this process does: skip tearing down ~150
                # modules (~10 ms, while the launch's stop waits for it)
                _end_process(status)
            return status
        if opts.files or opts.node_args or opts.nodes or opts.find_node or opts.dump_params or opts.ros_args:
            collecting = _pause_collector()  # (for the imports and the load: its ~10^5 objects free almost nothing)
            try:
                from launcher.cli import introspect
                status = introspect.main(opts)
            finally:
                if collecting:
                    gc.enable()
            if argv is None:
                # freeing the loaded launch's 10^5 objects one by one is ~10% of a big `--nodes`
                _end_process(status)
            return status
        if not opts.positional and not opts.core:
            build_parser().error("you must specify at least one input file")
        if opts.ui:
            # (prompt_toolkit is imported only here: a launch without --ui does not pay for it)
            from launcher.operate import ui
            if ui.terminal_ok():
                port_uri = "http://localhost:%d/" % opts.port if opts.port else None
                return ui.launch_with_view([a for a in args if a != "--ui"], port_uri or os.environ.get(
                    "ROS_MASTER_URI") or "http://localhost:11311/")
            from launcher.output import console
            console.printerrlog("launch --ui: no terminal (or TERM=dumb): the launch runs with plain lines")
        if opts.web:
            _start_web(opts.web, opts.port)
        run_opts = RunOptions.from_args(opts)
        reading = None
        try:
            collecting = _pause_collector()  # (for the run's imports; the run collects as always)
            try:
                if not run_opts.core:
                    # the launch files are read in a child forked now, before asyncio and the run's modules are
                    # imported: on the other core, while those imports go on here (run/apart.py)
                    from launcher.run.load import begin_plan
                    reading = begin_plan(run_opts)
                _import_asyncio_without_tls()
                from launcher.run import runtime
            finally:
                _imports_done(collecting)
            # a real command line (argv from sys.argv) may end the process as soon as all is stopped
            return runtime.run(run_opts, reading, exit_process=argv is None)
        finally:
            if reading is not None:
                reading.abandon()  # (its child killed and reaped if the run ended before it took the plan)
    except UsageError as e:
        from launcher.output import console
        console.flush()  # (the warnings already queued there come first)
        build_parser().error(str(e))  # roslaunch's parser.error: the usage, the message, exit status 2
        raise  # (not reached: error() exits)
    except LaunchError as e:
        from launcher.output import console
        console.printfatal(str(e))  # (through the console: after the warnings already queued there)
        return 1
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        # `launch --nodes f.launch | head`: the reader left; that is not an error of ours
        sys.stderr.close()
        return 0
    except Exception as e:  # a bug of ours: say so in one line, the traceback only with -v
        if opts.verbose:
            raise
        from launcher.output import console
        console.printfatal("launch: internal error: %s: %s (run with -v for the traceback; please report it)"
                           % (type(e).__name__, e))
        return 2
