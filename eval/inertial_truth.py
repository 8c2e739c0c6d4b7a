"""Ground truth of a raw-IMU drive at its camera frames, in the frame its estimates use.

A raw-IMU drive's ground truth is a time-stamped trajectory of the body (IMU) in a
gravity-aligned world (EuRoC's Vicon frame: z up), read by :func:`eval.trajectory_files.
read_trajectory` from ``DIR/groundtruth/NAME.csv`` (what ``vislam convert`` writes) or a file
given with ``--gt``. Here it becomes an :class:`eval.groundtruth.GroundTruth`:

- **at the camera frames**: a pose whose stamp is within :data:`SAME_INSTANT_S` of a frame is
  taken as it is; otherwise it is interpolated between the neighbours on both sides (position
  linearly, rotation by slerp) when they are at most :data:`MAX_INTERPOLATION_GAP_S` apart; a
  frame without is left out (the ground truth "covers" fewer frames);
- **in the estimates' world** (:data:`RAW_IMU_WORLD`): gravity-aligned, z up, origin at the
  IMU at frame 0, and the IMU's orientation at frame 0 the rotation of smallest angle that
  takes its up direction onto z (:func:`ekf.imu_init.level_rotation`: what an estimator
  initialised from a rest knows, and what dead reckoning and the smoother use).
  ``T_world_gt = W T_file(0)^-1 T_file`` with ``W = [level_rotation(up at frame 0), 0]``.
  Roll and pitch stay absolute (gravity fixes them), so a pose NEES needs no alignment beyond
  the gauge an estimator fixes itself; ATE aligns in yaw and translation (4-DoF).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from vislam.ekf.errors import InputError
from vislam.ekf.imu_init import level_rotation
from vislam.ekf.inertial import InertialDrive
from vislam.ekf.strapdown import held_pieces
from vislam.eval.groundtruth import GroundTruth
from vislam.eval.trajectory_files import TimedTrajectory, read_trajectory

#: Stamps closer than this are the same instant (files print seconds with 6-9 decimals).
SAME_INSTANT_S = 1e-5
#: Interpolate only between ground-truth poses at most this far apart (s).
MAX_INTERPOLATION_GAP_S = 0.1
#: The interval (s) over which :func:`gyro_agreement` compares the truth's turn with the gyro's.
AGREEMENT_INTERVAL_S = 1.0
#: The truth "turns away from the gyro" where it disagrees by more than this many times what
#: the data sheet allows the gyro over the interval (rms over pairs and axes).
AGREEMENT_RATIO = 3.0
#: The world frame of raw-IMU estimates, in words (reports and docs).
RAW_IMU_WORLD = ("gravity-aligned (z up), origin at the IMU at frame 0, its orientation there "
                 "the least rotation taking its up direction to z")


@dataclass(frozen=True)
class InertialTruth:
    """The ground truth at the camera frames (:class:`GroundTruth`, poses in the estimates'
    world) and, where the file has them, the velocity in that world (n, 3) and the biases."""

    truth: GroundTruth
    velocity: np.ndarray | None = None
    gyro_bias: np.ndarray | None = None
    accel_bias: np.ndarray | None = None


def inertial_truth_path(npz_path: str | os.PathLike) -> Path:
    """``DIR/groundtruth/NAME.csv`` for ``DIR/NAME.npz``."""
    p = Path(npz_path)
    return p.parent / "groundtruth" / f"{p.stem}.csv"


def world_from_file(pose0: np.ndarray) -> np.ndarray:
    """``W T0^-1`` (4, 4): takes the file's world to the estimates' world, for the file's pose
    ``pose0`` of the IMU at frame 0 (module docstring)."""
    up = pose0[:3, :3].T @ np.array([0.0, 0.0, 1.0])
    W = np.eye(4)
    W[:3, :3] = level_rotation(up)
    return W @ np.linalg.inv(pose0)


def at_frames(traj: TimedTrajectory, frame_times: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Frames covered, poses (n, 4, 4) and state (n, 9) or None at the absolute ``frame_times``
    (module docstring)."""
    t = traj.times
    i = np.clip(np.searchsorted(t, frame_times), 1, max(t.size - 1, 1))
    if t.size == 1:
        exact = np.abs(frame_times - t[0]) <= SAME_INSTANT_S
        idx = np.flatnonzero(exact)
        return idx, traj.poses[np.zeros(idx.size, dtype=int)], (
            None if traj.state is None else traj.state[np.zeros(idx.size, dtype=int)])
    lo, hi = t[i - 1], t[i]
    near_lo = np.abs(frame_times - lo) <= SAME_INSTANT_S
    near_hi = np.abs(frame_times - hi) <= SAME_INSTANT_S
    inside = (frame_times > lo) & (frame_times < hi) & (hi - lo <= MAX_INTERPOLATION_GAP_S)
    covered = near_lo | near_hi | inside
    frames = np.flatnonzero(covered)
    poses = np.empty((frames.size, 4, 4))
    state = None if traj.state is None else np.empty((frames.size, 9))
    for n, k in enumerate(frames):
        a, b = i[k] - 1, i[k]
        if near_lo[k] or near_hi[k]:
            j = a if near_lo[k] else b
            poses[n] = traj.poses[j]
            if state is not None:
                state[n] = traj.state[j]
            continue
        s = (frame_times[k] - t[a]) / (t[b] - t[a])
        poses[n] = np.eye(4)
        poses[n, :3, 3] = (1 - s) * traj.poses[a, :3, 3] + s * traj.poses[b, :3, 3]
        slerp = Slerp([0.0, 1.0], Rotation.from_matrix(traj.poses[[a, b], :3, :3]))
        poses[n, :3, :3] = slerp([s]).as_matrix()[0]
        if state is not None:
            state[n] = (1 - s) * traj.state[a] + s * traj.state[b]
    return frames, poses, state


