"""Anchored inverse-depth landmarks (ekf/inverse_depth.py) and their use in ekf-joint and
ekf-invariant: every Jacobian against finite differences, the conversions both ways, the
stacked updates against dense textbook references, and the filters on simulated drives."""

from __future__ import annotations

import numpy as np
import pytest

from vislam.ekf import inverse_depth as idp
from vislam.ekf import invariant as inv
from vislam.ekf.config import FilterConfig
from vislam.ekf.geometry import adjoint, hat, homogeneous, se3_exp, se3_inv
from vislam.ekf.joint import JointState, gauge_nullspace, run_joint
from vislam.ekf.stereo_update import StereoModel
from vislam.eval.simulate import SimConfig, simulate
from tests.numdiff import numeric_jacobian
from tests.test_ekf_invariant import CAL, observe, random_pose, visible_landmark

ID = FilterConfig(landmark_parameterisation="inverse-depth", gyro_bias=False)


def _anchor(rng, n=1):
    T = random_pose(rng)
    world_T_cam = T @ CAL.imu_T_cam
    return T, np.repeat(world_T_cam[None, :3, :3], n, 0), np.repeat(world_T_cam[None, :3, 3], n, 0)


def _x(rng, n=4, far=False):
    depth = rng.uniform(60, 400, n) if far else rng.uniform(3, 40, n)
    return np.column_stack([rng.uniform(-0.6, 0.6, n), rng.uniform(-0.2, 0.2, n), 1 / depth])


# --- the parameterisation ---------------------------------------------------------------
def test_from_stereo_is_the_triangulated_point_and_linear_in_the_pixels():
    rng = np.random.default_rng(0)
    T, R_a, p_a = _anchor(rng, 5)
    lms = np.array([visible_landmark(rng, T) for _ in range(5)])
    z = np.array([observe(T, m) for m in lms])
    x, Jz = idp.from_stereo(z, CAL.K, CAL.baseline)
    np.testing.assert_allclose(idp.world_point(x, R_a, p_a), lms, atol=1e-9)
    for zi in z:
        np.testing.assert_allclose(numeric_jacobian(lambda v: idp.from_stereo(v[None], CAL.K, CAL.baseline)[0][0], zi), Jz, atol=1e-9)


@pytest.mark.parametrize("far", [False, True])
def test_jacobians_of_the_parameterisation(far):
    rng = np.random.default_rng(1)
    _, R_a, p_a = _anchor(rng, 4)
    x = _x(rng, 4, far)
    G = idp.homogeneous_jacobian(R_a, p_a)
    J = idp.world_jacobian(x, R_a)
    Ji = idp.inverse_jacobian(x, R_a)
    N = idp.gauge_rows(x, R_a, p_a)
    m = idp.world_point(x, R_a, p_a)
    for j in range(4):
        one = slice(j, j + 1)
        np.testing.assert_allclose(
            numeric_jacobian(lambda v: idp.homogeneous_point(v[None], R_a[one], p_a[one])[0], x[j]), G[j], atol=1e-8)
        np.testing.assert_allclose(
            numeric_jacobian(lambda v: idp.world_point(v[None], R_a[one], p_a[one])[0], x[j], eps=1e-9 * (1 + far * 1e2)),
            J[j], rtol=1e-5)
        np.testing.assert_allclose(Ji[j] @ J[j], np.eye(3), atol=1e-9)
        np.testing.assert_allclose(idp.from_world(m[one], R_a[one], p_a[one])[0], x[j], rtol=1e-9, atol=1e-12)

        def moved(xi):  # x of the point after a change of world frame (m -> m + v - m^ w)
            return idp.from_world(m[one] + xi[:3] - np.cross(m[j], xi[3:]), R_a[one], p_a[one])[0]

        np.testing.assert_allclose(numeric_jacobian(moved, np.zeros(6), eps=1e-7), N[j], rtol=1e-5, atol=1e-9)
    assert np.all(np.isfinite(idp.gauge_rows(np.array([[0.1, 0.0, 0.0]]), R_a[:1], p_a[:1])))
    moved_x = x + 1e-3 * rng.standard_normal(x.shape)  # the change an update makes, in one call
    np.testing.assert_array_equal(idp.gauge_rows_change(x, moved_x, R_a, p_a),
                                  idp.gauge_rows(moved_x, R_a, p_a) - N)


