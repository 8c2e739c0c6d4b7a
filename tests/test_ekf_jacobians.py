"""Finite-difference checks of every EKF Jacobian: prediction, stereo model, initialisation."""

import numpy as np
import pytest

from vislam.ekf.camera import stereo_matrix
from vislam.ekf.geometry import se3_exp, se3_inv, se3_log
from vislam.ekf.prediction import (
    GYRO_SELECT,
    error_state_transition,
    paired_velocities,
    predict_mean,
    predict_pose,
    prediction_jacobian,
    se3_left_jacobian,
    twist_error_matrix,
)
from vislam.ekf.sequence import Calibration
from vislam.ekf.stereo_update import StereoModel, batched_landmark_update, chi2_gate
from tests.numdiff import numeric_jacobian

K = np.array([[707.0912, 0.0, 601.8873], [0.0, 707.0912, 183.1104], [0.0, 0.0, 1.0]])
CAM_T_IMU = np.array(
    [
        [-1.08863514e-03, -9.99976347e-01, 6.78718180e-03, 1.14389871e00],
        [-8.51207214e-03, -6.77767115e-03, -9.99940872e-01, -3.12718471e-01],
        [9.99963177e-01, -1.14634293e-03, -8.50449310e-03, 7.26546045e-01],
        [0.0, 0.0, 0.0, 1.0],
    ]
)
CALIB = Calibration(K=K, baseline=0.5371506532679237, cam_T_imu=CAM_T_IMU)


def _model(sigma=1.0, **kw):
    return StereoModel.create(CALIB, sigma**2 * np.eye(4), **kw)


def _scene(seed=0, n=7):
    """A random inverse pose U and landmarks in front of the camera."""
    rng = np.random.default_rng(seed)
    U = se3_exp(rng.normal(size=6) * [3, 3, 1, 0.1, 0.1, 0.5])
    p_cam = np.column_stack(
        [rng.uniform(-8, 8, n), rng.uniform(-2, 2, n), rng.uniform(4, 40, n)]
    )
    s = p_cam @ CALIB.imu_T_cam[:3, :3].T + CALIB.imu_T_cam[:3, 3]
    m = (se3_inv(U) @ np.column_stack([s, np.ones(n)]).T).T[:, :3]
    return U, m


def _pixels(model, U, m):
    return model.predicted_pixels(model.camera_points(U, m))


def test_prediction_jacobian_matches_exact_motion():
    rng = np.random.default_rng(1)
    U = se3_exp(rng.normal(size=6))
    u, tau = np.array([9.0, 0.3, -0.2, 0.02, -0.03, 0.25]), 0.1
    F = prediction_jacobian(tau, u)

    def f(d):  # perturbation of the predicted mean, as a function of the prior perturbation
        return se3_log(predict_mean(se3_exp(d) @ U, tau, u) @ se3_inv(predict_mean(U, tau, u)))

    np.testing.assert_allclose(F, numeric_jacobian(f, np.zeros(6)), atol=1e-7)


def test_predict_pose_covariance_and_mean():
    u, tau, W = np.array([10.0, 0, 0, 0, 0, 0.1]), 0.1, np.eye(6)
    U, S = predict_pose(np.eye(4), np.zeros((6, 6)), tau, u, W)
    np.testing.assert_allclose(S, tau**2 * W)
    np.testing.assert_allclose(se3_inv(U)[:3, 3], [np.sin(0.01) / 0.01, (1 - np.cos(0.01)) / 0.01, 0], atol=1e-12)


