"""What a drive's own data say about its stereo baseline: the profile Gauss-Newton step of log b.

    .venv/bin/python benchmarks/baseline_step.py FILE.npz [--white] [--file-extrinsic] [--steps N]

At the drive's identified model (`vislam calibrate`'s, from the cache), the smoother is solved and
the stereo rows' whitened Jacobian on log b (only uR moves: d uR / d log b = -f b / Z) is profiled
over the poses and landmarks (graph.out_of_sample.profile_rows, as graph.radial profiles its lens
term); the step and its sigma are printed, and the step is taken and solved again ``--steps``
times. Nothing but the velocities sets the metric scale against which the baseline is
measured, so the step is the stereo scale relative to the velocities' (a speed-scale error
of the velocities shows here too).

``--white``: the white noise levels EM identified (no long-run sigmas for the velocities, gyro
and pixels), where the estimators use the long-run ones; ``--file-extrinsic``: the file's
extrinsic and no lens term instead of the identified ones. Compare with
benchmarks/baseline_truth.py, which measures the same ratio against the ground truth.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np

from vislam.ekf.config import FilterConfig
from vislam.ekf.model import model_config, model_sequence
from vislam.eval.loader import load_sequence
from vislam.eval.model_cache import identified_model
from vislam.graph.extrinsic import stereo_rows
from vislam.graph.factors import camera_points, stereo_measurement, stereo_residuals
from vislam.graph.out_of_sample import profile_rows
from vislam.graph.settings import SmootherSettings
from vislam.graph.smoother import solve_smoother


def baseline_step(solution) -> tuple[float, float]:
    """The Gauss-Newton step of log b on the profile likelihood, and its sigma."""
    rows = solution.problem.rows
    calib = solution.calibration
    r, _ = stereo_residuals(solution.poses, solution.landmarks, calib, rows)
    system, posterior_of = solution.linearised()
    stereo = stereo_rows(solution)
    # each stereo row whitened as the linearisation whitens it (robust weights included), as
    # graph.radial.lens_rows reads it off the linearised right-hand side
    ratio = np.array([1.0, 1.0, np.sqrt(2.0)])
    e = -r * ratio
    b_rows = system.b[stereo].reshape(-1, 3)
    ee = np.sum(e * e, axis=1)
    scale = np.where(ee > 1e-18, -np.sum(b_rows * e, axis=1) / np.where(ee > 1e-18, ee, 1.0), np.nan)
    scale = np.where(np.isfinite(scale), scale, np.nanmedian(scale))
    X = camera_points(solution.poses, solution.landmarks, calib, rows)
    moves = np.zeros((X.shape[0], 4))
    moves[:, 2] = -calib.K[0, 0] * calib.baseline / X[:, 2]
    A_t = np.zeros((system.b.size, 1))
    A_t[stereo, 0] = (scale[:, None] * ratio * stereo_measurement(moves)).reshape(-1)
    A_p, b_p = profile_rows(system.A, np.array(system.b, dtype=float), A_t, posterior_of.solve)
    information = float(A_p[:, 0] @ A_p[:, 0])
    return float(A_p[:, 0] @ b_p) / information, 1.0 / np.sqrt(information)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("file", type=Path)
    parser.add_argument("--white", action="store_true")
    parser.add_argument("--file-extrinsic", action="store_true")
    parser.add_argument("--steps", type=int, default=3)
    args = parser.parse_args()
    seq = load_sequence(args.file)
    model = identified_model(seq, FilterConfig(), SmootherSettings()).model
    if args.file_extrinsic:
        model = dataclasses.replace(model, cam_T_imu=seq.calibration.cam_T_imu, radial_k1=None)
    config = model_config(FilterConfig(), model)
    if args.white:
        config = model_config(FilterConfig(), dataclasses.replace(
            model, velocity_correlation_time=None, gyro_correlation_time=None)).replace(
            pixel_sigma=model.pixel_sigma)
    moved = model_sequence(seq, model)
    settings = SmootherSettings(compute_marginals=False)
    solution = None
    for _ in range(args.steps):
        solution = solve_smoother(moved, config, settings, warm_start=solution)
        step, sigma = baseline_step(solution)
        b = moved.calibration.baseline
        print(f"baseline {b:.5f} m: step {100 * step:+.3f} % +- {100 * sigma:.3f} %")
        moved = dataclasses.replace(moved, calibration=dataclasses.replace(
            moved.calibration, baseline=b * float(np.exp(step))))


if __name__ == "__main__":
    main()
