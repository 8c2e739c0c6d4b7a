"""ekf-imu in the regression tier: the filter's own propagation against a Monte Carlo of a
noise-only drive, a stereo room Monte Carlo, and EuRoC V1_01's first 30 s (measured values:
docs/findings.md, the raw-IMU EKF entry). ``VISLAM_REGRESSION_BREAK=half-accel-noise`` (the
filter assumes half the accelerometer's noise density) fails the first."""

from __future__ import annotations

import time

import numpy as np
import pytest
from scipy.stats import chi2

from tests.regression.breaks import broken_imu_noise
from vislam.ekf.config import FilterConfig
from vislam.ekf.driver import inertial_motion_inputs, run_filter
from vislam.ekf.geometry import so3_log
from vislam.ekf.imu_ekf import ImuEkf
from vislam.ekf.imu_init import RestConfig
from vislam.ekf.inertial import ImuNoise
from vislam.ekf.numerics import NumericalGuard
from vislam.eval.imu_sim import simulate_imu
from vislam.eval.imu_sim_config import ImuSimConfig
from tests.test_imu_ekf import aligned_ate, pose_nees_in_gauge

pytestmark = pytest.mark.regression

#: The issue's targets for the 4-dof aligned ATE on EuRoC's 30 s (m): 0.08 m and twice the
#: smoother's (0.0131 m); measured 0.0239.
EUROC_ATE_TARGET_M = min(0.08, 2 * 0.0131)
#: Pin on the mean pose NEES against EuRoC's truth in the estimate's gauge: measured 282 (the
#: smoother: 465; docs/raw_imu.md on this ground truth). A pin, not the issue's target of 12.
EUROC_NEES_BAND = (150.0, 450.0)


def _local(ref, s) -> np.ndarray:
    return np.concatenate([so3_log(ref.R.T @ s.R), s.v - ref.v, s.p - ref.p, s.bg - ref.bg,
                           s.ba - ref.ba])


def test_filter_propagation_matches_a_monte_carlo_of_a_noise_only_drive():
    """120 runs of one trajectory (a 3 s room drive with no landmarks in view to speak of), the
    IMU's white noise ten times EuRoC's so that it dominates: ekf-imu's predict from the true
    state, its 15-state NEES at frames 20, 40 and 60 inside the two-sided 95 % bounds. Halving the
    accelerometer noise the filter assumes puts it far above."""
    runs, frames = 120, (20, 40, 60)
    noise = ImuNoise(1.7e-3, 1.9e-5, 2e-2, 3e-4)
    base = dict(n_frames=61, rest_s=1.0, scene_seed=3, n_landmarks=1, noise=noise,
                gyro_bias_sigma=0.0, accel_bias_sigma=0.0)
    nees = np.zeros((runs, len(frames)))
    config = FilterConfig()
    for r in range(runs):
        drive, truth = simulate_imu(ImuSimConfig(seed=1000 + r, **base))
        # the rest detection's tolerances widened for the tenfold noise: the state is replaced
        f = ImuEkf(noise=broken_imu_noise(drive.calibration.noise),
                   rest=RestConfig(accel_mean_tol=2.0, gyro_mean_tol=0.2))
        f.initialise(drive, config, NumericalGuard("ekf-imu", drive.timestamps))
        f.x = truth.frame_state(0)
        f.P = np.zeros_like(f.P)
        i = 0
        for m in inertial_motion_inputs(drive):
            f.predict(m)
            if m.frame == frames[i]:
                e = _local(f.x, truth.frame_state(m.frame))
                nees[r, i] = e @ np.linalg.solve(f.P[:15, :15], e)
                i += 1
                if i == len(frames):
                    break
    lo, hi = chi2.ppf([0.025, 0.975], 15 * runs) / runs
    anees = nees.mean(axis=0)
    assert np.all((anees > lo) & (anees < hi)), (anees, lo, hi)


def test_stereo_room_monte_carlo_is_consistent():
    """Eight runs of a 10 s stereo room drive: pose ANEES inside the 95 % bounds, aligned ATE
    under 2 cm in every run."""
    runs = 8
    nees, ates = [], []
    for seed in range(runs):
        drive, truth = simulate_imu(ImuSimConfig(camera="stereo", n_frames=201, n_landmarks=200,
                                                 scene_seed=11, seed=100 + seed))
        est = run_filter(ImuEkf(noise=broken_imu_noise(drive.calibration.noise)), drive)
        nees.append(np.nanmean(pose_nees_in_gauge(est, truth)))
        ates.append(aligned_ate(est, truth))
    lo, hi = chi2.ppf([0.025, 0.975], 6 * runs) / runs
    assert lo < np.mean(nees) < hi, (nees, lo, hi)
    assert max(ates) < 0.02, ates


@pytest.fixture(scope="module")
def euroc(euroc_drive):
    return euroc_drive


def test_ekf_imu_on_euroc(euroc):
    """EuRoC V1_01's first 30 s with the data sheet's noise and no per-drive settings: 4-dof
    aligned ATE within the issue's target, pose NEES pinned, every frame finite."""
    from vislam.eval.metrics import ate_rmse, nees, pose_errors
    from vislam.graph.inertial_init import in_estimate_gauge

    drive, truth = euroc
    start = time.process_time()
    est = run_filter(ImuEkf(noise=broken_imu_noise(drive.calibration.noise)), drive)
    cpu = time.process_time() - start
    assert ate_rmse(est.poses, truth, "yaw") <= EUROC_ATE_TARGET_M
    n = nees(pose_errors(est.poses, in_estimate_gauge(truth, est.poses)), est.pose_cov)[1:]
    assert np.all(np.isfinite(n))
    assert EUROC_NEES_BAND[0] < float(np.mean(n)) < EUROC_NEES_BAND[1]
    assert cpu < 20.0  # measured 0.9-1.4 s; the target (2 s on one core) is benchmarked, not tested