def inertial_truth(drive: InertialDrive, traj: TimedTrajectory) -> InertialTruth:
    """``traj`` at ``drive``'s camera frames in the estimates' world (module docstring)."""
    frame_times = drive.time_origin_ns * 1e-9 + drive.timestamps
    frames, poses, state = at_frames(traj, frame_times)
    if frames.size == 0 or frames[0] != 0:
        raise InputError(f"{traj.source}: no ground-truth pose at the drive's first frame "
                         f"({frame_times[0]:.6f} s; the file covers {traj.times[0]:.6f} to "
                         f"{traj.times[-1]:.6f} s): the estimates' world is defined there")
    Y_inv = world_from_file(poses[0])
    world_poses = Y_inv @ poses
    truth = GroundTruth(frames, world_poses, traj.source, times=drive.timestamps[frames])
    if state is None:
        return InertialTruth(truth)
    velocity = state[:, 0:3] @ Y_inv[:3, :3].T
    return InertialTruth(truth, velocity, state[:, 3:6], state[:, 6:9])


def find_inertial_truth(npz_path: str | os.PathLike, drive: InertialDrive,
                        override: str | os.PathLike | None = None) -> InertialTruth | None:
    """The ground truth of a raw-IMU drive: ``override`` if given (it must exist), else
    :func:`inertial_truth_path` where a file is there, else None."""
    path = Path(override) if override is not None else inertial_truth_path(npz_path)
    if override is None and not (path.exists() or path.is_symlink()):
        return None
    return inertial_truth(drive, read_trajectory(path))


def frame0_gauge(truth: GroundTruth, est_pose0: np.ndarray) -> GroundTruth:
    """``truth`` moved by the rotation about gravity and the translation that put its frame-0
    pose on the estimate's in position and yaw (``est_pose0``, world_T_imu at frame 0):
    :func:`graph.inertial_init.in_estimate_gauge`, why and how.

    A raw-IMU estimate fixes its world's yaw and origin at frame 0 from its own tilt there, a
    few mrad off the truth's, which moves that yaw by as much wherever the IMU's up is far from
    its z axis (EuRoC's IMU has x up), while the estimate's covariance rightly gives yaw and
    position at frame 0 no uncertainty (they are its gauge): so pose errors are scored in the
    estimate's gauge."""
    if len(truth.frames) == 0 or truth.frames[0] != 0:
        return truth
    from dataclasses import replace

    from vislam.graph.inertial_init import in_estimate_gauge

    return replace(truth, poses=in_estimate_gauge(truth.poses, np.asarray(est_pose0)[None]))


