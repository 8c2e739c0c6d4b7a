"""`vislam run`: one estimator on one sequence; trajectory, map, estimate, scores and the
benchmark's per-drive plots into a folder.

The output folder follows :mod:`eval.output_dir`: checked before the estimation starts, built
in a hidden staging folder and moved in only when every file is written; an error or an
interruption leaves nothing half-written, and no file vislam did not write is ever replaced.
The plots are drawn as ``vislam bench`` draws them (:func:`eval.drive_figures.sequence_figures`,
matplotlib's Agg canvas) into the same staging folder; as in the benchmark, a plot that fails
fails the command and nothing is written (the message says so, and ``--no-plots`` skips them).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from vislam.ekf.estimate import Estimate
from vislam.eval.atomic import write_json
from vislam.eval.commands.options import (
    add_align_argument,
    add_filter_arguments,
    environment_settings,
    filter_config_from_args,
    model_from_args,
    smoother_settings_from_args,
)
from vislam.eval.export import write_kitti, write_tum
from vislam.eval.registry import ESTIMATOR_NAMES

#: What ``vislam run`` writes into ``--out`` (write_run_outputs).
RUN_FILES = ("trajectory.tum", "trajectory.kitti", "map.npz", "estimate.npz", "metrics.json",
             "settings.json")
#: The plots ``vislam run`` can write besides (those of one estimator among the benchmark's
#: per-drive plots, eval.drive_figures.sequence_figures): the top-view trajectory and the map
#: (when the estimator maps landmarks) always; with ground truth, the error over distance and
#: the pose NEES over time. vs_smoother.png needs an EKF and a smoother on the same drive, so a
#: single estimator never draws it.
RUN_PLOTS = ("trajectories.png", "map.png")
RUN_PLOTS_WITH_TRUTH = ("error_over_distance.png", "nees.png")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", metavar="FILE.npz", help="the sequence (.npz data file)")
    parser.add_argument(
        "--estimator", "-e", required=True, metavar="NAME",
        help=f"one of: {', '.join(ESTIMATOR_NAMES)}, an installed plug-in, or MODULE:FUNCTION "
             "(a user's estimator, eval/registry.py)",
    )
    parser.add_argument("--out", "-o", required=True, metavar="DIR",
                        help="output folder: new, empty, or written by vislam before")
    parser.add_argument("--force", action="store_true",
                        help="write into a non-empty folder vislam did not write (its files are "
                             "never replaced)")
    parser.add_argument("--gt", metavar="FILE", help="ground-truth file (default: found next to FILE)")
    parser.add_argument("--quiet", "-q", action="store_true", help="no progress bar")
    parser.add_argument("--no-plots", dest="plots", action="store_false",
                        help="write no plots (by default: trajectories.png, map.png and, with "
                             "ground truth, error_over_distance.png and nees.png)")
    add_align_argument(parser)
    add_filter_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from vislam.eval.drives import landmark_truth_beside
    from vislam.eval.output_dir import OutputDir
    from vislam.eval.groundtruth import find_ground_truth
    from vislam.eval.loader import load_sequence
    from vislam.eval.registry import get_estimator
    from vislam.ekf.errors import InputError
    from vislam.ekf.model import model_sequence

    # Everything that can be wrong with the input is checked before anything is written.
    get_estimator(args.estimator)
    config = filter_config_from_args(args)
    smoother = smoother_settings_from_args(args)
    if args.gt is not None and not args.gt.strip():
        raise InputError("--gt: empty path; give a ground-truth file or leave --gt out")
    model = model_from_args(args)
    from vislam.eval.inertial_files import is_inertial_file

    if is_inertial_file(args.file):  # a raw-IMU drive: its own estimators, its own truth
        seq, gt = _raw_imu_drive(args, model)
    else:
        from vislam.eval.registry import DEFAULT_BENCH, estimator_kind

        if estimator_kind(args.estimator) == "raw-imu":
            raise InputError(f"{args.file}: a velocity drive; estimator {args.estimator!r} takes "
                             f"raw-IMU drives (velocity drives: {', '.join(DEFAULT_BENCH)}, ...)")
        seq = load_sequence(args.file, clean=False)
        if model is not None:  # the model's extrinsic and bias act on the data
            seq = model_sequence(seq, model)
        gt = find_ground_truth(args.file, override=args.gt,
                               cam_T_imu=None if model is None else model.cam_T_imu)
    plots = getattr(args, "plots", True)
    landmark_truth = landmark_truth_beside(args.file, seq) if plots else None
    inputs = [args.file, args.config, getattr(gt, "source", None) or args.gt]
    expected = [*RUN_FILES, *(_plot_files(gt) if plots else ())]
    out = OutputDir(args.out, force=args.force, inputs=inputs, expected=expected)
    with out as tmp:
        metrics = _estimate_and_write(args, seq, gt, config, smoother, model, tmp,
                                      plots=plots, landmark_truth=landmark_truth)
    print(_summary_line(metrics, args.out))
    return 0


def _raw_imu_drive(args, model):
    """A raw-IMU drive and its ground truth for ``vislam run`` (the estimator must be one of
    raw-IMU drives; a model file is for velocity drives)."""
    from vislam.ekf.errors import InputError
    from vislam.eval.inertial_files import load_inertial_drive
    from vislam.eval.inertial_truth import find_inertial_truth
    from vislam.eval.registry import INERTIAL_ESTIMATOR_NAMES, estimator_kind

    if estimator_kind(args.estimator) != "raw-imu":
        raise InputError(f"{args.file}: a raw-IMU drive; estimator {args.estimator!r} takes velocity "
                         f"drives (raw-IMU drives: {', '.join(INERTIAL_ESTIMATOR_NAMES)})")
    if model is not None:
        raise InputError(f"{args.file}: a raw-IMU drive; a [model] table is for velocity drives")
    drive = load_inertial_drive(args.file)
    truth = find_inertial_truth(args.file, drive, args.gt)
    return drive, None if truth is None else truth.truth


def _plot_files(gt) -> tuple[str, ...]:
    """The plots a run may write (checked for clashes before the estimation starts)."""
    return (*RUN_PLOTS, *(RUN_PLOTS_WITH_TRUTH if gt is not None else ()))


def _write_plots(tmp: Path, args, seq, gt, est, landmark_truth) -> list[Path]:
    """The benchmark's per-drive plots of this one estimator into ``tmp``. A failure is the
    command's (as in ``vislam bench``): the error goes up with a note, and nothing is written."""
    from vislam.eval.drive_figures import sequence_figures
    from vislam.eval.drives import BenchSequence

    bs = BenchSequence(name=seq.name, path=str(Path(args.file).resolve()), sequence=seq, gt=gt,
                       landmark_truth=landmark_truth)
    try:
        return sequence_figures(tmp, bs, {args.estimator: est})
    except Exception as exc:
        exc.add_note("vislam run: drawing the plots failed, so nothing was written; "
                     "--no-plots writes the results without them")
        raise


