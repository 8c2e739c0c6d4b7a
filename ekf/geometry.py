"""Lie-group math on SO(3) and SE(3), in the paper's conventions.

Conventions (see ``../shared/DESIGN.md``):

* A twist is ``xi = [rho; phi]`` in R^6, **translation first** (the paper's ``u = [v; w]``).
* ``twist_hat(xi)`` is the 4x4 matrix ``[[phi^, rho], [0, 0]]`` (paper eq. 12, first form).
* ``curly_hat(xi)`` is the 6x6 matrix ``[[phi^, rho^], [0, phi^]]`` (paper eq. 12, second form),
  the adjoint of the Lie algebra: ``exp(curly_hat(xi)) == adjoint(se3_exp(xi))``.
* ``odot(s)`` for a homogeneous point ``s = [s; s4]`` is the 4x6 matrix ``[[s4 I, -s^], [0, 0]]``
  so that ``twist_hat(xi) @ s == odot(s) @ xi`` (paper eq. 13).

Every exp and log here is closed form (no ``scipy.linalg.expm``), and every function that takes
one vector also takes a stack of them (leading batch axes), so the per-frame filter update can be
vectorised. Small angles switch to Taylor series to stay accurate to machine precision.
"""

from __future__ import annotations

import math

import numpy as np

_SMALL = 1e-6


def hat(w: np.ndarray) -> np.ndarray:
    """Skew-symmetric matrix of ``w`` (..., 3) -> (..., 3, 3): ``hat(a) @ b == cross(a, b)``."""
    w = np.asarray(w, dtype=float)
    out = np.zeros(w.shape[:-1] + (3, 3))
    out[..., 0, 1] = -w[..., 2]
    out[..., 0, 2] = w[..., 1]
    out[..., 1, 0] = w[..., 2]
    out[..., 1, 2] = -w[..., 0]
    out[..., 2, 0] = -w[..., 1]
    out[..., 2, 1] = w[..., 0]
    return out


def vee(W: np.ndarray) -> np.ndarray:
    """Inverse of :func:`hat` for 3x3 matrices, and of :func:`twist_hat` for 4x4 ones."""
    W = np.asarray(W, dtype=float)
    if W.shape[-2:] == (3, 3):
        return np.stack([W[..., 2, 1], W[..., 0, 2], W[..., 1, 0]], axis=-1)
    if W.shape[-2:] == (4, 4):
        return np.concatenate([W[..., :3, 3], vee(W[..., :3, :3])], axis=-1)
    raise ValueError(f"vee expects (...,3,3) or (...,4,4), got shape {W.shape}")


def twist_hat(xi: np.ndarray) -> np.ndarray:
    """4x4 matrix of a twist ``xi = [rho; phi]`` (paper eq. 12, ``u^``)."""
    xi = np.asarray(xi, dtype=float)
    out = np.zeros(xi.shape[:-1] + (4, 4))
    out[..., :3, :3] = hat(xi[..., 3:])
    out[..., :3, 3] = xi[..., :3]
    return out


def curly_hat(xi: np.ndarray) -> np.ndarray:
    """6x6 adjoint of a twist ``xi = [rho; phi]`` (paper eq. 12, ``u`` curly-hat)."""
    xi = np.asarray(xi, dtype=float)
    out = np.zeros(xi.shape[:-1] + (6, 6))
    ph = hat(xi[..., 3:])
    out[..., :3, :3] = ph
    out[..., :3, 3:] = hat(xi[..., :3])
    out[..., 3:, 3:] = ph
    return out


_SERIES = 0.1  # below this angle the coefficients use Taylor series (no cancellation)


def _series(theta: np.ndarray, coeffs: tuple[float, ...]) -> np.ndarray:
    t2 = theta * theta
    out = np.zeros_like(theta)
    for c in reversed(coeffs):
        out = out * t2 + c
    return out


#: Taylor coefficients (in t^2) of A = sin t / t, B = (1 - cos t) / t^2, C = (t - sin t) / t^3.
_A_SERIES = (1.0, -1 / 6, 1 / 120, -1 / 5040, 1 / 362880)
_B_SERIES = (1 / 2, -1 / 24, 1 / 720, -1 / 40320, 1 / 3628800)
_C_SERIES = (1 / 6, -1 / 120, 1 / 5040, -1 / 362880, 1 / 39916800)


