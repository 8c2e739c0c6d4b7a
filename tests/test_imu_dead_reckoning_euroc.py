"""Rest initialisation and raw-IMU dead reckoning on the shared EuRoC V1_01 IMU (regression tier:
real data). The drive is the IMU with the ground truth's frame times and no tracks."""

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tests.conftest import missing_data
from vislam.ekf.geometry import se3_inv, se3_log
from vislam.ekf.inertial import STANDARD_GRAVITY, InertialCalibration, InertialDrive
from vislam.ekf.inertial_dead_reckoning import run_inertial_dead_reckoning
from vislam.ekf.sequence import Observations
from vislam.eval.asl import read_imu_csv
from vislam.eval.imu_sim_config import EUROC_IMU_NOISE

EUROC = Path(__file__).resolve().parent.parent.parent / "shared" / "data" / "euroc-v1_01"


@pytest.fixture(scope="module")
def euroc():
    if not (EUROC / "mav0" / "imu0" / "data.csv").is_file():
        missing_data(f"{EUROC} not found")
    ns, imu = read_imu_csv(EUROC / "mav0" / "imu0" / "data.csv")
    gt = np.loadtxt(EUROC / "groundtruth" / "V1_01_easy.csv", delimiter=",", comments="#")
    t = (gt[:, 0].astype(np.int64) - ns[0]) * 1e-9
    keep = t <= t[0] + 30.0
    t, gt = t[keep], gt[keep]
    poses = np.tile(np.eye(4), (t.size, 1, 1))
    poses[:, :3, :3] = Rotation.from_quat(gt[:, [5, 6, 7, 4]]).as_matrix()
    poses[:, :3, 3] = gt[:, 1:4]
    obs = Observations(np.zeros(t.size + 1, dtype=np.int64), np.zeros(0, dtype=np.int64),
                       np.zeros((0, 2)))
    calib = InertialCalibration(np.eye(3), np.eye(4), EUROC_IMU_NOISE, gravity=STANDARD_GRAVITY)
    return InertialDrive("V1_01", t, imu, obs, 0, calib), poses, gt


@pytest.mark.realdata
def test_rest_and_dead_reckoning_on_euroc(euroc):
    drive, poses, gt = euroc
    est = run_inertial_dead_reckoning(drive)
    start, end = est.info["rest_s"]
    assert start == 0.0 and end >= 2.0  # standing with its motors running
    # the rest's gyro bias is the ground truth's
    bg = est.info["final_gyro_bias"]  # dead reckoning keeps the rest's biases
    np.testing.assert_allclose(bg, gt[0, 11:14], atol=2e-3)
    # yaw and position aligned at frame 0 (the dead reckoning's gauge)
    Rd = poses[0, :3, :3] @ est.poses[0, :3, :3].T
    yaw = np.arctan2(Rd[1, 0], Rd[0, 0])
    A = np.eye(4)
    A[:3, :3] = Rotation.from_rotvec([0.0, 0.0, yaw]).as_matrix()
    A[:3, 3] = poses[0, :3, 3] - A[:3, :3] @ est.poses[0, :3, 3]
    for k in (100, 200, drive.n_frames - 1):
        xi = se3_log(se3_inv(A @ est.poses[k]) @ poses[k])
        sigma = np.sqrt(np.diag(est.pose_cov[k]))
        assert np.all(np.abs(xi[:3]) < 3 * sigma[:3]), (k, xi, sigma)