def test_linearity_index():
    R_a, p_a = np.eye(3)[None], np.zeros((1, 3))
    x = np.array([[0.0, 0.0, 0.05]])  # 20 m along the anchor's axis
    # Seen from the anchor: parallax 0, d = 20 m: L = 4 (sigma_rho / rho^2) / d = 4 sigma_rho / rho.
    L = idp.linearity_index(x, np.array([0.01**2]), R_a, p_a, np.zeros(3))
    np.testing.assert_allclose(L, [4 * 0.01 / 0.05])
    # From the side (90 degrees of parallax) the depth error does not matter.
    assert idp.linearity_index(x, np.array([0.01**2]), R_a, p_a, np.array([20.0, 0, 20]))[0] < 1e-12
    assert idp.linearity_index(np.array([[0.0, 0.0, -0.1]]), np.array([1e-6]), R_a, p_a, np.zeros(3))[0] == np.inf


# --- ekf-joint ---------------------------------------------------------------------------
def _model():
    return StereoModel.from_config(CAL, ID)


def test_joint_homogeneous_jacobians_against_finite_differences():
    rng = np.random.default_rng(2)
    model = _model()
    U = se3_inv(random_pose(rng))
    world_T_cam = se3_inv(U) @ CAL.imu_T_cam
    R_a = np.repeat(world_T_cam[None, :3, :3], 3, 0)
    p_a = np.repeat(world_T_cam[None, :3, 3], 3, 0) + rng.normal(scale=2, size=(3, 3))
    x = _x(rng, 3)
    m_h = idp.homogeneous_point(x, R_a, p_a)
    q = m_h @ (CAL.cam_T_imu @ U).T
    Hp, Hx = model.homogeneous_jacobians(U, m_h, idp.homogeneous_jacobian(R_a, p_a), q, reduced=False)
    for j in range(3):
        one = slice(j, j + 1)

        def h_pose(d):
            return model.predicted_pixels((idp.homogeneous_point(x[one], R_a[one], p_a[one]) @ (CAL.cam_T_imu @ se3_exp(d) @ U).T))[0]

        def h_x(v):
            return model.predicted_pixels(idp.homogeneous_point(v[None], R_a[one], p_a[one]) @ (CAL.cam_T_imu @ U).T)[0]

        np.testing.assert_allclose(numeric_jacobian(h_pose, np.zeros(6)), Hp[j], rtol=1e-5, atol=1e-4)
        np.testing.assert_allclose(numeric_jacobian(h_x, x[j], eps=1e-8), Hx[j], rtol=1e-5, atol=1e-3)
        # The same pixels as the Euclidean point.
        m = idp.world_point(x[one], R_a[one], p_a[one])
        np.testing.assert_allclose(model.predicted_pixels(q[one]), model.predicted_pixels(model.camera_points(U, m)), atol=1e-8)


def _joint_with_landmarks(cfg, seed=3, n=6):
    """A joint state after initialising n landmarks seen from a random pose with a non-trivial
    pose covariance, then one prediction."""
    rng = np.random.default_rng(seed)
    st = JointState(cfg, n)
    T = random_pose(rng)
    st.U = se3_inv(T)
    A = rng.normal(size=(6, 6)) * 0.01
    st.P = A @ A.T + 1e-4 * np.eye(6)
    lms = np.array([visible_landmark(rng, T) for _ in range(n)])
    z = np.array([observe(T, m) for m in lms])
    model = StereoModel.from_config(CAL, cfg)
    st.initialise(model, np.arange(n), z, np.zeros(n, dtype=bool))
    return st, model, lms, rng


def test_joint_initialisation_jacobian_against_finite_differences():
    st, model, lms, _ = _joint_with_landmarks(ID)
    assert st.lm_id.all()
    U = st.U
    R_a, p_a = st.anchor_R, st.anchor_p
    z = np.array([model.predicted_pixels(model.camera_points(U, m[None]))[0] for m in lms])
    x0, _ = idp.from_stereo(z, CAL.K, CAL.baseline)
    np.testing.assert_allclose(st.lm_mean, x0, atol=1e-12)

    def x_of(d):  # the same pixels seen from the perturbed pose, in the fixed anchor
        m = model.initialise(se3_exp(d) @ U, z)[0]
        return idp.from_world(m, R_a, p_a).ravel()

    Jd = numeric_jacobian(x_of, np.zeros(6))  # (3n, 6)
    np.testing.assert_allclose(st.P[6:, :6], Jd @ st.P[:6, :6], rtol=1e-5, atol=1e-12)


