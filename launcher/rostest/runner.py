"""`launcher test [pkg] file.test [name:=value ...]`: rostest's runner, each `<test>` on its own master and fixture.

As rostest (Debian's rostest/runner.py), every `<test>` gets a fresh run of the
file: a master (ours, on a free port, so that several runs go in parallel;
the one at ROS_MASTER_URI with `--reuse-master`), the file's parameters and
`<node>`s, then the test node with `--gtest_output=xml:RESULT` appended to its
args, until it exits or its `time-limit` passes. A run is `runtime.Run` with
its services chosen for rostest (where the master comes from, no rosout,
no /diagnostics) and, instead of waiting for a stop signal, the test node.

Where rostest is wrong, this runner is not: a test that exits non-zero, dies by
a signal, times out or writes no results fails with that reason (rostest passes
a test that wrote its results and then segfaulted, ros_comm#2265), and test
cases are counted from the file's `<testcase>`s, not its `failures=` attribute;
a test file that does not exist or does not load is a failed `test_ran` result
(rostest's write_bad_filename_failure, #1140, which its own argument check
keeps from ever running: it writes no result at all).
"""

from __future__ import annotations

import argparse
import asyncio
import functools
import os
import shlex
import shutil
import signal
import sys
import tempfile
import time
from typing import Any

from launcher import compat
from launcher.compat import pidfd_open
from launcher.services import masterlink
from launcher.model.runopts import RunOptions
from launcher.plan.command import node_command
from launcher.model.config import Node
from launcher.model.errors import LaunchError
from launcher.services.masterlink import MasterSession, RemoteParams
from launcher.model.names import ns_join
from launcher.workspace.packages import PackageIndex, package_of
from launcher.output import console
from launcher.plan.specs import ProcessSpec
from launcher.process.spawn import start_process
from launcher.process.watchdog import Watchdog
from launcher.rostest.results import (TestOutcome, judge, results_dir, safe_test_name, summary, write_junit,
                                      write_test_file_failure)
from launcher.plan.plan import Plan
from launcher.run.load import load_plan, plan_for
from launcher.run.runtime import Run, Stopped
from launcher.xml import resolve_launch_arguments

DEFAULT_TIME_LIMIT = 60.0  # rostest's default time-limit
# a test node that outlives its time-limit: SIGINT, then SIGTERM, then SIGKILL after these many seconds
STOP_GRACE_S = (5.0, 2.0)
# parameters `--clear` keeps (rostest's whitelist; /roslaunch/* too)
CLEAR_KEEP = ("/run_id", "/rosversion", "/rosdistro")


def printlog(msg: str) -> None:
    console.printlog("[ROSTEST]" + msg)


class RostestMaster(MasterSession):
    """rostest's master session: ours on a free port of the kernel's choosing (parallel runs never meet), or
    with `--reuse-master` the one at ROS_MASTER_URI (`--clear`: its parameters cleared first); started and
    stopped without a word (rostest's master is a rosmaster.Master in its own process)."""

    is_a_process = False

    def __init__(self, opts: Any, plan: Plan, signals: Any, *, reuse_master: bool, clear: bool):
        super().__init__(opts, plan, signals)
        self.reuse_master = reuse_master
        self.clear = clear

    async def _find_master(self) -> tuple[bool, tuple[Any, Any] | None]:
        if not self.reuse_master:
            return False, None  # always our own master
        answers, reply = await masterlink.probe(self.uri)
        if not answers:
            raise LaunchError("--reuse-master: no ROS master answers at [%s]" % self.uri)
        if self.clear:
            params = RemoteParams(self.uri)
            for key in await params._call("getParamNames"):
                if key not in CLEAR_KEEP and not key.startswith("/roslaunch/"):
                    await params.delete(key)
        return True, reply

    async def _start_master(self, port: int) -> None:
        await super()._start_master(0)
        self.uri = self.plan.master_uri = self.master.uri


