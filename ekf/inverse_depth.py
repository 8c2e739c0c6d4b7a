"""Anchored inverse-depth landmarks (Civera, Davison and Montiel 2008), for ekf-joint and
ekf-invariant (``FilterConfig.landmark_parameterisation = "inverse-depth"``).

Why. A stereo point's depth ``fsu b / disparity`` is far from linear in the pixels once the
disparity is a few pixels (60 m: ~6 px), so a Gaussian on world ``x, y, z`` is a poor picture of
a far landmark: the first-order filters grow overconfident on far points. Its inverse depth
``disparity / (fsu b)`` is *exactly* linear in the pixels.

Parameterisation. A landmark is ``x = [alpha, beta, rho]`` in the frame of its *anchor*, the left
camera at its first observation (``world_T_anchor = (R_a, p_a)``, fixed once chosen: a constant
of the chart, not a state), with

    m = p_a + R_a b / rho,      b = [alpha, beta, 1]                              (ID-1)

and, as the homogeneous world point scaled by ``rho`` (finite even at infinity, ``rho -> 0``),

    m_h = [R_a b + rho p_a; rho],    dm_h/dx = G = [[R_a e1, R_a e2, p_a], [0, 0, 1]].   (ID-2)

The camera model (paper eq. 1-3) takes ``m_h`` unchanged: ``z = M pi(cam_T_imu U m_h)``, since
``pi`` divides by the third coordinate.

Initialisation from the first stereo pixels ``z = [uL, vL, uR, vR]``: ``alpha = (uL - cu)/fsu``,
``beta = ((vL + vR)/2 - cv)/fsv``, ``rho = (uL - uR)/(fsu b)``: linear, so the pixel part of the
covariance is exact (ID-3). The anchor pose's own error enters through
``dx/dm = D R_a^T`` (ID-4, ``D = [[rho, 0, -alpha rho], [0, rho, -beta rho], [0, 0, -rho^2]]``).

Conversion. Once the landmark's depth is well known from where it is seen, its Euclidean form is
as good; Civera's linearity index (ID-5)

    L = 4 sigma_d |cos(parallax)| / d,    sigma_d = sigma_rho / rho^2,

(``d`` the distance from the current camera, ``parallax`` the angle at the point between the
anchor's and the current camera's rays) below ``inverse_depth_linearity`` turns it into world
``m`` with ``P <- J P J^T`` on its rows (``J = dm/dx``, ID-6), which is exact to first order.

Gauge. A change of world frame ``g = exp([v; w])`` moves ``m`` by ``v - m^ w``, so the anchored
coordinates move by ``D R_a^T [I, -m^]`` (ID-7, :func:`gauge_rows`): the rows the filters'
observability constraints need.
"""

from __future__ import annotations

import numpy as np

from vislam.ekf.geometry import hat


def from_stereo(z: np.ndarray, K: np.ndarray, baseline: float) -> tuple[np.ndarray, np.ndarray]:
    """(ID-3) ``x`` (n, 3) in the left camera of the pixels ``z`` (n, 4), and ``dx/dz`` (3, 4),
    the same for every observation. Rows with non-positive disparity give ``rho <= 0``: callers
    check the disparity first."""
    z = np.atleast_2d(np.asarray(z, dtype=float))
    fsu, fsv, cu, cv = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    fb = fsu * baseline
    x = np.empty((z.shape[0], 3))
    x[:, 0] = (z[:, 0] - cu) / fsu
    x[:, 1] = (0.5 * (z[:, 1] + z[:, 3]) - cv) / fsv
    x[:, 2] = (z[:, 0] - z[:, 2]) / fb
    J = np.array(
        [
            [1.0 / fsu, 0.0, 0.0, 0.0],
            [0.0, 0.5 / fsv, 0.0, 0.5 / fsv],
            [1.0 / fb, 0.0, -1.0 / fb, 0.0],
        ]
    )
    return x, J


