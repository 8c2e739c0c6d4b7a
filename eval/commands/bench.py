"""`vislam bench`: every estimator on every sequence; results.json, summary.md, TUM
trajectories and figures in one folder (default ``results/<YYYYmmdd-HHMMSS>/``, with
``results/latest`` pointing at it).

Without PATH the simulator's default drive (seed 0, ``--frames`` steps) is benchmarked, with
its exact ground truth and true landmarks.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

#: Exit code when the benchmark finished and wrote its results but an estimator failed.
EXIT_FAILURES = 3


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from vislam.eval.commands.options import (
        add_align_argument,
        add_filter_arguments,
        add_model_argument,
    )
    from vislam.eval.drives import DEFAULT_BENCH_FRAMES
    from vislam.eval.executors import add_executor_arguments
    from vislam.eval.registry import DEFAULT_BENCH, ESTIMATOR_NAMES

    parser.add_argument("paths", nargs="*", metavar="PATH", help=".npz files or folders of them")
    parser.add_argument("--out", "-o", metavar="DIR",
                        help="output folder (default results/<YYYYmmdd-HHMMSS>, linked as results/latest)")
    parser.add_argument("--force", action="store_true",
                        help="write into a non-empty folder vislam did not write (its files are "
                             "never replaced)")
    parser.add_argument("--estimators", "-e", metavar="LIST",
                        help=f"comma-separated names, or MODULE:FUNCTION for a user's estimator "
                             f"(eval/registry.py), or 'all' (default: {','.join(DEFAULT_BENCH)}; "
                             f"all: {','.join(ESTIMATOR_NAMES)} and installed plug-ins)")
    parser.add_argument("--jobs", "-j", type=int, default=None, metavar="N",
                        help="worker processes (default: number of CPUs; with --executor dask "
                             "the workers of the cluster started here)")
    parser.add_argument("--frames", type=int, default=None, metavar="N",
                        help=f"length of the default simulated drive (default {DEFAULT_BENCH_FRAMES})")
    parser.add_argument("--seed", type=int, default=0, help="seed of the default simulated drive")
    parser.add_argument("--quiet", "-q", action="store_true", help="no progress bars, no table")
    add_model_argument(parser)
    add_executor_arguments(parser)
    add_align_argument(parser)
    add_filter_arguments(parser)


def drives_under_model(args: argparse.Namespace, sequences: list, config, smoother, model) -> list:
    """``sequences`` (eval.drives.BenchSequence) under the model the options ask for: the
    [model] table of --config (``model``, eval.commands.options.model_from_args) as it is, else
    ``--model identify`` (said on stderr unless --quiet: it takes a while once per drive)
    or ``as-given``."""
    from vislam.eval.drives import apply_model_to, as_given, identify_models
    from vislam.eval.model_cache import cache_dir

    if model is not None:
        return apply_model_to(sequences, model, None, "config", {"source": str(args.config)})
    if args.model == "identify":
        def announce(bs) -> None:
            if not args.quiet:
                print(f"identifying the model of {bs.name} from its data (once: kept in "
                      f"{cache_dir()})", file=sys.stderr)
        return identify_models(sequences, config, smoother, on_start=announce)
    return as_given(sequences)


def run(args: argparse.Namespace) -> int:
    from vislam.ekf.errors import InputError
    from vislam.eval.bench_output import default_out_dir, run_benchmark
    from vislam.eval.commands.options import (
        environment_settings,
        filter_config_from_args,
        model_from_args,
        smoother_settings_from_args,
    )
    from vislam.eval.drives import collect_sequences
    from vislam.eval.executors import check_executor, executor_settings
    from vislam.eval.registry import DEFAULT_BENCH, DEFAULT_BENCH_INERTIAL, estimators_from_flag

    # each drive runs the estimators of its kind (velocity or raw-IMU drives)
    estimators = estimators_from_flag(args.estimators, DEFAULT_BENCH + DEFAULT_BENCH_INERTIAL)
    config = filter_config_from_args(args)
    smoother = smoother_settings_from_args(args)
    if args.frames is not None and args.frames < 2:
        raise InputError(f"--frames must be >= 2, got {args.frames}")
    if args.frames is not None and args.paths:
        raise InputError("--frames sets the length of the default simulation; give no PATH with it")
    jobs = args.jobs if args.jobs is not None else (os.cpu_count() or 1)
    if jobs < 1:
        raise InputError(f"--jobs must be >= 1, got {jobs}")
    executor = check_executor(args.executor, args.scheduler)
    model = model_from_args(args)
    sequences = drives_under_model(
        args, collect_sequences(args.paths, frames=args.frames, seed=args.seed), config,
        smoother, model)
    jobs = min(jobs, len(sequences) * len(estimators))

    if args.out:
        out, latest = Path(args.out), None
    else:
        out = default_out_dir(Path("results"))
        latest = Path("results") / "latest"
    result = run_benchmark(
        sequences, estimators, config, out, jobs=jobs, show_progress=not args.quiet,
        settings={**environment_settings(), "model_mode": "config" if model is not None
                  else args.model,
                  "executor": executor_settings(executor, args.scheduler, jobs)},
        latest_link=latest, smoother=smoother, force=args.force,
        extra_inputs=(args.config,), align=getattr(args, "align", None),
        executor=executor, scheduler=args.scheduler,
    )
    if not args.quiet:
        print(result.summary)
    print(f"wrote {result.out_dir} in {result.wall_s:.1f} s", file=sys.stderr)
    for line in result.failures:
        print(f"vislam bench: failed: {line}", file=sys.stderr)
    return EXIT_FAILURES if result.failures else 0