def test_joint_conversion_to_euclidean_is_first_order_exact():
    st, model, lms, _ = _joint_with_landmarks(ID)
    slots = np.arange(3)
    mean_id, cov_id = st.world_landmarks(slots)
    J = idp.world_jacobian(st.lm_mean[slots], st.anchor_R[slots])
    cross = J @ st.P[6:15, :6].reshape(3, 3, 6)
    st.to_euclidean(slots)
    assert not st.lm_id[slots].any() and st.lm_id[3:].all()
    mean_eu, cov_eu = st.world_landmarks(slots)
    np.testing.assert_allclose(mean_eu, mean_id)
    np.testing.assert_allclose(cov_eu, cov_id, rtol=1e-10)
    np.testing.assert_allclose(st.P[6:15, :6].reshape(3, 3, 6), cross, rtol=1e-10)
    np.testing.assert_allclose(mean_eu, lms[:3], atol=1e-8)
    np.testing.assert_allclose(st.P, st.P.T)


def _joint_nullspace(st):
    """Gauge nullspace of a mixed joint state: ``-Ad(U)`` on the pose, ``[I, -m^]`` on a
    Euclidean landmark, ID-7 on an inverse-depth one."""
    N = gauge_nullspace(st.U, st.lm_mean, st.core)
    ids = np.flatnonzero(st.lm_id)
    rows = st.landmark_rows(ids)
    N[rows.ravel()] = idp.gauge_rows(st.lm_mean[ids], st.anchor_R[ids], st.anchor_p[ids]).reshape(-1, 6)
    return N


@pytest.mark.parametrize("linearisation", ["standard", "fej", "oc"])
def test_joint_update_with_inverse_depth_matches_dense_reference(linearisation):
    """The structured stacked update with a mix of Euclidean and inverse-depth landmarks equals
    the dense Joseph-form update with the 4-row model; with "oc" the transported covariance
    keeps the nullspace of the new estimate: T N(U-, x-) = N(U+, x+)."""
    cfg = ID.replace(gate_probability=None, joint_linearisation=linearisation)
    st, model, lms, rng = _joint_with_landmarks(cfg, seed=5, n=6)
    st.to_euclidean(np.array([1, 4]))
    st.predict(0.1, np.array([5.0, 0.1, 0.0, 0.01, 0.0, 0.05]), cfg)
    T1 = se3_inv(st.U) @ se3_exp(rng.normal(scale=[0.05, 0.05, 0.05, 0.002, 0.002, 0.002]))
    z = np.array([observe(T1, m) for m in lms]) + rng.normal(scale=0.5, size=(6, 4))
    U0, x0, P0 = st.U.copy(), st.lm_mean.copy(), st.P.copy()
    N0 = _joint_nullspace(st)
    slots = np.arange(6)
    q = st.camera_points(model, slots, x0)
    H = np.zeros((24, P0.shape[0]))
    for j in slots:
        i = np.array([j])
        if st.lm_id[j]:
            m_h = idp.homogeneous_point(x0[i], st.anchor_R[i], st.anchor_p[i])
            Hp, Hm = model.homogeneous_jacobians(U0, m_h, idp.homogeneous_jacobian(st.anchor_R[i], st.anchor_p[i]), q[i], reduced=False)
        else:
            Hp, Hm = model.jacobians(U0, x0[i], q[i], reduced=False)
        H[4 * j:4 * j + 4, :6], H[4 * j:4 * j + 4, 6 + 3 * j:9 + 3 * j] = Hp[0], Hm[0]
    V = np.kron(np.eye(6), model.V)
    Kg = P0 @ H.T @ np.linalg.inv(H @ P0 @ H.T + V)
    IKH = np.eye(P0.shape[0]) - Kg @ H
    P_ref = IKH @ P0 @ IKH.T + Kg @ V @ Kg.T
    dx = Kg @ (z - model.predicted_pixels(q)).ravel()
    assert st.update(model, np.arange(6), z) == (6, 0)
    np.testing.assert_allclose(st.lm_mean - x0, dx[6:].reshape(-1, 3), rtol=1e-6, atol=1e-10)
    if linearisation == "standard":
        np.testing.assert_allclose(st.P, P_ref, rtol=1e-6, atol=1e-12)
    if linearisation == "oc":
        T0 = N0 @ N0.T  # a covariance along the old nullspace is carried onto the new one
        st.P = T0.copy()
        st.lm_mean = x0 + dx[6:].reshape(-1, 3)
        from vislam.ekf.joint import transport

        transport(st.P, st.core, se3_exp(dx[:6]), st.transport_rows(dx[6:].reshape(-1, 3), x0, U0))
        st.U = se3_exp(dx[:6]) @ U0
        N1 = _joint_nullspace(st)
        np.testing.assert_allclose(st.P, N1 @ N1.T, rtol=1e-8, atol=1e-10)


