"""ekf-imu-invariant in the regression tier: its propagation against a Monte Carlo of a
noise-only drive, 8-run room consistency (stereo and mono), and EuRoC V1_01's first 30 s
(measured values: docs/findings.md, the invariant raw-IMU EKF entry).
``VISLAM_REGRESSION_BREAK=half-accel-noise`` (the filter assumes half the accelerometer's noise
density) fails the first."""

from __future__ import annotations

import time

import numpy as np
import pytest
from vislam.ekf.config import FilterConfig
from vislam.ekf.driver import run_filter
from vislam.ekf.geometry import se3_inv, se3_log
from vislam.ekf.imu_invariant import ImuInvariantEKF
from vislam.ekf.inertial import ImuNoise
from vislam.eval.consistency import anees
from vislam.eval.imu_sim import simulate_imu
from vislam.eval.imu_sim_config import ImuSimConfig
from vislam.graph.inertial_init import in_estimate_gauge

from tests.regression.breaks import broken_imu_noise
from tests.test_imu_invariant_propagation import _monte_carlo

pytestmark = pytest.mark.regression

#: The issue's targets for the 4-dof aligned ATE on EuRoC's 30 s (m): 0.08 and twice the
#: smoother's 0.0131. Measured 0.0200.
EUROC_ATE_TARGET_M = min(0.08, 2 * 0.0131)
#: Pin on the mean pose NEES against EuRoC's truth in the estimate's gauge: measured 280 (the
#: smoother's 465). A pin, not the issue's target of 12 (not met).
EUROC_NEES_BAND = (100.0, 600.0)


def test_propagation_matches_a_monte_carlo_of_a_noise_only_drive():
    """The invariant propagation (RI-3 .. RI-5) told the noise of the break (if any), against
    100 noise-only runs with velocity and position known at the start: the 21-dimensional
    ANEES inside the 95 % bounds. Under ``half-accel-noise`` it is far above them."""
    P0 = np.diag([1e-6] * 3 + [1e-8] * 6 + [1e-8] * 6 + [1e-2] * 6)
    value, lo, hi = _monte_carlo(P0, broken_imu_noise(ImuNoise(2e-3, 2e-4, 2e-2, 3e-3)),
                                 runs=100, seed=9)
    assert lo < value < hi, (value, lo, hi)


@pytest.mark.parametrize("camera", ["stereo", "mono"])
def test_room_drive_consistency_over_runs(camera):
    """Pose ANEES of 8 seeded 10 s room drives (one scene) inside the two-sided 95 % bounds of
    8 runs. Measured 2026-11-28: stereo 4.74, mono 7.15 (bounds [3.84, 8.63])."""
    rows = []
    for r in range(8):
        drive, truth = simulate_imu(ImuSimConfig(camera=camera, seed=200 + r, scene_seed=5,
                                                 n_frames=201))
        est = run_filter(ImuInvariantEKF(noise=broken_imu_noise(drive.calibration.noise)),
                         drive, FilterConfig())
        gt = in_estimate_gauge(truth.frame_poses, est.poses[0][None])
        xi = se3_log(np.einsum("nij,njk->nik", se3_inv(est.poses), gt))
        rows.append(np.einsum("ni,ni->n", xi,
                              np.linalg.solve(est.pose_cov, xi[:, :, None])[:, :, 0])[1:])
    a = anees(np.array(rows), 6)
    assert a.bounds[0] < a.mean < a.bounds[1], (a.mean, a.bounds)


@pytest.fixture(scope="module")
def euroc(euroc_drive):
    return euroc_drive


def test_ekf_imu_invariant_on_euroc(euroc):
    """EuRoC V1_01's first 30 s with the data sheet's noise and no per-drive settings: 4-dof
    aligned ATE within the issue's targets, pose NEES pinned, every frame finite."""
    from vislam.eval.metrics import ate_rmse, nees, pose_errors

    drive, truth = euroc
    start = time.process_time()
    est = run_filter(ImuInvariantEKF(noise=broken_imu_noise(drive.calibration.noise)), drive,
                     FilterConfig())
    cpu = time.process_time() - start
    assert ate_rmse(est.poses, truth, "yaw") <= EUROC_ATE_TARGET_M
    n = nees(pose_errors(est.poses, in_estimate_gauge(truth, est.poses)), est.pose_cov)[1:]
    assert np.all(np.isfinite(n))
    assert EUROC_NEES_BAND[0] < float(np.mean(n)) < EUROC_NEES_BAND[1], float(np.mean(n))
    assert cpu < 20.0  # measured 1.3-1.5 s; the target (2 s on one core) is benchmarked
