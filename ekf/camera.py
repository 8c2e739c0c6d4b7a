"""The stereo camera model of the paper (eq. 1-3) and stereo triangulation.

``z = M pi(q)`` with ``q = cam_T_imu U m`` a homogeneous point in the left camera frame,
``pi(q) = q / q3`` and the stereo matrix

    M = [[fsu, 0,   cu, 0       ],
         [0,   fsv, cv, 0       ],
         [fsu, 0,   cu, -fsu b  ],
         [0,   fsv, cv, 0       ]]

so that ``z = [uL, vL, uR, vR]`` and the disparity is ``uL - uR = fsu b / q3``.
All functions take stacks of points (leading axis N).
"""

from __future__ import annotations

import numpy as np


def stereo_matrix(K: np.ndarray, baseline: float) -> np.ndarray:
    """The 4x4 stereo calibration matrix M of paper eq. 2."""
    fsu, fsv, cu, cv = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    return np.array(
        [
            [fsu, 0.0, cu, 0.0],
            [0.0, fsv, cv, 0.0],
            [fsu, 0.0, cu, -fsu * baseline],
            [0.0, fsv, cv, 0.0],
        ]
    )


def pi(q: np.ndarray) -> np.ndarray:
    """Projection ``pi(q) = q / q3`` (paper eq. 3) of homogeneous points (..., 4)."""
    q = np.asarray(q, dtype=float)
    return q / q[..., 2:3]


def dpi_dq(q: np.ndarray) -> np.ndarray:
    """Jacobian of :func:`pi` (..., 4) -> (..., 4, 4).

    ``(1/q3) [[1, 0, -q1/q3, 0], [0, 1, -q2/q3, 0], [0, 0, 0, 0], [0, 0, -q4/q3, 1]]``.
    """
    q = np.asarray(q, dtype=float)
    inv = 1.0 / q[..., 2]
    out = np.zeros(q.shape[:-1] + (4, 4))
    out[..., 0, 0] = inv
    out[..., 1, 1] = inv
    out[..., 3, 3] = inv
    out[..., 0, 2] = -q[..., 0] * inv * inv
    out[..., 1, 2] = -q[..., 1] * inv * inv
    out[..., 3, 2] = -q[..., 3] * inv * inv
    return out


def project(M: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Predicted stereo pixels ``M pi(q)`` for camera-frame homogeneous points (..., 4)."""
    return pi(q) @ M.T


def triangulate_with_jacobian(
    z: np.ndarray, K: np.ndarray, baseline: float
) -> tuple[np.ndarray, np.ndarray]:
    """Stereo triangulation in the left camera frame and its Jacobian ``dp/dz``.

    ``z`` (N, 4) rows ``[uL, vL, uR, vR]``. Returns points (N, 3) and ``J`` (N, 3, 4).
    The vertical coordinate uses the mean of vL and vR (both carry the same information).
    Rows with non-positive disparity give NaN: callers reject them first.
    """
    z = np.atleast_2d(np.asarray(z, dtype=float))
    fsu, fsv, cu, cv = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    d = z[:, 0] - z[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        depth = np.where(d > 0, fsu * baseline / d, np.nan)
        dz_dd = -depth / d  # d depth / d uL; d depth / d uR is its negative
    x_n = (z[:, 0] - cu) / fsu
    y_n = (0.5 * (z[:, 1] + z[:, 3]) - cv) / fsv
    p = np.stack([x_n * depth, y_n * depth, depth], axis=-1)

    J = np.zeros((z.shape[0], 3, 4))
    J[:, 0, 0] = depth / fsu + x_n * dz_dd
    J[:, 0, 2] = -x_n * dz_dd
    J[:, 1, 0] = y_n * dz_dd
    J[:, 1, 1] = 0.5 * depth / fsv
    J[:, 1, 2] = -y_n * dz_dd
    J[:, 1, 3] = 0.5 * depth / fsv
    J[:, 2, 0] = dz_dd
    J[:, 2, 2] = -dz_dd
    return p, J


def triangulate(
    z: np.ndarray, K: np.ndarray, baseline: float, pixel_cov: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Stereo triangulation with its first-order covariance ``J V J^T`` (V = ``pixel_cov``).

    Returns points (N, 3) in the left camera frame and covariances (N, 3, 3).
    """
    p, J = triangulate_with_jacobian(z, K, baseline)
    return p, J @ pixel_cov @ np.swapaxes(J, -1, -2)


#: Orthonormal change of pixel coordinates whose first row is the disparity direction
#: ``(uL - uR) / sqrt(2)``: a square root of V built in this basis moves the disparity along a
#: single sigma-point axis (see :func:`triangulate_unscented`).
_DISPARITY_BASIS = np.array(
    [[1.0, 0.0, -1.0, 0.0], [1.0, 0.0, 1.0, 0.0], [0.0, 1.0, 0.0, -1.0], [0.0, 1.0, 0.0, 1.0]]
) / np.sqrt(2.0)


def triangulate_unscented(
    z: np.ndarray, K: np.ndarray, baseline: float, pixel_cov: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Stereo triangulation by the unscented transform of the pixel noise ``V = pixel_cov``.

    The 2n+1 = 9 sigma points ``z, z +- sqrt(3) L_j`` (Julier's ``kappa = 3 - n``, weights
    ``-1/3`` and ``1/6``) go through the exact triangulation. ``L`` is the square root of V whose
    first column alone changes the disparity, so along the depth the rule is the 3-point
    Gauss-Hermite quadrature (exact for the Gaussian moments up to degree 5): it captures the skew
    of ``depth = fsu b / disparity`` that the first-order ``J V J^T`` misses for far points.
    The covariance uses the weights ``W0 = -1/3 + beta`` (``beta = 2``, the Gaussian choice)
    and ``1/6``, which keeps it positive definite.

    ``z`` (N, 4). Returns the mean (N, 3) and covariance (N, 3, 3) of the left-camera point.
    Sigma points with non-positive disparity give NaN rows: callers reject those first.
    """
    z = np.atleast_2d(np.asarray(z, dtype=float))
    V = np.asarray(pixel_cov, dtype=float)
    n, kappa, beta = 4, -1.0, 2.0
    B = _DISPARITY_BASIS
    L = B.T @ np.linalg.cholesky(B @ V @ B.T)  # V = L L^T; column 0 carries the disparity
    offsets = np.sqrt(n + kappa) * np.concatenate([L.T, -L.T])  # (8, 4)
    sigma = np.concatenate([z[:, None, :], z[:, None, :] + offsets], axis=1)  # (N, 9, 4)
    y, _ = triangulate_with_jacobian(sigma.reshape(-1, 4), K, baseline)
    y = y.reshape(z.shape[0], 2 * n + 1, 3)
    w = np.full(2 * n + 1, 1.0 / (2.0 * (n + kappa)))
    w[0] = kappa / (n + kappa)
    mean = np.einsum("s,nsk->nk", w, y)
    wc = w.copy()
    wc[0] += beta
    d = y - mean[:, None, :]
    cov = np.einsum("s,nsi,nsj->nij", wc, d, d)
    return mean, cov