def _theta_coeffs(theta: np.ndarray):
    """A = sin t / t, B = (1 - cos t) / t^2, C = (t - sin t) / t^3.

    The closed forms of B and C cancel catastrophically for small t (1e-5 rad loses about
    six digits), so below ``_SERIES`` they come from Taylor series accurate to 1e-16.
    """
    small = theta < _SERIES
    t = np.where(small, 1.0, theta)
    t2 = t * t
    A = np.where(small, _series(theta, _A_SERIES), np.sin(t) / t)
    B = np.where(small, _series(theta, _B_SERIES), (1.0 - np.cos(t)) / t2)
    C = np.where(small, _series(theta, _C_SERIES), (t - np.sin(t)) / (t2 * t))
    return A, B, C


def theta_coeffs_scalar(theta: float) -> tuple[float, float, float]:
    """:func:`_theta_coeffs` for one angle, in plain floats (for single-vector hot loops);
    NaN for an angle that is not finite (an overflowed twist: the caller's guard then names
    the frame), where ``math.sin`` would raise."""
    if not math.isfinite(theta):
        return math.nan, math.nan, math.nan
    if theta < _SERIES:
        t2 = theta * theta
        out = []
        for coeffs in (_A_SERIES, _B_SERIES, _C_SERIES):
            v = 0.0
            for c in reversed(coeffs):
                v = v * t2 + c
            out.append(v)
        return out[0], out[1], out[2]
    s, c = math.sin(theta), math.cos(theta)
    return s / theta, (1.0 - c) / (theta * theta), (theta - s) / (theta ** 3)


def so3_exp(phi: np.ndarray) -> np.ndarray:
    """Rodrigues' formula: rotation vector (..., 3) -> rotation matrix (..., 3, 3)."""
    phi = np.asarray(phi, dtype=float)
    theta = np.linalg.norm(phi, axis=-1)
    A, B, _ = _theta_coeffs(theta)
    W = hat(phi)
    I = np.broadcast_to(np.eye(3), W.shape)
    return I + A[..., None, None] * W + B[..., None, None] * (W @ W)


