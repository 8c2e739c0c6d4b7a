"""Monte Carlo consistency of a raw-IMU EKF on the raw-IMU simulator: one scene per seed
(``scene_seed`` = seed, as docs/findings.md's ekf-imu entry ran it), the filter run directly
(``ekf.driver.run_filter``), its pose NEES against the truth in its own frame-0 gauge and the
landmark NEES of its map, per run and averaged, with the 95 % chi-square bounds.

    OPENBLAS_NUM_THREADS=1 python benchmarks/imu_ekf_consistency.py --camera mono --runs 20
    python benchmarks/imu_ekf_consistency.py --camera stereo --runs 10 --scenario handheld
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy.stats import chi2

from vislam.ekf.driver import run_filter
from vislam.ekf.geometry import se3_inv, se3_log
from vislam.ekf.imu_ekf import ImuEkf
from vislam.ekf.imu_landmarks import DepthPrior
from vislam.eval.imu_sim import simulate_imu
from vislam.eval.imu_sim_config import ImuSimConfig
from vislam.graph.inertial_init import in_estimate_gauge


def run_nees(est, truth) -> tuple[float, float]:
    """Mean pose NEES over frames 1.. and median landmark NEES of one run."""
    gt = in_estimate_gauge(truth.frame_poses, est.poses[:1])
    pose = []
    for k in range(1, est.n_frames):
        xi = se3_log(se3_inv(est.poses[k]) @ gt[k])
        pose.append(xi @ np.linalg.solve(est.pose_cov[k], xi))
    # landmarks: the truth moved by the same gauge as the poses (frame 0's)
    A = gt[0] @ se3_inv(truth.frame_poses[0])
    origin = np.asarray(est.info.get("track_origin", np.arange(est.landmarks.shape[0])))
    m = truth.landmarks[origin] @ A[:3, :3].T + A[:3, 3]  # split tracks share their landmark
    ok = np.isfinite(est.landmarks).all(axis=1)
    e = est.landmarks[ok] - m[ok]
    lm = np.einsum("ni,nij,nj->n", e, np.linalg.inv(est.landmark_cov[ok]), e)
    return float(np.mean(pose)), float(np.median(lm)) if lm.size else float("nan")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--camera", choices=("mono", "stereo"), default="mono")
    ap.add_argument("--scenario", default="room")
    ap.add_argument("--runs", type=int, default=8)
    ap.add_argument("--frames", type=int, default=201)
    ap.add_argument("--landmarks", type=int, default=None, help="scene landmarks (default: the scenario's)")
    ap.add_argument("--mature-ratio", type=float, default=0.5)
    ap.add_argument("--linearisation", choices=("standard", "oc"), default="standard")
    ap.add_argument("--min-depth", type=float, default=1.0,
                    help="the monocular depth prior's least depth (m; ekf.imu_landmarks.DepthPrior)")
    args = ap.parse_args()
    poses, lms = [], []
    for seed in range(args.runs):
        drive, truth = simulate_imu(ImuSimConfig(scenario=args.scenario, camera=args.camera,
                                                 n_frames=args.frames, seed=seed,
                                                 n_landmarks=args.landmarks))
        start = time.process_time()
        est = run_filter(ImuEkf(mature_ratio=args.mature_ratio, linearisation=args.linearisation,
                                depth_prior=DepthPrior(args.min_depth)), drive)
        cpu = time.process_time() - start
        p, lm = run_nees(est, truth)
        poses.append(p)
        lms.append(lm)
        print(f"seed {seed}: pose NEES {p:.2f}, landmark NEES (median) {lm:.2f}, {cpu:.2f} s CPU",
              flush=True)
    lo, hi = chi2.ppf([0.025, 0.975], 6 * args.runs) / args.runs
    print(f"pose ANEES {np.mean(poses):.2f} (95 % bounds {lo:.2f}-{hi:.2f}, 6 dof); median run "
          f"{np.median(poses):.2f}; landmark NEES, median of runs' medians {np.median(lms):.2f} "
          "(3 dof)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