def test_se3_left_jacobian_and_bias_jacobian():
    xi = np.array([1.5, -0.4, 0.2, 0.05, 0.02, -0.3])

    def f(e):
        return se3_log(se3_exp(xi + e) @ se3_inv(se3_exp(xi)))

    np.testing.assert_allclose(se3_left_jacobian(xi), numeric_jacobian(f, np.zeros(6)), atol=1e-7)

    rng = np.random.default_rng(2)
    U = se3_exp(rng.normal(size=6))
    u, tau, b = np.array([8.0, 0.1, 0.0, 0.01, 0.02, 0.2]), 0.1, np.array([0.01, -0.02, 0.005])
    u_c, Phi, F = error_state_transition(tau, u, b, GYRO_SELECT)
    np.testing.assert_allclose(u_c, u - GYRO_SELECT @ b)
    U1 = predict_mean(U, tau, u_c)

    def g(x):  # x = [d; db]
        Ut = se3_exp(x[:6]) @ U
        return se3_log(predict_mean(Ut, tau, u - GYRO_SELECT @ (b + x[6:])) @ se3_inv(U1))

    np.testing.assert_allclose(Phi[:6], numeric_jacobian(g, np.zeros(9)), atol=1e-7)


@pytest.mark.parametrize("gyro_bias", [True, False])
def test_error_state_transition_with_a_speed_scale(gyro_bias):
    """Phi of [d; (db); ds] against finite differences of the exact prediction with the twist
    ``[(1 + s) v; w - b]``."""
    rng = np.random.default_rng(3)
    U = se3_exp(rng.normal(size=6))
    u, tau = np.array([8.0, 0.1, -0.05, 0.01, 0.02, 0.2]), 0.1
    e = np.r_[[0.01, -0.02, 0.005] if gyro_bias else [], 0.004]
    B = twist_error_matrix(u, gyro_bias, True)
    assert B.shape == (6, e.size)
    u_c, Phi, F = error_state_transition(tau, u, e, B)
    b = e[:3] if gyro_bias else np.zeros(3)
    np.testing.assert_allclose(u_c, np.r_[(1 + e[-1]) * u[:3], u[3:] - b])
    U1 = predict_mean(U, tau, u_c)

    def g(x):  # x = [d; (db); ds]
        Ut = se3_exp(x[:6]) @ U
        et = e + x[6:]
        bt = et[:3] if gyro_bias else np.zeros(3)
        return se3_log(predict_mean(Ut, tau, np.r_[(1 + et[-1]) * u[:3], u[3:] - bt]) @ se3_inv(U1))

    np.testing.assert_allclose(Phi[:6], numeric_jacobian(g, np.zeros(6 + e.size)), atol=1e-7)
    np.testing.assert_array_equal(Phi[6:], np.eye(6 + e.size)[6:])
    if gyro_bias:  # the bias alone: twist_error_matrix's columns are GYRO_SELECT
        np.testing.assert_array_equal(twist_error_matrix(u, True, False), GYRO_SELECT)


def test_paired_velocities():
    u = np.arange(18.0).reshape(3, 6)
    np.testing.assert_allclose(paired_velocities(u, "current"), u[:2])
    np.testing.assert_allclose(paired_velocities(u, "next"), u[1:])
    np.testing.assert_allclose(paired_velocities(u, "mean"), (u[:2] + u[1:]) / 2)


def test_landmark_jacobian_eq_7_8():
    model = _model()
    U, m = _scene()
    q = model.camera_points(U, m)
    H = model.landmark_jacobian(U, q)
    for i in range(m.shape[0]):
        num = numeric_jacobian(lambda x: _pixels(model, U, x[None])[0], m[i])
        np.testing.assert_allclose(H[i], num, rtol=1e-6, atol=1e-6)


def test_pose_jacobian_eq_13_15_left_perturbation():
    model = _model()
    U, m = _scene(3)
    q = model.camera_points(U, m)
    H = model.pose_jacobian(U, m, q)
    num = numeric_jacobian(lambda d: _pixels(model, se3_exp(d) @ U, m), np.zeros(6))
    np.testing.assert_allclose(H, num, rtol=1e-6, atol=1e-5)
    Hp, Hm = model.jacobians(U, m, q, reduced=False)
    np.testing.assert_allclose(Hp, H)
    np.testing.assert_allclose(Hm, model.landmark_jacobian(U, q))


