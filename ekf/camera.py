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


# --- a radial lens term -------------------------------------------------------------------------
# The pixels of a file may carry a residual radial distortion that K does not describe. With
# one coefficient k1 (Brown-Conrady, normalised coordinates about the principal point, each
# image about its own, the same (cu, cv) in a rectified pair):
#     x_d = x (1 + k1 r^2),   r^2 = x^2 + y^2,   x = (u - cu) / fsu,  y = (v - cv) / fsv.
# vislam removes it from the measurements once (ekf.model.model_sequence), so that every
# estimator keeps the pinhole model of paper eq. 1-3.


def _radius_undistorted(r_d: np.ndarray, k1: float) -> np.ndarray:
    """The radius ``r`` with ``r (1 + k1 r^2) = r_d`` (Newton from ``r_d``; monotone where
    ``1 + 3 k1 r^2 > 0``, which :func:`undistort_pixels` checks)."""
    r = r_d.copy()
    for _ in range(20):
        f = r * (1.0 + k1 * r * r) - r_d
        r = r - f / (1.0 + 3.0 * k1 * r * r)
    return r


def distort_pixels(z: np.ndarray, K: np.ndarray, k1: float) -> np.ndarray:
    """Stereo pixels ``[uL, vL, uR, vR]`` (N, 4) of a pinhole camera as a lens with radial
    coefficient ``k1`` shows them (the simulator's fault; :func:`undistort_pixels` inverts)."""
    z = np.array(z, dtype=float)
    fsu, fsv, cu, cv = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    for c in (0, 2):
        x, y = (z[:, c] - cu) / fsu, (z[:, c + 1] - cv) / fsv
        s = 1.0 + k1 * (x * x + y * y)
        z[:, c], z[:, c + 1] = cu + fsu * x * s, cv + fsv * y * s
    return z


def undistort_pixels(z: np.ndarray, K: np.ndarray, k1: float) -> np.ndarray:
    """The pinhole pixels (N, 4) of stereo pixels ``z`` that carry a radial term ``k1``
    (:func:`distort_pixels` inverted). Raises ValueError where the lens map folds over
    (``1 + 3 k1 r^2 <= 0``: not invertible there). Non-finite rows stay non-finite."""
    z = np.array(z, dtype=float)
    fsu, fsv, cu, cv = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    for c in (0, 2):
        x_d, y_d = (z[:, c] - cu) / fsu, (z[:, c + 1] - cv) / fsv
        r_d = np.hypot(x_d, y_d)
        r = _radius_undistorted(r_d, k1)
        fold = ~(1.0 + 3.0 * k1 * r * r > 0) & np.isfinite(r_d)
        if np.any(fold):
            raise ValueError(f"a radial term k1 = {k1:g} folds the image over at normalised "
                             f"radius {float(r_d[fold].min()):.3g} (1 + 3 k1 r^2 <= 0)")
        with np.errstate(invalid="ignore", divide="ignore"):
            scale = np.where(r_d > 0, r / r_d, 1.0)
        z[:, c], z[:, c + 1] = cu + fsu * x_d * scale, cv + fsv * y_d * scale
    return z
