"""`vislam calibrate FILE` on a raw-IMU drive: the camera-IMU time offset by maximum likelihood
around the raw-IMU smoother (:mod:`graph.inertial_time_offset`), then the IMU's noise densities
and bias random walks and the pixel sigma by EM around it (:mod:`graph.inertial_identification`)
on the drive with the offset applied, then the offset again under the identified figures.

The offset comes first because an IMU misplaced in time makes its factors' residuals look like
noise, which EM would read as a noisier IMU; it is checked again under the identified figures
(the first one's sigma is that of the data sheet's figures; skipped when the figures written
are the sheet's) and the two add up. An offset the
BIC does not support stays zero. The report gives the estimate, its sigma, the likelihood ratio
against zero and the decision for each pass, and the total.

Prints the data sheet's figures (the file's ``imu_noise``) beside the identified ones, with each
one's standard deviation and the ratio, the figures the drive cannot determine (kept at the
sheet's), and the smoother's IMU and pixel statistics under the identified model.

Whether the identified figures are to be used is said first and plainly: a figure EM did not
settle (still moving at its last step) and, when the smoother does not find the identified
model's solution from its own initial values, every figure, keeps the sheet's value in what is
written (``ImuNoiseFit.usable``, :mod:`graph.inertial_identification`), named with the reason.

``--out DRIVE.npz`` writes the drive again with the usable figures as its ``imu_noise`` and its
IMU stamps moved onto the camera's clock by the kept offset (:func:`ekf.inertial.
imu_on_camera_clock`; camera frames the moved IMU no longer covers are dropped, and said): the
raw-IMU estimators (the smoother, the EKFs, dead reckoning) read the IMU noise from the drive
file, and the ``[model]`` table of ``--config`` holds velocity-drive settings only, so that is
the route a raw-IMU model has. The pixel sigma is printed, not written (the drive file has no
key for it; the smoother identifies it from the residuals on every run). The camera-IMU
extrinsic is not identified or tested for raw-IMU drives (the module docstring of
:mod:`graph.inertial_identification` says why); the report says so.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

#: The figures' printed names and units.
LABELS = {
    "gyro_noise_density": "gyro noise density (rad/s/sqrt(Hz))",
    "gyro_random_walk": "gyro random walk (rad/s^2/sqrt(Hz))",
    "accel_noise_density": "accel noise density (m/s^2/sqrt(Hz))",
    "accel_random_walk": "accel random walk (m/s^3/sqrt(Hz))",
    "pixel_sigma": "pixel sigma (px; the smoother's start)",
}


def check_out(out: Path, force: bool) -> None:
    """``--out`` for a raw-IMU drive: a ``.npz`` in an existing folder, new unless ``--force``."""
    from vislam.ekf.errors import InputError

    if out.suffix != ".npz":
        raise InputError(f"--out {out}: a raw-IMU drive's model is written as a drive file with the "
                         "identified imu_noise; give a name ending in .npz")
    if out.is_dir():
        raise InputError(f"--out {out}: is a folder; give a file name such as drive-identified.npz")
    if out.exists() and not force:
        raise InputError(f"--out {out}: exists; choose another name, or --force to replace it")
    parent = out.parent if str(out.parent) else Path(".")
    if not parent.is_dir():
        raise InputError(f"--out {out}: folder {parent} does not exist")


def run_raw_imu(args: argparse.Namespace) -> int:
    """The command on a raw-IMU drive (module docstring)."""
    from vislam.ekf.errors import InputError
    from vislam.ekf.inertial import imu_on_camera_clock
    from vislam.eval.inertial_files import load_inertial_drive, save_inertial_drive
    from vislam.graph.inertial_identification import identify_imu_noise, with_noise
    from vislam.graph.inertial_time_offset import identify_imu_time_offset, too_short

    if not 1 <= args.max_iterations <= 1000:
        raise InputError(f"--max-iterations must be between 1 and 1000, got {args.max_iterations}")
    out = Path(args.out) if args.out else None
    if out is not None:
        check_out(out, args.force)
    drive = load_inertial_drive(args.file)
    short = too_short(drive)
    first = identify_imu_time_offset(drive) if short is None else None
    moved, head, tail = imu_on_camera_clock(drive, first.offset if first is not None else 0.0)
    fit = identify_imu_noise(moved, max_iterations=args.max_iterations)
    # again under the figures written, when they are not the sheet's that the first pass used
    second = (identify_imu_time_offset(with_noise(moved, fit.usable))
              if first is not None and fit.usable is not None
              and fit.usable != drive.calibration.noise else None)
    total = (first.offset if first is not None else 0.0) + (second.offset if second is not None else 0.0)
    if second is not None and second.offset:
        moved, head, tail = imu_on_camera_clock(drive, total)
    print(report(drive.name, drive.n_frames, fit))
    print(offset_report(first, second, total, head, tail) if first is not None else
          f"\ncamera-IMU time offset: not estimated ({short}); none applied")
    if out is not None:
        save_inertial_drive(out, with_noise(moved, fit.usable))
        kept = fit.withheld + fit.undetermined
        print(f"wrote {out} (the drive with the identified imu_noise"
              + (f"; the sheet's for {', '.join(kept)}" if kept else "")
              + (f"; its IMU stamps moved by {-1e3 * total:+.2f} ms onto the camera's clock"
                 if total else "") + ")", file=sys.stderr)
    return 0


def offset_report(first, second, total: float, head: int, tail: int) -> str:
    """The camera-IMU time offset's lines: each pass, the total, and the frames it drops."""
    lines = ["", "camera-IMU time offset (imu_time_offset, positive: the IMU's stamps late "
             "against the camera's), by maximum likelihood around the raw-IMU smoother:",
             f"- under the data sheet's figures ({first.frames_used} frames, "
             f"{first.seconds:.1f} s): {first.words()}"]
    if second is not None:
        lines.append(f"- again under the identified figures written ({second.seconds:.1f} s): "
                     f"{second.words()}")
    if total:
        dropped = (f"; {head} frame(s) at the start and {tail} at the end fall outside the moved "
                   "IMU and are left out" if head or tail else "")
        lines.append(f"applied: {1e3 * total:+.2f} ms (the IMU's stamps moved onto the camera's "
                     f"clock in what is written{dropped})")
    else:
        lines.append("applied: none")
    return "\n".join(lines)


