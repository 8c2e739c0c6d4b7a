"""Initialising a raw-IMU drive from a rest at its start: gravity, gyro bias and the world frame.

**The rest detector** (:func:`detect_rest`). The IMU stream from its first sample is cut into
blocks of ``block_s`` (0.1 s); each block's mean gyro and accelerometer reading is a low-passed
sample in which a vehicle's engine or rotor vibration averages out (EuRoC V1_01's drone sits on
the ground for its first ~4 s with its motors running: the raw accelerometer's standard deviation
is 1.3 m/s^2 there, its 0.1 s means move by 0.2 m/s^2 at most). The rest is the longest run of
blocks from the start whose means all stay within ``gyro_tol`` (rad/s) and ``accel_tol`` (m/s^2)
of the mean over the run so far, per axis, less its last ``margin_blocks`` blocks (0.4 s: a
motion that starts slowly stays inside the tolerances for a few blocks; a simulated car eases
away 0.3-0.4 s before its means leave them, already at 0.02-0.05 m/s, where zero velocity is
wrong; the EKFs' detector leaves out as much, :class:`ekf.imu_init.RestConfig`); it must last
``min_rest_s``. (A vehicle that moves at
a constant velocity from its first sample looks the same to an IMU: its drive cannot be told
from a rest, and the zero-velocity assumption below would be wrong.)

**What the rest gives**, over its samples:

- the gyro bias: the mean angular rate (the vehicle does not turn);
- the direction of gravity: the mean specific force is ``-g`` in the IMU frame, i.e. it points
  **up**; the accelerometer bias cannot be told from a tilt at rest, so it starts at zero (the
  smoother estimates it with the tilt, under its prior);
- zero velocity at every camera frame inside the rest.

**The world frame** (:func:`gravity_aligned_rotation`): z up (against gravity), the origin at the
IMU at camera frame 0, and the yaw of the IMU at frame 0: ``world_R_imu0`` is the rotation of
least angle that takes the measured up direction (IMU frame) onto the world z axis. So when the
IMU's own z axis points up, the world's x and y axes are the IMU's; otherwise they are the IMU's
tilted by the shortest arc. The same rule applied to the true attitude
(:func:`to_gravity_world`) puts ground truth in that frame, for scoring without alignment.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation
from vislam.ekf.errors import InputError
from vislam.ekf.filter import ImuSamples
from vislam.ekf.geometry import se3_inv
from vislam.ekf.imu_init import level_rotation


@dataclass(frozen=True)
class RestInterval:
    """A rest at the start of a drive: ``[t_start, t_end]`` (s, the drive's clock), the number of
    IMU samples in it, the mean specific force ``accel_mean`` (3,) m/s^2 and the mean angular
    rate ``gyro_mean`` (3,) rad/s (the gyro bias), both in the IMU frame."""

    t_start: float
    t_end: float
    n_samples: int
    accel_mean: np.ndarray
    gyro_mean: np.ndarray

    @property
    def duration(self) -> float:
        return self.t_end - self.t_start

    @property
    def up(self) -> np.ndarray:
        """The unit vector against gravity, in the IMU frame."""
        return self.accel_mean / np.linalg.norm(self.accel_mean)


@dataclass(frozen=True)
class RestDetector:
    """The rest detector's thresholds (module docstring)."""

    block_s: float = 0.1
    gyro_tol: float = 0.02
    accel_tol: float = 0.3
    min_rest_s: float = 0.5
    #: The last blocks of the run left out: a motion that starts slowly stays inside the
    #: tolerances for a few blocks (a simulated car: 0.3-0.4 s) and zero velocity there is wrong.
    #: 0.4 s, as the EKFs' rest detector leaves out (ekf.imu_init.RestConfig.margin_windows).
    margin_blocks: int = 4


def detect_rest(imu: ImuSamples, detector: RestDetector = RestDetector()) -> RestInterval | None:
    """The rest at the start of ``imu`` (module docstring), or None when there is none."""
    t = np.asarray(imu.time, dtype=float)
    if t.size < 2:
        return None
    block = np.floor((t - t[0]) / detector.block_s).astype(np.int64)
    n_blocks = int(block[-1]) + 1
    counts = np.bincount(block, minlength=n_blocks)
    full = counts > 0
    g_mean = np.stack([np.bincount(block, imu.gyro[:, i], n_blocks) for i in range(3)], axis=1)
    a_mean = np.stack([np.bincount(block, imu.accel[:, i], n_blocks) for i in range(3)], axis=1)
    g_sum, a_sum, n = np.zeros(3), np.zeros(3), 0
    last = -1
    for b in range(n_blocks):
        if not full[b]:
            break
        gb, ab = g_mean[b] / counts[b], a_mean[b] / counts[b]
        if n:
            if np.any(np.abs(gb - g_sum / n) > detector.gyro_tol) or \
                    np.any(np.abs(ab - a_sum / n) > detector.accel_tol):
                break
        g_sum += g_mean[b]
        a_sum += a_mean[b]
        n += int(counts[b])
        last = b
    last -= int(detector.margin_blocks)
    if last < 0:
        return None
    inside = block <= last
    t_end = float(t[inside][-1])
    if t_end - t[0] < detector.min_rest_s:
        return None
    kept = slice(0, last + 1)
    n = int(counts[kept].sum())
    return RestInterval(float(t[0]), t_end, n, a_mean[kept].sum(axis=0) / n,
                        g_mean[kept].sum(axis=0) / n)


def gravity_aligned_rotation(up: np.ndarray) -> np.ndarray:
    """``world_R_imu`` (3, 3): the least rotation taking ``up`` (IMU frame) onto the world z
    axis (module docstring). Upside down (``up`` along -z) it turns about the IMU's x axis."""
    up = np.asarray(up, dtype=float)
    norm = float(np.linalg.norm(up))
    if not np.isfinite(norm) or norm == 0.0:
        raise InputError(f"gravity direction {up.tolist()} is not a direction")
    return level_rotation(up / norm)


def to_gravity_world(poses: np.ndarray) -> np.ndarray:
    """Ground-truth ``world_T_imu`` poses (T, 4, 4) of any gravity-aligned world (z up) moved
    into the smoother's world (module docstring): origin at the IMU of ``poses[0]``, z up, and
    the yaw given by :func:`gravity_aligned_rotation` of the true up direction at ``poses[0]``."""
    poses = np.asarray(poses, dtype=float)
    R0 = poses[0, :3, :3]
    up_imu = R0.T @ np.array([0.0, 0.0, 1.0])
    new_T_imu0 = np.eye(4)
    new_T_imu0[:3, :3] = gravity_aligned_rotation(up_imu)
    new_T_old = new_T_imu0 @ se3_inv(poses[0])
    return new_T_old @ poses


def in_estimate_gauge(truth: np.ndarray, est_poses: np.ndarray) -> np.ndarray:
    """Ground truth (T, 4, 4) in a gravity-aligned world (z up, e.g. :func:`to_gravity_world`'s)
    moved by a rotation about z and a translation so that its frame 0 has the estimate's yaw
    and position: the four directions the smoother's priors fix (its gauge). Needed for a NEES
    without alignment: :func:`to_gravity_world` takes its yaw from the *true* up direction at
    frame 0 through :func:`gravity_aligned_rotation`, the smoother from the *measured* one, and
    for an IMU whose up is far from its z axis (EuRoC's: 68 degrees) a tilt difference of
    ``d`` between them turns into a yaw difference of the order of ``d`` (0.7 degrees on
    EuRoC V1_01), which the estimate's covariance (yaw fixed at frame 0) rightly does not hold.

    The rotation about z is the best one from the truth's frame-0 rotation ``B`` onto the
    estimate's ``A`` in the Frobenius norm, in closed form: with ``M = A B^T``,
    ``yaw = atan2(M10 - M01, M00 + M11)``."""
    truth = np.asarray(truth, dtype=float)
    est0 = np.asarray(est_poses, dtype=float)[0]
    M = est0[:3, :3] @ truth[0, :3, :3].T
    yaw = float(np.arctan2(M[1, 0] - M[0, 1], M[0, 0] + M[1, 1]))
    move = np.eye(4)
    move[:3, :3] = Rotation.from_rotvec([0.0, 0.0, yaw]).as_matrix()
    move[:3, 3] = est0[:3, 3] - move[:3, :3] @ truth[0, :3, 3]
    return move @ truth
