"""eval.baseline_truth: the baseline on which a drive's ground truth and its pixels agree."""

from __future__ import annotations

import numpy as np
import pytest

from vislam.ekf.errors import InputError
from vislam.ekf.geometry import se3_inv
from vislam.eval.baseline_truth import baseline_from_truth, triangulate_left
from vislam.eval.sim_config import SimConfig
from vislam.eval.simulate import simulate


@pytest.fixture(scope="module")
def drive():
    result = simulate(SimConfig(seed=1, n_frames=150))
    seq = result.sequence
    camera_poses = result.poses @ se3_inv(result.true_cam_T_imu)  # world_T_cam
    return seq, camera_poses


def _fit(drive, scale: float):
    seq, P = drive
    o = seq.obs
    return baseline_from_truth(P, o.frame_index, o.track, o.z, seq.calibration.K,
                               seq.calibration.baseline * scale)


def test_left_rays_triangulate_their_point_exactly():
    rng = np.random.default_rng(0)
    K = np.array([[700.0, 0.0, 600.0], [0.0, 700.0, 180.0], [0.0, 0.0, 1.0]])
    X = np.array([1.5, -0.7, 14.0])
    poses = np.repeat(np.eye(4)[None], 6, axis=0)
    poses[:, :3, 3] = rng.normal(scale=0.5, size=(6, 3)) + np.c_[np.zeros(6), np.zeros(6), np.arange(6.0)]
    Xc = np.einsum("kij,kj->ki", np.linalg.inv(poses)[:, :3, :3], X[None] - poses[:, :3, 3])
    uv = np.c_[700.0 * Xc[:, 0] / Xc[:, 2] + 600.0, 700.0 * Xc[:, 1] / Xc[:, 2] + 180.0]
    np.testing.assert_allclose(triangulate_left(poses, K, uv), X, rtol=1e-9)


def test_the_files_baseline_when_it_is_the_pixels(drive):
    fit = _fit(drive, 1.0)
    assert fit.n_tracks > 50
    assert fit.ratio == pytest.approx(1.0, abs=0.004)
    assert fit.pixels_baseline == pytest.approx(drive[0].calibration.baseline, rel=0.004)


def test_a_file_baseline_two_percent_short_is_seen_in_every_band(drive):
    fit = _fit(drive, 1.0 / 1.02)
    assert fit.ratio == pytest.approx(1.02, abs=0.004)
    assert fit.pixels_baseline == pytest.approx(drive[0].calibration.baseline, rel=0.004)
    for band in fit.bands:
        if band.n_observations > 100:
            assert band.ratio == pytest.approx(1.02, abs=0.008), band


def test_bad_input_is_refused_naming_what_is_wrong(drive):
    seq, P = drive
    o = seq.obs
    with pytest.raises(InputError, match="camera poses of shape"):
        baseline_from_truth(P[:1], o.frame_index, o.track, o.z, seq.calibration.K, 0.5)
    with pytest.raises(InputError, match="stereo pixels"):
        baseline_from_truth(P, o.frame_index, o.track, o.z[:, :2], seq.calibration.K, 0.5)
    with pytest.raises(InputError, match="baseline -0.5"):
        baseline_from_truth(P, o.frame_index, o.track, o.z, seq.calibration.K, -0.5)
    with pytest.raises(InputError, match="no track spans"):
        baseline_from_truth(P, o.frame_index, o.track, o.z, seq.calibration.K, 0.5, min_views=10**6)
