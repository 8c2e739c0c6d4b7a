"""EKF prediction of the inverse IMU pose (paper eq. 4, 11, 12).

State convention (the paper's, see ``ekf/conventions.py``): ``U = imu_T_world`` perturbed on the
left, ``U_true = exp(d^) U_est`` with ``d = [dp; dth]`` (translation first).

Motion (paper eq. 4 and 11)::

    U_{k+1} = exp(-tau u^) U_k,           u = [v; w] the body twist covering [k, k+1]
    d_{k+1} = F d_k + noise,             F = exp(-tau curly_hat(u)) = Ad(exp(-tau u^))
    Sigma_{k+1} = F Sigma_k F^T + Q,     Q = tau^2 W  (first order in the twist noise W)

``F`` is computed in closed form as ``adjoint(se3_exp(-tau u))`` (no matrix exponential).

With a gyro-bias state ``b`` (rad/s, body frame) the corrected twist is ``u - B b`` with
``B = [0; I3]`` (6x3), and the pose perturbation picks up ``G db`` with
``G = tau J_l(-tau (u - B b)) B``, ``J_l`` the left Jacobian of SE(3)
(:func:`error_state_transition` with ``B = GYRO_SELECT``); the bias follows a random
walk of density ``sigma_walk`` (variance ``sigma_walk^2 tau`` per step).

With a speed-scale state ``s`` (``config.speed_scale``: the linear velocity is off by a slowly
varying factor, ``v_true = (1 + s) v``) the same holds with one more column: the twist errors
``e = [b; s]`` (the bias where there is one) correct the twist as ``u - B(u) e`` with
``B(u) = [[0, -v], [I3, 0]]`` (:func:`twist_error_matrix`), so ``G = tau J_l(-tau u_c) B(u)``
(:func:`error_state_transition`); ``s`` is a random walk too.

Public building blocks (also used by ``ekf/invariant.py``):
:func:`paired_velocities`, :func:`motion_increment`, :func:`predict_mean`,
:func:`prediction_jacobian`, :func:`process_noise`, :func:`predict_pose`,
:func:`se3_left_jacobian` (closed form), :func:`twist_error_matrix`,
:func:`error_state_transition`, :func:`se3_exp_single`,
:func:`so3_exp_and_left_jacobian`.
"""

from __future__ import annotations

import math

import numpy as np

from vislam.ekf.errors import InputError
from vislam.ekf.geometry import adjoint, curly_hat, se3_exp, theta_coeffs_scalar

#: Selects the angular rows of a twist: ``u - GYRO_SELECT @ b`` removes a gyro bias ``b``.
GYRO_SELECT = np.vstack([np.zeros((3, 3)), np.eye(3)])


def twist_error_matrix(u: np.ndarray, gyro_bias: bool, speed_scale: bool) -> np.ndarray:
    """``B(u)`` (6, m): the corrected twist is ``u - B(u) e`` for the twist errors ``e`` of the
    state, in order: a gyro bias (3 columns, :data:`GYRO_SELECT`) and a speed scale (one column,
    ``-[v; 0]``: ``(1 + s) v``), each where configured (module docstring)."""
    u = np.asarray(u, dtype=float)
    cols = []
    if gyro_bias:
        cols.append(GYRO_SELECT)
    if speed_scale:
        cols.append(np.r_[-u[:3], np.zeros(3)][:, None])
    return np.hstack(cols) if cols else np.zeros((6, 0))


def twist_error_coupling(
    B: np.ndarray, tau: float, velocity: np.ndarray, gyro_bias: bool, speed_scale: bool
) -> np.ndarray | None:
    """``F = -tau B E(u)`` (n, m), ``E(u)`` :func:`twist_error_matrix`: where the twist errors
    act as twist noise (ekf.invariant's "imperfect IEKF"), the error transition is ``I + F
    S_e``. ``B`` (n, 6) how twist noise moves each error row, ``velocity`` the measured linear
    velocity ``v``; the columns are the bias's ``-tau B_R`` (3) and the speed scale's ``tau B_p
    v`` (1), each where configured. None with neither."""
    if not (gyro_bias or speed_scale):
        return None
    u = np.r_[np.asarray(velocity, dtype=float), np.zeros(3)]
    return -tau * (B @ twist_error_matrix(u, gyro_bias, speed_scale))


