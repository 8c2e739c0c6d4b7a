"""`vislam inspect FILE [--gt FILE] [--check [--config TOML ...]]`: summarise a data file before
estimating.

Prints frames and timing, tracks and observations, the invalid observations the loader dropped
(partial or negative pixel coordinates, :mod:`eval.loader`), the repeated-observation events
and bad disparities that the cleaning step repairs (:mod:`ekf.cleaning`), far points, velocity
statistics, and whether ground truth was found. Either observation layout (dense or sparse) is
read; a drive of monocular tracks is summarised too (no cleaning or disparity lines), with a
line saying that the estimators refuse it.

``--check`` then solves the batch smoother under the settings (``--config`` and the estimator
flags, as ``vislam run`` takes them; a ``[model]`` table's extrinsic and gyro bias applied to
the data) and says where the velocities and the vision disagree beyond their noise, stretch by
stretch (:mod:`graph.data_check`): a wrong file is flagged before anyone trusts a score. The
estimator settings are accepted only with ``--check``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from vislam.ekf.cleaning import clean_sequence, find_repeat_events
from vislam.eval.groundtruth import find_ground_truth
from vislam.eval.loader import load_sequence_with_report, require_stereo

#: Depth (m) beyond which a point counts as far; its disparity is fsu * b / FAR_DEPTH px.
FAR_DEPTH = 80.0
#: Disparities (px) below this are "tiny" (depth sigma of tens of metres).
TINY_DISPARITY = 1.0
#: Event frames listed in full up to this many.
MAX_FRAMES_LISTED = 40
#: ``--check``: default length (s) of a stretch and the test level per stretch.
CHECK_STRETCH_S = 10.0
CHECK_LEVEL = 0.999


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", type=Path, help="drive in the data format (.npz)")
    parser.add_argument(
        "--gt", type=Path, default=None,
        help="ground-truth file (KITTI poses; for a raw-IMU drive ASL/OpenVINS csv or TUM); "
             "default DIR/groundtruth/NAME.txt (NAME.csv for a raw-IMU drive)",
    )
    parser.add_argument(
        "--check", action="store_true",
        help="also solve the smoother and check that velocities and vision agree within their "
             "noise, per stretch of the drive (takes as long as a smoother run)",
    )
    parser.add_argument(
        "--stretch", metavar="S", default=None,
        help=f"--check: length of a stretch in seconds (default {CHECK_STRETCH_S:g})",
    )
    from vislam.eval.commands.options import add_filter_arguments

    before = {a.dest for a in parser._actions}
    add_filter_arguments(parser)
    # The estimator settings mean something only to --check (run() refuses them otherwise).
    parser.set_defaults(_check_settings=tuple(
        a.dest for a in parser._actions if a.dest not in before) + ("stretch",))


def _mmm(values: np.ndarray, fmt: str = "{:.3g}") -> str:
    if values.size == 0:
        return "n/a"
    return "min {} / median {} / max {}".format(
        *(fmt.format(v) for v in (values.min(), np.median(values), values.max()))
    )


def _frames_text(frames: list[int]) -> str:
    if len(frames) <= MAX_FRAMES_LISTED:
        return " ".join(str(f) for f in frames)
    head = " ".join(str(f) for f in frames[:MAX_FRAMES_LISTED])
    return f"{head} ... ({len(frames) - MAX_FRAMES_LISTED} more)"


def summarise(path: Path, gt_path: Path | None = None) -> list[str]:
    """The lines ``vislam inspect`` prints."""
    return _summarise(path, gt_path)[0]


def _summarise(path: Path, gt_path: Path | None = None):
    """The lines ``vislam inspect`` prints, and the drive (stereo or monocular) they are of."""
    seq, load_report = load_sequence_with_report(path, monocular=True)
    stereo = seq.obs.is_stereo
    cal = seq.calibration
    lines = [f"file: {path}"]
    T = seq.n_frames
    dt = seq.dt
    duration = float(seq.timestamps[-1] - seq.timestamps[0])
    lines.append(f"frames: {T}, duration {duration:.2f} s")
    lines.append(f"dt (s): {_mmm(dt, '{:.4f}')}" if dt.size else "dt (s): n/a (one frame)")
    lines.append(
        f"calibration: fsu {cal.fsu:.2f} fsv {cal.fsv:.2f} cu {cal.cu:.2f} cv {cal.cv:.2f} "
        + (f"px, baseline {cal.baseline:.4f} m" if np.isfinite(cal.baseline) else "px, no baseline")
    )
    if not stereo:
        lines.append("camera: monocular tracks ([u, v]); vislam's estimators are stereo and "
                     "refuse this drive: it needs a raw-IMU estimator")

    lengths = seq.track_lengths()
    observed = lengths[lengths > 0]
    lines.append(
        f"tracks: {seq.n_tracks} ({observed.size} observed), observations {len(seq.obs)}"
    )
    if load_report.n_invalid:
        j, t = load_report.first_invalid
        lines.append(
            f"invalid observations: {load_report.n_invalid} dropped as unobserved "
            f"({load_report.n_partial} partial: one to three of uL, vL, uR, vR are -1; "
            f"{load_report.n_negative} with another negative coordinate), first at track {j}, "
            f"frame {t}"
        )
    else:
        lines.append("invalid observations: none (no partial or negative pixel coordinates)")
    lines.append(f"observations per frame: {_mmm(seq.obs.per_frame, '{:.0f}')}")
    lines.append(
        f"track lengths (frames): {_mmm(observed, '{:.0f}')}, "
        f"{int(np.sum(observed == 1))} of length 1"
    )

    events = find_repeat_events(seq)
    if stereo:  # the cleaning step and disparities are stereo
        lines += _stereo_lines(seq, events)
    else:
        lines.append(
            f"repeated-observation events: {len(events)} frames, "
            f"{sum(e.n_repeats for e in events)} repeats (tracks repeating their previous "
            "observation exactly)")
        if events:
            lines.append(f"  event frames: {_frames_text([e.frame for e in events])}")

    v = seq.linear_velocity
    w = seq.angular_velocity
    nv = np.linalg.norm(v, axis=1)
    nw = np.linalg.norm(w, axis=1)
    lines.append(
        f"|v| (m/s): mean {nv.mean():.3f} std {nv.std():.3f} max {nv.max():.3f}; "
        f"per-axis mean {np.array2string(v.mean(axis=0), precision=3)}"
    )
    lines.append(
        f"|w| (rad/s): mean {nw.mean():.4f} std {nw.std():.4f} max {nw.max():.4f}; "
        f"per-axis mean {np.array2string(w.mean(axis=0), precision=4)}"
    )

    gt = find_ground_truth(path, override=gt_path, calibration=cal, n_frames=T)
    if gt is None:
        lines.append("ground truth: none found")
    else:
        length = float(np.sum(np.linalg.norm(np.diff(gt.poses[:, :3, 3], axis=0), axis=1)))
        lines.append(
            f"ground truth: {gt.source}, covers {gt.covers(T)}, path length {length:.1f} m"
        )
    return lines, seq


def _stereo_lines(seq, events) -> list[str]:
    """The lines of a stereo drive's repeats, cleaning and disparities."""
    cal = seq.calibration
    _, report = clean_sequence(seq, min_disparity=TINY_DISPARITY)
    n_event_repeats = sum(e.n_repeats for e in events)
    lines = [
        f"repeated-observation events: {len(events)} frames, {n_event_repeats} repeats "
        f"(tracks repeating their previous observation exactly; {report.n_isolated_repeats} "
        "more outside events)"
    ]
    if events:
        lines.append(f"  event frames: {_frames_text([e.frame for e in events])}")
        lines.append(
            f"  repeats per event: {_mmm(np.array([e.n_repeats for e in events]), '{:.0f}')}; "
            f"new tracks per event: {_mmm(np.array([e.n_new for e in events]), '{:.0f}')}"
        )
    lines.append(
        f"  cleaning splits {report.n_tracks_split} tracks into {report.n_new_tracks} new ones, "
        f"dropping {report.n_repeats_found} repeated observations"
    )

    d = seq.obs.z[:, 0] - seq.obs.z[:, 2]
    far_disp = cal.fsu * cal.baseline / FAR_DEPTH
    n_nonpos = int(np.sum(d <= 0))
    n_tiny = int(np.sum((d > 0) & (d < TINY_DISPARITY)))
    n_far = int(np.sum((d >= TINY_DISPARITY) & (d < far_disp)))
    lines.append(
        f"bad disparities: {n_nonpos} non-positive (min {d.min():.1f} px), {n_tiny} tiny "
        f"(0 < d < {TINY_DISPARITY:g} px)" if d.size else "bad disparities: n/a"
    )
    lines.append(
        f"far points: {n_far} observations with disparity {TINY_DISPARITY:g}-{far_disp:.2f} px "
        f"(depth > {FAR_DEPTH:g} m)"
    )
    return lines


