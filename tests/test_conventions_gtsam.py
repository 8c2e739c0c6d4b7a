"""ekf/conventions.py checked against GTSAM itself, both ways, and GTSAM's Marginals converted.

The Estimate convention is ``T_true = T @ se3_exp(xi)`` with ``xi = [rho; phi]``; GTSAM's Pose3
is perturbed on the right with ``[w; v]`` through ``Pose3.Expmap``; the EKF perturbs the inverse
pose on the left, ``U_true = se3_exp(d) @ U``.
"""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from vislam.ekf.conventions import (
    EKF_TO_GTSAM,
    ESTIMATE_TO_GTSAM,
    convert_joint_pose_block,
    ekf_cov_to_gtsam,
    estimate_cov_to_gtsam,
    gtsam_cov_to_ekf,
    gtsam_cov_to_estimate,
)
from vislam.ekf.geometry import se3_exp, se3_inv
from vislam.graph.factors import relative_motions
from vislam.graph.marginals import gtsam_marginals, schur_marginals
from vislam.graph.pose_conversions import L, X, expmap_right_jacobian, from_pose3, to_pose3, twist_to_gtsam


def random_pose(rng: np.random.Generator) -> np.ndarray:
    return se3_exp(np.concatenate([rng.normal(0, 5, 3), rng.normal(0, 1.0, 3)]))


def random_cov(rng: np.random.Generator, n: int = 6) -> np.ndarray:
    A = rng.normal(size=(n, n))
    return A @ A.T / n + 0.1 * np.eye(n)


@pytest.mark.parametrize("seed", range(5))
def test_estimate_tangent_is_gtsam_local_coordinates(seed):
    rng = np.random.default_rng(seed)
    T = random_pose(rng)
    xi = rng.normal(0, 0.3, 6)  # not small: exact with the Expmap chart
    T_true = T @ se3_exp(xi)
    pose, pose_true = to_pose3(T), to_pose3(T_true)
    # GTSAM -> Estimate: the same relative pose from Pose3.Expmap
    np.testing.assert_allclose(from_pose3(pose.compose(gtsam.Pose3.Expmap(ESTIMATE_TO_GTSAM @ xi))),
                               T_true, atol=1e-12)
    # Estimate -> GTSAM: Logmap of the relative pose
    np.testing.assert_allclose(gtsam.Pose3.Logmap(pose.between(pose_true)), ESTIMATE_TO_GTSAM @ xi, atol=1e-9)
    # localCoordinates agrees to first order (its chart may differ from Expmap at second order)
    small = 1e-4 * xi
    local = pose.localCoordinates(to_pose3(T @ se3_exp(small)))
    np.testing.assert_allclose(local, ESTIMATE_TO_GTSAM @ small, atol=1e-10)
    np.testing.assert_allclose(twist_to_gtsam(xi), ESTIMATE_TO_GTSAM @ xi)


@pytest.mark.parametrize("seed", range(5))
def test_ekf_tangent_to_gtsam(seed):
    rng = np.random.default_rng(seed)
    T = random_pose(rng)
    U = se3_inv(T)
    d = rng.normal(0, 0.3, 6)
    U_true = se3_exp(d) @ U
    local = gtsam.Pose3.Logmap(to_pose3(T).between(to_pose3(se3_inv(U_true))))
    np.testing.assert_allclose(local, EKF_TO_GTSAM @ d, atol=1e-9)
    # and back
    np.testing.assert_allclose(np.linalg.solve(EKF_TO_GTSAM, local), d, atol=1e-9)


def test_covariance_conversions_monte_carlo():
    """Samples drawn in the EKF convention, pushed through GTSAM, have the converted covariance."""
    rng = np.random.default_rng(7)
    T = random_pose(rng)
    P_ekf = 1e-4 * random_cov(rng)
    U = se3_inv(T)
    n = 20000
    d = rng.multivariate_normal(np.zeros(6), P_ekf, size=n)
    pose = to_pose3(T)
    locals_ = np.stack([pose.localCoordinates(to_pose3(se3_inv(se3_exp(di) @ U))) for di in d])
    P_mc = np.cov(locals_.T)
    P_expected = ekf_cov_to_gtsam(P_ekf)
    scale = np.sqrt(np.outer(np.diag(P_expected), np.diag(P_expected)))
    assert np.max(np.abs(P_mc - P_expected) / scale) < 0.05
    np.testing.assert_allclose(gtsam_cov_to_ekf(P_expected), P_ekf, atol=1e-15)
    np.testing.assert_allclose(gtsam_cov_to_estimate(estimate_cov_to_gtsam(P_ekf)), P_ekf)


