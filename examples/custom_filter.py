"""A filter of your own on vislam's per-frame protocol, benchmarked and held to a NEES test.

``FirstSightMapper`` is about forty lines: dead reckoning (paper eq. 11: ``U <- exp(-tau u^) U``,
``P <- F P F^T + tau^2 W`` with ``F = exp(-tau u_curlyhat)``, the adjoint of the step) and every landmark triangulated once, at its first sight, with the pose
uncertainty of that moment. The driver (``vislam.filters.run_filter``) calls ``initialise``
once, then for each frame ``predict`` (from the second frame on), ``update`` and
``marginalise``, exactly as it drives vislam's own EKFs. This script then

1. runs it beside ekf-invariant and the smoother with ``vislam bench`` (``MODULE:CLASS``),
2. runs the Monte Carlo consistency study ``vislam nees`` on it,
3. asserts what a regression test of your filter would (``vislam.testing``): its pose ANEES
   inside the 95 % chi-square bounds.

    python examples/custom_filter.py [--out DIR]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from vislam.filters import (FrameObservations, Landmarks, MotionInput, StereoModel,
                            UpdateCounts, adjoint, ekf_cov_to_estimate, se3_exp, se3_inv)


class FirstSightMapper:
    """Dead reckoning, and each landmark triangulated at its first sight."""

    name = "first-sight-mapper"

    def initialise(self, seq, config, guard):
        self.camera = StereoModel.from_config(seq.calibration, config)
        self.W, self.U, self.P = config.velocity_cov, np.eye(4), config.initial_pose_cov
        self.mean = np.full((seq.n_tracks, 3), np.nan)
        self.cov = np.full((seq.n_tracks, 3, 3), np.nan)
        self.active = np.zeros(seq.n_tracks, dtype=bool)

    def predict(self, motion: MotionInput):  # U = imu_T_world; paper eq. 11
        step = se3_exp(-motion.dt * motion.twist)
        F = adjoint(step)  # exp(-tau u_curlyhat)
        self.U, self.P = step @ self.U, F @ self.P @ F.T + motion.dt**2 * self.W

    def update(self, frame: FrameObservations) -> UpdateCounts:
        new = np.isnan(self.mean[frame.tracks, 0]) & self.camera.valid_observations(frame.z)
        tracks = frame.tracks[new]
        if tracks.size:
            m, J_d, C_z = self.camera.initialise_with_cov(self.U, frame.z[new])
            self.mean[tracks] = m
            self.cov[tracks] = C_z + J_d @ self.P @ np.swapaxes(J_d, 1, 2)
            self.active[tracks] = True
        return UpdateCounts(0, int(frame.tracks.size - tracks.size), int(tracks.size))

    def marginalise(self, tracks):
        self.active[tracks] = False

    def pose(self):
        return se3_inv(self.U)

    def pose_cov(self):
        return ekf_cov_to_estimate(self.P)

    def active_landmarks(self):
        tracks = np.flatnonzero(self.active)
        return Landmarks(tracks, self.mean[tracks], self.cov[tracks])

    def landmark_map(self):
        ended = ~self.active
        return (np.where(ended[:, None], self.mean, np.nan),
                np.where(ended[:, None, None], self.cov, np.nan))

    def info(self):
        return {}


def vislam(*args: str) -> None:
    subprocess.run([sys.executable, "-m", "vislam.eval.cli", *args], check=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, help="folder for the results (default: a temporary one)")
    args = ap.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix="vislam-custom-filter-"))
    spec = f"{Path(__file__).resolve()}:FirstSightMapper"

    # 1. The benchmark, beside vislam's own (the simulated drive; the model as given).
    vislam("bench", "--frames", "100", "--model", "as-given", "-q", "--force",
           "-e", f"{spec},ekf-invariant,smoother", "--out", str(out / "bench"))
    (drive,) = json.loads((out / "bench" / "results.json").read_text())["sequences"]
    for row in drive["estimators"]:
        print(f"bench: {Path(row['name']).name:40s} aligned ATE {row['ate_aligned_m']:.3f} m, "
              f"pose NEES {row['nees_pose_mean']:.2f}")

    # 2. Monte Carlo consistency on the simulator.
    vislam("nees", "--runs", "8", "--frames", "80", "-q", "--force", "-e", spec,
           "--out", str(out / "nees"))
    row = json.loads((out / "nees" / "nees.json").read_text())["estimators"][spec]
    print(f"nees: pose ANEES {row['anees_pose']:.2f}, bounds {row['bounds_pose']}")

    # 3. The regression test you would keep in your suite (pytest: one assert per property).
    from vislam.testing import assert_nees_consistent, monte_carlo

    study = monte_carlo([spec], runs=8, frames=80, reference=None)
    assert_nees_consistent(study, what=("pose",))
    print("regression test: pose ANEES inside the 95 % bounds")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
