"""Tracks the velocities refute: does each track fit a point that stands still, under dead
reckoning's motion and the noise the model claims for it?

Vision assumes a static world. A track on a moving object (a car ahead pulling away with
ours) breaks that, and where such tracks are many, every vision estimator follows them (on
kitti-utias's first two seconds: docs/findings.md, 2026-12-03). Over the span of one track,
dead reckoning is a motion that owes nothing to vision, with a covariance the model gives; the
test asks whether the track's pixels fit one world point seen from those poses.

Conventions are the filters' (paper eq. 11, :mod:`ekf.prediction`): ``U_k = imu_T_world``,
``U_{k+1} = exp(-tau_k u_k^) U_k``, its error a left perturbation ``U = exp(eps^) U_bar`` with
``eps_{k+1} = F_k eps_k + n_k``, ``F_k = Ad(exp(-tau_k u_k^))`` and ``n_k ~ N(0, tau_k^2 W)``.
A track observed at frames ``k_1 < ... < k_m`` is tested relative to its first frame
(``eps_{k_1} = 0``). Each observation's rows are GTSAM's ``[uL, uR, v]`` (``v`` the mean of the
two rows' v) of ``z = M pi(cam_T_imu U_k p)``, with

* the Jacobian on the pose error ``H_i odot(U_i p)``, ``H_i = E M dpi(c_i) cam_T_imu``,
* the Jacobian on the world point ``H_i R(U_i)``, and
* the residual covariance ``S = S_pix + sum_n G_n tau_n^2 W G_n^T``, where ``G_n`` stacks
  ``H_i odot(U_i p) Phi_{k_i <- n+1}`` over the observations after interval ``n``
  (``Phi`` the product of the ``F`` between), and ``S_pix`` the pixel noise: ``[s, s, s/sqrt 2]``
  per observation, correlated along the track as ``a^|k_i - k_j|`` where the model says so.

The point is the generalised least-squares fit (Gauss-Newton from the rows' linear
triangulation), and the statistic ``r^T S^-1 r`` at it is chi-square with ``3m - 3`` degrees
of freedom when the point stands still and the model is right. A track is refuted at ``level``
(the chance that a static one is).

Not told apart here: one bad velocity sample makes every track across its interval fail
together, where a moving object fails on its own tracks only. The estimators do not
call it; ``benchmarks/moving_tracks.py`` does.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import gammaincc

from vislam.ekf.camera import dpi_dq, pi
from vislam.ekf.errors import InputError
from vislam.ekf.geometry import adjoint, homogeneous, odot
from vislam.ekf.model import ar1_coefficient
from vislam.ekf.prediction import motion_increment, paired_velocities
from vislam.ekf.sequence import track_runs

#: GTSAM's stereo rows [uL, uR, v] of the pixels [uL, vL, uR, vR].
ROWS = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.5, 0.0, 0.5]])
#: The rows' noise variance in units of the pixel variance.
ROW_VARIANCE = np.array([1.0, 1.0, 0.5])
#: Gauss-Newton steps of each track's point.
POINT_STEPS = 3


@dataclass(frozen=True)
class TrackTest:
    """Per tested track (3 or more observations): its index, first and last frame, the
    statistic ``r^T S^-1 r``, its degrees of freedom and the chance ``p_value`` of at least
    that for a static point under the model (NaN where the fitted point falls behind a
    camera: not tested)."""

    track: np.ndarray
    first: np.ndarray
    last: np.ndarray
    statistic: np.ndarray
    dof: np.ndarray
    p_value: np.ndarray


def dead_reckoning_inverse(velocities: np.ndarray, dt: np.ndarray,
                           pairing: str) -> tuple[np.ndarray, np.ndarray]:
    """``U_k = imu_T_world`` (T, 4, 4) of dead reckoning (identity at 0) and each interval's
    ``F_k`` (T-1, 6, 6) (module docstring)."""
    u = paired_velocities(velocities, pairing)
    steps = np.array([motion_increment(float(t), x) for t, x in zip(dt, u)]).reshape(-1, 4, 4)
    U = np.empty((len(u) + 1, 4, 4))
    U[0] = np.eye(4)
    for k, step in enumerate(steps):
        U[k + 1] = step @ U[k]
    return U, adjoint(steps)


def observation_jacobians(U: np.ndarray, cam_T_imu: np.ndarray, M: np.ndarray, p: np.ndarray):
    """At the world point ``p`` (3,) seen from ``U`` (m, 4, 4): the predicted rows (m, 3), their
    Jacobians on the pose errors (m, 3, 6) and on the point (m, 3, 3), and the point's depth in
    each camera (m,)."""
    q = U @ homogeneous(p)  # IMU frame
    c = q @ cam_T_imu.T  # camera frame
    H = ROWS @ M @ dpi_dq(c) @ cam_T_imu  # (m, 3, 4)
    return pi(c) @ M.T @ ROWS.T, H @ odot(q), H[:, :, :3] @ U[:, :3, :3], c[:, 2]


def linear_point(U: np.ndarray, cam_T_imu: np.ndarray, M: np.ndarray, z: np.ndarray) -> np.ndarray:
    """The world point whose projections best fit the pixels ``z`` (m, 4) linearly: left u, v
    and right u of every view (the homogeneous solve); NaN where there is none."""
    P = M @ cam_T_imu @ U  # (m, 4, 4): rows uL, vL, uR, vR before the division by depth
    w = (cam_T_imu @ U)[:, 2]  # depth row
    A = np.concatenate([z[:, 0:1] * w - P[:, 0], z[:, 1:2] * w - P[:, 1], z[:, 2:3] * w - P[:, 2]])
    h = np.linalg.svd(A)[2][-1]
    return h[:3] / h[3] if abs(h[3]) > 1e-12 else np.full(3, np.nan)


def pose_error_covariance(frames: np.ndarray, J_eps: np.ndarray, F: np.ndarray,
                          Q: np.ndarray) -> np.ndarray:
    """``sum_n G_n Q_n G_n^T`` (3m, 3m) over the intervals of the track's span (module
    docstring): the rows' covariance from dead reckoning's errors relative to the first frame."""
    m = len(frames)
    S = np.zeros((3 * m, 3 * m))
    B = np.zeros((m, 3, 6))
    for n in range(int(frames[-1]) - 1, int(frames[0]) - 1, -1):
        later = frames > n + 1
        if later.any():
            B[later] = B[later] @ F[n + 1]
        here = frames == n + 1
        B[here] = J_eps[here]
        G = B.reshape(3 * m, 6)
        S += G @ Q[n] @ G.T
    return S


def track_statistic(U: np.ndarray, F: np.ndarray, frames: np.ndarray, z: np.ndarray,
                    cam_T_imu: np.ndarray, M: np.ndarray, Q: np.ndarray, pixel_sigma: float,
                    pixel_a: float = 0.0) -> tuple[float, int]:
    """The statistic and degrees of freedom of one track (module docstring): ``U`` (T, 4, 4)
    and ``F`` (T-1, 6, 6) of dead reckoning, the track's ``frames`` (m,) increasing and pixels
    ``z`` (m, 4), the intervals' twist-error covariances ``Q`` (T-1, 6, 6) (``tau^2 W``), the
    white pixel sigma and its AR(1) coefficient along the track. NaN where the point falls
    behind a camera or is undetermined."""
    m = len(frames)
    dof = 3 * m - 3
    Uk = U[frames]
    p = linear_point(Uk, cam_T_imu, M, z)
    if not np.all(np.isfinite(p)):
        return float("nan"), dof
    zr = z @ ROWS.T
    lag = np.abs(frames[:, None] - frames[None, :])
    correlation = np.power(float(pixel_a), lag) if pixel_a else np.eye(m)
    pixels = pixel_sigma ** 2 * np.kron(correlation, np.diag(ROW_VARIANCE))
    for _ in range(2):  # the covariance at the linear point, then at the fitted one
        _, J_eps, _, _ = observation_jacobians(Uk, cam_T_imu, M, p)
        S = pixels + pose_error_covariance(frames, J_eps, F, Q)
        for _ in range(POINT_STEPS):
            pred, _, J_p, depth = observation_jacobians(Uk, cam_T_imu, M, p)
            if np.any(depth <= 0):
                return float("nan"), dof
            r = (zr - pred).reshape(-1)
            Jp = J_p.reshape(3 * m, 3)
            SJ = np.linalg.solve(S, Jp)
            p = p + np.linalg.solve(Jp.T @ SJ, SJ.T @ r)
    pred, _, _, depth = observation_jacobians(Uk, cam_T_imu, M, p)
    if np.any(depth <= 0):
        return float("nan"), dof
    r = (zr - pred).reshape(-1)
    return float(r @ np.linalg.solve(S, r)), dof


def track_tests(seq, velocity_cov: np.ndarray, pairing: str, pixel_sigma: float,
                pixel_correlation_time: float | None = None, min_views: int = 3) -> TrackTest:
    """:func:`track_statistic` for every track of ``seq`` with ``min_views`` or more
    observations, under dead reckoning with the per-interval twist covariance ``velocity_cov``
    (6, 6, per sample as the filters' ``W``), the velocity ``pairing``, the white pixel sigma
    and its correlation time along a track (frames; None: white)."""
    if pixel_sigma <= 0 or not np.isfinite(pixel_sigma):
        raise InputError(f"motion check: pixel sigma {pixel_sigma} must be positive")
    W = np.asarray(velocity_cov, dtype=float)
    if W.shape != (6, 6):
        raise InputError(f"motion check: twist covariance of shape {W.shape}, need (6, 6)")
    a = ar1_coefficient(pixel_correlation_time)
    calib = seq.calibration
    M = np.asarray(calib.M, dtype=float)
    X = np.asarray(calib.cam_T_imu, dtype=float)
    U, F = dead_reckoning_inverse(seq.velocities, seq.dt, pairing)
    Q = np.asarray(seq.dt, dtype=float)[:, None, None] ** 2 * W
    o = seq.obs
    order, starts, ends = track_runs(o.frame_index, o.track)
    frame, track, z = o.frame_index[order], o.track[order], o.z[order]
    rows = []
    for s, e in zip(starts, ends):
        if e - s < min_views:
            continue
        stat, dof = track_statistic(U, F, frame[s:e], z[s:e], X, M, Q, pixel_sigma, a)
        rows.append((track[s], frame[s], frame[e - 1], stat, dof))
    t = np.array(rows, dtype=float).reshape(-1, 5)
    stat, dof = t[:, 3], t[:, 4]
    with np.errstate(invalid="ignore"):
        p_value = np.where(np.isfinite(stat), gammaincc(dof / 2.0, np.maximum(stat, 0.0) / 2.0), np.nan)
    return TrackTest(track=t[:, 0].astype(np.int64), first=t[:, 1].astype(np.int64),
                     last=t[:, 2].astype(np.int64), statistic=stat, dof=dof.astype(np.int64),
                     p_value=p_value)


__all__ = ["TrackTest", "dead_reckoning_inverse", "linear_point", "observation_jacobians",
           "pose_error_covariance", "track_statistic", "track_tests"]