def _estimate_and_write(args, seq, gt, config, smoother, model, tmp: Path, *, plots: bool = True,
                        landmark_truth: np.ndarray | None = None) -> dict:
    from vislam.eval.bench_scores import (RPE_DEFINITION, default_alignment, trajectory_scores,
                                          truth_in_gauge)
    from vislam.eval.progress import Progress
    from vislam.eval.signals import deferred
    from vislam.eval.study import run_estimator

    with Progress(f"{args.estimator} {seq.name}", total=seq.n_frames, enabled=not args.quiet) as bar:
        job = run_estimator(seq, args.estimator, config, progress=bar, smoother=smoother)
    est = job.estimate
    metrics = {
        "sequence": seq.name,
        "estimator": args.estimator,
        "frames": seq.n_frames,
        "runtime_s": job.wall_s,
        "frames_per_s": seq.n_frames / job.wall_s if job.wall_s > 0 else None,
        "landmarks": int(np.count_nonzero(est.has_landmark)),
        "numerical_rejections": int(est.info.get("numerical_rejections", 0)),
        "has_ground_truth": gt is not None,
        **trajectory_scores(est, truth_in_gauge(gt, seq, est),
                            align=default_alignment(getattr(args, "align", None), seq)),
        "rpe_definition": RPE_DEFINITION,
    }
    settings = {
        "input": str(Path(args.file).resolve()),
        "ground_truth": _gt_path(gt, args.gt),
        "ground_truth_extrinsic": None if gt is None else getattr(gt, "extrinsic_source", "file"),
        "model": None if model is None else model.to_dict(),
        "estimator": args.estimator,
        "filter": config.to_dict(),
        "alignment": metrics["alignment"],
        **({"smoother": smoother.to_dict()} if args.estimator.startswith("smoother") else {}),
        **environment_settings(),
    }
    with deferred():  # a signal waits until the files are written (matplotlib's C code too)
        write_run_outputs(tmp, seq, est, metrics, settings)
        if plots:
            _write_plots(tmp, args, seq, gt, est, landmark_truth)
    return metrics


def _gt_path(gt, override) -> str | None:
    if gt is None:
        return None
    path = getattr(gt, "source", None) or getattr(gt, "path", None) or override
    return str(path) if path is not None else None


def _summary_line(m: dict, out: str) -> str:
    def fmt(x, unit=""):
        return "n/a" if x is None else f"{x:.3f}{unit}"

    return (
        f"{m['estimator']} on {m['sequence']}: {m['frames']} frames in {m['runtime_s']:.2f} s; "
        f"ATE {fmt(m['ate_m'], ' m')} (aligned, {m.get('alignment', 'se3')}: "
        f"{fmt(m['ate_aligned_m'], ' m')}), "
        f"pose NEES {fmt(m['nees_pose_mean'])}; wrote {out}"
    )


def write_map_npz(path: Path, est: Estimate) -> None:
    """Landmark positions (M, 3), 3x3 covariances and the source column of each track."""
    origin = est.info.get("track_origin")
    origin = (
        np.asarray(origin, dtype=np.int64)
        if origin is not None
        else np.arange(est.landmarks.shape[0], dtype=np.int64)
    )
    with open(path, "wb") as fh:
        np.savez_compressed(
            fh,
            landmarks=est.landmarks,
            landmark_cov=est.landmark_cov,
            track_origin=origin,
            has_landmark=est.has_landmark,
        )


def write_run_outputs(out_dir: Path, seq, est: Estimate, metrics: dict, settings: dict) -> None:
    """trajectory.tum, trajectory.kitti, map.npz, estimate.npz, metrics.json, settings.json."""
    out_dir = Path(out_dir)
    write_tum(out_dir / "trajectory.tum", est.timestamps, est.poses)
    write_kitti(out_dir / "trajectory.kitti", est.poses)
    write_map_npz(out_dir / "map.npz", est)
    est.save_npz(out_dir / "estimate.npz")
    write_json(out_dir / "metrics.json", metrics)
    write_json(out_dir / "settings.json", settings)
