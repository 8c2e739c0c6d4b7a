"""The lever arm on which a drive's ground truth and its velocities agree.

``vislam calibrate`` identifies the camera's position in the IMU frame (the lever arm ``p``)
from the data alone. Where a drive has ground truth, the same quantity can be measured without
vision: over each interval [k, k+1] the camera's ground-truth relative pose ``C_k = P_k^-1
P_{k+1}`` and the IMU's motion from the velocities, ``D_k = exp(tau_k u_k)``, are tied by the
extrinsic ``X = cam_T_imu = [R, -R p]`` through ``C_k = X D_k X^-1``, whose translation is

    R^T t(C_k) - t(D_k) = (R_k - I) p                                   (the lever-arm equation)

with ``R_k`` the IMU's rotation over the interval. That is linear in ``p``: one least-squares
solve over the drive. ``R_k`` is taken from the ground truth (``R^T R(C_k) R``), not from the
gyro, so that gyro noise in the regressor does not shrink the estimate towards zero (errors in
variables: on the shared 0027, whose angular velocities carry 0.05 rad/s of added noise, the
gyro's rotations give x 0.66 m, the ground truth's 0.75 m).

The standard deviations are a delete-one-block jackknife over ``blocks`` contiguous stretches
of the drive, so that velocity errors correlated in time (the KITTI velocities' lateral errors
stay for seconds) widen them as they should.

This is what the velocities are *of*: if they are not those of the point the calibration calls
the IMU, the lever arm the data support is not the calibration's, whatever estimator reads them.
``benchmarks/lever_arm_truth.py`` prints it beside KITTI's and the identified one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vislam.ekf.errors import InputError
from vislam.ekf.geometry import se3_exp
from vislam.ekf.prediction import paired_velocities

#: Contiguous stretches of the drive of the jackknife's standard deviations.
JACKKNIFE_BLOCKS = 10


@dataclass(frozen=True)
class LeverArmFit:
    """The lever arm (3,) in IMU axes (m), its standard deviations (3,) (block jackknife) and
    covariance (3, 3), the residual rms (m per interval) and the intervals used."""

    lever_arm: np.ndarray
    sigma: np.ndarray
    covariance: np.ndarray
    rms: float
    n_intervals: int


def lever_arm_equation(camera_poses: np.ndarray, velocities: np.ndarray, tau: np.ndarray,
                       cam_R_imu: np.ndarray, pairing: str) -> tuple[np.ndarray, np.ndarray]:
    """The lever-arm equation's rows: ``A`` (n, 3, 3) = ``R_k - I`` and ``b`` (n, 3) =
    ``R^T t(C_k) - t(D_k)``, one block per interval whose two ground-truth poses are finite.

    ``camera_poses`` (n + 1, 4, 4): the ground truth's camera poses of frames 0..n;
    ``velocities`` (at least n + 1, 6): the drive's twists per frame (linear first);
    ``tau`` (at least n,): interval lengths (s); ``cam_R_imu``: the extrinsic's rotation."""
    P = np.asarray(camera_poses, dtype=float)
    n = P.shape[0] - 1
    if n < 1:
        raise InputError(f"ground truth: {P.shape[0]} pose(s), need at least 2 for a lever arm")
    u = paired_velocities(np.asarray(velocities, dtype=float)[: n + 1], pairing)
    tau = np.asarray(tau, dtype=float)[:n]
    if u.shape[0] != n or tau.shape[0] != n:
        raise InputError(f"ground truth has {n + 1} poses but the drive only "
                         f"{min(u.shape[0], tau.shape[0]) + 1} frames")
    R = np.asarray(cam_R_imu, dtype=float)
    C = np.linalg.inv(P[:-1]) @ P[1:]
    D = se3_exp(tau[:, None] * u)
    R_imu = np.einsum("ji,njk,kl->nil", R, C[:, :3, :3], R)
    A = R_imu - np.eye(3)
    b = np.einsum("ji,nj->ni", R, C[:, :3, 3]) - D[:, :3, 3]
    ok = np.isfinite(A).all(axis=(1, 2)) & np.isfinite(b).all(axis=1)
    return A[ok], b[ok]


def _solve(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.linalg.lstsq(A.reshape(-1, 3), b.reshape(-1), rcond=None)[0]


def lever_arm_from_truth(camera_poses: np.ndarray, velocities: np.ndarray, tau: np.ndarray,
                         cam_R_imu: np.ndarray, pairing: str,
                         blocks: int = JACKKNIFE_BLOCKS) -> LeverArmFit:
    """The least-squares solution of the lever-arm equation over the drive (module docstring),
    with delete-one-block jackknife standard deviations over ``blocks`` stretches."""
    A, b = lever_arm_equation(camera_poses, velocities, tau, cam_R_imu, pairing)
    n = A.shape[0]
    if n < 2 * blocks:
        raise InputError(f"ground truth: {n} usable intervals, need at least {2 * blocks} for "
                         "a lever arm with a standard deviation")
    if np.linalg.matrix_rank(A.reshape(-1, 3)) < 3:
        raise InputError("ground truth: the drive does not rotate about enough axes to "
                         "determine a lever arm")
    p = _solve(A, b)
    edges = np.linspace(0, n, blocks + 1).astype(int)
    keep = np.ones(n, dtype=bool)
    leave_out = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        keep[:] = True
        keep[lo:hi] = False
        leave_out.append(_solve(A[keep], b[keep]))
    leave_out = np.array(leave_out)
    d = leave_out - leave_out.mean(axis=0)
    cov = (blocks - 1) / blocks * d.T @ d
    r = b - np.einsum("nij,j->ni", A, p)
    return LeverArmFit(lever_arm=p, sigma=np.sqrt(np.diag(cov)), covariance=cov,
                       rms=float(np.sqrt(np.mean(r ** 2))), n_intervals=n)


__all__ = ["LeverArmFit", "lever_arm_equation", "lever_arm_from_truth", "JACKKNIFE_BLOCKS"]
