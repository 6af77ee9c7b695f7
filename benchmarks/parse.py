#!/usr/bin/env python3
"""Parse benchmark: `--dump-params` and `--nodes` on the generated 1000-node tree, ours vs roslaunch.

Generates the tree with the shared bench's gen_tree.py, then times both commands side by
side in ABBA order (whole-process wall time, as a user sees it) and reports the median of
the per-repetition paired ratios ours/roslaunch (target: <= 0.10). Outputs are compared
(parsed YAML for --dump-params, sorted lines for --nodes) so a fast wrong answer shows.

    python3 benchmarks/parse.py [--reps 10] [--modes dump-params,nodes]
    python3 benchmarks/parse.py --profile            # where our loader spends its time
    python3 benchmarks/parse.py --shared-bench       # also run ../shared/bench/bench.py parse

Debian's roslaunch needs Debian's python: it is run with /usr/bin first on PATH.
"""

from __future__ import annotations

import argparse
import cProfile
import io
import json
import os
import pstats
import shlex
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

from common import ROS_PATH  # (this folder is on the path of a script run from it)

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
DEFAULT_BENCH_DIR = os.path.join(REPO, "..", "shared", "bench")


def our_command() -> list[str]:
    """The `launch` console script next to this interpreter (what a venv user runs), else -m."""
    script = os.path.join(os.path.dirname(sys.executable), "launch")
    return [script] if os.path.exists(script) else [sys.executable, "-m", "launcher"]


def run_once(argv: list[str], env: dict[str, str]) -> tuple[float, float, str, int]:
    """(wall seconds, cpu seconds of the process tree, stdout, exit code)."""
    with tempfile.TemporaryFile() as out:
        t0 = time.perf_counter()
        p = subprocess.Popen(argv, env=env, stdout=out, stderr=subprocess.DEVNULL, stdin=subprocess.DEVNULL)
        _, status, usage = os.wait4(p.pid, 0)
        wall = time.perf_counter() - t0
        p.returncode = os.waitstatus_to_exitcode(status)
        out.seek(0)
        return wall, usage.ru_utime + usage.ru_stime, out.read().decode("utf-8", "replace"), p.returncode


def normalise(mode: str, text: str):
    if mode == "nodes":
        return sorted(line for line in text.splitlines() if line.strip())
    import yaml
    try:
        return json.dumps(yaml.safe_load(text), sort_keys=True, default=str)
    except yaml.YAMLError:
        return text


def bench(args, main: str, env: dict[str, str]) -> dict:
    ours = our_command()
    ref = shutil.which("roslaunch", path=ROS_PATH)
    cmds = [("roslaunch", [ref], dict(env, PATH=ROS_PATH + ":" + env.get("PATH", ""))), ("ours", ours, env)]
    if ref is None:
        print("roslaunch not installed: timing ours only", file=sys.stderr)
        cmds = cmds[1:]
    summary = {}
    for mode in args.modes.split(","):
        walls: dict[str, list[float]] = {label: [] for label, _, _ in cmds}
        cpus: dict[str, list[float]] = {label: [] for label, _, _ in cmds}
        outputs: dict[str, object] = {}
        ratios, cpu_ratios = [], []
        for rep in range(args.reps):
            order = cmds if rep % 2 == 0 else cmds[::-1]  # ABBA: drift hits both sides alike
            this, this_cpu = {}, {}
            for label, argv, cmd_env in order:
                wall, cpu, text, rc = run_once(argv + ["--" + mode, main], cmd_env)
                if rc != 0:
                    raise SystemExit("%s --%s failed (exit %d)" % (label, mode, rc))
                walls[label].append(wall)
                cpus[label].append(cpu)
                this[label] = wall
                this_cpu[label] = cpu
                outputs.setdefault(label, normalise(mode, text))
            if "roslaunch" in this:
                ratios.append(this["ours"] / this["roslaunch"])
                cpu_ratios.append(this_cpu["ours"] / this_cpu["roslaunch"])
        res = {label: {"wall_median_s": round(statistics.median(v), 4), "wall_min_s": round(min(v), 4),
                       "cpu_median_s": round(statistics.median(cpus[label]), 4)} for label, v in walls.items()}
        if ratios:
            res["ratio_median"] = round(statistics.median(ratios), 3)
            res["ratio_min"] = round(min(ratios), 3)
            res["ratio_max"] = round(max(ratios), 3)
            # CPU time is less disturbed than wall time when the machine is shared
            res["cpu_ratio_median"] = round(statistics.median(cpu_ratios), 3)
            res["outputs_identical"] = outputs["ours"] == outputs["roslaunch"]
        summary[mode] = res
        print(json.dumps({"mode": mode, "reps": args.reps, **res}))
    return summary


