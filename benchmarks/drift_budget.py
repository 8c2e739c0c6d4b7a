"""Where an estimator's drift comes from, against ground truth, under the identified model.

    .venv/bin/python benchmarks/drift_budget.py [FILE.npz] [--estimators a,b] [--set NAME=VALUE ...]

Issue 13 asks why the smoother's covariance is too small on real drives. This script prints,
for one drive with ground truth (default: the shared 0027) under the model `vislam bench`
identifies (cached), per estimator:

* the mean pose NEES and its translation and rotation parts (3 dof each), and the rotation
  error at the last frame beside the estimator's own sigma;
* the errors of the estimated interval motions (:func:`eval.metrics.interval_errors`), split
  into intervals no track spans (the repeat events' gaps, where only the velocity and, in the
  smoother, the twist-smoothness prior bridge) and intervals vision spans: their mean (the
  systematic part: it adds up coherently, shown summed over the intervals in degrees) and rms
  (the random part), and how much too large the estimated turns are (a turn-scale error:
  the rotation error along the true rotation per unit of rotation, :func:`eval.metrics.
  turn_scale_error`; it adds up with the drive's net turn, printed in the header);
* the velocity and gyro errors of the data against the ground truth's interval twists, under
  the model's pairing: their spread beside the model's interval sigma, lag-1 and lag-2
  autocorrelation, and the long-run variance over that of one interval (sums of 16 intervals;
  1 for white interval noise, 2 for the "mean" pairing's MA(1) of white samples).

``--set`` changes a SmootherSettings field for the smoothers (e.g. gap_twist_prior=off).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from vislam.ekf.cleaning import clean_sequence
from vislam.ekf.config import FilterConfig
from vislam.ekf.geometry import se3_inv, se3_log
from vislam.eval.drives import identify_models, load_bench_sequence
from vislam.eval.consistency import pose_nees
from vislam.eval.datasets import drive_path
from vislam.eval.metrics import interval_errors, pose_errors, turn_scale_error
from vislam.eval.registry import get_estimator
from vislam.graph.factors import interval_twists, unconstrained_intervals, usable_rows
from vislam.graph.settings import SmootherSettings

LONG_RUN_WINDOW = 16  # intervals summed for the long-run variance


def motions(poses: np.ndarray, k: np.ndarray) -> np.ndarray:
    """The motions ``se3_log(P_k^-1 P_k+1)`` (n, 6) of the intervals starting at ``k``."""
    return se3_log(se3_inv(poses[k]) @ poses[k + 1])


def part_nees(est, frames, gt_poses, rows: slice) -> float:
    """Mean NEES of the translation (rows 0:3) or rotation (3:6) part over frames 1..."""
    xi = pose_errors(est.poses[frames], gt_poses)[1:, rows]
    P = est.pose_cov[frames][1:, rows, rows]
    return float(np.nanmean(np.einsum("ki,ki->k", xi, np.linalg.solve(P, xi[..., None])[..., 0])))


def drift_lines(name, est, gt, gaps: np.ndarray) -> list[str]:
    frames = gt.frames
    nees = np.nanmean(pose_nees(est, frames, gt.poses)[1:])
    last = frames[-1]
    rot_err = np.degrees(pose_errors(est.poses[last][None], gt.poses[-1][None])[0, 3:])
    rot_sd = np.degrees(np.sqrt(np.diag(est.pose_cov[last])[3:]))
    out = [f"{name}: pose NEES {nees:.1f} (translation {part_nees(est, frames, gt.poses, slice(0, 3)):.1f}, "
           f"rotation {part_nees(est, frames, gt.poses, slice(3, 6)):.1f}; 3 dof each); last frame "
           f"rotation error {np.round(rot_err, 2).tolist()} deg, sigma {np.round(rot_sd, 2).tolist()} deg"]
    consecutive = np.flatnonzero(np.diff(frames) == 1)  # intervals [k, k+1] with truth at both
    e = interval_errors(est.poses[frames], gt.poses)[consecutive]
    true = motions(gt.poses, consecutive)
    gap = gaps[frames[consecutive]]
    for label, sel in (("gaps", gap), ("vision", ~gap)):
        if not sel.any():
            continue
        rot, trans = e[sel, 3:], e[sel, :3]
        k, k_sd = turn_scale_error(e[sel], true[sel])
        out.append(
            f"  {label:6s} {int(sel.sum()):5d} intervals: rotation mean {np.round(1e3 * rot.mean(0), 3).tolist()} "
            f"rms {np.round(1e3 * np.sqrt((rot ** 2).mean(0)), 2).tolist()} mrad, summed mean "
            f"{np.round(np.degrees(rot.sum(0)), 2).tolist()} deg; turns {100 * k:+.2f} % "
            f"(+-{100 * k_sd:.2f}) too large; translation rms "
            f"{np.round(1e2 * np.sqrt((trans ** 2).mean(0)), 2).tolist()} cm")
    return out


def velocity_lines(seq, config: FilterConfig, gt) -> list[str]:
    frames = gt.frames
    k = np.flatnonzero(np.diff(frames) == 1)
    twist, tau = interval_twists(seq, config.velocity_pairing)
    f0 = frames[k]
    true = motions(gt.poses, k)  # the true interval motions
    err = twist[f0] - true / tau[f0][:, None]
    sigma = np.r_[config.velocity_sigmas, config.gyro_sigmas]
    w = LONG_RUN_WINDOW
    n = err.shape[0] // w
    sums = err[: n * w].reshape(n, w, 6).sum(axis=1)
    long_run = sums.var(axis=0) / w / err.var(axis=0) if n > 1 else np.full(6, np.nan)

    def lag(j):
        return [float(np.corrcoef(err[:-j, a], err[j:, a])[0, 1]) for a in range(6)]

    def fmt(x, d=3):
        return np.round(np.asarray(x, dtype=float), d).tolist()

    return [f"velocity errors against the ground truth (pairing {config.velocity_pairing}; "
            f"vx vy vz m/s, wx wy wz rad/s):",
            f"  spread {fmt(err.std(axis=0), 4)}; model's interval sigma {fmt(sigma, 4)}",
            f"  autocorrelation lag 1 {fmt(lag(1), 2)}, lag 2 {fmt(lag(2), 2)}",
            f"  long-run variance / interval variance ({w} intervals) {fmt(long_run, 2)}"]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("path", nargs="?", type=Path, default=drive_path("0027"))
    ap.add_argument("--estimators", default="ekf-invariant,smoother")
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                    help="a SmootherSettings field for the smoothers (repeatable)")
    args = ap.parse_args(argv)
    settings = SmootherSettings()
    for item in args.set:
        key, _, text = item.partition("=")
        kind = type(getattr(settings, key))
        settings = settings.replace(**{key: text.lower() in ("1", "true", "yes") if kind is bool
                                       else kind(text)})
    (bs,) = identify_models([load_bench_sequence(args.path)], FilterConfig(), SmootherSettings())
    if bs.gt is None:
        raise SystemExit(f"{args.path}: no ground truth beside it (groundtruth/NAME.txt)")
    config = bs.config
    cleaned, _ = clean_sequence(bs.sequence, min_disparity=config.min_disparity)
    rows, _ = usable_rows(cleaned, config.min_disparity)
    gaps = unconstrained_intervals(rows, cleaned.n_frames)
    net_turn = np.degrees(motions(bs.gt.poses, np.arange(bs.gt.n - 1))[:, 3:].sum(axis=0))
    print(f"{args.path}: {bs.sequence.n_frames} frames, {int(gaps.sum())} intervals no track spans; "
          f"net turn {np.round(net_turn, 1).tolist()} deg; model: {bs.model['mode']}; "
          f"smoother settings changed: {args.set or 'none'}")
    initial = get_estimator("ekf-invariant")(bs.sequence, config)
    for name in args.estimators.split(","):
        est = initial if name == "ekf-invariant" else get_estimator(name)(
            bs.sequence, config, initial=initial, smoother=settings)
        print("\n".join(drift_lines(name, est, bs.gt, gaps)))
    print("\n".join(velocity_lines(bs.sequence, config, bs.gt)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
