"""Stereo model z = M pi(q), its Jacobian, and triangulation with its covariance."""

import numpy as np
import pytest

from vislam.ekf import camera
from tests.numdiff import numeric_jacobian

K = np.array([[707.0912, 0.0, 601.8873], [0.0, 707.0912, 183.1104], [0.0, 0.0, 1.0]])
B = 0.5371506532679237
RNG = np.random.default_rng(11)


def random_points(n):
    p = np.column_stack(
        [RNG.uniform(-10, 10, n), RNG.uniform(-2, 3, n), RNG.uniform(3, 60, n), np.ones(n)]
    )
    return p


def test_stereo_matrix_layout():
    M = camera.stereo_matrix(K, B)
    assert M.shape == (4, 4)
    assert np.allclose(M[1], M[3]), "rows 2 and 4 of M are identical (vL = vR)"
    assert np.isclose(M[2, 3], -K[0, 0] * B)


def test_projection_disparity_is_fsu_b_over_depth():
    q = random_points(50)
    z = camera.project(camera.stereo_matrix(K, B), q)
    assert np.allclose(z[:, 0] - z[:, 2], K[0, 0] * B / q[:, 2])
    assert np.allclose(z[:, 1], z[:, 3])


def test_dpi_dq_finite_differences():
    for q in random_points(5):
        assert np.allclose(camera.dpi_dq(q), numeric_jacobian(camera.pi, q), atol=1e-8)


def test_triangulation_inverts_projection():
    q = random_points(100)
    z = camera.project(camera.stereo_matrix(K, B), q)
    p, cov = camera.triangulate(z, K, B, np.eye(4))
    assert np.allclose(p, q[:, :3], atol=1e-9)
    assert cov.shape == (100, 3, 3)
    assert np.all(np.linalg.eigvalsh(cov) > 0)


def test_triangulation_jacobian_finite_differences():
    q = random_points(4)
    z = camera.project(camera.stereo_matrix(K, B), q)
    _, J = camera.triangulate_with_jacobian(z, K, B)
    for zi, Ji in zip(z, J):
        J_num = numeric_jacobian(lambda x: camera.triangulate_with_jacobian(x, K, B)[0][0], zi, 1e-4)
        assert np.allclose(Ji, J_num, rtol=1e-6, atol=1e-9)


def test_triangulation_covariance_matches_monte_carlo():
    q = np.array([[2.0, 1.0, 20.0, 1.0]])
    z = camera.project(camera.stereo_matrix(K, B), q)
    V = np.diag([0.5, 0.5, 0.5, 0.5]) ** 2
    _, cov = camera.triangulate(z, K, B, V)
    rng = np.random.default_rng(0)
    noisy = z + rng.multivariate_normal(np.zeros(4), V, size=20000)
    pts, _ = camera.triangulate(noisy, K, B, V)
    emp = np.cov(pts.T)
    # first order: agree within a few percent at 20 m with half-pixel noise
    assert np.allclose(np.sqrt(np.diag(emp)), np.sqrt(np.diag(cov[0])), rtol=0.05)


def test_non_positive_disparity_gives_nan():
    z = np.array([[600.0, 180.0, 600.0, 180.0], [600.0, 180.0, 610.0, 180.0]])
    p, cov = camera.triangulate(z, K, B, np.eye(4))
    assert np.all(np.isnan(p))


def test_radial_lens_term_round_trip():
    """undistort_pixels inverts distort_pixels to 1e-9 px (strong barrel to mild pincushion),
    and the term moves the pixels."""
    rng = np.random.default_rng(5)
    K = np.array([[718.9, 0.0, 607.2], [0.0, 718.9, 185.2], [0.0, 0.0, 1.0]])
    u = rng.uniform(0.0, 1241.0, 40)
    v = rng.uniform(0.0, 376.0, 40)
    z = np.stack([u, v, u - rng.uniform(1.0, 80.0, 40), v], axis=1)
    for k1 in (0.02, -0.3, 0.0):
        back = camera.undistort_pixels(camera.distort_pixels(z, K, k1), K, k1)
        np.testing.assert_allclose(back, z, rtol=0, atol=1e-9)
    moved = camera.distort_pixels(z, K, 0.02) - z
    corner = np.argmax(np.hypot(u - 607.2, v - 185.2))
    assert np.hypot(moved[corner, 0], moved[corner, 1]) > 5.0  # px at the far corner


def test_a_radial_term_that_folds_the_image_over_is_refused():
    K = np.array([[700.0, 0.0, 600.0], [0.0, 700.0, 180.0], [0.0, 0.0, 1.0]])
    corner = np.array([[1240.0, 370.0, 1200.0, 370.0]])
    with pytest.raises(ValueError, match="folds the image over"):
        camera.undistort_pixels(corner, K, -1.0)