def new_landmarks(z: np.ndarray, K: np.ndarray, baseline: float, pixel_cov: np.ndarray,
                  world_T_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Landmarks started from their first stereo pixels ``z`` (n, 4), all anchored in the camera
    ``world_T_cam``: ``(x (n, 3), R_a (n, 3, 3), p_a (n, 3), C_z (n, 3, 3))`` with ``C_z`` the
    pixel-noise covariance of ``x`` (ID-3: exact). The anchor pose's own error is the filter's
    to add (its pose Jacobian)."""
    x, Jz = from_stereo(z, K, baseline)
    n = x.shape[0]
    R_a = np.broadcast_to(world_T_cam[:3, :3], (n, 3, 3)).copy()
    p_a = np.broadcast_to(world_T_cam[:3, 3], (n, 3)).copy()
    return x, R_a, p_a, np.broadcast_to(Jz @ pixel_cov @ Jz.T, (n, 3, 3))


def bearing(x: np.ndarray) -> np.ndarray:
    """``b = [alpha, beta, 1]`` (n, 3)."""
    b = np.ones((x.shape[0], 3))
    b[:, :2] = x[:, :2]
    return b


def homogeneous_point(x: np.ndarray, R_a: np.ndarray, p_a: np.ndarray) -> np.ndarray:
    """(ID-2) ``m_h = [R_a b + rho p_a; rho]`` (n, 4); ``R_a`` (n, 3, 3), ``p_a`` (n, 3)."""
    m_h = np.empty((x.shape[0], 4))
    m_h[:, :3] = np.einsum("nij,nj->ni", R_a, bearing(x)) + x[:, 2:3] * p_a
    m_h[:, 3] = x[:, 2]
    return m_h


def homogeneous_jacobian(R_a: np.ndarray, p_a: np.ndarray) -> np.ndarray:
    """(ID-2) ``G = dm_h/dx`` (n, 4, 3)."""
    G = np.zeros((R_a.shape[0], 4, 3))
    G[:, :3, :2] = R_a[:, :, :2]
    G[:, :3, 2] = p_a
    G[:, 3, 2] = 1.0
    return G


def world_point(x: np.ndarray, R_a: np.ndarray, p_a: np.ndarray) -> np.ndarray:
    """(ID-1) ``m = p_a + R_a b / rho`` (n, 3); not finite where ``rho == 0``."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return p_a + np.einsum("nij,nj->ni", R_a, bearing(x)) / x[:, 2:3]


def world_jacobian(x: np.ndarray, R_a: np.ndarray) -> np.ndarray:
    """(ID-6) ``J = dm/dx = R_a [[1/rho, 0, -alpha/rho^2], [0, 1/rho, -beta/rho^2],
    [0, 0, -1/rho^2]]`` (n, 3, 3)."""
    r = x[:, 2]
    B = np.zeros((x.shape[0], 3, 3))
    with np.errstate(divide="ignore", invalid="ignore"):
        B[:, 0, 0] = B[:, 1, 1] = 1.0 / r
        B[:, 0, 2] = -x[:, 0] / r**2
        B[:, 1, 2] = -x[:, 1] / r**2
        B[:, 2, 2] = -1.0 / r**2
    return R_a @ B


def _D(x: np.ndarray) -> np.ndarray:
    """``D = d x / d q_a`` (n, 3, 3) at ``q_a = b / rho`` (the point in the anchor frame)."""
    a, b, r = x[:, 0], x[:, 1], x[:, 2]
    D = np.zeros((x.shape[0], 3, 3))
    D[:, 0, 0] = D[:, 1, 1] = r
    D[:, 0, 2] = -a * r
    D[:, 1, 2] = -b * r
    D[:, 2, 2] = -r * r
    return D


def inverse_jacobian(x: np.ndarray, R_a: np.ndarray) -> np.ndarray:
    """(ID-4) ``dx/dm = D R_a^T`` (n, 3, 3), the inverse of :func:`world_jacobian`."""
    return _D(x) @ np.swapaxes(R_a, 1, 2)


def from_world(m: np.ndarray, R_a: np.ndarray, p_a: np.ndarray) -> np.ndarray:
    """The inverse of :func:`world_point`: ``x`` (n, 3) of world points ``m`` (n, 3)."""
    q = np.einsum("nji,nj->ni", R_a, m - p_a)
    return np.stack([q[:, 0] / q[:, 2], q[:, 1] / q[:, 2], 1.0 / q[:, 2]], axis=1)


def gauge_rows(x: np.ndarray, R_a: np.ndarray, p_a: np.ndarray) -> np.ndarray:
    """(ID-7) ``dx`` (n, 3, 6) under a change of world frame ``[v; w]`` (``m -> m + v - m^ w``):
    ``D R_a^T [I, -m^]``, written so that it stays finite as ``rho -> 0``:
    ``E R_a^T [rho I, -s^]`` with ``E = D / rho`` and ``[s; rho] = m_h`` (ID-2)."""
    a, b, r = x[:, 0], x[:, 1], x[:, 2]
    E = np.zeros((x.shape[0], 3, 3))
    E[:, 0, 0] = E[:, 1, 1] = 1.0
    E[:, 0, 2] = -a
    E[:, 1, 2] = -b
    E[:, 2, 2] = -r
    ERt = E @ np.swapaxes(R_a, 1, 2)
    N = np.empty((x.shape[0], 3, 6))
    N[:, :, :3] = ERt * r[:, None, None]
    N[:, :, 3:] = -ERt @ hat(homogeneous_point(x, R_a, p_a)[:, :3])
    return N


def gauge_rows_change(x_from: np.ndarray, x_to: np.ndarray, R_a: np.ndarray,
                      p_a: np.ndarray) -> np.ndarray:
    """``gauge_rows(x_to) - gauge_rows(x_from)`` (n, 3, 6): how an update that moves
    inverse-depth landmarks from ``x_from`` to ``x_to`` moves their gauge rows (ID-7), the
    transport rows of the observability-constrained filters; both in one batched evaluation."""
    n = x_from.shape[0]
    N = gauge_rows(np.concatenate([x_to, x_from]), np.concatenate([R_a, R_a]),
                   np.concatenate([p_a, p_a]))
    return N[:n] - N[n:]


def linearity_index(
    x: np.ndarray, var_rho: np.ndarray, R_a: np.ndarray, p_a: np.ndarray, centre: np.ndarray
) -> np.ndarray:
    """(ID-5) Civera's linearity index of the inverse-depth -> Euclidean conversion (n,):
    ``4 sigma_d |cos parallax| / d`` seen from the camera at ``centre`` (3,); inf where
    ``rho <= 0`` (a point at or beyond infinity stays in inverse depth)."""
    r = x[:, 2]
    out = np.full(x.shape[0], np.inf)
    ok = r > 0
    if not ok.any():
        return out
    ray_a = np.einsum("nij,nj->ni", R_a[ok], bearing(x[ok]))  # anchor -> point, times rho
    m = p_a[ok] + ray_a / r[ok, None]
    ray_c = m - centre
    d = np.linalg.norm(ray_c, axis=1)
    cos = np.einsum("ni,ni->n", ray_a, ray_c) / (np.linalg.norm(ray_a, axis=1) * d)
    sigma_d = np.sqrt(np.maximum(var_rho[ok], 0.0)) / r[ok] ** 2
    out[ok] = 4.0 * sigma_d * np.abs(cos) / d
    return out
