"""`vislam calibrate`: identify the noise model of a drive from the data alone (no ground truth).

EM around the batch smoother (:mod:`graph.identification`): per-axis velocity and gyro noise,
the stereo pixel noise, the velocity pairing with the largest likelihood, and a constant gyro
bias when a likelihood-ratio test supports one. Prints each value with its standard deviation
beside the settings it would replace, and writes the model as TOML (``--out``, the ``[model]``
table every command's ``--config`` reads).

The camera-IMU extrinsic is not identified by this version: the model keeps the file's
``cam_T_imu`` and says so (``cam_T_imu_sigma`` absent).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from eval.runjob import add_filter_arguments

    parser.add_argument("file", metavar="FILE.npz", help="the drive (.npz data file)")
    parser.add_argument("--out", "-o", metavar="MODEL.toml",
                        help="write the model here (a [model] table for --config)")
    parser.add_argument("--force", action="store_true",
                        help="replace --out even when it is a file vislam did not write")
    parser.add_argument("--pairings", metavar="LIST", default="current,next,mean",
                        help="velocity pairings to compare (default current,next,mean)")
    parser.add_argument("--max-iterations", type=int, default=12, metavar="N",
                        help="EM steps per pairing at most (default 12)")
    add_filter_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from ekf.config import VELOCITY_PAIRINGS
    from ekf.errors import InputError
    from ekf.model import Model
    from eval.atomic import write_text
    from eval.loader import load_sequence
    from eval.runjob import filter_config_from_args, smoother_settings_from_args
    from graph.identification import identify_noise

    config = filter_config_from_args(args)
    smoother = smoother_settings_from_args(args).replace(compute_marginals=False)
    pairings = tuple(p.strip() for p in args.pairings.split(",") if p.strip())
    bad = [p for p in pairings if p not in VELOCITY_PAIRINGS]
    if not pairings or bad:
        raise InputError(f"--pairings {args.pairings!r}: each must be one of "
                         f"{', '.join(VELOCITY_PAIRINGS)}")
    if not 3 <= args.max_iterations <= 1000:
        raise InputError(f"--max-iterations must be between 3 and 1000, got {args.max_iterations}")
    out = Path(args.out) if args.out else None
    if out is not None:
        _check_out(out, args.force)
    seq = load_sequence(args.file, clean=False)

    fit = identify_noise(seq, config, smoother, pairings=pairings,
                         max_iterations=args.max_iterations)
    model = Model(
        velocity_sigma=tuple(map(float, fit.velocity_sigma)),
        gyro_sigma=tuple(map(float, fit.gyro_sigma)),
        pixel_sigma=float(fit.pixel_sigma),
        velocity_pairing=fit.pairing,
        cam_T_imu=np.array(seq.calibration.cam_T_imu),
        gyro_bias=None if fit.gyro_bias is None else tuple(map(float, fit.gyro_bias)),
        gyro_bias_sigma=None if fit.gyro_bias_std is None else tuple(map(float, fit.gyro_bias_std)),
        source=f"vislam calibrate {Path(args.file).name} (EM around the smoother; the extrinsic "
               "is the file's, not identified)",
        file={"cam_T_imu": np.array(seq.calibration.cam_T_imu)},
    )
    print(report(seq.name, seq.n_frames, fit, config))
    if out is not None:
        write_text(out, model.to_toml())
        print(f"wrote {out}", file=sys.stderr)
    return 0


def _check_out(out: Path, force: bool) -> None:
    """``--out`` is a new file, or a model file vislam wrote (or ``--force``)."""
    from ekf.errors import InputError
    from ekf.model import MODEL_FILE_HEADER

    if out.is_dir():
        raise InputError(f"--out {out}: is a folder; give a file name such as model.toml")
    if out.exists() and not force:
        try:
            head = out.read_text(encoding="utf-8", errors="replace")[:len(MODEL_FILE_HEADER)]
        except OSError as exc:
            raise InputError(f"--out {out}: cannot read ({exc.strerror})") from None
        if head != MODEL_FILE_HEADER:
            raise InputError(f"--out {out}: exists and was not written by vislam; choose another "
                             "name, or --force to replace it")
    parent = out.parent if str(out.parent) else Path(".")
    if not parent.is_dir():
        raise InputError(f"--out {out}: folder {parent} does not exist")


def _fmt(values, digits: int = 4) -> str:
    return " ".join(f"{float(v):.{digits}g}" for v in np.atleast_1d(values))


def report(name: str, frames: int, fit, config) -> str:
    """The identified model beside the settings it replaces, and a verdict per quantity."""
    given_v, given_g = config.velocity_sigmas, config.gyro_sigmas
    lines = [
        f"calibrate {name} ({frames} frames): EM around the smoother, {fit.iterations} steps "
        f"({'converged' if fit.converged else 'NOT converged'}), {fit.seconds:.1f} s",
        "",
        "| quantity | identified | sigma | settings as given |",
        "|---|---|---|---|",
        f"| velocity sigma x y z (m/s) | {_fmt(fit.velocity_sigma)} | {_fmt(fit.velocity_sigma_std, 2)} "
        f"| {_fmt(given_v)} |",
        f"| gyro sigma x y z (rad/s) | {_fmt(fit.gyro_sigma)} | {_fmt(fit.gyro_sigma_std, 2)} "
        f"| {_fmt(given_g)} |",
        f"| pixel sigma (px) | {fit.pixel_sigma:.4g} | {fit.pixel_sigma_std:.2g} | {config.pixel_sigma:.4g} |",
        f"| gyro bias x y z (rad/s) | "
        f"{'none' if fit.gyro_bias is None else _fmt(fit.gyro_bias)} | "
        f"{'' if fit.gyro_bias_std is None else _fmt(fit.gyro_bias_std, 2)} | "
        f"{'estimated' if config.gyro_bias else 'off'} |",
        f"| velocity pairing | {fit.pairing} | | {config.velocity_pairing} |",
        "| cam_T_imu | not identified (the file's) | | |",
        "",
    ]
    t = fit.bias_test
    lines.append(f"gyro bias: likelihood ratio {t['statistic']:.1f} against {t['threshold']:.2f} "
                 f"(chi-square, 3 dof, {t['level']:.0%}): {t['decision']}")
    scores = ", ".join(f"{p} {s:.2f}" for p, s in sorted(fit.pairing_scores.items(), key=lambda x: x[1]))
    lines.append(f"velocity pairing: sum of log per-sample variance {scores} (lowest wins)")
    for what, found, given in (("velocity sigma", fit.velocity_sigma, given_v),
                               ("gyro sigma", fit.gyro_sigma, given_g),
                               ("pixel sigma", [fit.pixel_sigma], [config.pixel_sigma])):
        ratio = float(np.max(np.maximum(np.asarray(given) / found, np.asarray(found) / given)))
        if ratio > 1.5:
            lines.append(f"settings' {what} is {ratio:.1f}x off the data's: estimators given it "
                         "misweigh velocities against vision")
    return "\n".join(lines)
