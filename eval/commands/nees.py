"""`vislam nees`: Monte Carlo consistency on the simulator. N runs of one simulated drive that
differ only in their noise draws; per estimator the ANEES of pose (6 dof) and landmarks (3 dof)
against truth, the two-sided 95 % chi-square bounds and a verdict; nees.json and nees.png.
With ``--imu`` the drives are the raw-IMU simulator's (``--scenario``, ``--camera``, as
``vislam simulate --imu``) and the estimators those of raw-IMU drives (:mod:`eval.montecarlo_imu`)."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

NEES_DEFAULT = ("ekf-joint", "ekf-invariant", "smoother")
#: Flags of velocity drives and their estimators (the raw-IMU estimators read none of them):
#: refused with --imu.
VELOCITY_FLAGS = ("sim_max_depth", "config", "pixel_sigma", "velocity_sigma", "gyro_sigma",
                  "gate_probability", "no_clean", "velocity_pairing", "keep_landmarks",
                  "gyro_bias", "max_depth", "min_disparity", "landmarks", "pixel_reading",
                  "smoother_init", "gap_prior")
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
    from vislam.eval.imu_sim_config import CAMERAS
    from vislam.eval.imu_trajectories import SCENARIOS
    from vislam.eval.montecarlo import DEFAULT_NEES_FRAMES
    from vislam.eval.montecarlo_imu import DEFAULT_IMU_NEES_FRAMES
    from vislam.eval.registry import DEFAULT_BENCH_INERTIAL
    from vislam.eval.simulate import DEFAULT_SIM

    parser.add_argument("--runs", "-n", type=int, required=True, metavar="N", help="Monte Carlo runs")
    parser.add_argument("--seed", type=int, default=0,
                        help="seed of the drive: its trajectory, landmarks and tracks, the same in "
                             "every run; each run draws its own noise from [SEED, run]: velocity "
                             "and pixel noise on the velocity simulator (numpy default_rng), with "
                             "--imu the raw-IMU simulator's seed (numpy SeedSequence: biases, IMU "
                             "and pixel noise; nees.json lists them) (default 0)")
    parser.add_argument("--imu", action="store_true",
                        help="raw-IMU drives (accelerometer and gyro at 200 Hz, tracks at 20 Hz, "
                             "EuRoC's IMU noise: as vislam simulate --imu) and the raw-IMU "
                             "estimators, scored against the truth in each estimate's gauge as "
                             "vislam bench scores raw-IMU drives")
    parser.add_argument("--scenario", choices=SCENARIOS, default=None,
                        help="--imu: room (a drone), handheld or road (a car) (default room)")
    parser.add_argument("--camera", choices=CAMERAS, default=None,
                        help="--imu: one camera (mono) or a rectified stereo pair (default mono)")
    parser.add_argument("--estimators", "-e", metavar="LIST",
                        help=f"comma-separated names or MODULE:FUNCTION (a user's estimator, "
                             f"eval/registry.py), or 'all' (those of the drive's kind) (default: "
                             f"{','.join(NEES_DEFAULT)}; with --imu "
                             f"{','.join(DEFAULT_BENCH_INERTIAL)})")
    parser.add_argument("--jobs", "-j", type=int, default=None, metavar="N",
                        help="worker processes (default: number of CPUs; with --executor dask "
                             "the workers of the cluster started here)")
    parser.add_argument("--frames", type=int, default=None, metavar="N",
                        help=f"length of the simulated drive (default {DEFAULT_NEES_FRAMES}; with "
                             f"--imu {DEFAULT_IMU_NEES_FRAMES} camera frames at 20 Hz)")
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
    from vislam.eval.imu_sim_config import MAX_IMU_SIM_FRAMES
    from vislam.eval.montecarlo import monte_carlo_nees
    from vislam.eval.output_dir import OutputDir
    from vislam.eval.signals import deferred

    imu = bool(getattr(args, "imu", False))
    check_drive_flags(args)
    estimators = nees_estimators(args.estimators, imu)
    config = filter_config_from_args(args)
    smoother = smoother_settings_from_args(args)
    if not 1 <= args.runs <= MAX_RUNS:
        raise InputError(f"--runs must be between 1 and {MAX_RUNS}, got {args.runs} (every run's "
                         "drive is built up front, about 1 MB each)")
    if args.frames is not None and args.frames < 2:
        raise InputError(f"--frames must be >= 2, got {args.frames}")
    if imu and args.frames is not None and args.frames > MAX_IMU_SIM_FRAMES:
        raise InputError(f"--frames: at most {MAX_IMU_SIM_FRAMES} with --imu (the raw-IMU "
                         f"simulator's longest drive, 10 minutes at 20 Hz), got {args.frames}")
    depth = args.sim_max_depth
    if depth is not None and (why := sim_depth_error(depth)):
        raise InputError(f"--sim-max-depth {why}")
    jobs = args.jobs if args.jobs is not None else (os.cpu_count() or 1)
    if jobs < 1:
        raise InputError(f"--jobs must be >= 1, got {jobs}")
    executor = check_executor(args.executor, args.scheduler)
    jobs = min(jobs, args.runs * len(estimators))
    landmarks = "" if depth is None else f", landmarks up to {depth:g} m"
    if imu:
        landmarks = f", raw IMU: {args.scenario or 'room'}, {args.camera or 'mono'}"
    out = Path(args.out) if args.out else Path("results") / time.strftime("nees-%Y%m%d-%H%M%S")

    t0 = time.perf_counter()
    with OutputDir(out, force=args.force, expected=NEES_FILES, inputs=[args.config]) as tmp:
        result = monte_carlo_nees(args.runs, args.seed, estimators, config, frames=args.frames,
                                  jobs=jobs, show_progress=not args.quiet, smoother=smoother,
                                  sim_max_depth=depth, executor=executor,
                                  scheduler=args.scheduler, imu=imu,
                                  scenario=args.scenario or "room", camera=args.camera or "mono")
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


def check_drive_flags(args: argparse.Namespace) -> None:
    """InputError naming the first flag that does not apply to the drives asked for: a flag of
    velocity drives or their estimators with --imu, a raw-IMU flag without it."""
    from vislam.ekf.errors import InputError

    if getattr(args, "imu", False):
        for dest in VELOCITY_FLAGS:
            if getattr(args, dest, None) not in (None, False):
                raise InputError(f"--{dest.replace('_', '-')}: a setting of velocity drives; "
                                 "--imu simulates raw-IMU drives (EuRoC's IMU noise, one-pixel "
                                 "tracks) and runs their estimators, which read none of them")
        return
    for dest in ("scenario", "camera"):
        if getattr(args, dest, None) is not None:
            raise InputError(f"--{dest}: a setting of raw-IMU simulations; add --imu")


def nees_estimators(text: str | None, imu: bool) -> list:
    """The estimators of ``--estimators`` for velocity drives or, ``imu``, raw-IMU drives: the
    kind's default list when absent, every estimator of the kind for 'all'; InputError naming
    an estimator of the other kind."""
    from vislam.ekf.errors import InputError
    from vislam.eval.registry import (DEFAULT_BENCH_INERTIAL, INERTIAL_ESTIMATOR_NAMES,
                                      estimator_kind, estimators_from_flag)

    kind = "raw-imu" if imu else "velocity"
    estimators = estimators_from_flag(text, DEFAULT_BENCH_INERTIAL if imu else NEES_DEFAULT)
    if text is not None and text.strip() == "all":
        return [n for n in estimators if estimator_kind(n) == kind]
    for n in estimators:
        if estimator_kind(n) == kind:
            continue
        if imu:
            raise InputError(f"estimator {n!r} takes velocity drives; --imu runs the estimators "
                             f"of raw-IMU drives ({', '.join(INERTIAL_ESTIMATOR_NAMES)})")
        raise InputError(f"estimator {n!r} takes raw-IMU drives; add --imu")
    return estimators


def _table(result: dict) -> str:
    def f(x):
        return "–" if x is None else f"{x:.2f}"

    drive = result["simulation"]
    kind = (f", raw IMU: {drive['scenario']}, {drive['camera']}"
            if result.get("drive_kind") == "raw-imu" else "")
    lines = [
        f"ANEES over {result['runs']} runs ({result['frames']} frames{kind})",
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