def profile(main: str, env: dict[str, str], top: int) -> None:
    """cProfile of one in-process load + the output step, for each mode."""
    os.environ.update(env)
    from launcher.workspace.packages import PackageIndex
    from launcher.params.rosyaml import dump_yaml
    from launcher.xml import load

    for mode in ("dump-params", "nodes"):
        prof = cProfile.Profile()
        t0 = time.perf_counter()
        prof.enable()
        config = load([main], [], environ=env, packages=PackageIndex(env), core=(mode != "dump-params"))
        if mode == "dump-params":
            dump_yaml({k: p.value for k, p in config.params.items()})
        else:
            "\n".join(n.full_name for n in config.nodes)
        prof.disable()
        elapsed = time.perf_counter() - t0
        buf = io.StringIO()
        pstats.Stats(prof, stream=buf).sort_stats("cumulative").print_stats(top)
        print("==== --%s in-process: %.3f s (profiled)\n%s" % (mode, elapsed, buf.getvalue()))
        buf = io.StringIO()
        pstats.Stats(prof, stream=buf).sort_stats("tottime").print_stats(top)
        print("==== --%s by own time\n%s" % (mode, buf.getvalue()))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reps", type=int, default=10)
    ap.add_argument("--modes", default="dump-params,nodes")
    ap.add_argument("--bench-dir", default=DEFAULT_BENCH_DIR, help="the shared bench (gen_tree.py, bench.py)")
    ap.add_argument("--nodes", type=int, default=1000)
    ap.add_argument("--params", type=int, default=5000)
    ap.add_argument("--leaves", type=int, default=20)
    ap.add_argument("--yaml-keys", type=int, default=2000)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--profile", action="store_true", help="profile our loader in-process instead of timing")
    ap.add_argument("--top", type=int, default=30)
    ap.add_argument("--shared-bench", action="store_true", help="also run the shared bench.py parse scenario")
    ap.add_argument("--keep", action="store_true", help="keep the generated tree")
    ap.add_argument("--no-compile", action="store_true", help="do not precompile our modules to .pyc first")
    args = ap.parse_args()

    if not args.no_compile:
        # Debian's roslaunch runs from precompiled .pyc files; a pip install compiles ours too,
        # but this environment sets PYTHONDONTWRITEBYTECODE, which would make every run of ours
        # compile all its modules again (~30 ms). Compare like with like.
        import compileall

        import launcher
        compileall.compile_dir(os.path.dirname(launcher.__file__), quiet=1)
    bench_dir = os.path.abspath(args.bench_dir)
    sys.path.insert(0, bench_dir)
    from gen_tree import generate

    work = tempfile.mkdtemp(prefix="parse-bench-")
    try:
        pkgs = os.path.join(work, "pkgs")
        main_file = generate(pkgs, nodes=args.nodes, params=args.params, leaves=args.leaves,
                             yaml_keys=args.yaml_keys, seed=args.seed)
        env = {k: v for k, v in os.environ.items() if not k.startswith("ROS_")}
        env.update(ROS_PACKAGE_PATH=pkgs, ROS_HOME=os.path.join(work, "home"))
        if args.profile:
            profile(main_file, env, args.top)
            return 0
        bench(args, main_file, env)
        if args.shared_bench:
            cmd = [sys.executable, os.path.join(bench_dir, "bench.py"), "parse", "--cmd", "roslaunch",
                   "--cmd", "new=" + " ".join(shlex.quote(a) for a in our_command()), "--reps", str(args.reps)]
            subprocess.run(cmd, env=dict(os.environ, PATH=ROS_PATH + ":" + os.environ.get("PATH", "")), check=False)
        return 0
    finally:
        if args.keep:
            print("tree kept in %s" % work, file=sys.stderr)
        else:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
