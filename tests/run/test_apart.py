"""run/apart.py: a launch's plan made in a forked child, so that what only the making imports (the XML loader, PyYAML)
never enters the launch's memory; the child's answers, errors, output and Ctrl-C, on real processes."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import threading
import time

import pytest

from helpers import ROOT, until
from launcher.process.reaper import stat_fields
from launcher.run.apart import begin_apart


def made_apart(make):
    """The value made apart, begun and taken at once."""
    return begin_apart(make).result()


def _run(code: str, **kwargs) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", textwrap.dedent(code)], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, **kwargs)


PRELUDE = ("from launcher.run.apart import begin_apart\n"
           "made_apart = lambda make: begin_apart(make).result()\n")


def _apart(code: str, **kwargs) -> str:
    """What a script prints, run in a process of its own: a fork copies only one thread, so `made_apart` forks
    only where no other thread runs (pytest's process has some, from other tests)."""
    proc = _run(PRELUDE + textwrap.dedent(code), **kwargs)
    out, _ = proc.communicate(timeout=60)
    assert proc.returncode == 0, out
    return out


def test_the_value_is_made_in_another_process_whose_imports_stay_there():
    out = _apart("""
        import os, sys
        def there():
            import colorsys  # (nothing of the launcher's imports it: the child's alone)
            return os.getpid(), "colorsys" in sys.modules
        print(repr((os.getpid(), made_apart(there), "colorsys" in sys.modules)))
    """)
    here, (there, imported_there), imported_here = eval(out)  # noqa: S307 - (our own repr)
    assert here != there and imported_there and not imported_here


def test_a_launch_error_there_is_raised_here_with_its_words_and_its_kind():
    """A UsageError stays one (`launch` exits 2 for it, with the usage); an error made of other arguments than its
    text (PackageNotFound) crosses as a LaunchError of its words."""
    out = _apart("""
        from launcher.model.errors import LaunchError, UsageError
        from launcher.workspace.packages import PackageNotFound
        def refuse(error):
            def make():
                raise error
            return make
        for error in (LaunchError("a.launch:3: node [/b]: bad"), UsageError("The following input files do not "
                      "exist: robot=r3"), PackageNotFound("nopkg", ["/opt/ros"])):
            try:
                made_apart(refuse(error))
            except LaunchError as e:
                print(type(e).__name__, str(e) == str(error))
    """)
    assert out.splitlines() == ["LaunchError True", "UsageError True", "LaunchError True"]


def test_a_bug_there_is_one_line_here_naming_it_and_a_value_that_cannot_cross_is_one_too():
    out = _apart("""
        import threading
        for make in (lambda: {}["missing"], threading.Lock):
            try:
                made_apart(make)
            except RuntimeError as e:
                print(e)
    """)
    bug, lock = out.splitlines()
    assert bug == "KeyError: 'missing' (while the launch files were read)"
    assert "pickle" in lock and lock.endswith("(while the launch files were read)")


def test_with_a_thread_running_it_is_made_here():
    """A fork copies only the thread that forks: a lock another thread holds would stay held in the child."""
    stop = threading.Event()
    other = threading.Thread(target=stop.wait)
    other.start()
    try:
        assert made_apart(os.getpid) == os.getpid()
    finally:
        stop.set()
        other.join()


def test_the_making_goes_on_in_the_child_while_the_launch_does_other_work():
    """`launch` begins the making before it imports the run's modules: `begin_apart` returns at once, the child
    makes the value meanwhile, `result()` takes it."""
    out = _apart("""
        import time
        from launcher.run.apart import begin_apart
        started = time.monotonic()
        making = begin_apart(lambda: (time.sleep(1.0), time.monotonic())[1])
        begun = time.monotonic() - started
        time.sleep(1.0)  # (the launch's imports)
        made_at = making.result()
        print(repr((begun, made_at - started, time.monotonic() - started)))
    """)
    begun, made, taken = eval(out)  # noqa: S307 - (our own repr)
    assert begun < 0.5 and made < 1.6 and taken < 1.8  # (made beside the second, not after it: 2 s)


def test_an_abandoned_making_leaves_no_process():
    """A launch that ends before it takes its plan (an error of its own, a Ctrl-C in its imports): its child is
    stopped with the command it runs (a `<param command>`), and reaped: nothing left behind, no zombie."""
    out = _apart("""
        import os, subprocess, time
        from launcher.run.apart import begin_apart
        making = begin_apart(lambda: subprocess.run(["sleep", "30"]))
        pid = making.pid
        def command():
            found = subprocess.run(["pgrep", "-P", str(pid), "-x", "sleep"], capture_output=True, text=True)
            return [int(p) for p in found.stdout.split()]
        deadline = time.monotonic() + 30
        while not command() and time.monotonic() < deadline:
            time.sleep(0.05)
        sleep, = command()
        making.abandon()
        def state():
            try:
                with open("/proc/%d/stat" % sleep) as f:
                    return f.read().split(") ")[1][0]
            except OSError:
                return "gone"
        # (its SIGKILL is sent: on a busy machine it may run a moment longer before it dies)
        deadline = time.monotonic() + 10
        while state() not in ("Z", "gone") and time.monotonic() < deadline:
            time.sleep(0.01)
        print(repr((pid, os.path.exists("/proc/%d" % pid), state())))
    """)
    pid, left, command = eval(out)  # noqa: S307 - (our own repr)
    # (killed by the child's subprocess.run: reaped there, or by whoever it was re-parented to)
    assert pid > 0 and not left and command in ("Z", "gone")


def test_what_the_child_prints_comes_once_between_what_the_launch_printed_before_and_after():
    """The launch's output is a pipe (block-buffered): what it had not written yet must not be written by the child
    a second time, and the child's lines (the load's warnings) come where they are made."""
    proc = _run("""
        from launcher.run.apart import begin_apart
        made_apart = lambda make: begin_apart(make).result()  # noqa: E731
        from launcher.output import console
        print("before")
        made_apart(lambda: (console.printlog("the child's line"), console.printerrlog("WARNING: the child's warning")))
        print("after")
    """, env={k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"})
    out, _ = proc.communicate(timeout=60)
    assert proc.returncode == 0, out
    assert out.splitlines() == ["before", "the child's line", "WARNING: the child's warning", "after"]


def test_a_ctrl_c_of_the_launch_alone_ends_the_child_and_the_command_it_runs():
    """SIGINT to the launch's pid while its child waits on a `<param command>`: the launch ends at once (130, as
    before), and neither the child nor its command is left running."""
    proc = _run("""
        import subprocess, sys
        from launcher.run.apart import begin_apart
        made_apart = lambda make: begin_apart(make).result()  # noqa: E731
        try:
            made_apart(lambda: subprocess.run(["sleep", "30"]))
        except KeyboardInterrupt:
            print("interrupted")
            sys.exit(130)
    """, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL), start_new_session=True)
    try:
        def sleeping() -> list[int]:
            found = subprocess.run(["pgrep", "-s", str(proc.pid), "-x", "sleep"], capture_output=True, text=True)
            return [int(p) for p in found.stdout.split()]
        command = until(sleeping, 30, what="the child's command running")[0]
        started = time.monotonic()
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=30)
        assert time.monotonic() - started < 5
        assert proc.returncode == 130 and out.strip() == "interrupted"
        # (killed, it is reaped by whoever it was re-parented to: init, or here a subreaper the test runs under)
        until(lambda: (stat_fields(command) or ["gone"])[0] in ("Z", "gone"), 10, what="the command ended")
        left = subprocess.run(["ps", "-o", "pid=,stat=,cmd=", "-s", str(proc.pid)], capture_output=True, text=True)
        assert [line for line in left.stdout.splitlines() if line.split()[1][0] != "Z"] == []
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


def test_a_launchs_plan_made_apart_leaves_the_parsers_out_and_keeps_its_anon_names_and_parameters(tmp_path):
    """The real thing: `begin_plan` of a launch with `<rosparam>` and `$(anon)`, in a process of its own; the
    same plan as one made in-process, its parameters' text made there, and neither the XML loader, the YAML
    writer nor PyYAML imported by the launch's process."""
    from launcher.model.runopts import RunOptions
    from launcher.run.load import load_plan
    from launcher.services.runrecord import params_text
    (tmp_path / "params.yaml").write_text("gains: {p: 1.5, i: [0.1, 0.2]}\nplugins:\n  - {name: a, type: 'x::A'}\n")
    launch = tmp_path / "a.launch"
    launch.write_text('<launch>\n  <rosparam command="load" file="%s" ns="ctl"/>\n'
                      '  <param name="who" value="$(anon me)"/>\n</launch>\n' % (tmp_path / "params.yaml"))
    env = dict(os.environ, ROS_HOME=str(tmp_path / "home"), ROS_PACKAGE_PATH=str(tmp_path))
    proc = _run("""
        import os, pickle, sys
        from launcher.model.runopts import RunOptions
        from launcher.run.load import begin_plan
        plan = begin_plan(RunOptions(positional=(%r,))).result()
        import launcher.run.runtime  # (nor by the run's modules: the YAML writer too is the making's)
        left = sorted(m for m in sys.modules if m.startswith(("launcher.xml", "launcher.params", "yaml", "_yaml")))
        params = {k: p.value for k, p in plan.config.params.items()}
        sys.stdout.write(repr((os.getpid(), left, plan.params_text, params)))
    """ % str(launch), env=env)
    out, _ = proc.communicate(timeout=60)
    assert proc.returncode == 0, out
    pid, left, text, params = eval(out)  # noqa: S307 - (our own repr)
    assert left == []
    assert params["/who"].startswith("me_") and "_%d_" % pid in params["/who"]  # (the launch's pid, as roslaunch)
    here = load_plan(RunOptions(positional=(str(launch),)))
    assert params == dict({k: p.value for k, p in here.config.params.items()}, **{"/who": params["/who"]})
    assert text == params_text(here.config).replace(here.config.params["/who"].value, params["/who"])
    assert "plugins:" in text and "x::A" in text  # (a list of mappings: what PyYAML writes, there)



def test_a_parameter_no_master_could_be_sent_refuses_the_run_at_its_line(tmp_path):
    """roslaunch's --dump-params prints a YAML date, and its run dies of a TypeError as it sends it: ours refuses the
    run with the tag's file and line, before anything runs."""
    from launcher.model.errors import LaunchError
    from launcher.model.runopts import RunOptions
    from launcher.run.load import load_plan
    launch = tmp_path / "a.launch"
    launch.write_text('<launch>\n  <param name="ok" value="2015-01-01"/>\n'
                      '  <rosparam ns="cfg">since: 2015-01-01</rosparam>\n</launch>\n')
    with pytest.raises(LaunchError) as e:
        load_plan(RunOptions(positional=(str(launch),)))
    assert str(e.value) == ("%s:3: parameter [/cfg/since] cannot be set: a value of type date (2015-01-01) cannot be "
                            "sent over XML-RPC (in YAML, quote it to keep it a string)" % launch)