def test_reduction_is_lossless():
    """Updating with (C z, C H, R3) gives the same posterior as (z, H, V)."""
    model = _model(sigma=1.3)
    U, m = _scene(4, n=5)
    q = model.camera_points(U, m)
    H4 = model.pose_jacobian(U, m, q).reshape(-1, 6)
    H3 = model.pose_jacobian(U, m, q, reduced=True).reshape(-1, 6)
    np.testing.assert_allclose(H3, (model.C @ model.pose_jacobian(U, m, q)).reshape(-1, 6))
    info4 = H4.T @ np.kron(np.eye(5), np.linalg.inv(model.V)) @ H4
    info3 = H3.T @ np.kron(np.eye(5), np.linalg.inv(model.R3)) @ H3
    np.testing.assert_allclose(info3, info4, rtol=1e-9)
    # 4x4 innovation covariance recovered from the reduced one.
    P = np.diag([0.1, 0.2, 0.1, 1e-3, 2e-3, 1e-3])
    Hp4 = model.pose_jacobian(U, m, q)
    Hp3 = model.pose_jacobian(U, m, q, reduced=True)
    S4 = Hp4 @ P @ np.swapaxes(Hp4, 1, 2) + model.V
    S3 = Hp3 @ P @ np.swapaxes(Hp3, 1, 2) + model.R3
    np.testing.assert_allclose(model.full_innovation_cov(S3), S4, rtol=1e-9, atol=1e-9)


def test_initialisation_jacobians_and_roundtrip():
    model = _model()
    U, m_true = _scene(5)
    z = _pixels(model, U, m_true)
    m, J_d, J_z = model.initialise(U, z)
    np.testing.assert_allclose(m, m_true, atol=1e-6)  # cam_T_imu is orthonormal to ~1e-8 only
    num_d = numeric_jacobian(lambda d: model.initialise(se3_exp(d) @ U, z)[0], np.zeros(6))
    np.testing.assert_allclose(J_d, num_d, rtol=1e-6, atol=1e-6)
    for i in range(z.shape[0]):
        num_z = numeric_jacobian(lambda x: model.initialise(U, x[None])[0][0], z[i], eps=1e-4)
        np.testing.assert_allclose(J_z[i], num_z, rtol=1e-5, atol=1e-6)


def test_observation_checks():
    model = _model(min_disparity=2.0, max_depth=50.0)
    fb = K[0, 0] * CALIB.baseline
    z = np.array(
        [
            [600, 180, 590, 180],  # disparity 10 -> 38 m, ok
            [600, 180, 605, 180],  # negative disparity
            [600, 180, 599, 180],  # disparity 1 < 2
            [600, 180, 600 - fb / 60, 180],  # 60 m > 50 m
        ],
        dtype=float,
    )
    assert model.valid_observations(z).tolist() == [True, False, False, False]
    q = np.array([[0, 0, -1.0, 1], [0, 0, 10.0, 1], [0, 0, 70.0, 1]])
    assert model.valid_predictions(q).tolist() == [False, True, False]


def test_gating_rejects_outliers_and_landmark_update_converges():
    model = _model(gate_probability=0.99)
    assert chi2_gate(0.99) == pytest.approx(13.2767, abs=1e-3)
    U, m_true = _scene(6, n=20)
    z = _pixels(model, U, m_true)
    z[0] += [30, 0, 30, 0]  # a gross outlier
    P = np.tile(0.01 * np.eye(3), (20, 1, 1))
    m, P1, acc = batched_landmark_update(model, U, m_true + 0.01, P, z)
    assert not acc[0] and acc[1:].all()
    assert np.linalg.norm(m[1:] - m_true[1:], axis=1).max() < 0.01 * np.sqrt(3)
    assert np.all(np.linalg.eigvalsh(P1) > 0)
    np.testing.assert_allclose(m[0], m_true[0] + 0.01)


def test_stereo_matrix_rows_repeat():
    M = stereo_matrix(K, CALIB.baseline)
    np.testing.assert_array_equal(M[1], M[3])


def test_se3_exp_single_matches_geometry():
    from vislam.ekf.geometry import se3_exp as batched
    from vislam.ekf.prediction import se3_exp_single

    rng = np.random.default_rng(7)
    for scale in (1e-9, 1e-4, 0.3, 2.0):
        xi = rng.normal(size=6) * scale
        np.testing.assert_allclose(se3_exp_single(xi), batched(xi), atol=1e-14, rtol=1e-12)


