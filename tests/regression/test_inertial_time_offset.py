"""The camera-IMU time offset of raw-IMU drives (issue 39 item 1): found by maximum likelihood
around the raw-IMU smoother on simulated flights and car drives of both cameras with offsets of
0, +-30 and 100 ms, and on EuRoC V1_01 (graph.inertial_time_offset; figures in
docs/findings.md)."""

from __future__ import annotations

import numpy as np
import pytest

pytestmark = pytest.mark.regression

#: The issue's figure (s), or 3 of the estimate's sigmas where those are larger (a car on a
#: simulated road determines its offset to about 2 ms: little turning, little acceleration).
TOLERANCE_S = 0.002
SIGMAS = 3.0

CASES = [  # scenario, camera, offset (s), seed
    ("room", "mono", 0.0, 1),
    ("room", "mono", 0.03, 1),
    ("room", "stereo", 0.1, 2),
    ("room", "stereo", -0.03, 1),
    ("road", "stereo", 0.03, 1),
    ("road", "mono", 0.1, 2),
    ("road", "mono", 0.0, 3),
]


def _drive(scenario, camera, offset, seed):
    from vislam.eval.imu_sim import simulate_imu
    from vislam.eval.imu_sim_config import ImuSimConfig

    return simulate_imu(ImuSimConfig(scenario=scenario, camera=camera, seed=seed, n_frames=201,
                                     imu_time_offset=offset))


@pytest.mark.parametrize("scenario,camera,offset,seed", CASES)
def test_offset_recovered_on_simulated_drives(scenario, camera, offset, seed):
    from vislam.graph.inertial_time_offset import identify_imu_time_offset

    drive, _ = _drive(scenario, camera, offset, seed)
    fit = identify_imu_time_offset(drive)
    print(f"\n{scenario} {camera} seed {seed}: true {1e3 * offset:+.1f} ms, {fit.words()}")
    assert abs(fit.estimate - offset) <= max(TOLERANCE_S, SIGMAS * fit.sigma)
    assert fit.kept == (offset != 0.0)
    if scenario == "room":  # a flight's offset is determined to about 1 ms: the 2 ms hold
        assert abs(fit.estimate - offset) <= TOLERANCE_S


def test_the_identified_offset_gives_the_accuracy_of_the_true_one():
    """The smoother on the drive moved by the identified offset is within 5 % (aligned ATE) of
    the smoother on the drive moved by the true one, and far better than on the drive as given."""
    from vislam.ekf.inertial import imu_on_camera_clock
    from vislam.eval.metrics import ate_rmse
    from vislam.graph.inertial_init import to_gravity_world
    from vislam.graph.inertial_smoother import smooth
    from vislam.graph.inertial_time_offset import identify_imu_time_offset

    drive, truth = _drive("room", "mono", 0.03, 1)
    fit = identify_imu_time_offset(drive)
    ates = {}
    for name, d in (("identified", fit.offset), ("true", 0.03), ("given", 0.0)):
        moved, head, tail = imu_on_camera_clock(drive, d)
        est = smooth(moved).estimate
        frames = np.arange(head, drive.n_frames - tail)
        ates[name] = ate_rmse(est.poses, to_gravity_world(truth.frame_poses[frames]), align="yaw")
    print(f"\naligned ATE (m): {ates}")
    assert ates["identified"] <= 1.05 * ates["true"]
    assert ates["given"] > 1.5 * ates["true"]


def test_euroc_offset(euroc_drive):
    """EuRoC V1_01's IMU is found 2.5 ms late against its camera (half an IMU sample: every
    raw-IMU estimator holds a sample from its stamp to the next one, which an instantaneous
    sample at its stamp is not; docs/findings.md), to a tenth of a millisecond."""
    from vislam.graph.inertial_time_offset import identify_imu_time_offset

    drive, _ = euroc_drive
    fit = identify_imu_time_offset(drive)
    print(f"\nEuRoC V1_01: {fit.words()} ({fit.seconds:.1f} s)")
    assert fit.kept and 0.0015 < fit.estimate < 0.0035 and fit.sigma < 0.0005