def so3_log(R: np.ndarray) -> np.ndarray:
    """Rotation matrix (..., 3, 3) -> rotation vector (..., 3) with angle in [0, pi]."""
    R = np.asarray(R, dtype=float)
    cos_t = np.clip((np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    skew = vee(R - np.swapaxes(R, -1, -2)) / 2.0  # = sin(theta) * axis
    # atan2 keeps full precision for small angles, where arccos(cos) loses half the digits.
    theta = np.arctan2(np.linalg.norm(skew, axis=-1), cos_t)
    small = theta < _SMALL
    near_pi = theta > np.pi - 1e-3
    sin_t = np.sin(theta)
    scale = np.where(small, 1.0 + theta**2 / 6.0, theta / np.where(small | near_pi, 1.0, sin_t))
    out = scale[..., None] * skew
    if np.any(near_pi):
        # Near pi the skew part vanishes: take the axis from the symmetric part of R.
        Rs = R[near_pi]
        th = theta[near_pi]
        B = (Rs + np.swapaxes(Rs, -1, -2)) / 2.0 - np.cos(th)[..., None, None] * np.eye(3)
        B = B / (1.0 - np.cos(th))[..., None, None]  # = axis axis^T
        diag = np.diagonal(B, axis1=-2, axis2=-1)
        k = np.argmax(diag, axis=-1)
        col = np.take_along_axis(B, k[..., None, None].repeat(3, axis=-1), axis=-2)[..., 0, :]
        axis = col / np.sqrt(np.take_along_axis(diag, k[..., None], axis=-1))
        sk = np.take_along_axis(vee(Rs - np.swapaxes(Rs, -1, -2)), k[..., None], axis=-1)
        sign = np.where(np.take_along_axis(axis, k[..., None], axis=-1) * sk < 0, -1.0, 1.0)
        out[near_pi] = axis * sign * th[..., None]
    return out


def so3_left_jacobian(phi: np.ndarray) -> np.ndarray:
    """Left Jacobian J_l(phi) of SO(3): ``exp((phi + d)^) ~ exp((J_l d)^) exp(phi^)``."""
    phi = np.asarray(phi, dtype=float)
    theta = np.linalg.norm(phi, axis=-1)
    _, B, C = _theta_coeffs(theta)
    W = hat(phi)
    I = np.broadcast_to(np.eye(3), W.shape)
    return I + B[..., None, None] * W + C[..., None, None] * (W @ W)


def so3_left_jacobian_inv(phi: np.ndarray) -> np.ndarray:
    """Inverse of :func:`so3_left_jacobian`."""
    phi = np.asarray(phi, dtype=float)
    theta = np.linalg.norm(phi, axis=-1)
    small = theta < _SERIES
    t = np.where(small, 1.0, theta)
    D = np.where(
        small,
        _series(theta, (1 / 12, 1 / 720, 1 / 30240, 1 / 1209600, 1 / 47900160)),
        (1.0 - t * np.sin(t) / (2.0 * (1.0 - np.cos(t)))) / (t * t),
    )
    W = hat(phi)
    I = np.broadcast_to(np.eye(3), W.shape)
    return I - 0.5 * W + D[..., None, None] * (W @ W)


def se3_exp(xi: np.ndarray) -> np.ndarray:
    """Closed-form exponential of a twist ``[rho; phi]`` (..., 6) -> (..., 4, 4)."""
    xi = np.asarray(xi, dtype=float)
    out = np.zeros(xi.shape[:-1] + (4, 4))
    out[..., :3, :3] = so3_exp(xi[..., 3:])
    out[..., :3, 3] = (so3_left_jacobian(xi[..., 3:]) @ xi[..., :3, None])[..., 0]
    out[..., 3, 3] = 1.0
    return out


def se3_log(T: np.ndarray) -> np.ndarray:
    """Closed-form logarithm of a rigid transform (..., 4, 4) -> twist ``[rho; phi]`` (..., 6)."""
    T = np.asarray(T, dtype=float)
    phi = so3_log(T[..., :3, :3])
    rho = (so3_left_jacobian_inv(phi) @ T[..., :3, 3, None])[..., 0]
    return np.concatenate([rho, phi], axis=-1)


def se3_inv(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid transform without a general matrix inverse."""
    T = np.asarray(T, dtype=float)
    out = np.zeros_like(T)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -(Rt @ T[..., :3, 3, None])[..., 0]
    out[..., 3, 3] = 1.0
    return out


def adjoint(T: np.ndarray) -> np.ndarray:
    """6x6 adjoint of a rigid transform, translation first: ``[[R, p^ R], [0, R]]``.

    ``T exp(xi^) T^-1 == exp((adjoint(T) xi)^)``.
    """
    T = np.asarray(T, dtype=float)
    R = T[..., :3, :3]
    out = np.zeros(T.shape[:-2] + (6, 6))
    out[..., :3, :3] = R
    out[..., :3, 3:] = hat(T[..., :3, 3]) @ R
    out[..., 3:, 3:] = R
    return out


def odot(s: np.ndarray) -> np.ndarray:
    """The paper's odot of a homogeneous point ``s = [s; s4]`` (..., 4) -> (..., 4, 6).

    ``odot(s) = [[s4 I3, -s^], [0, 0]]``, so that ``twist_hat(xi) @ s == odot(s) @ xi``.
    """
    s = np.asarray(s, dtype=float)
    out = np.zeros(s.shape[:-1] + (4, 6))
    out[..., :3, :3] = s[..., 3, None, None] * np.eye(3)
    out[..., :3, 3:] = -hat(s[..., :3])
    return out


def homogeneous(p: np.ndarray) -> np.ndarray:
    """Append a 1 to points (..., 3) -> (..., 4)."""
    p = np.asarray(p, dtype=float)
    return np.concatenate([p, np.ones(p.shape[:-1] + (1,))], axis=-1)


def transform_points(T: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Apply a rigid transform (4, 4) to points (..., 3)."""
    T = np.asarray(T, dtype=float)
    return np.asarray(p, dtype=float) @ T[:3, :3].T + T[:3, 3]


def is_rigid(T: np.ndarray, tol: float = 1e-6) -> bool:
    """True when ``T`` is a finite 4x4 rigid transform (orthonormal, det +1, last row 0 0 0 1)."""
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        return False
    R = T[:3, :3]
    return bool(
        np.allclose(R @ R.T, np.eye(3), atol=tol)
        and abs(np.linalg.det(R) - 1.0) < tol
        and np.allclose(T[3], [0.0, 0.0, 0.0, 1.0], atol=tol)
    )