def test_so3_exp_and_left_jacobian_match_geometry():
    from vislam.ekf.geometry import so3_exp, so3_left_jacobian
    from vislam.ekf.prediction import so3_exp_and_left_jacobian

    rng = np.random.default_rng(8)
    for scale in (1e-9, 1e-6, 1e-4, 0.3, 2.0):
        phi = rng.normal(size=3) * scale
        R, J = so3_exp_and_left_jacobian(phi)
        np.testing.assert_allclose(R, so3_exp(phi), atol=1e-14, rtol=1e-12)
        np.testing.assert_allclose(J, so3_left_jacobian(phi), atol=1e-14, rtol=1e-12)


# --- the gauge nullspace of the joint EKF (observability-constrained / FEJ linearisation) ---


def _gauge(seed=1):
    rng = np.random.default_rng(seed)
    return se3_exp(rng.normal(size=6) * [2, 2, 1, 0.1, 0.1, 0.4]), rng.normal(size=6)


def test_gauge_nullspace_is_the_derivative_of_an_invisible_change_of_world():
    from vislam.ekf.joint import gauge_nullspace

    model = _model()
    U, m = _scene(seed=3)
    g, _ = _gauge()
    # A finite change of world frame leaves every pixel unchanged ...
    gm = m @ g[:3, :3].T + g[:3, 3]
    assert np.allclose(_pixels(model, U @ se3_inv(g), gm), _pixels(model, U, m), atol=1e-8)
    # ... and N xi is its first-order effect on [d, m] (left perturbation of U).
    xi = np.random.default_rng(5).normal(size=6)

    def state(eps):
        ge = se3_exp(eps * xi)
        d = se3_log((U @ se3_inv(ge)) @ se3_inv(U))
        return np.concatenate([d, (m @ ge[:3, :3].T + ge[:3, 3]).ravel()])

    num = (state(1e-6) - state(-1e-6)) / 2e-6
    assert np.allclose(num, gauge_nullspace(U, m) @ xi, atol=1e-5)


@pytest.mark.parametrize("reduced", [False, True])
def test_measurement_jacobians_annihilate_the_nullspace(reduced):
    from vislam.ekf.joint import gauge_nullspace

    model = _model()
    U, m = _scene(seed=4, n=5)
    q = model.camera_points(U, m)
    Hp, Hm = model.jacobians(U, m, q, reduced=reduced)
    n, r = m.shape[0], Hp.shape[1]
    H = np.zeros((n * r, 6 + 3 * n))
    for j in range(n):
        H[j * r : (j + 1) * r, :6] = Hp[j]
        H[j * r : (j + 1) * r, 6 + 3 * j : 9 + 3 * j] = Hm[j]
    N = gauge_nullspace(U, m)
    assert np.abs(H @ N).max() < 1e-8 * np.abs(H).max() * np.abs(N).max()


def test_prediction_and_initialisation_map_the_nullspace():
    from vislam.ekf.joint import gauge_nullspace

    model = _model()
    U, _ = _scene(seed=6)
    tau, u = 0.1, np.array([8.0, 0.2, -0.1, 0.01, -0.02, 0.3])
    F = prediction_jacobian(tau, u)
    U1 = predict_mean(U, tau, u)
    assert np.allclose(F @ gauge_nullspace(U, np.zeros((0, 3))), gauge_nullspace(U1, np.zeros((0, 3))))
    m_true = _scene(seed=6)[1]
    z = _pixels(model, U, m_true)
    m, J_d, _ = model.initialise(U, z)
    N = gauge_nullspace(U, m)
    assert np.allclose(J_d @ N[:6], N[6:].reshape(-1, 3, 6), atol=1e-9)


