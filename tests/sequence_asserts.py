"""Assertions on :class:`ekf.sequence.Sequence` shared by the tests."""

from __future__ import annotations

import numpy as np

from vislam.ekf.sequence import Sequence


def assert_same_sequence(a: Sequence, b: Sequence, name=True):
    if name:
        assert a.name == b.name
    np.testing.assert_array_equal(a.timestamps, b.timestamps)
    np.testing.assert_array_equal(a.linear_velocity, b.linear_velocity)
    np.testing.assert_array_equal(a.angular_velocity, b.angular_velocity)
    np.testing.assert_array_equal(a.obs.frame_ptr, b.obs.frame_ptr)
    np.testing.assert_array_equal(a.obs.track, b.obs.track)
    np.testing.assert_array_equal(a.obs.z, b.obs.z)
    assert a.n_tracks == b.n_tracks
    np.testing.assert_array_equal(a.calibration.K, b.calibration.K)
    assert a.calibration.baseline == b.calibration.baseline
    np.testing.assert_allclose(a.calibration.cam_T_imu, b.calibration.cam_T_imu, atol=1e-14)