def verdict(fit) -> str:
    """One plain line: whether the identified figures can be used, and if not which and why."""
    from vislam.graph.inertial_identification import COLD_START_NEES

    if fit.trusted:
        kept = (f"; the drive does not determine {', '.join(fit.undetermined)}: the sheet's kept"
                if fit.undetermined else "")
        return ("identified figures: usable (EM converged and the smoother finds their solution "
                f"from its own initial values{kept})")
    why = []
    if fit.unconverged:
        why.append(f"EM had not settled {', '.join(fit.unconverged)} after {fit.iterations} steps")
    if fit.undetermined_at_end:
        why.append(f"the posterior holds over 99 % of the residuals of {', '.join(fit.undetermined_at_end)} "
                   "at the model EM reached")
    if fit.cold_start_nees > COLD_START_NEES:
        why.append(f"the smoother under the identified figures, started from its own initial values, "
                   f"lands {fit.cold_start_nees:.3g} squared sigmas a frame from their solution "
                   f"(allowed {COLD_START_NEES:g}): a different minimum")
    return (f"identified figures: NOT to be trusted as a whole ({'; '.join(why)}); the sheet's value "
            f"is kept (and written) for {', '.join(fit.withheld + fit.undetermined)}")


def report(name: str, frames: int, fit) -> str:
    """The sheet's figures beside the identified ones (module docstring)."""
    lines = [f"calibrate {name} ({frames} frames, raw IMU): EM around the raw-IMU smoother, "
             f"{fit.iterations} steps ({'converged' if fit.converged else 'NOT converged'}), "
             f"{fit.seconds:.1f} s", "",
             verdict(fit), "",
             "| quantity | data sheet (file) | identified | sigma | identified / sheet | written |",
             "|---|---|---|---|---|---|"]
    usable = dict(zip(LABELS, fit.usable.as_array())) if fit.usable is not None else {}
    for key, sheet, value, sd, ratio in fit.rows():
        sd_text = "undetermined" if not np.isfinite(sd) else f"{sd:.2g}"
        written = (("sheet's" if usable[key] == sheet else "identified") if key in usable
                   else "not written")
        lines.append(f"| {LABELS[key]} | {sheet:.4g} | {value:.4g} | {sd_text} | {ratio:.3g} | {written} |")
    lines.append("")
    if fit.undetermined:
        lines.append(f"the drive cannot determine {', '.join(fit.undetermined)} (the posterior holds "
                     "over 99 % of its expected residuals): the sheet's figure is kept")
    share = ", ".join(f"{k} {m:.3f}" for k, m in zip(LABELS, fit.missing_share))
    lines.append(f"share of each figure's expected squared residuals the posterior holds: {share}")
    info = fit.result.info if fit.result is not None else {}
    if "imu_noise_em_scale" in info:
        lines.append(f"IMU factors under the identified model: mean chi2 {info['imu_chi2_mean']:.2f} + "
                     f"leverage {info['imu_leverage_mean']:.2f} of 15")
    for key, ratio in zip(LABELS, fit.ratio):
        if key not in fit.undetermined + fit.withheld and max(ratio, 1.0 / ratio) > 1.5:
            lines.append(f"the sheet's {key} is {max(ratio, 1.0 / ratio):.1f}x off the data's: the "
                         "raw-IMU estimators given it misweigh the IMU against vision")
    lines.append("camera-IMU extrinsic: not checked for raw-IMU drives (the file's is used; "
                 "graph.inertial_identification says why)")
    return "\n".join(lines)