def _check_inputs(args: argparse.Namespace):
    """``--check``'s settings, every one checked before anything is printed:
    ``(config, smoother settings, model or None, stretch_s)``; InputError otherwise."""
    from vislam.ekf.errors import InputError
    from vislam.eval.commands.options import (
        filter_config_from_args,
        model_from_args,
        smoother_settings_from_args,
    )

    given = [d for d in getattr(args, "_check_settings", ())
             if getattr(args, d, None) not in (None, False)]
    if not args.check:
        if given:
            flag = "--" + given[0].replace("_", "-")
            raise InputError(f"{flag}: estimator settings are used only by the velocity check; "
                             "add --check, or leave them out")
        return None
    stretch = CHECK_STRETCH_S
    if args.stretch is not None:
        try:
            stretch = float(args.stretch)
        except ValueError:
            stretch = float("nan")
        if not (np.isfinite(stretch) and 0.0 < stretch <= 1e6):
            raise InputError(f"--stretch: must be a positive number of seconds, got "
                             f"{args.stretch!r}")
    config = filter_config_from_args(args)
    settings = smoother_settings_from_args(args).replace(compute_marginals=False)
    model = model_from_args(args)
    return config, settings, model, stretch


def check_lines(path: Path, config, settings, model=None, *, stretch_s: float = CHECK_STRETCH_S,
                level: float = CHECK_LEVEL) -> list[str]:
    """The lines of ``--check``: the drive solved by the smoother under ``config`` (a model's
    extrinsic and gyro bias applied to the data first) and its velocity check."""
    from vislam.ekf.model import model_sequence, per_interval_config
    from vislam.eval.loader import load_sequence
    from vislam.graph.data_check import velocity_check
    from vislam.graph.smoother import solve_smoother

    def fmt(values) -> str:
        return ",".join(f"{x:.3g}" for x in values)

    seq = load_sequence(path, clean=False)
    if model is not None:  # its noise model is in config already (filter_config_from_args)
        seq = model_sequence(seq, model)
        config = per_interval_config(config, model)  # the check reads one interval at a time
    solution = solve_smoother(seq, config, settings)
    check = velocity_check(solution, config, stretch_s=stretch_s, level=level)
    where = "the file's" if model is None else "the model's"
    head = (f"velocity check: smoother under velocity sigma {fmt(config.velocity_sigmas)} m/s, "
            f"gyro sigma {fmt(config.gyro_sigmas)} rad/s per interval, pairing "
            f"{config.velocity_pairing}, {where} extrinsic"
            + ("" if model is None or model.gyro_bias is None else ", the model's gyro bias"))
    return [head, *check.lines()]


def run(args: argparse.Namespace) -> int:
    from vislam.eval.inertial_files import is_inertial_file

    check = _check_inputs(args)
    if is_inertial_file(args.file):
        if check is not None:
            from vislam.ekf.errors import InputError

            raise InputError(f"{args.file}: --check compares velocities with vision; this is a "
                             "raw-IMU drive")
        from vislam.eval.commands.inspect_inertial import summarise_inertial

        print("\n".join(summarise_inertial(args.file, args.gt)))
        return 0
    lines, seq = _summarise(args.file, args.gt)
    if check is not None:
        require_stereo(seq, args.file)  # --check runs the (stereo) smoother
    for line in lines:
        print(line)
    if check is not None:
        config, settings, model, stretch = check
        sys.stdout.flush()  # the summary shows while the smoother runs
        for line in check_lines(args.file, config, settings, model, stretch_s=stretch):
            print(line)
    return 0