def test_joint_pose_landmark_block_against_gtsam():
    """GTSAM's joint [pose, landmark] marginal of a small stereo graph, converted to the Estimate
    and EKF conventions, matches samples pushed through the definitions of each convention."""
    from vislam.ekf.conventions import EKF_TO_ESTIMATE
    from vislam.ekf.geometry import se3_log

    rng = np.random.default_rng(3)
    T = random_pose(rng)
    K = gtsam.Cal3_S2Stereo(700.0, 700.0, 0.0, 600.0, 180.0, 0.5)
    point = T[:3, :3] @ np.array([0.5, -0.3, 8.0]) + T[:3, 3]
    camera = gtsam.StereoCamera(to_pose3(T), K)
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorPose3(X(0), to_pose3(T), gtsam.noiseModel.Gaussian.Covariance(1e-4 * random_cov(rng))))
    noise = gtsam.noiseModel.Isotropic.Sigma(3, 1.0)
    graph.add(gtsam.GenericStereoFactor3D(camera.project(point), noise, X(0), L(0), K))
    graph.add(gtsam.PriorFactorPoint3(L(0), point, gtsam.noiseModel.Isotropic.Sigma(3, 100.0)))
    values = gtsam.Values()
    values.insert(X(0), to_pose3(T))
    values.insert(L(0), point)
    joint_g = gtsam.Marginals(graph, values).jointMarginalCovariance(gtsam.KeyVector([X(0), L(0)])).fullMatrix()
    assert abs(joint_g[:6, 6:]).max() > 1e-6  # really coupled
    joint_est = convert_joint_pose_block(joint_g, ESTIMATE_TO_GTSAM.T)
    joint_ekf = convert_joint_pose_block(joint_est, EKF_TO_ESTIMATE)
    # samples in GTSAM's convention, mapped through the definitions
    n = 20000
    s = rng.multivariate_normal(np.zeros(9), joint_g, size=n)
    pose = to_pose3(T)
    T_s = np.stack([from_pose3(pose.compose(gtsam.Pose3.Expmap(si[:6]))) for si in s])
    xi = se3_log(se3_inv(T) @ T_s)  # Estimate: T_true = T exp(xi)
    U = se3_inv(T)
    d = se3_log(se3_inv(T_s) @ se3_inv(U))  # EKF: U_true = exp(d) U
    for tangent, expected in ((xi, joint_est), (d, joint_ekf)):
        cov = np.cov(np.hstack([tangent, point + s[:, 6:]]).T)
        scale = np.sqrt(np.outer(np.diag(expected), np.diag(expected)))
        assert np.max(np.abs(cov - expected) / scale) < 0.05


def test_marginals_of_a_prior_convert_to_the_estimate_covariance():
    rng = np.random.default_rng(11)
    T = random_pose(rng)
    P_est = 1e-3 * random_cov(rng)
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorPose3(X(0), to_pose3(T), gtsam.noiseModel.Gaussian.Covariance(estimate_cov_to_gtsam(P_est))))
    values = gtsam.Values()
    values.insert(X(0), to_pose3(T))
    pose_cov, _ = gtsam_marginals(graph, values, 1, np.zeros(0, int), 0)
    np.testing.assert_allclose(pose_cov[0], P_est, rtol=1e-9)
    pose_cov, _ = schur_marginals(graph, values, 1, np.zeros(0, int), 0)
    np.testing.assert_allclose(pose_cov[0], P_est, rtol=1e-9)


def test_expmap_right_jacobian_matches_finite_differences():
    rng = np.random.default_rng(5)
    xi = rng.normal(0, 0.5, 6)
    J = expmap_right_jacobian(xi)
    E = gtsam.Pose3.Expmap(xi)
    eps = 1e-6
    num = np.zeros((6, 6))
    for i in range(6):
        d = np.zeros(6)
        d[i] = eps
        num[:, i] = gtsam.Pose3.Logmap(E.between(gtsam.Pose3.Expmap(xi + d))) / eps
    np.testing.assert_allclose(J, num, atol=1e-5)


def test_motion_covariance_monte_carlo():
    """Twist noise W over tau gives the relative-pose covariance used by the BetweenFactor."""
    from vislam.ekf.config import FilterConfig
    from vislam.ekf.sequence import Calibration, Observations, Sequence

    rng = np.random.default_rng(2)
    u = np.array([[8.0, 0.3, -0.1, 0.05, -0.02, 0.4]] * 2)
    tau = 0.5  # long interval so the Jacobian matters
    seq = Sequence("t", np.array([0.0, tau]), u[:, :3], u[:, 3:],
                   Observations.from_rows(np.zeros(0), np.zeros(0), np.zeros((0, 4)), 2), 0,
                   Calibration(np.eye(3), 0.5, np.eye(4)))
    config = FilterConfig(velocity_sigma=0.5, gyro_sigma=0.05, velocity_pairing="current")
    deltas, covs = relative_motions(seq, config)
    w = rng.multivariate_normal(np.zeros(6), config.velocity_cov, size=20000)
    delta = to_pose3(deltas[0])
    samples = np.stack([delta.localCoordinates(to_pose3(se3_exp(tau * (u[0] + wi)))) for wi in w])
    P_mc = np.cov(samples.T)
    scale = np.sqrt(np.outer(np.diag(covs[0]), np.diag(covs[0])))
    assert np.max(np.abs(P_mc - covs[0]) / scale) < 0.06
    # without the Jacobian the translation-rotation coupling would be missing
    naive = estimate_cov_to_gtsam(tau**2 * config.velocity_cov)
    assert np.max(np.abs(P_mc - naive) / scale) > 0.1
