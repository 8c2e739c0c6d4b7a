"""The raw-IMU smoother on EuRoC V1_01's first 30 s (the ASL folder's IMU and noise, gtsam's
eqvio tracks): its 4-dof aligned ATE and pose NEES against the ground truth, pinned with a margin
(measured values: docs/raw_imu.md and benchmarks/inertial_smoother.py)."""

from __future__ import annotations


import numpy as np
import pytest


pytestmark = pytest.mark.regression

#: The issue's target for the 4-dof aligned ATE (m).
ATE_TARGET_M = 0.04
#: Pin on the mean pose NEES over the 601 frames against the truth in the estimate's gauge
#: (6 dof: about 6 when consistent): measured 465 with the identified pixel sigma
#: (overconfident: docs/raw_imu.md); a pin, not a target.
NEES_BAND = (300.0, 700.0)
#: The pixel sigma identified from the residuals (px): measured 0.834.
PIXEL_SIGMA_BAND = (0.75, 0.92)
#: The largest position gap between the incremental (iSAM2) and the batch trajectories (m):
#: measured 0.026.
INCREMENTAL_GAP_M = 0.05


@pytest.fixture(scope="module")
def euroc(euroc_drive):
    from vislam.graph.inertial_smoother import batch_solve, build_problem, incremental_solve, to_result

    drive, truth = euroc_drive
    problem = build_problem(drive)
    inc = incremental_solve(problem)
    return drive, truth, to_result(problem, batch_solve(problem, inc)), inc


def test_smoother_ate_on_euroc_within_target(euroc):
    from vislam.eval.metrics import ate_rmse

    _, truth, result, _ = euroc
    assert ate_rmse(result.estimate.poses, truth, "yaw") <= ATE_TARGET_M


def test_incremental_and_batch_agree_on_euroc(euroc):
    from vislam.eval.metrics import ate_rmse
    from vislam.graph.inertial_smoother import X

    drive, truth, result, inc = euroc
    poses = np.stack([inc.values.atPose3(X(k)).matrix() for k in range(drive.n_frames)])
    gap = np.linalg.norm(poses[:, :3, 3] - result.estimate.poses[:, :3, 3], axis=1)
    assert gap.max() <= INCREMENTAL_GAP_M
    assert ate_rmse(poses, truth, "yaw") <= ATE_TARGET_M


def test_pixel_sigma_identified_on_euroc(euroc):
    _, _, result, _ = euroc
    assert result.info["pixel_sigma_identified"]
    assert PIXEL_SIGMA_BAND[0] < result.info["pixel_sigma"] < PIXEL_SIGMA_BAND[1]


def test_smoother_pose_nees_on_euroc_pinned(euroc):
    from vislam.eval.metrics import nees, pose_errors

    _, truth, result, _ = euroc
    from vislam.graph.inertial_init import in_estimate_gauge

    err = pose_errors(result.estimate.poses, in_estimate_gauge(truth, result.estimate.poses))
    assert np.allclose(err[0, :3], 0.0) and np.linalg.norm(err[0, 3:]) < 5e-3  # frame 0: tilt only
    n = nees(err, result.estimate.pose_cov)
    assert np.all(np.isfinite(n))
    assert NEES_BAND[0] < float(np.mean(n)) < NEES_BAND[1]
