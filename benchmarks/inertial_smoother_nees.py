"""The raw-IMU smoother's consistency on simulated drives: pose ANEES over Monte Carlo runs.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/inertial_smoother_nees.py
        [--runs 50] [--frames 201] [--scenarios room,handheld,road] [--first-seed 0]
        [--camera mono|stereo]

Each run is a drive of :func:`eval.imu_sim.simulate_imu` (``--camera`` mono or stereo) with its own seed (trajectory, landmarks, biases and noise), solved by
:func:`graph.inertial_smoother.smooth` with the data sheet's noise and the pixel sigma identified.
Its pose NEES against the truth in the estimate's gauge (:func:`eval.inertial_truth.frame0_gauge`:
yaw and position of frame 0, which the estimate's covariance rightly leaves out) is averaged over
frames 1..T-1 and runs: the ANEES, with the two-sided 95 % bounds of ``chi2(6 N) / N`` for N runs
(:func:`eval.consistency.chi2_bounds`; per frame, so the bounds are those of one frame's average
and the mean over frames is compared with them, as ``vislam nees`` does). Also printed: the
translation and rotation parts (3 dof each) and the share of runs whose 4-dof aligned ATE is
within 3 of the smoother's own position sigmas (RMS over frames).
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from vislam.eval.consistency import chi2_bounds  # noqa: E402
from vislam.eval.groundtruth import GroundTruth  # noqa: E402
from vislam.eval.imu_sim import simulate_imu  # noqa: E402
from vislam.eval.imu_sim_config import ImuSimConfig  # noqa: E402
from vislam.eval.inertial_truth import frame0_gauge  # noqa: E402
from vislam.eval.metrics import ate_rmse, pose_errors  # noqa: E402
from vislam.graph.inertial_smoother import smooth  # noqa: E402


def run_once(scenario: str, seed: int, frames: int, camera: str = "mono") -> dict:
    """One simulated drive solved by the smoother: its NEES parts and ATE against its sigmas."""
    drive, truth = simulate_imu(ImuSimConfig(scenario=scenario, camera=camera, seed=seed,
                                             n_frames=frames))
    start = time.process_time()
    est = smooth(drive).estimate
    cpu = time.process_time() - start
    gt = frame0_gauge(GroundTruth(np.arange(drive.n_frames), truth.frame_poses, source="simulation"),
                      est.poses[0])
    err = pose_errors(est.poses, gt.poses)[1:]
    P = est.pose_cov[1:]

    def part(s: slice) -> float:
        return float(np.mean([e[s] @ np.linalg.solve(C[s, s], e[s]) for e, C in zip(err, P)]))

    sigma = float(np.sqrt(np.mean(np.trace(P[:, :3, :3], axis1=1, axis2=2))))
    return {"nees": part(slice(0, 6)), "trans": part(slice(0, 3)), "rot": part(slice(3, 6)),
            "ate": ate_rmse(est.poses, gt.poses, "yaw"), "sigma": sigma, "cpu": cpu}


def study(scenario: str, runs: int, frames: int, first_seed: int = 0, camera: str = "mono") -> dict:
    """ANEES and the rest over ``runs`` seeds from ``first_seed``."""
    rows = [run_once(scenario, first_seed + i, frames, camera) for i in range(runs)]
    lo, hi = chi2_bounds(runs, 6)
    anees = float(np.mean([r["nees"] for r in rows]))
    return {"scenario": scenario, "camera": camera, "runs": runs, "frames": frames, "anees": anees, "bounds": (lo, hi),
            "inside": lo <= anees <= hi,
            "trans": float(np.mean([r["trans"] for r in rows])),
            "rot": float(np.mean([r["rot"] for r in rows])),
            "ate_within_3_sigma": float(np.mean([r["ate"] <= 3 * r["sigma"] for r in rows])),
            "ate_m": float(np.median([r["ate"] for r in rows])),
            "cpu_s": float(np.mean([r["cpu"] for r in rows]))}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=50)
    ap.add_argument("--frames", type=int, default=201)
    ap.add_argument("--scenarios", default="room,handheld,road")
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--camera", choices=("mono", "stereo"), default="mono")
    args = ap.parse_args(argv)
    print(f"{'scenario':<9} {'runs':>4} {'frames':>6} {'ANEES':>7} {'95% bounds':>15} "
          f"{'trans':>6} {'rot':>6} {'ATE m':>8} {'ATE<=3sd':>8} {'CPU s/run':>9}")
    for scenario in args.scenarios.split(","):
        r = study(scenario, args.runs, args.frames, args.first_seed, args.camera)
        lo, hi = r["bounds"]
        print(f"{scenario:<9} {r['runs']:>4} {r['frames']:>6} {r['anees']:>7.2f} "
              f"[{lo:5.2f}, {hi:5.2f}]{'' if r['inside'] else ' !':<2} {r['trans']:>6.2f} "
              f"{r['rot']:>6.2f} {r['ate_m']:>8.4f} {r['ate_within_3_sigma']:>8.0%} "
              f"{r['cpu_s']:>9.1f}", flush=True)


if __name__ == "__main__":
    main()