class TestAttempt:
    """One attempt of one `<test>`: a run of the file's fixture, then the test node, then tear-down.

    The run is `runtime.Run` with its services chosen for rostest: `RostestMaster`;
    no rosout (rostest's master is up before its runner launches, and roslaunch
    starts its core nodes only with a master it started itself: a test sees only
    the file's nodes), no /diagnostics (the launcher's, not rostest's: the test's
    graph would have a node more), no log-disk check; and, as its body, the test
    node instead of waiting for a stop signal.
    """

    def __init__(self, opts: Any, plan: Plan, watchdog: Any, test: Node, result_file: str, *,
                 reuse_master: bool, clear: bool, text: bool, processes_before: int = 0):
        self.opts = opts
        self.plan = plan
        self.watchdog = watchdog
        self.reuse_master = reuse_master
        self.clear = clear
        # rostest numbers its processes with one counter for the whole file (roslaunch's, global in its
        # process: fixture nodes, then the test, across tests and retries) and runs no rosout process:
        # talk-1, test-2, then talk-3, test-4 for a second <test>
        self.processes_before = processes_before
        self.process_count = processes_before
        self.test = test
        self.result_file = result_file
        self.text = text
        self.returncode: int | None = None
        self.timed_out = False
        self.start_problem: str | None = None
        self.interrupted = False

    async def main(self) -> int:
        master = functools.partial(RostestMaster, reuse_master=self.reuse_master, clear=self.clear)
        run = Run(self.opts, self.plan, self.watchdog, master=master, rosout=False, diagnostics=False,
                  reap_orphans=False,  # (its test node is waited for by popen.wait(): its exit status is the result)
                  log_disk=False, body=self._body, first_number=self.processes_before)
        try:
            return await run.main()
        finally:
            self.process_count = max(self.process_count, run.process_count)

    async def _body(self, run: Run) -> None:
        run.signals.check()
        self.process_count = run.process_count
        try:
            await run.signals.guard(self._run_test(run))
        except Stopped:
            self.interrupted = True
            raise

    async def _run_test(self, run: Run) -> None:
        test = self.test
        extra = "--gtest_output=xml:" + shlex.quote(self.result_file)
        if self.text:
            extra += " --text"
        node = test._replace(args=(test.args + " " + extra) if test.args else extra)
        self.process_count += 1
        name = ("%s-%d" % (ns_join(node.namespace, node.name), self.process_count)).lstrip("/")
        run_dir = run.log.run_dir
        log_name = name.replace("/", "-")
        try:
            command = node_command(node, master_uri=run.master.uri, environ=run.nodes.node_environ(),
                                   packages=self.plan.packages,
                                   log_file=os.path.join(run_dir, log_name + ".log") if run_dir else None)
        except LaunchError as e:
            self.start_problem = str(e)
            return
        screen = self.text or node.output == "screen"
        spec = ProcessSpec(name, command, log_dir=run_dir, node_name=ns_join(node.namespace, node.name),
                           stdout_path=os.path.join(run_dir, log_name + "-stdout.log") if run_dir and not screen
                           else None)
        printlog("running test %s" % test.test_name)
        popen = start_process(spec, self.watchdog)
        if popen is None:
            self.start_problem = "test [%s] could not be started" % test.test_name
            return
        loop = asyncio.get_running_loop()
        exited = loop.create_future()
        pidfd = pidfd_open(popen.pid)
        loop.add_reader(pidfd, lambda: exited.done() or exited.set_result(None))
        try:
            limit = test.time_limit if test.time_limit is not None else DEFAULT_TIME_LIMIT
            try:
                await compat.wait_for(asyncio.shield(exited), limit)
            except asyncio.TimeoutError:
                self.timed_out = True
                console.printerrlog("[ROSTEST]test [%s] timed out" % test.test_name)
                await self._stop(popen, exited)
        finally:
            loop.remove_reader(pidfd)
            os.close(pidfd)
            if popen.poll() is None:  # cancelled (a stop signal): no grace
                _signal_group(popen.pid, signal.SIGKILL)
            self.returncode = popen.wait()
            _signal_group(popen.pid, signal.SIGKILL)  # whatever the test left behind in its group
            if self.watchdog is not None:
                self.watchdog.forget(popen.pid)
        if self.returncode and not self.timed_out:
            console.printerrlog("[%s] process has died [pid %s, exit code %s, cmd %s]."
                                % (name, popen.pid, self.returncode, " ".join(command.argv)))
        printlog("test [%s] finished" % test.test_name)

    async def _stop(self, popen: Any, exited: asyncio.Future) -> None:
        for sig, grace in zip((signal.SIGINT, signal.SIGTERM), STOP_GRACE_S):
            _signal_group(popen.pid, sig)
            try:
                await compat.wait_for(asyncio.shield(exited), grace)
                return
            except asyncio.TimeoutError:
                pass
        _signal_group(popen.pid, signal.SIGKILL)
        await exited


def _signal_group(pgid: int, sig: int) -> None:
    try:
        os.killpg(pgid, sig)
    except OSError:
        pass


def rostest_name_from_path(pkg_dir: str, test_file: str) -> str:
    """rosunit's name of a test file's results: its package-relative path, `/` as `_`, without extension."""
    path = os.path.abspath(test_file)
    if path.startswith(pkg_dir):
        path = path[len(pkg_dir):].lstrip(os.sep)
    name = path.replace(os.sep, "_")
    return name[:name.rfind(".")] if "." in name else name


class TestFileFailure(LaunchError):
    """The test file does not exist or does not load; `results_file` holds a failed test that says so."""

    results_file: str | None = None


