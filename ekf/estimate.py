"""What every estimator returns: :class:`Estimate`.

Pose convention: ``poses[k]`` is ``world_T_imu`` at step k, with the world frame equal to the
IMU frame at step 0. ``pose_cov[k]`` is the 6x6 covariance of ``xi = [rho; phi]`` (translation
first) in a **right** perturbation of that pose::

    world_T_imu_true = world_T_imu_est @ se3_exp(xi)

This is, up to the sign of ``xi``, the paper's left perturbation of the inverse pose
``U = imu_T_world`` (``U_true = exp(d^) U_est`` gives ``xi = -d``), so the pose covariance of
the filter is stored as it is. Conversions to and from other conventions (GTSAM's Pose3,
left perturbations) live in :mod:`ekf.conventions`.

Raw-IMU drives (:class:`ekf.inertial.InertialDrive`, the smoother of
:mod:`graph.inertial_smoother`): the world is **gravity-aligned** instead (z up, against
gravity), with its origin at the IMU at camera frame 0 and the yaw of the IMU at frame 0 (the
least rotation taking the measured up direction onto z: :mod:`graph.inertial_init`); poses are
``world_T_imu`` at the camera frames, in the same covariance convention. Velocities and IMU
biases have no field here: the smoother returns them beside the Estimate
(:class:`graph.inertial_smoother.InertialStates`).

Landmarks: ``landmarks[j]`` the world position of track j, ``landmark_cov[j]`` its 3x3
covariance; both NaN where track j got no landmark.
"""

from __future__ import annotations

import json
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from vislam.ekf.errors import EstimationError, time_text

_ARRAYS = (
    "timestamps",
    "poses",
    "pose_cov",
    "landmarks",
    "landmark_cov",
    "step_time_s",
    "n_updates",
    "n_rejected",
    "n_initialised",
)


@dataclass
class Estimate:
    """Per-step poses and covariances, the landmark map, run time and counters.

    ``estimator`` the estimator's name; ``timestamps`` (T,); ``poses`` (T, 4, 4);
    ``pose_cov`` (T, 6, 6); ``landmarks`` (M, 3); ``landmark_cov`` (M, 3, 3);
    ``step_time_s`` (T,) wall time spent on each step; ``n_updates`` (T,) observations used in
    updates; ``n_rejected`` (T,) observations rejected (gating, disparity, depth, cheirality);
    ``n_initialised`` (T,) landmarks initialised; ``info`` free-form JSON-able settings and
    summary figures (e.g. the smoother's time split). Every estimator sets
    ``info["numerical_rejections"]`` (frames whose update was rejected because it could not be
    computed, :mod:`ekf.numerics`; their observations count in ``n_rejected``) and
    ``info["numerical_rejection_frames"]`` (the first 20 of them), and returns only finite
    poses and pose covariances (:meth:`check_finite`).
    """

    estimator: str
    timestamps: np.ndarray
    poses: np.ndarray
    pose_cov: np.ndarray
    landmarks: np.ndarray
    landmark_cov: np.ndarray
    step_time_s: np.ndarray
    n_updates: np.ndarray
    n_rejected: np.ndarray
    n_initialised: np.ndarray
    info: dict = field(default_factory=dict)

    @property
    def n_frames(self) -> int:
        return int(self.timestamps.size)

    @property
    def runtime_s(self) -> float:
        return float(np.sum(self.step_time_s))

    @property
    def positions(self) -> np.ndarray:
        """IMU positions (T, 3) in the world frame."""
        return self.poses[:, :3, 3]

    @property
    def has_landmark(self) -> np.ndarray:
        """Boolean (M,): the track got a landmark."""
        return np.all(np.isfinite(self.landmarks), axis=1)

    @classmethod
    def empty(cls, estimator: str, timestamps: np.ndarray, n_tracks: int) -> "Estimate":
        """An estimate of the right shapes: identity poses, NaN covariances and landmarks."""
        T = int(np.asarray(timestamps).size)
        return cls(
            estimator=estimator,
            timestamps=np.asarray(timestamps, dtype=float).copy(),
            poses=np.tile(np.eye(4), (T, 1, 1)),
            pose_cov=np.full((T, 6, 6), np.nan),
            landmarks=np.full((n_tracks, 3), np.nan),
            landmark_cov=np.full((n_tracks, 3, 3), np.nan),
            step_time_s=np.zeros(T),
            n_updates=np.zeros(T, dtype=np.int64),
            n_rejected=np.zeros(T, dtype=np.int64),
            n_initialised=np.zeros(T, dtype=np.int64),
        )

    def check_finite(self) -> None:
        """EstimationError naming the estimator and the first frame whose pose or pose
        covariance is not finite, or the first landmark that :attr:`has_landmark` says exists
        whose mean or covariance is not finite (landmarks without an estimate are NaN by
        design and pass). Pose covariances that were not computed at all (a smoother with
        ``compute_marginals = false``: ``info["marginals_computed"]`` False) are all NaN by
        design too."""
        T = self.n_frames
        poses = np.asarray(self.poses, dtype=float).reshape(T, -1)
        cov = np.asarray(self.pose_cov, dtype=float).reshape(T, -1)
        no_cov = self.info.get("marginals_computed", True) is False
        checks = [("pose", poses)]
        if not (no_cov and np.isnan(cov).all()):
            checks.append(("pose covariance", cov))
        for what, arr in checks:
            bad = np.flatnonzero(~np.isfinite(arr).all(axis=1))
            if bad.size:
                t = int(bad[0])
                stamp = float(self.timestamps[t]) if t < np.size(self.timestamps) else float("nan")
                raise EstimationError(
                    f"{self.estimator}: frame {t} (t={time_text(stamp)} s): {what} not finite"
                )
        lm = np.asarray(self.landmarks, dtype=float)
        partial = np.flatnonzero(~self.has_landmark & ~np.isnan(lm).all(axis=1))
        if partial.size:
            raise EstimationError(f"{self.estimator}: landmark {int(partial[0])}: mean not finite")
        if lm.shape[0] and not (no_cov and np.isnan(self.landmark_cov).all()):
            lcov = np.asarray(self.landmark_cov, dtype=float).reshape(lm.shape[0], -1)
            bad = np.flatnonzero(self.has_landmark & ~np.isfinite(lcov).all(axis=1))
            if bad.size:
                raise EstimationError(
                    f"{self.estimator}: landmark {int(bad[0])}: covariance not finite"
                )

    def save_npz(self, path: str | os.PathLike) -> None:
        """Write atomically (temporary file, then rename) to ``path``; an estimate with a
        non-finite pose or landmark (:meth:`check_finite`) is refused before anything is written."""
        self.check_finite()
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        arrays = {k: getattr(self, k) for k in _ARRAYS}
        fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".npz.tmp")
        try:
            with os.fdopen(fd, "wb") as fh:
                np.savez_compressed(
                    fh,
                    estimator=np.array(self.estimator),
                    info_json=np.array(json.dumps(self.info, default=_jsonable)),
                    **arrays,
                )
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise

    @classmethod
    def load_npz(cls, path: str | os.PathLike) -> "Estimate":
        with np.load(path, allow_pickle=False) as d:
            return cls(
                estimator=str(d["estimator"]),
                info=json.loads(str(d["info_json"])),
                **{k: d[k] for k in _ARRAYS},
            )


def _jsonable(x):
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, Path):
        return str(x)
    raise TypeError(f"not JSON-serialisable: {type(x).__name__}")
