"""vislam's reference smoother as a GTSAM factor graph, built in a few visible lines.

In the style of GTSAM's Python examples: a short simulated drive, a Pose3 ``X(k)`` per frame
(``world_T_imu``, the world being the IMU frame at frame 0) and a Point3 ``L(j)`` per track,
motion factors from the integrated body twist of each interval, stereo factors seen through the
camera-IMU extrinsic under a Huber kernel, a prior on the first pose (and a weak one on each
landmark), Levenberg-Marquardt and the marginal covariance of the last pose. Then vislam's own smoother runs on the same drive, and both
trajectories' ATE against the truth is printed with how far apart they are.

    python examples/smoother_graph.py [--frames 100] [--seed 0] [--out DIR]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, X

from vislam import FilterConfig, SimConfig, simulate, trajectory_metrics
from vislam.graph.factors import interval_twists
from vislam.graph.pose_conversions import to_pose3
from vislam.graph.settings import SmootherSettings
from vislam.graph.smoother import run_smoother


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=100)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, help="write both trajectories to DIR/trajectories.npz")
    args = parser.parse_args(argv)

    sim = simulate(SimConfig(n_frames=args.frames, seed=args.seed))
    seq, config = sim.sequence, FilterConfig()  # the simulator's noise is FilterConfig's default
    c = seq.calibration
    graph = gtsam.NonlinearFactorGraph()
    initial = gtsam.Values()

    # A prior on the first pose: the world is the IMU frame at frame 0 (GTSAM: rotation first).
    prior = gtsam.noiseModel.Diagonal.Sigmas(np.r_[np.full(3, config.initial_rotation_sigma),
                                                   np.full(3, config.initial_position_sigma)])
    graph.add(gtsam.PriorFactorPose3(X(0), gtsam.Pose3(), prior))
    initial.insert(X(0), gtsam.Pose3())

    # Motion: X(k+1) = X(k) exp(tau u) with u the body twist of the interval. A twist error w of
    # covariance W moves it by exp(tau J_r w), so its noise is tau^2 J_r W J_r^T.
    W = np.diag(np.r_[config.gyro_sigmas, config.velocity_sigmas] ** 2)
    twists, taus = interval_twists(seq, config.velocity_pairing)  # (T-1, 6) [v; w], (T-1,)
    for k, (u, tau) in enumerate(zip(twists, taus)):
        xi = tau * np.r_[u[3:], u[:3]]  # GTSAM's twist order: rotation first
        J, delta = gtsam.Pose3.ExpmapDerivative(xi), gtsam.Pose3.Expmap(xi)
        noise = gtsam.noiseModel.Gaussian.Covariance(tau**2 * J @ W @ J.T)
        graph.add(gtsam.BetweenFactorPose3(X(k), X(k + 1), delta, noise))
        initial.insert(X(k + 1), initial.atPose3(X(k)).compose(delta))  # dead reckoning

    # Vision: stereo pixels [uL, uR, v] (v the mean of vL and vR, hence sigma / sqrt(2)) of a
    # landmark seen by the left camera at X(k) imu_T_cam; tracks seen at least twice.
    K = gtsam.Cal3_S2Stereo(c.fsu, c.fsv, 0.0, c.cu, c.cv, c.baseline)
    imu_T_cam = to_pose3(np.linalg.inv(c.cam_T_imu))
    s = config.pixel_sigma
    stereo_noise = gtsam.noiseModel.Robust.Create(
        gtsam.noiseModel.mEstimator.Huber.Create(1.345),  # vislam's huber_k, in sigmas
        gtsam.noiseModel.Diagonal.Sigmas(np.array([s, s, s / np.sqrt(2.0)])))
    landmark_prior = gtsam.noiseModel.Isotropic.Sigma(3, 100.0)  # weak: far points stay determinate
    obs = seq.obs
    disparity = obs.z[:, 0] - obs.z[:, 2]
    use = disparity > config.min_disparity
    use &= np.bincount(obs.track[use], minlength=seq.n_tracks)[obs.track] >= 2
    rows = np.flatnonzero(use)[np.argsort(-disparity[use], kind="stable")]  # largest disparity first
    for k, j, (uL, vL, uR, vR) in zip(obs.frame_index[rows].tolist(), obs.track[rows].tolist(),
                                      obs.z[rows].tolist()):
        pixels = gtsam.StereoPoint2(uL, uR, 0.5 * (vL + vR))
        graph.add(gtsam.GenericStereoFactor3D(pixels, stereo_noise, X(k), L(j), K, imu_T_cam))
        if not initial.exists(L(j)):  # triangulated where its depth is best known (dead reckoning)
            camera = gtsam.StereoCamera(initial.atPose3(X(k)).compose(imu_T_cam), K)
            initial.insert(L(j), camera.backproject(pixels))
            graph.add(gtsam.PriorFactorPoint3(L(j), initial.atPoint3(L(j)), landmark_prior))

    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-5)
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, initial, params)
    result = optimizer.optimize()
    last = gtsam.Marginals(graph, result).marginalCovariance(X(seq.n_frames - 1))
    poses = np.stack([result.atPose3(X(k)).matrix() for k in range(seq.n_frames)])
    print(f"graph: {graph.size()} factors, {initial.size()} variables; LM {optimizer.iterations()} "
          f"iterations, error {graph.error(initial):.5g} -> {graph.error(result):.5g}")

    # vislam's smoother on the same drive, from the same start and without what it adds to this
    # graph (a gyro bias, a second round without the outliers): the same problem, the same
    # answer. Its marginals leave out the Huber weights (graph/factors.py: gaussian_stereo).
    same = SmootherSettings(init="dead-reckoning", gyro_bias="off", rejection_rounds=0,
                            gap_twist_prior="off")
    est = run_smoother(seq, config, settings=same)
    default = run_smoother(seq, config)  # as `vislam run -e smoother` runs it
    ate = {name: trajectory_metrics(p, sim.poses)["ate_rmse_m"]
           for name, p in [("graph", poses), ("vislam", est.poses), ("default", default.poses)]}
    apart = np.abs(poses[:, :3, 3] - est.poses[:, :3, 3]).max()
    print(f"last pose position sigma (m): this graph {np.sqrt(np.diag(last)[3:]).round(4)}, "
          f"vislam {np.sqrt(np.diag(est.pose_cov[-1])[:3]).round(4)}")
    print(f"ATE this graph: {ate['graph']:.4f} m")
    print(f"ATE vislam smoother, same graph: {ate['vislam']:.4f} m")
    print(f"ATE vislam smoother, its defaults: {ate['default']:.4f} m")
    print(f"largest position difference, this graph - vislam's same graph: {apart:.2e} m")
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        np.savez(args.out / "trajectories.npz", graph=poses, vislam=est.poses, truth=sim.poses)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