# --- ekf-invariant ----------------------------------------------------------------------
def test_invariant_inverse_depth_jacobians_against_finite_differences():
    rng = np.random.default_rng(6)
    T, R_a, p_a = _anchor(rng, 3)
    x = _x(rng, 3)
    T = T @ se3_exp(rng.normal(scale=[1, 0.2, 0.1, 0.02, 0.02, 0.1]))
    m_h = idp.homogeneous_point(x, R_a, p_a)
    q_h, Hp, Hx = inv.inverse_depth_jacobians(T, m_h, idp.homogeneous_jacobian(R_a, p_a), CAL.cam_T_imu, CAL.M)
    for j in range(3):
        one = slice(j, j + 1)
        m = idp.world_point(x[one], R_a[one], p_a[one])[0]
        np.testing.assert_allclose(inv.project(CAL.M, q_h[one])[0], observe(T, m), atol=1e-8)
        np.testing.assert_allclose(numeric_jacobian(lambda xi: observe(se3_exp(xi) @ T, m), np.zeros(6)), Hp[j], rtol=1e-5, atol=1e-4)
        np.testing.assert_allclose(
            numeric_jacobian(lambda v: observe(T, idp.world_point(v[None], R_a[one], p_a[one])[0]), x[j], eps=1e-8),
            Hx[j], rtol=1e-5, atol=1e-3)


def _invariant_state(seed=7, n=5, bias=False):
    """An invariant-filter state with n inverse-depth landmarks (added by _augment)."""
    rng = np.random.default_rng(seed)
    cfg = ID.replace(gyro_bias=bias, gate_probability=None)
    off = inv.landmark_offset(bias)
    T = random_pose(rng)
    A = rng.normal(size=(off, off)) * 0.01
    st = inv.InvariantState(T=T, landmarks=np.zeros((0, 3)), tracks=np.zeros(0, dtype=np.int64),
                    P=A @ A.T + 1e-4 * np.eye(off), bias=np.zeros(3) if bias else None)
    lms = np.array([visible_landmark(rng, T) for _ in range(n)])
    z = np.array([observe(T, m) for m in lms])
    slot_of = -np.ones(n, dtype=np.int64)
    assert inv._augment(st, np.arange(n), z, CAL, CAL.imu_T_cam, cfg.pixel_cov, cfg, off, slot_of)[0] == n
    return st, cfg, off, lms, z, rng


def test_invariant_augmentation_jacobian_against_finite_differences():
    st, cfg, off, lms, z, _ = _invariant_state()
    assert st.lm_id.all()
    T, R_a, p_a = st.T, st.anchor_R, st.anchor_p
    pc, _ = inv.triangulate_with_jacobian(z, CAL.K, CAL.baseline)

    def x_of(xi):  # the same pixels from the pose exp(xi) T, in the fixed anchor
        Tp = se3_exp(xi) @ T
        m = (homogeneous(pc) @ (Tp @ CAL.imu_T_cam).T)[:, :3]
        return idp.from_world(m, R_a, p_a).ravel()

    Jd = numeric_jacobian(x_of, np.zeros(6))
    np.testing.assert_allclose(st.P[off:, :6], Jd @ st.P[:6, :6], rtol=1e-5, atol=1e-12)


def test_invariant_conversion_to_the_group_is_first_order_exact():
    st, cfg, off, lms, _, _ = _invariant_state(n=4)
    slots = np.arange(4)
    mean_id, cov_id = st.world_landmarks(slots, off)
    inv._to_group(st, np.array([0, 2]), off)
    assert list(st.lm_id) == [False, True, False, True]
    mean, cov = st.world_landmarks(slots, off)
    np.testing.assert_allclose(mean, mean_id)
    np.testing.assert_allclose(mean, lms, atol=1e-8)
    np.testing.assert_allclose(cov, cov_id, rtol=1e-9, atol=1e-14)
    np.testing.assert_allclose(st.P, st.P.T, atol=1e-15)