class TestFile:
    """Every `<test>` of one file, each in its own attempts; the outcomes, in file order."""

    def __init__(self, opts: argparse.Namespace):
        self.opts = opts
        self.environ = dict(os.environ)
        self.packages = PackageIndex(self.environ, warn=lambda m: console.printerrlog("WARNING: %s" % m))
        self.junit_path: str | None = None
        try:
            files, self.argv = resolve_launch_arguments(list(opts.positional), self.packages)
        except LaunchError as e:
            named = self._named_test_file()
            if named is None:
                raise
            self._name_results(*named)
            raise self._test_file_failure("rostest file [%s] does not exist" % named[0], e) from None
        if not files:
            raise LaunchError("you must supply a test file argument")
        if len(files) != 1:
            raise LaunchError("only a single test file is accepted")
        self.test_file = files[0]
        if opts.pkg_dir and opts.package:
            self._name_results(self.test_file, opts.package, opts.pkg_dir)
        else:
            self._name_results(self.test_file, *package_of(self.test_file))
        self.launch_opts = RunOptions(positional=(self.test_file, *self.argv), screen=bool(opts.text))

    def _name_results(self, test_file: str, pkg: str, pkg_dir: str) -> None:
        """Where the results go: rostest's `<results dir>/<pkg>/rostest-<name>.xml` (or --junit-xml)."""
        opts = self.opts
        self.pkg, self.pkg_dir = pkg, pkg_dir
        if opts.results_filename:
            outname = opts.results_filename
            outname = outname[:outname.rfind(".")] if "." in outname else outname
        else:
            outname = rostest_name_from_path(pkg_dir, test_file)
        self.outname = outname
        self.results_dir = os.path.join(results_dir(self.environ, opts.results_base_dir), pkg)
        self.junit_path = opts.junit_xml or os.path.join(self.results_dir, "rostest-%s.xml" % safe_test_name(outname))

    def _named_test_file(self) -> tuple[str, str, str] | None:
        """(test file, package, package dir) of a command line whose test file does not exist, for its
        failure result; None when it names no package."""
        opts = self.opts
        words = [a for a in opts.positional if ":=" not in a]
        if not words:
            return None
        if opts.pkg_dir and opts.package:
            return words[-1], opts.package, opts.pkg_dir
        if len(words) >= 2:
            try:
                pkg_dir = self.packages.get_path(words[0])
                return os.path.join(pkg_dir, words[1]), words[0], pkg_dir
            except LaunchError:
                return None  # (neither a package nor, with a second word, a file: roslaunch's rule)
        try:
            return (words[0],) + package_of(words[0])
        except LaunchError:
            return None

    def _test_file_failure(self, message: str, error: LaunchError) -> TestFileFailure:
        """A test file that cannot be run is a failed test in its results, as rostest means it to be (#1140,
        its write_bad_filename_failure: Debian's rostest exits before it gets there, and writes nothing a CI
        job would see)."""
        failure = TestFileFailure(error.message, error.filename, error.line, error.include_chain)
        if self.junit_path is not None:
            try:
                write_test_file_failure(self.junit_path, self.outname, message)
                failure.results_file = self.junit_path
            except OSError as e:
                console.printerrlog("cannot write [%s]: %s" % (self.junit_path, e.strerror))
        return failure

    def run(self) -> int:
        try:
            plan = load_plan(self.launch_opts)
        except LaunchError as e:
            raise self._test_file_failure("rostest file [%s] does not load: %s" % (self.test_file, e), e) from None
        config = plan.config
        fixture = config._replace(tests=())
        outcomes: list[TestOutcome] = []
        self.processes = 0  # processes started so far (rostest's process numbers)
        watchdog = Watchdog.start()
        scratch = tempfile.mkdtemp(prefix="launcher-test-")
        seen: set[str] = set()
        broken_fixture = []  # rostest: the test fails when the nodes it runs against cannot be launched
        for node in fixture.nodes:
            try:
                self.packages.find_node(node.package, node.type)
            except LaunchError:
                broken_fixture.append(node.full_name)
        try:
            for test in config.tests:
                problem = None
                try:
                    self.packages.find_node(test.package, test.type)
                except LaunchError:
                    problem = "Test node [%s/%s] does not exist or is not executable" % (test.package, test.type)
                if problem is None and broken_fixture:
                    problem = "Test Fixture Nodes %s failed to launch" % broken_fixture
                if problem is None and test.test_name in seen:
                    problem = "Duplicate tests named [%s] in rostest suite" % test.test_name
                seen.add(test.test_name)
                if problem is not None:
                    console.printerrlog(problem)
                    outcomes.append(TestOutcome(test.test_name, problem=problem))
                    continue
                outcome = self._run_test(test, fixture, plan, watchdog, scratch)
                if outcome is None:  # interrupted
                    return 130
                outcomes.append(outcome)
        finally:
            if watchdog is not None:
                watchdog.close()
            shutil.rmtree(scratch, ignore_errors=True)
        write_junit(self.junit_path, "rostest", outcomes)
        console.printlog(summary(outcomes))
        console.printlog("test results are in %s" % self.junit_path)
        if any(o.problem is not None for o in outcomes):
            return 1
        return 2 if any(not o.passed for o in outcomes) else 0

    def _run_test(self, test: Node, fixture: Any, plan: Plan, watchdog: Any, scratch: str) -> TestOutcome | None:
        """Attempts of one test until it passes or its retries are used up; None when a stop signal came."""
        retries = test.retry
        attempt = 0
        # the test writes into this run's own directory (parallel runs of one file never share a result
        # file); the final one is then copied where rostest keeps it, rosunit-<test>.xml
        private = os.path.join(scratch, "rosunit-%s.xml" % safe_test_name(test.test_name))
        limit = test.time_limit if test.time_limit is not None else DEFAULT_TIME_LIMIT
        while True:
            attempt += 1
            if os.path.exists(private):
                os.remove(private)
            printlog("Running test [%s]" % test.test_name)
            started = time.monotonic()
            run = TestAttempt(self.launch_opts, plan_for(fixture, plan.master_uri, plan.environ, packages=self.packages),
                              watchdog, test, private, reuse_master=self.opts.reuse_master, clear=self.opts.clear,
                              text=self.opts.text, processes_before=self.processes)
            asyncio.run(run.main())
            self.processes = max(self.processes, run.process_count)
            if run.interrupted:
                return None
            elapsed = time.monotonic() - started
            if run.start_problem is not None:
                outcome = TestOutcome(test.test_name, problem=run.start_problem, time=elapsed, attempts=attempt)
            else:
                outcome = judge(test.test_name, run.returncode, run.timed_out, limit, private, elapsed, attempt,
                                text=self.opts.text,
                                prefix="%s.%s" % (self.pkg, os.path.splitext(os.path.basename(private))[0]))
            if outcome.passed or retries <= 0:
                break
            retries -= 1
            printlog("test [%s] failed (%s), retrying. Retries left: %d"
                     % (test.test_name, outcome.problem or "failing test cases", retries))
        if outcome.result_file:
            final = os.path.join(self.results_dir, os.path.basename(private))
            os.makedirs(self.results_dir, exist_ok=True)
            shutil.copyfile(private, final + ".tmp%d" % os.getpid())
            os.replace(final + ".tmp%d" % os.getpid(), final)
            outcome = outcome._replace(result_file=final)
        printlog("test [%s] results summary: %d errors, %d failures, %d tests%s"
                 % (test.test_name, outcome.errors, outcome.failures, len(outcome.cases),
                    "" if outcome.problem is None else " (%s)" % outcome.problem))
        return outcome


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="launcher test", usage="launcher test [options] [package] <file.test> [name:=value ...]",
                                description="Run a rostest file: its nodes, then each <test> node, on a fresh master.")
    p.add_argument("-t", "--text", action="store_true", help="test output on the screen instead of XML results")
    p.add_argument("--pkgdir", dest="pkg_dir", metavar="PKG_DIR", help="package dir (with --package)")
    p.add_argument("--package", metavar="PACKAGE", help="package (with --pkgdir)")
    p.add_argument("--results-filename", metavar="RESULTS_FILENAME", help="name of the results file (rostest-NAME.xml)")
    p.add_argument("--results-base-dir", metavar="RESULTS_BASE_DIR",
                   help="base directory of the test results (a PKG subdirectory is made in it)")
    p.add_argument("-r", "--reuse-master", action="store_true",
                   help="connect to the ROS master at ROS_MASTER_URI instead of starting one per test")
    p.add_argument("-c", "--clear", action="store_true", help="clear all parameters of the reused master first")
    p.add_argument("--junit-xml", metavar="PATH", help="write the JUnit results here instead")
    p.add_argument("positional", nargs="*", metavar="ARG", help="[package] file.test name:=value ...")
    return p


def main(argv: list[str]) -> int:
    parser = build_parser()
    opts = parser.parse_intermixed_args(argv)
    if opts.clear and not opts.reuse_master:
        print("The --clear option is only valid with --reuse-master", file=sys.stderr)
        return 1
    try:
        status = TestFile(opts).run()
    except LaunchError as e:
        console.flush()
        print(str(e), file=sys.stderr)
        if getattr(e, "results_file", None):
            print("test file is invalid. Generated failure case result file in %s" % e.results_file, file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        status = 130
    console.flush()
    return status
