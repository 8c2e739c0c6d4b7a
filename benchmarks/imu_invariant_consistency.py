"""Consistency of ``ekf-imu-invariant`` on simulated raw-IMU drives: pose and landmark ANEES over
N seeded runs per scenario (room and road, mono and stereo), against the two-sided 95 %
chi-square bounds.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/imu_invariant_consistency.py --runs 50

Each run simulates a drive (``eval.imu_sim``, ``scene_seed`` fixed per scenario, ``seed`` =
run: a Monte Carlo of the noise on one scene) and runs the filter through the per-frame driver
(``ekf.driver.run_filter``). The truth is moved into the estimate's gauge (its yaw and position
at frame 0: ``eval.inertial_truth.frame0_gauge``'s rule, :func:`graph.inertial_init.in_estimate_gauge`)
before the NEES, as ``vislam bench`` scores a raw-IMU drive. Printed per scenario: the pose
ANEES (6 dof; mean over frames 1.. of the N-run average) with its bounds and the share of frames
inside them, the same for translation and rotation alone (3 dof each), the landmark ANEES (3 dof,
over the landmarks every run mapped), the mean position error and the filter's CPU seconds.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from vislam.ekf.config import FilterConfig
from vislam.ekf.driver import run_filter
from vislam.ekf.geometry import se3_inv, se3_log
from vislam.ekf.imu_invariant import ImuInvariantEKF
from vislam.eval.consistency import anees
from vislam.eval.imu_sim import simulate_imu
from vislam.eval.imu_sim_config import ImuSimConfig
from vislam.graph.inertial_init import in_estimate_gauge

SCENARIOS = (("room", "stereo"), ("room", "mono"), ("road", "stereo"), ("road", "mono"))


def one_run(scenario: str, camera: str, seed: int, n_frames: int, scene_seed: int = 7):
    drive, truth = simulate_imu(ImuSimConfig(scenario=scenario, camera=camera, seed=seed,
                                             scene_seed=scene_seed, n_frames=n_frames))
    start = time.process_time()
    est = run_filter(ImuInvariantEKF(), drive, FilterConfig())
    cpu = time.process_time() - start
    gt = in_estimate_gauge(truth.frame_poses, est.poses[0][None])
    xi = se3_log(np.einsum("nij,njk->nik", se3_inv(est.poses), gt))
    cov = est.pose_cov

    def nees(sl):
        e = xi[:, sl]
        return np.einsum("ni,ni->n", e, np.linalg.solve(cov[:, sl, sl], e[:, :, None])[:, :, 0])

    pose, trans, rot = nees(slice(0, 6)), nees(slice(0, 3)), nees(slice(3, 6))
    # landmarks: the truth moved by the same gauge transform
    G = gt[0] @ se3_inv(truth.frame_poses[0])
    origin = np.asarray(est.info.get("track_origin", np.arange(est.landmarks.shape[0])))
    lm_true = truth.landmarks[origin] @ G[:3, :3].T + G[:3, 3]
    ok = np.isfinite(est.landmarks).all(axis=1) & np.isfinite(est.landmark_cov.reshape(-1, 9)).all(axis=1)
    lm = np.full(est.landmarks.shape[0], np.nan)
    d = lm_true[ok] - est.landmarks[ok]
    lm[ok] = np.einsum("ni,ni->n", d, np.linalg.solve(est.landmark_cov[ok], d[:, :, None])[:, :, 0])
    err = np.linalg.norm(est.poses[:, :3, 3] - gt[:, :3, 3], axis=1)
    return pose, trans, rot, lm, float(err.mean()), cpu


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=10)
    ap.add_argument("--frames", type=int, default=601, help="frames per drive (20 Hz)")
    ap.add_argument("--scenario", action="append", default=None,
                    help="SCENARIO:CAMERA, e.g. room:mono (repeatable; default all four)")
    args = ap.parse_args(argv)
    todo = SCENARIOS if not args.scenario else [tuple(s.split(":")) for s in args.scenario]
    for scenario, camera in todo:
        rows = [one_run(scenario, camera, 100 + r, args.frames) for r in range(args.runs)]
        pose, trans, rot, lm = (np.array([r[i] for r in rows])[:, 1:] if i < 3 else
                                np.array([r[i] for r in rows]) for i in range(4))
        a6, a3t, a3r = anees(pose, 6), anees(trans, 3), anees(rot, 3)
        la = anees(lm, 3)
        errs = [r[4] for r in rows]
        cpu = [r[5] for r in rows]
        print(f"{scenario:5s} {camera:6s} runs {args.runs} frames {args.frames}: "
              f"pose ANEES {a6.mean:.2f} bounds [{a6.bounds[0]:.2f}, {a6.bounds[1]:.2f}] "
              f"({a6.verdict}; {100 * a6.inside_fraction:.0f} % of frames inside); "
              f"translation {a3t.mean:.2f}, rotation {a3r.mean:.2f} "
              f"(3-dof bounds [{a3t.bounds[0]:.2f}, {a3t.bounds[1]:.2f}]); "
              f"landmark ANEES {la.mean:.2f} over {int(np.isfinite(la.per_item).sum())} "
              f"landmarks; mean position error {np.mean(errs):.3f} m; "
              f"{np.mean(cpu):.2f} s CPU per run", flush=True)


if __name__ == "__main__":
    main()
