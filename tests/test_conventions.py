"""Pose-perturbation conventions (numpy side; the GTSAM side is in test_conventions_gtsam.py)."""

import numpy as np

from vislam.ekf import conventions as c
from vislam.ekf import geometry as g
from tests.test_geometry import random_poses

RNG = np.random.default_rng(5)


def test_ekf_left_inverse_pose_perturbation_is_minus_right_pose_perturbation_exactly():
    for T in random_poses(10):
        d = RNG.normal(scale=0.3, size=6)
        U_true = g.se3_exp(d) @ g.se3_inv(T)
        xi = g.se3_log(g.se3_inv(T) @ g.se3_inv(U_true))
        assert np.allclose(xi, c.EKF_TO_ESTIMATE @ d, atol=1e-10)


def test_ekf_estimate_round_trip_and_cross_covariance_sign():
    A = RNG.normal(size=(9, 9))
    P = A @ A.T
    P_est = c.convert_joint_pose_block(P, c.EKF_TO_ESTIMATE)
    assert np.allclose(P_est[:6, :6], P[:6, :6])
    assert np.allclose(P_est[:6, 6:], -P[:6, 6:])
    assert np.allclose(P_est[6:, 6:], P[6:, 6:])
    back = c.convert_joint_pose_block(P_est, np.linalg.inv(c.EKF_TO_ESTIMATE))
    assert np.allclose(back, P)
    assert np.allclose(c.estimate_cov_to_ekf(c.ekf_cov_to_estimate(P[:6, :6])), P[:6, :6])


def test_gtsam_permutation_round_trip():
    A = RNG.normal(size=(6, 6))
    P = A @ A.T
    G = c.estimate_cov_to_gtsam(P)
    assert np.allclose(G[:3, :3], P[3:, 3:]) and np.allclose(G[3:, 3:], P[:3, :3])
    assert np.allclose(c.gtsam_cov_to_estimate(G), P)
    assert np.allclose(c.gtsam_cov_to_ekf(c.ekf_cov_to_gtsam(P)), P)


def test_left_to_right_perturbation_monte_carlo():
    T = random_poses(1)[0]
    A = RNG.normal(size=(6, 6)) * 0.01
    P_left = A @ A.T
    xi_l = RNG.multivariate_normal(np.zeros(6), P_left, size=20000)
    T_true = g.se3_exp(xi_l) @ T
    xi_r = g.se3_log(g.se3_inv(T) @ T_true)
    emp = np.cov(xi_r.T)
    pred = c.left_cov_to_estimate(T, P_left)
    assert np.allclose(emp, pred, atol=0.05 * np.abs(pred).max())
    assert np.allclose(c.estimate_cov_to_left(T, pred), P_left)