@dataclass(frozen=True)
class GyroAgreement:
    """How the truth's turn between two of its poses ``interval_s`` apart compares with the
    gyro's over the same interval: ``rms_mrad`` per body axis over ``pairs`` pairs,
    ``sheet_mrad`` what the data sheet allows the gyro (white noise and bias walk), and whether
    the truth's own gyro bias was used (else one constant bias fitted to the whole drive)."""

    interval_s: float
    pairs: int
    rms_mrad: tuple[float, float, float]
    sheet_mrad: float
    truth_bias: bool

    @property
    def ratio(self) -> float:
        return float(np.sqrt(np.mean(np.square(self.rms_mrad)))) / self.sheet_mrad

    def to_dict(self) -> dict:
        return {"interval_s": self.interval_s, "pairs": self.pairs, "rms_mrad": list(self.rms_mrad),
                "sheet_mrad": self.sheet_mrad, "truth_bias": self.truth_bias, "ratio": self.ratio}

    @classmethod
    def from_dict(cls, d: dict) -> "GyroAgreement":
        """The check as :meth:`to_dict` wrote it (results.json's ``truth_check``)."""
        return cls(float(d["interval_s"]), int(d["pairs"]), tuple(float(x) for x in d["rms_mrad"]),
                   float(d["sheet_mrad"]), bool(d["truth_bias"]))

    def words(self) -> str:
        """The figures in words: how far the truth's turn departs from the gyro's."""
        axes = " / ".join(f"{x:.2f}" for x in self.rms_mrad)
        bias = "the truth's own gyro bias" if self.truth_bias else "one constant bias fitted to the drive"
        return (f"the ground truth's turn over {self.interval_s:.1f} s departs from the gyro's "
                f"(corrected by {bias}) by {axes} mrad (rms per IMU axis, {self.pairs} pairs), "
                f"{self.ratio:.1f}x what the IMU's data sheet allows ({self.sheet_mrad:.2f} mrad)")


def gyro_agreement(drive: InertialDrive, truth: InertialTruth,
                   interval_s: float = AGREEMENT_INTERVAL_S) -> GyroAgreement | None:
    """The truth's relative rotation over consecutive ground-truth frames ``interval_s`` apart
    against the gyro's (each sample held over its piece, :func:`ekf.strapdown.held_pieces`, as
    every raw-IMU estimator integrates it), less the truth's gyro bias at each frame interval's
    start, or, where the file has none, the one constant bias that best explains the whole
    drive. A pose NEES against a truth that turns away from the gyro by more than the sheet
    allows also counts the truth's own error. None when fewer than two such pairs exist."""
    frames = np.asarray(truth.truth.frames, dtype=np.int64)
    R = np.asarray(truth.truth.poses)[:, :3, :3]
    period = float(np.median(np.diff(drive.timestamps)))
    lag = max(1, int(round(interval_s / period)))
    imu = drive.imu
    t = drive.timestamps[frames]
    # frame intervals k with the truth at both ends and the IMU over all of it
    step = np.flatnonzero((np.diff(frames) == 1) & (t[:-1] >= imu.time[0]) & (t[1:] <= imu.time[-1]))
    if step.size < lag + 1:
        return None
    turn = np.zeros((frames.size - 1, 3))  # the gyro's rotation vector over each interval
    dts = np.diff(t)
    for k in step:
        piece = Rotation.identity()
        for j, dt in held_pieces(imu.time, t[k], t[k + 1]):
            piece = piece * Rotation.from_rotvec(imu.gyro[j] * dt)
        turn[k] = piece.as_rotvec()
    truth_rel = Rotation.from_matrix(np.einsum("nji,njk->nik", R[:-1], R[1:]))
    if truth.gyro_bias is not None:
        bias = np.asarray(truth.gyro_bias, dtype=float)[:-1]
    else:  # per interval the truth's turn is the gyro's less bias * dt (small angles)
        d = (truth_rel[step] * Rotation.from_rotvec(turn[step]).inv()).as_rotvec()
        bias = np.broadcast_to(-d.sum(axis=0) / dts[step].sum(), (frames.size - 1, 3))
    exact = Rotation.from_rotvec(turn - bias * dts[:, None])
    contiguous = np.zeros(frames.size, dtype=bool)
    contiguous[step] = True
    chain = [Rotation.identity()]  # the gyro's turn from frame 0 on, through the intervals
    for k in range(frames.size - 1):
        chain.append(chain[-1] * exact[k])
    chain = Rotation.concatenate(chain)
    run = np.convolve(contiguous[:-1].astype(int), np.ones(lag, dtype=int), "valid")
    first = np.flatnonzero(run == lag)  # pairs (i, i + lag) with the truth at every frame between
    if first.size < 2:
        return None
    gyro = chain[first].inv() * chain[first + lag]
    truth_turn = Rotation.from_matrix(np.einsum("nji,njk->nik", R[first], R[first + lag]))
    e = 1e3 * (truth_turn * gyro.inv()).as_rotvec()
    T = lag * period
    noise = drive.calibration.noise
    sheet = 1e3 * float(np.sqrt(noise.gyro_noise_density ** 2 * T + noise.gyro_random_walk ** 2 * T ** 3 / 3.0))
    return GyroAgreement(float(T), int(e.shape[0]), tuple(float(x) for x in np.sqrt(np.mean(e * e, axis=0))),
                         sheet, truth.gyro_bias is not None)

