"""ekf.motion_check: tracks the velocities refute (a point that stands still under dead
reckoning and the model's noise)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from vislam.ekf.config import FilterConfig
from vislam.ekf.errors import InputError
from vislam.ekf.geometry import homogeneous, se3_exp
from vislam.ekf.model import model_config, model_sequence
from vislam.ekf.motion_check import (dead_reckoning_inverse, observation_jacobians,
                                     pose_error_covariance, track_tests)
from vislam.eval.sim_config import SimConfig
from vislam.eval.simulate import simulate


@pytest.fixture(scope="module")
def drive():
    """A drive with velocities as clean as kitti-utias's GPS/IMU (0.05 m/s, 0.005 rad/s)."""
    result = simulate(SimConfig(seed=1, n_frames=120, velocity_sigma=0.05, gyro_sigma=0.005))
    model = result.model
    return (model_sequence(result.sequence, model), model_config(FilterConfig(), model), model,
            result)


def _tests(seq, config, model, *_):
    return track_tests(seq, config.velocity_cov, config.velocity_pairing, model.pixel_sigma,
                       model.pixel_correlation_time)


def test_jacobians_match_finite_differences():
    rng = np.random.default_rng(3)
    U = se3_exp(rng.normal(scale=0.3, size=(4, 6)))
    X = se3_exp(rng.normal(scale=0.2, size=6))
    K = np.array([[700.0, 0.0, 600.0], [0.0, 690.0, 180.0], [0.0, 0.0, 1.0]])
    from vislam.ekf.camera import stereo_matrix

    M = stereo_matrix(K, 0.54)
    # a point in front of every camera: 8 m along each camera's axis from the first
    p = (np.linalg.inv(X @ U[0]) @ np.array([0.5, -0.3, 8.0, 1.0]))[:3]
    pred, J_eps, J_p, depth = observation_jacobians(U, X, M, p)
    h = 1e-6
    for j in range(6):
        d = np.zeros(6)
        d[j] = h
        up = observation_jacobians(se3_exp(d) @ U, X, M, p)[0]
        dn = observation_jacobians(se3_exp(-d) @ U, X, M, p)[0]
        np.testing.assert_allclose((up - dn) / (2 * h), J_eps[:, :, j], rtol=1e-5, atol=1e-4)
    for j in range(3):
        d = np.zeros(3)
        d[j] = h
        up = observation_jacobians(U, X, M, p + d)[0]
        dn = observation_jacobians(U, X, M, p - d)[0]
        np.testing.assert_allclose((up - dn) / (2 * h), J_p[:, :, j], rtol=1e-5, atol=1e-4)
    assert np.all(depth > 0)


def test_pose_error_covariance_is_the_propagated_interval_noise():
    """Against the brute-force sum over intervals of J_i Phi_{k_i <- n+1} Q_n (...)^T."""
    rng = np.random.default_rng(0)
    T = 7
    F = rng.normal(size=(T - 1, 6, 6)) * 0.3 + np.eye(6)
    Q = np.array([np.diag(rng.uniform(0.1, 1.0, 6)) for _ in range(T - 1)])
    frames = np.array([1, 2, 4, 6])
    J = rng.normal(size=(4, 3, 6))
    S = pose_error_covariance(frames, J, F, Q)
    brute = np.zeros_like(S)
    for n in range(frames[0], frames[-1]):
        G = np.zeros((12, 6))
        for i, k in enumerate(frames):
            if k >= n + 1:
                Phi = np.eye(6)
                for l in range(n + 1, k):
                    Phi = F[l] @ Phi
                G[3 * i:3 * i + 3] = J[i] @ Phi
        brute += G @ Q[n] @ G.T
    np.testing.assert_allclose(S, brute, rtol=1e-12, atol=1e-12)


def test_dead_reckoning_follows_the_filters_prediction(drive):
    seq, config = drive[:2]
    from vislam.ekf.prediction import motion_increment, paired_velocities

    U, F = dead_reckoning_inverse(seq.velocities, seq.dt, config.velocity_pairing)
    u = paired_velocities(seq.velocities, config.velocity_pairing)
    np.testing.assert_allclose(U[5], motion_increment(seq.dt[4], u[4]) @ U[4], atol=1e-12)
    assert F.shape == (seq.n_frames - 1, 6, 6)


def test_static_tracks_under_the_true_model_give_chi_square_statistics(drive):
    t = _tests(*drive)
    ok = np.isfinite(t.statistic)
    assert ok.mean() > 0.98
    assert np.mean(t.statistic[ok] / t.dof[ok]) == pytest.approx(1.0, abs=0.15)
    assert np.mean(t.p_value[ok] < 1e-4) < 0.01


def test_a_moving_object_is_refuted_and_the_static_world_is_not(drive):
    """Eight tracks moved onto a body that drives ahead at 3 m/s (a car pulling away, seen
    through the true poses with 1 px of noise): every one is refuted at 1e-4, and at most 1 %
    of the other tracks are."""
    from vislam.ekf.camera import project

    seq, config, model, result = drive
    o = seq.obs
    calib = seq.calibration
    X, M = np.asarray(calib.cam_T_imu), np.asarray(calib.M)
    t0 = _tests(*drive)
    moving = t0.track[t0.last - t0.first >= 8][:8]
    assert moving.size == 8
    rng = np.random.default_rng(0)
    z = o.z.copy()
    for track in moving:
        rows = np.flatnonzero(o.track == track)
        frames = o.frame_index[rows]
        k0 = frames.min()
        p0 = result.landmarks[track]
        heading = result.poses[k0][:3, 0]
        for r, k in zip(rows, frames):
            p = p0 + 3.0 * (seq.timestamps[k] - seq.timestamps[k0]) * heading
            z[r] = project(M, X @ np.linalg.inv(result.poses[k]) @ homogeneous(p))
            z[r] += rng.normal(scale=model.pixel_sigma, size=4)
    moved = dataclasses.replace(seq, obs=dataclasses.replace(o, z=z))
    t = _tests(moved, config, model)
    refuted = set(t.track[t.p_value < 1e-4].tolist())
    assert set(moving.tolist()) <= refuted
    assert len(refuted - set(moving.tolist())) <= 0.01 * t.track.size


def test_bad_noise_is_refused_naming_it(drive):
    seq, config = drive[:2]
    with pytest.raises(InputError, match="pixel sigma 0"):
        track_tests(seq, config.velocity_cov, config.velocity_pairing, 0.0)
    with pytest.raises(InputError, match=r"twist covariance of shape \(3, 3\)"):
        track_tests(seq, np.eye(3), config.velocity_pairing, 1.0)
