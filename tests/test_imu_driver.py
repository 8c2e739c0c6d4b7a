"""The per-frame driver on raw-IMU drives (ekf/driver.py): what a filter is given, how an
interval's IMU samples are cut, and the velocity path untouched by it."""

import numpy as np
import pytest

from vislam.ekf.driver import inertial_motion_inputs, run_filter
from vislam.ekf.filter import FrameObservations, Landmarks, MotionInput, UpdateCounts
from vislam.ekf.inertial import InertialDrive
from vislam.ekf.inertial_dead_reckoning import WORLD_GRAVITY_DIRECTION, strapdown_frames
from vislam.ekf.strapdown import integrate
from vislam.eval.imu_sim import simulate_imu
from vislam.eval.imu_sim_config import ImuSimConfig


def _drive(camera="mono", n_frames=41, **kw):
    return simulate_imu(ImuSimConfig(camera=camera, n_frames=n_frames, n_landmarks=30, **kw))


def test_every_instant_between_frames_is_integrated_once():
    drive, _ = _drive()
    # frames off the samples too: move every camera time by a third of a sample
    shifted = InertialDrive(drive.name, drive.timestamps + 0.0017, drive.imu, drive.obs,
                            drive.n_tracks, drive.calibration)
    for d in (drive, shifted):
        motion = inertial_motion_inputs(d)
        assert len(motion) == d.n_frames - 1
        held = np.zeros(d.imu.time.size)  # time each sample is held over all intervals
        ends = np.append(d.imu.time[1:], np.inf)
        index = {float(t): i for i, t in enumerate(d.imu.time)}
        for k, m in enumerate(motion, start=1):
            assert m.frame == k and m.start == d.timestamps[k - 1] and m.end == d.timestamps[k]
            assert m.dt == pytest.approx(m.end - m.start)
            assert np.all(np.isnan(m.twist))
            assert m.imu.time[0] <= m.start < m.imu.time[1] if m.imu.time.size > 1 else True
            assert np.all(m.imu.time[1:] > m.start) and np.all(m.imu.time <= m.end)
            for t in m.imu.time:
                i = index[float(t)]
                held[i] += max(min(ends[i], m.end) - max(t, m.start), 0.0)
        t0, t1 = d.timestamps[0], d.timestamps[-1]
        expect = np.clip(np.minimum(ends, t1) - np.maximum(d.imu.time, t0), 0.0, None)
        np.testing.assert_allclose(held, expect, atol=1e-12)


class _Recorder:
    """A filter that dead-reckons the raw IMU and records what it is given."""

    name = "recorder"

    def initialise(self, drive, config, guard):
        self.drive = drive
        self.calls = []
        self.state, self.P = None, None
        self.initial = strapdown_frames(drive).initial
        self.state, self.P = self.initial.state, self.initial.cov
        self.g = drive.calibration.gravity * WORLD_GRAVITY_DIRECTION

    def predict(self, motion: MotionInput):
        self.calls.append(("predict", motion.frame, motion.imu is not None))
        self.state, self.P = integrate(self.state, self.P, motion.imu, motion.start, motion.end,
                                       self.g, self.drive.calibration.noise)

    def update(self, frame: FrameObservations):
        self.calls.append(("update", frame.frame, frame.z.shape[1]))
        return UpdateCounts()

    def marginalise(self, tracks):
        self.calls.append(("marginalise", tracks.size))

    def pose(self):
        return self.state.pose

    def pose_cov(self):
        return np.eye(6)

    def active_landmarks(self):
        return Landmarks.none()

    def landmark_map(self):
        n = self.drive.n_tracks
        return np.full((n, 3), np.nan), np.full((n, 3, 3), np.nan)

    def info(self):
        return {}


@pytest.mark.parametrize("camera,columns", [("mono", 2), ("stereo", 4)])
def test_a_filter_over_a_raw_imu_drive_gets_the_samples_and_pixels(camera, columns):
    drive, _ = _drive(camera)
    f = _Recorder()
    est = run_filter(f, drive)
    assert f.drive is drive  # no track needed splitting: the drive as given
    kinds = [c[0] for c in f.calls]
    assert kinds.count("predict") == drive.n_frames - 1
    assert kinds.count("update") == kinds.count("marginalise") == drive.n_frames
    assert all(c[2] for c in f.calls if c[0] == "predict")
    assert {c[2] for c in f.calls if c[0] == "update"} == {columns}
    # driving strapdown through the loop is dead reckoning, to the bit
    dr = strapdown_frames(drive)
    np.testing.assert_array_equal(est.poses, dr.poses)
    assert est.info["cleaned"] is False
    assert est.info["track_origin"] == list(range(drive.n_tracks))


def test_tracks_carried_through_gaps_split_beyond_the_bound():
    drive, _ = _drive(n_frames=121)
    est = run_filter(_Recorder(), drive, max_carried=1)
    splits = est.info.get("n_carry_splits", 0)
    assert splits > 0
    assert len(est.info["track_origin"]) == drive.n_tracks + splits
    assert est.landmarks.shape[0] == drive.n_tracks + splits