@pytest.mark.parametrize("core", [6, 9])
@pytest.mark.parametrize("with_landmarks", [True, False])
def test_gauge_transport_maps_prior_nullspace_to_posterior(core, with_landmarks):
    """OC-EKF: T N(U-, m-) = N(E U-, m- + dm), so P = N N^T maps to N' N'^T; the pose-only
    transport (FEJ) maps the pose rows and leaves the landmark rows at their first estimates."""
    from vislam.ekf.joint import gauge_nullspace, gauge_transport

    U, m = _scene(seed=7, n=4)
    rng = np.random.default_rng(8)
    E = se3_exp(rng.normal(size=6) * [0.3, 0.3, 0.3, 0.02, 0.02, 0.05])
    dm = rng.normal(size=m.shape) * 0.5
    N0 = gauge_nullspace(U, m, core)
    N1 = gauge_nullspace(E @ U, m + dm, core)
    P = N0 @ N0.T
    gauge_transport(P, core, E, U[:3, :3], dm if with_landmarks else None)
    if with_landmarks:
        assert np.allclose(P, N1 @ N1.T, atol=1e-7 * np.abs(P).max())
    else:
        N1[core:] = N0[core:]
        assert np.allclose(P, N1 @ N1.T, atol=1e-7 * np.abs(P).max())


@pytest.mark.parametrize("rotation", [0.0, 1e-7, 1e-3, 0.0999, 0.1001, 0.5, 2.5])
def test_se3_left_jacobian_closed_form_is_the_series(rotation):
    """Barfoot's closed form of the SE(3) left Jacobian equals its defining series (40 terms)
    on both sides of the Taylor threshold of its coefficients, and finite differences of
    ``exp((xi + e)^) exp(xi^)^-1`` where the angle is large enough for them."""
    from vislam.ekf.prediction import se3_left_jacobian_series

    rng = np.random.default_rng(7)
    for _ in range(20):
        axis = rng.normal(size=3)
        xi = np.concatenate([rng.normal(scale=2.0, size=3), rotation * axis / np.linalg.norm(axis)])
        J = se3_left_jacobian(xi)
        np.testing.assert_allclose(J, se3_left_jacobian_series(xi, 40), rtol=0, atol=1e-13)
    if rotation >= 1e-3:
        f = lambda e: se3_log(se3_exp(xi + e) @ se3_inv(se3_exp(xi)))  # noqa: E731
        np.testing.assert_allclose(J, numeric_jacobian(f, np.zeros(6)), atol=1e-7)
    batch = np.stack([xi, -xi])
    np.testing.assert_allclose(se3_left_jacobian(batch), se3_left_jacobian_series(batch, 40),
                               rtol=0, atol=1e-13)
    assert se3_left_jacobian(np.zeros((0, 6))).shape == (0, 6, 6)


def test_q_coefficients_are_their_exact_series():
    """The three coefficients of the SE(3) left Jacobian's ``Q`` against their Taylor series
    in exact rational arithmetic (12 terms): the series branch below 0.1 rad to 5e-15 relative
    (a wrong t^6 coefficient of c3 was 3e-12 off at 0.1); the closed forms above it to 1e-9,
    their cancellation just above the threshold (3e-11 at 0.1001: about 1e-14 of J)."""
    from fractions import Fraction
    from math import factorial

    from vislam.ekf.prediction import _q_coefficients

    def exact(theta: float) -> list[float]:
        t = Fraction(theta)
        c1 = sum(Fraction((-1) ** n, factorial(2 * n + 3)) * t ** (2 * n) for n in range(12))
        c2 = sum(Fraction((-1) ** n, factorial(2 * n + 4)) * t ** (2 * n) for n in range(12))
        # (2t - 3 sin t + t cos t) / (2 t^5): coefficient of t^(2n+1) is (-1)^n (1/(2n)! - 3/(2n+1)!)
        c3 = sum(Fraction((-1) ** n, factorial(2 * n)) * (1 - Fraction(3, 2 * n + 1)) / 2
                 * t ** (2 * n - 4) for n in range(2, 14))
        return [float(c1), float(c2), float(c3)]

    for theta in (0.0, 1e-4, 0.05, 0.0999, 0.1001, 0.3, 1.0):
        np.testing.assert_allclose(_q_coefficients(theta), exact(theta), rtol=5e-15 if theta < 0.1 else 1e-9)
