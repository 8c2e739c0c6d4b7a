"""The batch smoother under three readings of a drive's correlated pixel errors (issue 34;
docs/findings.md, "Pixel errors along a track as AR(1) in the smoother").

    .venv/bin/python benchmarks/ar1_pixel_smoother.py FILE.npz [--modes long-run,white,ar1]
    .venv/bin/python benchmarks/ar1_pixel_smoother.py --campaign 2,7,15,19,20,27

The identified model (or, with ``--campaign``, each campaign drive's true model) carries a
white pixel sigma ``s`` and an integrated correlation time ``tau`` along a track. The modes:

- ``long-run``: what every estimator does (``ekf.model.model_config``): independent rows with
  the long-run sigma ``s sqrt(tau)``;
- ``white``: independent rows with ``s`` (the correlation ignored);
- ``ar1``: the errors as AR(1) with ``a = (tau - 1) / (tau + 1)`` per frame, exactly: a track's
  first observation keeps the stereo factor with ``s``, each later one (``m`` frames after the
  previous) a differenced factor on both poses and the landmark, residual ``r_k - a^m r_prev``
  with sigma ``s sqrt(1 - a^2m)`` (Bryson and Henrikson's whitening). A Python
  ``gtsam.CustomFactor`` per row, so 10-100x slower than the others: this measures, it is
  not a product path.

Prints aligned ATE and KITTI t_rel against the ground truth (and, on campaign drives, the
smoother's mean pose NEES) per mode. The smoother's settings are the defaults (its EKF start
included, which takes the mode's sigma too).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import time

import numpy as np

#: The rows' sigmas in units of the pixel sigma: GTSAM's stereo [uL, uR, v], v the mean of two.
ROW_SCALE = np.array([1.0, 1.0, 1.0 / math.sqrt(2.0)])


def stereo_projection(calibration, body_P_sensor):
    """``h(pose, p) -> (z, dz/dpose, dz/dp)``: GTSAM's stereo projection ``[uL, uR, v]`` of a
    world point from a ``Pose3`` (world_T_imu) and its Jacobians (GTSAM's right perturbation,
    rotation first)."""
    fx, fy, cu, cv, b = (calibration.fx(), calibration.fy(), calibration.px(), calibration.py(),
                         calibration.baseline())
    R_ic, t_ic = body_P_sensor.rotation().matrix(), body_P_sensor.translation()

    def h(pose, p):
        R, t = pose.rotation().matrix(), pose.translation()
        p_i = R.T @ (p - t)
        x, y, z = R_ic.T @ (p_i - t_ic)
        value = np.array([fx * x / z + cu, fx * (x - b) / z + cu, fy * y / z + cv])
        dz_dq = np.array([[fx / z, 0.0, -fx * x / z ** 2],
                          [fx / z, 0.0, -fx * (x - b) / z ** 2],
                          [0.0, fy / z, -fy * y / z ** 2]])
        skew = np.array([[0.0, -p_i[2], p_i[1]], [p_i[2], 0.0, -p_i[0]], [-p_i[1], p_i[0], 0.0]])
        return value, dz_dq @ R_ic.T @ np.hstack([skew, -np.eye(3)]), dz_dq @ R_ic.T @ R.T

    return h


def ar1_stereo_factors(a: float):
    """A replacement for ``graph.factors.NoiseModels.add_stereo_factors`` with AR(1) rows."""
    import gtsam
    from gtsam.symbol_shorthand import L, X

    def add(self, graph, rows, robust=True):
        h = stereo_projection(self.calibration, self.body_P_sensor)
        sigma = float(np.asarray(self.stereo_gaussian.sigmas())[0])
        huber = gtsam.noiseModel.mEstimator.Huber.Create(1.345)
        order = np.lexsort((rows.frame, rows.track))
        previous = {}
        for i in range(1, order.size):
            if rows.track[order[i]] == rows.track[order[i - 1]]:
                previous[int(order[i])] = (int(order[i - 1]), int(rows.frame[order[i]] - rows.frame[order[i - 1]]))
        for r in range(len(rows)):
            x, lm = X(int(rows.frame[r])), L(int(rows.track[r]))
            if r not in previous:
                u_l, u_r, v = rows.measured[r]
                graph.add(gtsam.GenericStereoFactor3D(gtsam.StereoPoint2(u_l, u_r, v),
                                                      self.stereo if robust else self.stereo_gaussian,
                                                      x, lm, self.calibration, self.body_P_sensor))
                continue
            q, m = previous[r]
            am = a ** m
            base = gtsam.noiseModel.Diagonal.Sigmas(sigma * math.sqrt(1.0 - am * am) * ROW_SCALE)
            noise = gtsam.noiseModel.Robust.Create(huber, base) if robust else base
            xq = X(int(rows.frame[q]))

            def error(this, values, H, zk=rows.measured[r].copy(), zq=rows.measured[q].copy(),
                      am=am, x=x, xq=xq, lm=lm):
                p = values.atPoint3(lm)
                hk, Jk, Pk = h(values.atPose3(x), p)
                hq, Jq, Pq = h(values.atPose3(xq), p)
                if H is not None:
                    H[0], H[1], H[2] = Jk, -am * Jq, Pk - am * Pq
                return (hk - zk) - am * (hq - zq)

            graph.add(gtsam.CustomFactor(noise, [x, xq, lm], error))

    return add


def solve(seq, config, model, mode: str, marginals: bool):
    from vislam.ekf.model import ar1_coefficient
    from vislam.graph import factors
    from vislam.graph.settings import SmootherSettings
    from vislam.graph.smoother import run_smoother

    if mode != "long-run":
        config = dataclasses.replace(config, pixel_sigma=model.pixel_sigma)
    original = factors.NoiseModels.add_stereo_factors
    if mode == "ar1":
        factors.NoiseModels.add_stereo_factors = ar1_stereo_factors(ar1_coefficient(model.pixel_correlation_time))
    try:
        tick = time.perf_counter()
        est = run_smoother(seq, config, settings=SmootherSettings(compute_marginals=marginals))
        return est, time.perf_counter() - tick
    finally:
        factors.NoiseModels.add_stereo_factors = original


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("file", nargs="?", help="a drive with ground truth beside it")
    parser.add_argument("--campaign", help="comma-separated campaign seeds instead (true model)")
    parser.add_argument("--modes", default="long-run,white,ar1")
    args = parser.parse_args(argv)
    from vislam.ekf.config import FilterConfig
    from vislam.ekf.model import model_config, model_sequence
    from vislam.eval.consistency import pose_nees
    from vislam.eval.metrics import ate_rmse, kitti_drift

    modes = args.modes.split(",")
    if args.campaign:
        from vislam.eval.campaign import draw_drive, drive_true_model

        for seed in (int(s) for s in args.campaign.split(",")):
            drive = draw_drive(seed)
            result = drive.simulate()
            model = drive_true_model(drive, result)
            seq = model_sequence(result.sequence, model)
            config = model_config(FilterConfig(), model)
            for mode in modes:
                est, wall = solve(seq, config, model, mode, marginals=True)
                nees = float(np.nanmean(pose_nees(est, np.arange(len(result.poses)), result.poses)))
                print(f"drive {seed:3d} ({seq.obs.frame_index.size / seq.n_frames:.1f} obs/frame, tau "
                      f"{model.pixel_correlation_time or 1.0:.2f}) {mode:8s}: aligned ATE "
                      f"{ate_rmse(est.poses, result.poses, 'se3'):.4f} m, pose NEES {nees:.2f} ({wall:.1f} s)",
                      flush=True)
        return 0
    if not args.file:
        parser.error("give FILE.npz or --campaign SEEDS")
    from vislam.eval.groundtruth import ground_truth_path, load_ground_truth
    from vislam.eval.loader import load_sequence
    from vislam.eval.model_cache import identified_model

    raw = load_sequence(args.file)
    model = identified_model(raw).model
    seq = model_sequence(raw, model)
    config = model_config(FilterConfig(), model)
    gt = load_ground_truth(ground_truth_path(args.file), seq.calibration, seq.n_frames)
    print(f"{args.file}: white pixel sigma {model.pixel_sigma:.3f} px, tau "
          f"{model.pixel_correlation_time or 1.0:.2f} frames, long-run {config.pixel_sigma:.3f} px")
    for mode in modes:
        est, wall = solve(seq, config, model, mode, marginals=False)
        P = est.poses[gt.frames]
        print(f"  {mode:8s}: aligned ATE {ate_rmse(P, gt.poses, 'se3'):.3f} m, t_rel "
              f"{kitti_drift(P, gt.poses)['t_rel_pct']:.2f} % ({wall:.0f} s)", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
