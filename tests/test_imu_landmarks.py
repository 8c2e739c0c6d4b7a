"""The raw-IMU filters' inverse-depth landmarks (ekf/imu_landmarks.py): every Jacobian against
finite differences, the chart change against an exact re-reading, and the initialisation."""

import numpy as np
import pytest

from tests.numdiff import numeric_jacobian
from vislam.ekf import imu_landmarks as il
from vislam.ekf import inverse_depth as idp
from vislam.ekf.errors import InputError
from vislam.ekf.geometry import se3_exp, se3_inv, so3_exp

K = np.array([[458.0, 0.0, 376.0], [0.0, 457.0, 240.0], [0.0, 0.0, 1.0]])


def _pose(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    T = np.eye(4)
    T[:3, :3] = so3_exp(rng.normal(size=3))
    T[:3, 3] = rng.normal(size=3)
    return T


def _setup(seed: int = 0):
    rng = np.random.default_rng(seed)
    cam_T_imu = _pose(seed + 10)
    anchor = _pose(seed + 1)  # world_T_cam_a
    x = np.array([[0.1, -0.2, 0.3], [-0.3, 0.05, 0.08]]) + 0.01 * rng.normal(size=(2, 3))
    m = idp.world_point(x, anchor[None, :3, :3].repeat(2, 0), anchor[None, :3, 3].repeat(2, 0))
    # a current camera looking at the points: the anchor moved a little
    world_T_cam = anchor @ se3_exp(np.array([0.05, -0.03, 0.02, 0.01, 0.02, -0.01]))
    world_T_imu = world_T_cam @ cam_T_imu
    return x, anchor, world_T_imu, cam_T_imu, m


def _anchors(anchor, n):
    return anchor[None, :3, :3].repeat(n, 0), anchor[None, :3, 3].repeat(n, 0)


def test_imu_points_are_the_world_points_in_the_imu_frame():
    x, anchor, T, _, m = _setup()
    q = il.imu_points(x, *_anchors(anchor, 2), T)
    p_imu = (m - T[:3, 3]) @ T[:3, :3]
    np.testing.assert_allclose(q[:, :3] / q[:, 3:], p_imu, atol=1e-12)


def test_landmark_pose_and_anchor_jacobians_match_finite_differences():
    x, anchor, T, _, _ = _setup(1)
    R_a, p_a = _anchors(anchor, 2)
    for i in range(2):
        xi_ = x[i:i + 1]
        Jx = il.landmark_jacobian(xi_, R_a[:1], p_a[:1], T)[0]
        num = numeric_jacobian(lambda v: il.imu_points(v[None], R_a[:1], p_a[:1], T)[0], xi_[0])
        np.testing.assert_allclose(Jx, num, atol=1e-8)
        q = il.imu_points(xi_, R_a[:1], p_a[:1], T)
        Jp = il.pose_jacobian(q)[0]
        num = numeric_jacobian(
            lambda e: il.imu_points(xi_, R_a[:1], p_a[:1], T @ se3_exp(e))[0], np.zeros(6))
        np.testing.assert_allclose(Jp, num, atol=1e-8)
        Ja = il.anchor_jacobian(xi_, R_a[:1], T)[0]

        def moved_anchor(e):
            A = anchor @ se3_exp(e)
            return il.imu_points(xi_, A[None, :3, :3], A[None, :3, 3], T)[0]

        np.testing.assert_allclose(Ja, numeric_jacobian(moved_anchor, np.zeros(6)), atol=1e-8)


@pytest.mark.parametrize("baseline", [None, 0.11])
def test_pixel_jacobian_matches_finite_differences(baseline):
    x, anchor, T, cam_T_imu, _ = _setup(2)
    model = il.PixelModel(K, cam_T_imu, baseline)
    q = il.imu_points(x, *_anchors(anchor, 2), T)
    z, J, depth = model.predict(q)
    assert z.shape == (2, model.rows) and J.shape == (2, model.rows, 4)
    assert np.all(depth > 0)
    for i in range(2):
        num = numeric_jacobian(lambda v: model.predict(v[None])[0][0], q[i])
        np.testing.assert_allclose(J[i], num, rtol=1e-6, atol=1e-6)


def test_pixels_match_the_stereo_camera_model():
    from vislam.ekf.camera import project, stereo_matrix

    x, anchor, T, cam_T_imu, m = _setup(3)
    q = il.imu_points(x, *_anchors(anchor, 2), T)
    z, _, _ = il.PixelModel(K, cam_T_imu, 0.11).predict(q)
    p_cam = np.c_[m, np.ones(2)] @ (cam_T_imu @ se3_inv(T)).T
    np.testing.assert_allclose(z, project(stereo_matrix(K, 0.11), p_cam), atol=1e-9)
    zm, _, _ = il.PixelModel(K, cam_T_imu).predict(q)
    np.testing.assert_allclose(zm, z[:, :2], atol=1e-9)


def test_chart_change_matches_an_exact_rereading():
    x, anchor, _, _, _ = _setup(4)

    def reread(e):
        """x_true read in the estimated anchor when the true anchor is anchor Exp(e)."""
        true_anchor = anchor @ se3_exp(e)
        R_a, p_a = _anchors(true_anchor, 2)
        m = idp.world_point(x, R_a, p_a)
        return idp.from_world(m, *_anchors(anchor, 2))

    J = il.chart_change_jacobian(x)
    num = numeric_jacobian(reread, np.zeros(6))  # (2, 3, 6)
    np.testing.assert_allclose(J, num, atol=1e-8)


def test_camera_from_imu_adjoint_moves_the_camera_pose():
    T, cam_T_imu = _pose(5), _pose(6)
    imu_T_cam = se3_inv(cam_T_imu)
    xi = 1e-3 * np.arange(1, 7)
    lhs = T @ se3_exp(xi) @ imu_T_cam
    rhs = T @ imu_T_cam @ se3_exp(il.camera_from_imu_jacobian(cam_T_imu) @ xi)
    np.testing.assert_allclose(lhs, rhs, atol=1e-12)


def test_a_new_landmark_keeps_its_bearing_when_pose_and_chart_move_together():
    """At the first observation, moving the pose by xi and the chart by the chart change of the
    camera's xi leaves the predicted pixels unchanged: the anchor's error is the pose's."""
    _, _, T, cam_T_imu, _ = _setup(7)
    world_T_cam = T @ se3_inv(cam_T_imu)
    model = il.PixelModel(K, cam_T_imu)
    x, _ = il.from_monocular(np.array([[400.0, 200.0], [100.0, 300.0]]), K, il.DepthPrior())
    R_a, p_a = _anchors(world_T_cam, 2)
    xi = 1e-5 * np.array([1.0, -2.0, 0.5, 3.0, -1.0, 2.0])
    x_moved = x + il.chart_change_jacobian(x) @ (il.camera_from_imu_jacobian(cam_T_imu) @ xi)
    z0 = model.predict(il.imu_points(x, R_a, p_a, T))[0]
    z1 = model.predict(il.imu_points(x_moved, R_a, p_a, T @ se3_exp(xi)))[0]
    np.testing.assert_allclose(z1, z0, atol=1e-7)


def test_initial_landmarks_mono_and_stereo():
    prior = il.DepthPrior(min_depth=2.0)
    assert prior.rho == pytest.approx(0.25) and prior.sigma == pytest.approx(0.125)
    z = np.array([[376.0 + 45.8, 240.0 - 45.7]])
    x, C = il.initial_landmarks(z, K, None, 0.25, prior)
    np.testing.assert_allclose(x, [[0.1, -0.1, 0.25]])
    np.testing.assert_allclose(np.diag(C[0]), [0.25 / 458.0**2, 0.25 / 457.0**2, 0.125**2])
    zs = np.array([[400.0, 200.0, 390.0, 200.0]])
    xs, Cs = il.initial_landmarks(zs, K, 0.11, 1.0, prior)
    xr, Jz = idp.from_stereo(zs, K, 0.11)
    np.testing.assert_allclose(xs, xr)
    np.testing.assert_allclose(Cs[0], Jz @ Jz.T)
    with pytest.raises(InputError, match="min_depth"):
        il.DepthPrior(min_depth=0.0)
