"""SO(3)/SE(3) math: exp/log against scipy, identities, and Jacobians against finite differences."""

import numpy as np
import pytest
from scipy.linalg import expm
from scipy.spatial.transform import Rotation

from vislam.ekf import geometry as g
from tests.numdiff import numeric_jacobian

RNG = np.random.default_rng(7)


def random_poses(n, rng=RNG, scale=3.0):
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = Rotation.random(n, random_state=rng.integers(1 << 31)).as_matrix()
    T[:, :3, 3] = rng.normal(scale=scale, size=(n, 3))
    return T


def test_hat_vee_cross():
    a, b = RNG.normal(size=(2, 20, 3))
    assert np.allclose(g.hat(a) @ b[..., None], np.cross(a, b)[..., None])
    assert np.allclose(g.vee(g.hat(a)), a)
    xi = RNG.normal(size=(20, 6))
    assert np.allclose(g.vee(g.twist_hat(xi)), xi)


def test_so3_exp_matches_scipy():
    phi = RNG.normal(scale=1.5, size=(200, 3))
    assert np.allclose(g.so3_exp(phi), Rotation.from_rotvec(phi).as_matrix(), atol=1e-14)


def test_so3_log_matches_scipy_including_small_and_near_pi():
    phi = Rotation.random(300, random_state=3).as_rotvec()
    tiny = RNG.normal(scale=1e-9, size=(5, 3))
    axis = RNG.normal(size=(5, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    near_pi = axis * (np.pi - 1e-6)
    for p in (phi, tiny, near_pi):
        R = Rotation.from_rotvec(p).as_matrix()
        assert np.allclose(g.so3_log(R), Rotation.from_matrix(R).as_rotvec(), atol=1e-8)
        assert np.allclose(g.so3_exp(g.so3_log(R)), R, atol=1e-12)


def test_se3_exp_matches_matrix_exponential_and_log_inverts():
    xi = RNG.normal(size=(50, 6))
    xi[:, 3:] *= 0.9  # keep |phi| < pi so that log(exp(xi)) == xi
    for x in xi[:10]:
        assert np.allclose(g.se3_exp(x), expm(g.twist_hat(x)), atol=1e-12)
    assert np.allclose(g.se3_log(g.se3_exp(xi)), xi, atol=1e-10)
    small = RNG.normal(scale=1e-9, size=(5, 6))
    assert np.allclose(g.se3_log(g.se3_exp(small)), small, atol=1e-20 + 1e-12)


def test_curly_hat_is_adjoint_of_exp():
    for x in RNG.normal(size=(10, 6)):
        assert np.allclose(expm(g.curly_hat(x)), g.adjoint(g.se3_exp(x)), atol=1e-11)


def test_adjoint_identity_and_inverse():
    T = random_poses(10)
    xi = RNG.normal(scale=0.3, size=(10, 6))
    lhs = T @ g.se3_exp(xi) @ g.se3_inv(T)
    rhs = g.se3_exp((g.adjoint(T) @ xi[..., None])[..., 0])
    assert np.allclose(lhs, rhs, atol=1e-10)
    assert np.allclose(g.se3_inv(T) @ T, np.eye(4), atol=1e-12)


def test_odot_identity():
    s = RNG.normal(size=(30, 4))
    xi = RNG.normal(size=(30, 6))
    lhs = (g.twist_hat(xi) @ s[..., None])[..., 0]
    rhs = (g.odot(s) @ xi[..., None])[..., 0]
    assert np.allclose(lhs, rhs)


@pytest.mark.parametrize("seed", range(5))
def test_so3_left_jacobian_finite_differences(seed):
    rng = np.random.default_rng(seed)
    phi = rng.normal(size=3)
    # exp((phi + d)^) ~ exp((J_l d)^) exp(phi^)  =>  J_l = d/dd log(exp(phi + d) exp(phi)^T)
    R0 = g.so3_exp(phi)
    J_num = numeric_jacobian(lambda d: g.so3_log(g.so3_exp(phi + d) @ R0.T), np.zeros(3))
    assert np.allclose(g.so3_left_jacobian(phi), J_num, atol=1e-7)
    assert np.allclose(g.so3_left_jacobian_inv(phi) @ g.so3_left_jacobian(phi), np.eye(3))


def test_left_jacobian_small_angle_branch_is_continuous():
    for f in (g.so3_left_jacobian, g.so3_left_jacobian_inv):
        a = f(np.array([1e-7, 0, 0]))
        b = f(np.array([1e-5, 0, 0]))
        assert np.allclose(a, b, atol=1e-5)


def test_odot_is_jacobian_of_left_perturbation():
    """d/dd [exp(d^) U m] at d = 0 equals odot(U m) (paper eq. 13)."""
    U = random_poses(1)[0]
    m = g.homogeneous(RNG.normal(size=3) * 10)
    J_num = numeric_jacobian(lambda d: g.se3_exp(d) @ U @ m, np.zeros(6))
    assert np.allclose(J_num, g.odot(U @ m), atol=1e-6)


def test_prediction_jacobian_is_exp_of_curly_hat():
    """Paper eq. 11: the left perturbation propagates through exp(-tau u^) mu with
    F = exp(-tau u curly-hat) = Ad(exp(-tau u^))."""
    U = random_poses(1)[0]
    u = RNG.normal(size=6)
    tau = 0.1
    A = g.se3_exp(-tau * u)
    f = lambda d: g.se3_log(A @ g.se3_exp(d) @ U @ g.se3_inv(A @ U))
    J_num = numeric_jacobian(f, np.zeros(6))
    F = expm(g.curly_hat(-tau * u))
    assert np.allclose(J_num, F, atol=1e-6)
    assert np.allclose(F, g.adjoint(A), atol=1e-12)


def test_is_rigid():
    T = random_poses(1)[0]
    assert g.is_rigid(T)
    bad = T.copy()
    bad[0, 0] += 0.1
    assert not g.is_rigid(bad)
    bad = T.copy()
    bad[3, 0] = 1.0
    assert not g.is_rigid(bad)
    reflect = np.diag([1.0, 1.0, -1.0, 1.0])
    assert not g.is_rigid(reflect)
    nan = T.copy()
    nan[0, 3] = np.nan
    assert not g.is_rigid(nan)