def error_state_transition(
    tau: float, u: np.ndarray, errors: np.ndarray, B: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Corrected twist ``u_c = u - B e``, the transition ``Phi = [[F, G], [0, I]]`` of the pose
    perturbation and the twist errors ``e`` (``G = tau J_l(-tau u_c) B``, module docstring) and
    ``F``. Returns ``(u_c, Phi, F)``."""
    B = np.asarray(B, dtype=float)
    m = B.shape[1]
    u_c = np.asarray(u, dtype=float) - B @ np.asarray(errors, dtype=float)
    F = prediction_jacobian(tau, u_c)
    Phi = np.eye(6 + m)
    Phi[:6, :6] = F
    Phi[:6, 6:] = tau * se3_left_jacobian(-tau * u_c) @ B
    return u_c, Phi, F


def paired_velocities(velocities: np.ndarray, pairing: str) -> np.ndarray:
    """The twist covering each interval [k, k+1] (T-1, 6) from per-frame samples (T, 6).

    ``"current"``: u_k (the paper); ``"next"``: u_{k+1}; ``"mean"``: (u_k + u_{k+1}) / 2.
    """
    u = np.asarray(velocities, dtype=float)
    if u.ndim != 2 or u.shape[1] != 6:
        raise InputError(f"velocities must have shape (T, 6), got {u.shape}")
    if pairing == "current":
        return u[:-1].copy()
    if pairing == "next":
        return u[1:].copy()
    if pairing == "mean":
        return 0.5 * (u[:-1] + u[1:])
    raise InputError(f"velocity pairing must be 'current', 'next' or 'mean', got {pairing!r}")


def so3_exp_and_left_jacobian(phi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``so3_exp(phi)`` and ``so3_left_jacobian(phi)`` of one vector (3,), without batching
    overhead (hot loop): ``I + A W + B W^2`` and ``I + B W + C W^2``, ``W = phi^``."""
    p1, p2, p3 = float(phi[0]), float(phi[1]), float(phi[2])
    A, B, C = theta_coeffs_scalar(math.sqrt(p1 * p1 + p2 * p2 + p3 * p3))
    W = np.array([[0.0, -p3, p2], [p3, 0.0, -p1], [-p2, p1, 0.0]])
    W2 = W @ W
    I3 = np.eye(3)
    return I3 + A * W + B * W2, I3 + B * W + C * W2


def se3_exp_single(xi: np.ndarray) -> np.ndarray:
    """:func:`ekf.geometry.se3_exp` for one twist (6,), without batching overhead (hot loop)."""
    x = np.asarray(xi, dtype=float)
    R, J = so3_exp_and_left_jacobian(x[3:])
    out = np.eye(4)
    out[:3, :3] = R
    out[:3, 3] = J @ x[:3]
    return out


def motion_increment(tau: float, u: np.ndarray) -> np.ndarray:
    """``exp(-tau u^)`` (4x4, batched over leading axes of ``u``): paper eq. 11."""
    u = np.asarray(u, dtype=float)
    if u.shape == (6,):
        return se3_exp_single(-tau * u)
    return se3_exp(-tau * u)


def predict_mean(U: np.ndarray, tau: float, u: np.ndarray) -> np.ndarray:
    """Paper eq. 11, mean: ``mu <- exp(-tau u^) mu``."""
    return motion_increment(tau, u) @ U


def prediction_jacobian(tau: float, u: np.ndarray) -> np.ndarray:
    """Paper eq. 11-12: ``F = exp(-tau curly_hat(u)) = Ad(exp(-tau u^))``, closed form (6x6)."""
    return adjoint(motion_increment(tau, u))


def process_noise(tau: float, W: np.ndarray) -> np.ndarray:
    """Pose process noise ``Q = tau^2 W`` (first order in the twist noise, paper eq. 4)."""
    return tau * tau * np.asarray(W, dtype=float)


def predict_pose(
    U: np.ndarray, Sigma: np.ndarray, tau: float, u: np.ndarray, W: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """One prediction step of the 6x6 pose EKF (paper eq. 11). Returns ``(U, Sigma)``."""
    F = prediction_jacobian(tau, u)
    Sigma = F @ Sigma @ F.T + process_noise(tau, W)
    return predict_mean(U, tau, u), 0.5 * (Sigma + Sigma.T)


#: Below this angle the coefficients of :func:`se3_left_jacobian`'s ``Q`` come from Taylor
#: series (their closed forms cancel catastrophically).
_Q_SERIES = 0.1


def _q_coefficients(theta: float) -> tuple[float, float, float]:
    """``c1 = (t - sin t) / t^3``, ``c2 = (t^2/2 + cos t - 1) / t^4`` and
    ``c3 = (2t - 3 sin t + t cos t) / (2 t^5)`` (Barfoot 2017, eq. 7.86); Taylor series below
    ``_Q_SERIES`` (the next terms, in t^8, under 1e-17 relative there); NaN for an angle that is
    not finite."""
    if not math.isfinite(theta):
        return math.nan, math.nan, math.nan
    if theta < _Q_SERIES:
        t2 = theta * theta
        return (1 / 6 - t2 / 120 + t2 * t2 / 5040 - t2 ** 3 / 362880,
                1 / 24 - t2 / 720 + t2 * t2 / 40320 - t2 ** 3 / 3628800,
                1 / 120 - t2 / 2520 + t2 * t2 / 120960 - t2 ** 3 / 9979200)
    s, c = math.sin(theta), math.cos(theta)
    t2 = theta * theta
    # divided step by step, so that a huge angle gives its tiny coefficients, not 0 / overflow
    return ((1.0 - s / theta) / t2, (0.5 + (c - 1.0) / t2) / t2,
            ((2.0 + c - 3.0 * s / theta) / (2.0 * t2)) / t2)


def se3_left_jacobian(xi: np.ndarray) -> np.ndarray:
    """Left Jacobian of SE(3) (6x6, translation first), ``sum_k curly_hat(xi)^k / (k+1)!``:
    ``exp((xi + e)^) ~ exp((J_l(xi) e)^) exp(xi^)`` to first order in ``e``.

    Closed form (Barfoot 2017, eq. 7.85-7.86), ``xi = [rho; phi]``, ``t = |phi|``,
    ``P = phi^``, ``X = rho^``: ``J_l = [[J, Q], [0, J]]`` with ``J`` the SO(3) left Jacobian and
    ``Q = X/2 + c1 (P X + X P + P X P) + c2 (P P X + X P P - 3 P X P)
    + c3 (P X P P + P P X P)`` (coefficients :func:`_q_coefficients`). A single twist (6,) or a
    batch (..., 6) (:func:`se3_left_jacobian_series` is the series itself, the reference in
    tests)."""
    xi = np.asarray(xi, dtype=float)
    if xi.shape != (6,):
        out = np.empty(xi.shape[:-1] + (6, 6))
        for i, x in zip(np.ndindex(xi.shape[:-1]), xi.reshape(-1, 6)):
            out[i] = se3_left_jacobian(x)
        return out
    p1, p2, p3 = float(xi[3]), float(xi[4]), float(xi[5])
    theta = math.sqrt(p1 * p1 + p2 * p2 + p3 * p3)
    _, J = so3_exp_and_left_jacobian(xi[3:])
    c1, c2, c3 = _q_coefficients(theta)
    P = np.array([[0.0, -p3, p2], [p3, 0.0, -p1], [-p2, p1, 0.0]])
    r1, r2, r3 = float(xi[0]), float(xi[1]), float(xi[2])
    X = np.array([[0.0, -r3, r2], [r3, 0.0, -r1], [-r2, r1, 0.0]])
    PX, XP = P @ X, X @ P
    PXP = PX @ P
    PPX = P @ PX
    Q = 0.5 * X + c1 * (PX + XP + PXP) + c2 * (PPX + XP @ P - 3.0 * PXP) + c3 * (PXP @ P + P @ PXP)
    out = np.zeros((6, 6))
    out[:3, :3] = J
    out[3:, 3:] = J
    out[:3, 3:] = Q
    return out


def se3_left_jacobian_series(xi: np.ndarray, terms: int = 20) -> np.ndarray:
    """:func:`se3_left_jacobian` as its series, ``sum_k curly_hat(xi)^k / (k+1)!`` by a Horner
    scheme (20 terms: exact to ~1e-12 for ``|xi| <= 2.5``); batched."""
    A = curly_hat(np.asarray(xi, dtype=float))
    I = np.broadcast_to(np.eye(6), A.shape)
    J = I.copy()
    for k in range(terms + 1, 1, -1):
        J = I + (A @ J) / k
    return J
