"""`vislam nees`: Monte Carlo consistency on the simulator. N runs of one simulated drive that
differ only in their noise draws; per estimator the ANEES of pose (6 dof) and landmarks (3 dof)
against truth, the two-sided 95 % chi-square bounds and a verdict; nees.json and nees.png."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

NEES_DEFAULT = ("ekf-joint", "ekf-invariant", "smoother")
#: Most Monte Carlo runs in one call (all runs' drives are held in memory).
MAX_RUNS = 2000
#: What ``vislam nees`` writes into its folder.
NEES_FILES = ("nees.json", "nees.png")
#: Longest landmark range of the simulated drive (m): the simulator places no landmark further
#: than 80 m ahead of the drive's end or 50 m to the side, and a 0.5 px disparity is 760 m deep.
MAX_SIM_DEPTH = 1000.0


def sim_depth_error(depth: float) -> str | None:
    """Why ``depth`` is not a usable simulated landmark range (None when it is)."""
    from vislam.eval.simulate import DEFAULT_SIM

    if DEFAULT_SIM.min_depth < depth <= MAX_SIM_DEPTH:
        return None
    return (f"must be above the simulator's min_depth {DEFAULT_SIM.min_depth:g} m and at most "
            f"{MAX_SIM_DEPTH:g} m, got {depth:g}")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from vislam.eval.commands.options import add_filter_arguments
    from vislam.eval.executors import add_executor_arguments
    from vislam.eval.montecarlo import DEFAULT_NEES_FRAMES
    from vislam.eval.simulate import DEFAULT_SIM

    parser.add_argument("--runs", "-n", type=int, required=True, metavar="N", help="Monte Carlo runs")
    parser.add_argument("--seed", type=int, default=0, help="seed of the drive (and of the noise)")
    parser.add_argument("--estimators", "-e", metavar="LIST",
                        help=f"comma-separated names or MODULE:FUNCTION (a user's estimator, "
                             f"eval/registry.py), or 'all' (default: {','.join(NEES_DEFAULT)})")
    parser.add_argument("--jobs", "-j", type=int, default=None, metavar="N",
                        help="worker processes (default: number of CPUs; with --executor dask "
                             "the workers of the cluster started here)")
    parser.add_argument("--frames", type=int, default=None, metavar="N",
                        help=f"length of the simulated drive (default {DEFAULT_NEES_FRAMES})")
    parser.add_argument("--sim-max-depth", type=float, default=None, metavar="M",
                        help=f"simulated landmarks up to M m deep (default {DEFAULT_SIM.max_depth:g})")
    parser.add_argument("--out", "-o", metavar="DIR",
                        help="output folder (default results/nees-<YYYYmmdd-HHMMSS>)")
    parser.add_argument("--force", action="store_true",
                        help="write into a non-empty folder vislam did not write (its files are "
                             "never replaced)")
    parser.add_argument("--quiet", "-q", action="store_true", help="no progress bar, no table")
    add_executor_arguments(parser)
    add_filter_arguments(parser)


def run(args: argparse.Namespace) -> int:
    import time

    from vislam.ekf.errors import InputError
    from vislam.eval import plots
    from vislam.eval.atomic import write_json
    from vislam.eval.commands.bench import EXIT_FAILURES
    from vislam.eval.commands.options import (
        environment_settings,
        filter_config_from_args,
        smoother_settings_from_args,
    )
    from vislam.eval.executors import check_executor, executor_settings
    from vislam.eval.montecarlo import monte_carlo_nees
    from vislam.eval.output_dir import OutputDir
    from vislam.eval.registry import estimators_from_flag
    from vislam.eval.signals import deferred

    estimators = estimators_from_flag(args.estimators, NEES_DEFAULT)
    config = filter_config_from_args(args)
    smoother = smoother_settings_from_args(args)
    if not 1 <= args.runs <= MAX_RUNS:
        raise InputError(f"--runs must be between 1 and {MAX_RUNS}, got {args.runs} (every run's "
                         "drive is built up front, about 1 MB each)")
    if args.frames is not None and args.frames < 2:
        raise InputError(f"--frames must be >= 2, got {args.frames}")
    depth = args.sim_max_depth
    if depth is not None and (why := sim_depth_error(depth)):
        raise InputError(f"--sim-max-depth {why}")
    jobs = args.jobs if args.jobs is not None else (os.cpu_count() or 1)
    if jobs < 1:
        raise InputError(f"--jobs must be >= 1, got {jobs}")
    executor = check_executor(args.executor, args.scheduler)
    jobs = min(jobs, args.runs * len(estimators))
    landmarks = "" if depth is None else f", landmarks up to {depth:g} m"
    out = Path(args.out) if args.out else Path("results") / time.strftime("nees-%Y%m%d-%H%M%S")

    t0 = time.perf_counter()
    with OutputDir(out, force=args.force, expected=NEES_FILES, inputs=[args.config]) as tmp:
        result = monte_carlo_nees(args.runs, args.seed, estimators, config, frames=args.frames,
                                  jobs=jobs, show_progress=not args.quiet, smoother=smoother,
                                  sim_max_depth=depth, executor=executor,
                                  scheduler=args.scheduler)
        result["settings"] = {**environment_settings(),
                              "executor": executor_settings(executor, args.scheduler, jobs)}
        with deferred():  # a signal waits until the files are written
            write_json(tmp / "nees.json", result)
            series = {n: r["nees_pose_over_time"] for n, r in result["estimators"].items()}
            plots.plot_nees(tmp / "nees.png", series, dof=6, n_runs=args.runs,
                            times=result["timestamps"],
                            title=f"Pose ANEES over {args.runs} Monte Carlo runs "
                                  f"({result['frames']} frames, seed {args.seed}{landmarks})")
    if not args.quiet:
        print(_table(result))
    print(f"wrote {out} in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    failed = {n: r for n, r in result["estimators"].items() if r["runs_failed"]}
    for n, r in failed.items():
        first = r["errors"][0] if r["errors"] else "no message"
        print(f"vislam nees: failed: {n}: {r['runs_failed']} of {args.runs} runs ({first})",
              file=sys.stderr)
    return EXIT_FAILURES if failed else 0


def _table(result: dict) -> str:
    def f(x):
        return "–" if x is None else f"{x:.2f}"

    lines = [
        f"ANEES over {result['runs']} runs ({result['frames']} frames)",
        "| estimator | ANEES pose | bounds | verdict | ANEES landmark | bounds | verdict |",
        "|---|---|---|---|---|---|---|",
    ]
    for n, r in result["estimators"].items():
        bp, bl = r["bounds_pose"], r["bounds_landmark"]
        lines.append(
            f"| {n} | {f(r['anees_pose'])} | [{bp[0]:.2f}, {bp[1]:.2f}] | {r['verdict_pose']} "
            f"| {f(r['anees_landmark'])} | [{bl[0]:.2f}, {bl[1]:.2f}] | {r['verdict_landmark']} |"
        )
    return "\n".join(lines)