@pytest.mark.parametrize("bias", [False, True])
def test_invariant_update_with_inverse_depth_matches_dense_reference(bias):
    """The compressed stacked update with inverse-depth rows equals the dense update with the
    full 4-row Jacobians, followed by the transport of the world-change directions."""
    st, cfg, off, lms, _, rng = _invariant_state(seed=8, n=5, bias=bias)
    inv._to_group(st, np.array([1]), off)
    T1 = se3_exp(rng.normal(scale=[0.05, 0.05, 0.05, 0.002, 0.002, 0.002])) @ st.T
    z = np.array([observe(T1, m) for m in lms]) + rng.normal(scale=0.5, size=(5, 4))
    T0, X0, P0 = st.T.copy(), st.landmarks.copy(), st.P.copy()
    n = P0.shape[0]
    H = np.zeros((20, n))
    for j in range(5):
        if st.lm_id[j]:
            i = slice(j, j + 1)
            m_h = idp.homogeneous_point(X0[i], st.anchor_R[i], st.anchor_p[i])
            _, Hp, Hx = inv.inverse_depth_jacobians(T0, m_h, idp.homogeneous_jacobian(st.anchor_R[i], st.anchor_p[i]), CAL.cam_T_imu, CAL.M)
            H[4 * j:4 * j + 4, :6], H[4 * j:4 * j + 4, off + 3 * j:off + 3 * j + 3] = Hp[0], Hx[0]
        else:
            q = (CAL.cam_T_imu @ se3_inv(T0) @ homogeneous(X0[j]))[:3]
            A = inv.observation_jacobian(T0, q[None], CAL.cam_T_imu, CAL.M)[0]
            H[4 * j:4 * j + 4, :3], H[4 * j:4 * j + 4, off + 3 * j:off + 3 * j + 3] = -A, A
    r = np.concatenate([z[j] - observe(T0, st.world_landmarks(np.array([j]), off)[0][0]) for j in range(5)])
    V = np.kron(np.eye(5), cfg.pixel_cov)
    Kg = P0 @ H.T @ np.linalg.inv(H @ P0 @ H.T + V)
    P_ref = P0 - Kg @ H @ P0
    delta = Kg @ r
    used, _, _ = inv._update(st, np.arange(5), z, CAL.M, CAL.cam_T_imu, cfg.pixel_cov,
                             np.linalg.inv(cfg.pixel_cov), None, cfg, off)
    assert used == 5
    ids = np.flatnonzero(st.lm_id)
    np.testing.assert_allclose(st.landmarks[ids] - X0[ids], delta[off:].reshape(-1, 3)[ids], rtol=1e-6, atol=1e-12)
    # The transport: C = N(x+) - N(x-) on the inverse-depth rows, identity elsewhere.
    Tm = np.eye(n)
    for j in ids:
        i = slice(j, j + 1)
        Tm[off + 3 * j:off + 3 * j + 3, :6] = (idp.gauge_rows(st.landmarks[i], st.anchor_R[i], st.anchor_p[i])
                                              - idp.gauge_rows(X0[i], st.anchor_R[i], st.anchor_p[i]))[0]
    np.testing.assert_allclose(st.P, Tm @ P_ref @ Tm.T, rtol=1e-6, atol=1e-12)


# --- the filters on simulated drives -------------------------------------------------------
@pytest.fixture(scope="module")
def clean_drive():
    return simulate(SimConfig(seed=3, n_frames=120, noise_free=True))


@pytest.mark.parametrize("run", [run_joint, inv.run_invariant])
def test_noise_free_drive_is_recovered_with_inverse_depth(clean_drive, run):
    est = run(clean_drive.sequence, ID)
    err = np.linalg.norm(est.positions - clean_drive.poses[:, :3, 3], axis=1)
    assert err.max() < 1e-3
    has = est.has_landmark
    assert has.mean() > 0.9
    d = np.linalg.norm(est.landmarks[has] - clean_drive.landmarks[est.info["track_origin"]][has], axis=1)
    assert np.median(d) < 1e-3


def test_inverse_depth_landmarks_are_converted_once_linear(clean_drive):
    """With the threshold at 0 nothing is converted; with a generous one most landmarks are,
    and the result moves by little (the conversion is first-order exact)."""
    never = run_joint(clean_drive.sequence, ID.replace(inverse_depth_linearity=0.0))
    soon = run_joint(clean_drive.sequence, ID.replace(inverse_depth_linearity=10.0))
    assert never.info["inverse_depth_converted"] == 0
    assert soon.info["inverse_depth_converted"] > 0.5 * soon.has_landmark.sum()
    np.testing.assert_allclose(never.positions, soon.positions, atol=1e-3)


def test_adjoint_identity_used_by_the_joint_transport():
    """``[0, dm^] Ad(U)^-1 = [0, dm^ R^T]``: the Euclidean rows of transport_rows are
    gauge_transport's."""
    rng = np.random.default_rng(9)
    U, dm = se3_exp(rng.normal(size=6)), rng.normal(size=3)
    lhs = np.hstack([np.zeros((3, 3)), hat(dm)]) @ adjoint(se3_inv(U))
    np.testing.assert_allclose(lhs, np.hstack([np.zeros((3, 3)), hat(dm) @ U[:3, :3].T]), atol=1e-12)
