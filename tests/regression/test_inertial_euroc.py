"""The raw-IMU smoother on EuRoC V1_01's first 30 s (the ASL folder's IMU and noise, gtsam's
eqvio tracks): its 4-dof aligned ATE and pose NEES against the ground truth, pinned with a margin
(measured values: docs/raw_imu.md and benchmarks/inertial_smoother.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.regression.conftest import REPO, skip_or_fail

pytestmark = pytest.mark.regression

DATA = REPO.parent / "shared" / "data" / "euroc-v1_01"
#: The issue's target for the 4-dof aligned ATE (m).
ATE_TARGET_M = 0.04
#: Upper pin on the mean pose NEES over the 601 frames (6 dof: about 6 when consistent).
NEES_UPPER = 3000.0  # measured 1997 (overconfident: docs/raw_imu.md); a pin, not a target


@pytest.fixture(scope="module")
def euroc():
    if not (DATA / "mav0" / "imu0" / "data.csv").is_file():
        skip_or_fail(f"EuRoC V1_01 not found at {DATA}")
    from vislam.eval.asl import read_asl_folder
    from vislam.eval.eqvio import EQVIO_FILE
    from vislam.graph.inertial_smoother import smooth

    try:
        drive = read_asl_folder(DATA, "eqvio")
    except Exception as exc:  # gtsam without its eqvio file
        skip_or_fail(f"{EQVIO_FILE} not readable: {exc}")
    from vislam.eval.trajectory_files import read_trajectory
    from vislam.graph.inertial_init import to_gravity_world

    gt = read_trajectory(DATA / "groundtruth" / "V1_01_easy.csv")
    t = drive.timestamps + drive.time_origin_ns * 1e-9
    i = np.clip(np.searchsorted(gt.times, t - 1e-3), 0, gt.times.size - 1)
    assert np.all(np.abs(gt.times[i] - t) < 1e-3)
    truth = to_gravity_world(gt.poses[i])
    return drive, truth, smooth(drive)


def test_smoother_ate_on_euroc_within_target(euroc):
    from vislam.eval.metrics import ate_rmse

    _, truth, result = euroc
    assert ate_rmse(result.estimate.poses, truth, "yaw") <= ATE_TARGET_M


def test_smoother_pose_nees_on_euroc_pinned(euroc):
    from vislam.eval.metrics import nees, pose_errors

    _, truth, result = euroc
    n = nees(pose_errors(result.estimate.poses, truth), result.estimate.pose_cov)
    assert np.all(np.isfinite(n))
    assert 0.5 < float(np.mean(n)) < NEES_UPPER
