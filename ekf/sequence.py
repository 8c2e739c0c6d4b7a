"""The input both estimators share: :class:`Sequence` and its :class:`Calibration`.

Observations are stored frame by frame in compressed-row form (:class:`Observations`): the
observations of frame ``t`` are rows ``frame_ptr[t]:frame_ptr[t+1]`` of ``track`` and ``z``,
so one frame's lookup costs O(observations of that frame). The dense (4, M, T) array of the
published data files is over 98 % empty (-1) and is never kept; the sparse file layout (one row
per observation, :mod:`eval.loader`) maps onto these rows directly. Pixels are stereo
``[uL, vL, uR, vR]`` (four columns) or monocular ``[u, v]`` (two): see
:attr:`Observations.camera`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from vislam.ekf.camera import stereo_matrix
from vislam.ekf.geometry import se3_inv



def track_runs(frame: np.ndarray, track: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Observation rows grouped by track: ``(order, starts, ends)``, where the rows of the j-th
    track (in increasing track index) are ``order[starts[j]:ends[j]]``, in frame order."""
    frame, track = np.asarray(frame), np.asarray(track)
    order = np.lexsort((frame, track))
    t = track[order]
    starts = np.flatnonzero(np.r_[True, t[1:] != t[:-1]]) if t.size else np.zeros(0, dtype=np.int64)
    return order, starts, np.r_[starts[1:], t.size].astype(np.int64)

@dataclass(frozen=True)
class Calibration:
    """Left camera intrinsics ``K`` (3x3), stereo ``baseline`` (m), and ``cam_T_imu`` (4x4),
    the pose of the IMU in the left camera frame: ``p_cam = cam_T_imu @ p_imu``."""

    K: np.ndarray
    baseline: float
    cam_T_imu: np.ndarray

    @property
    def M(self) -> np.ndarray:
        """The stereo matrix of paper eq. 2."""
        return stereo_matrix(self.K, self.baseline)

    @property
    def imu_T_cam(self) -> np.ndarray:
        return se3_inv(self.cam_T_imu)

    @property
    def fsu(self) -> float:
        return float(self.K[0, 0])

    @property
    def fsv(self) -> float:
        return float(self.K[1, 1])

    @property
    def cu(self) -> float:
        return float(self.K[0, 2])

    @property
    def cv(self) -> float:
        return float(self.K[1, 2])


#: Pixel columns of a stereo observation ``[uL, vL, uR, vR]`` and of a monocular one ``[u, v]``.
STEREO_COLUMNS = 4
MONO_COLUMNS = 2


@dataclass(frozen=True)
class Observations:
    """Observations sorted by frame (compressed rows).

    ``frame_ptr`` (T+1,) int64; ``track`` (N,) int64 track index; ``z`` (N, 4) stereo pixels
    ``[uL, vL, uR, vR]``, or (N, 2) monocular pixels ``[u, v]`` (:attr:`camera` says which).
    Within a frame, rows are sorted by track index.
    """

    frame_ptr: np.ndarray
    track: np.ndarray
    z: np.ndarray

    def frame(self, t: int) -> tuple[np.ndarray, np.ndarray]:
        """Track indices (n,) and pixels (n, 4) (monocular: (n, 2)) observed at frame ``t``."""
        a, b = self.frame_ptr[t], self.frame_ptr[t + 1]
        return self.track[a:b], self.z[a:b]

    @property
    def frame_index(self) -> np.ndarray:
        """Frame of each observation row (N,)."""
        counts = np.diff(self.frame_ptr)
        return np.repeat(np.arange(counts.size), counts)

    @property
    def per_frame(self) -> np.ndarray:
        """Number of observations per frame (T,)."""
        return np.diff(self.frame_ptr)

    @property
    def is_stereo(self) -> bool:
        """True for stereo pixels (four columns), False for monocular ones (two)."""
        return self.z.ndim != 2 or self.z.shape[1] != MONO_COLUMNS

    @property
    def camera(self) -> str:
        """``"stereo"`` (``z`` has four columns ``[uL, vL, uR, vR]``) or ``"monocular"`` (two,
        ``[u, v]``). Today's estimators take stereo observations only."""
        return "stereo" if self.is_stereo else "monocular"

    def __len__(self) -> int:
        return int(self.track.size)

    @classmethod
    def from_rows(cls, frame: np.ndarray, track: np.ndarray, z: np.ndarray, n_frames: int):
        """Build from unsorted (frame, track, z) rows; ``z`` (N, 4) stereo or (N, 2)
        monocular pixels (anything else is read as stereo rows of four)."""
        frame = np.asarray(frame, dtype=np.int64)
        track = np.asarray(track, dtype=np.int64)
        z = np.asarray(z, dtype=float)
        width = MONO_COLUMNS if z.ndim == 2 and z.shape[1] == MONO_COLUMNS else STEREO_COLUMNS
        order = np.lexsort((track, frame))
        ptr = np.zeros(n_frames + 1, dtype=np.int64)
        np.cumsum(np.bincount(frame, minlength=n_frames), out=ptr[1:])
        return cls(ptr, track[order], z[order].reshape(-1, width))

    @classmethod
    def from_dense(cls, features: np.ndarray) -> "Observations":
        """From the data files' (4, M, T) array, -1 where a track is not observed."""
        features = np.asarray(features, dtype=float)
        observed = ~np.all(features == -1, axis=0)  # (M, T)
        track, frame = np.nonzero(observed)
        z = features[:, track, frame].T
        return cls.from_rows(frame, track, z, features.shape[2])

    def to_dense(self, n_tracks: int) -> np.ndarray:
        """The (4, M, T) array of the dense data files (-1 where not observed); (2, M, T) for
        monocular pixels. It takes 8 x columns x M x T bytes: vislam's own readers and writers
        never build it (the sparse layout is what they write)."""
        T = self.frame_ptr.size - 1
        out = -np.ones((self.z.shape[1] if self.z.ndim == 2 else STEREO_COLUMNS, n_tracks, T))
        out[:, self.track, self.frame_index] = self.z.T
        return out


@dataclass(frozen=True)
class Sequence:
    """One drive: time stamps, body-frame velocities, stereo observations and calibration.

    ``timestamps`` (T,) s; ``linear_velocity`` and ``angular_velocity`` (T, 3) in the IMU body
    frame; ``obs`` the stereo observations; ``n_tracks`` the number of track indices;
    ``track_origin`` (n_tracks,) the column of the source file each track came from (tracks split
    by cleaning share their origin). ``name`` and ``source`` identify the drive.
    """

    name: str
    timestamps: np.ndarray
    linear_velocity: np.ndarray
    angular_velocity: np.ndarray
    obs: Observations
    n_tracks: int
    calibration: Calibration
    track_origin: np.ndarray = field(default=None)  # type: ignore[assignment]
    source: str | None = None

    def __post_init__(self) -> None:
        if self.track_origin is None:
            object.__setattr__(self, "track_origin", np.arange(self.n_tracks, dtype=np.int64))

    @property
    def n_frames(self) -> int:
        return int(self.timestamps.size)

    def window(self, start: int, stop: int) -> "Sequence":
        """Frames ``start`` to ``stop - 1`` of this drive as a drive of their own: their stamps,
        velocities and observations, the track indices and the calibration unchanged."""
        if not 0 <= start < stop <= self.n_frames:
            raise ValueError(f"window: frames [{start}, {stop}) outside the drive's "
                             f"{self.n_frames}")
        a, b = self.obs.frame_ptr[start], self.obs.frame_ptr[stop]
        obs = Observations(self.obs.frame_ptr[start:stop + 1] - a, self.obs.track[a:b],
                           self.obs.z[a:b])
        return replace(self, timestamps=self.timestamps[start:stop],
                       linear_velocity=self.linear_velocity[start:stop],
                       angular_velocity=self.angular_velocity[start:stop], obs=obs)

    @property
    def dt(self) -> np.ndarray:
        """Interval lengths (T-1,) in seconds."""
        return np.diff(self.timestamps)

    @property
    def velocities(self) -> np.ndarray:
        """Body twists ``u_t = [v_t; w_t]`` (T, 6), translation first as in the paper."""
        return np.concatenate([self.linear_velocity, self.angular_velocity], axis=1)

    def frame(self, t: int) -> tuple[np.ndarray, np.ndarray]:
        """Track indices and pixels (n, 4) observed at frame ``t``."""
        return self.obs.frame(t)

    def track_lengths(self) -> np.ndarray:
        """Number of observations of each track (n_tracks,)."""
        return np.bincount(self.obs.track, minlength=self.n_tracks)

    def track_last_frame(self) -> np.ndarray:
        """Last frame each track is observed in (n_tracks,), -1 for tracks never observed."""
        last = -np.ones(self.n_tracks, dtype=np.int64)
        np.maximum.at(last, self.obs.track, self.obs.frame_index)
        return last

    def track_first_frame(self) -> np.ndarray:
        """First frame each track is observed in (n_tracks,), -1 for tracks never observed."""
        first = np.full(self.n_tracks, np.iinfo(np.int64).max, dtype=np.int64)
        np.minimum.at(first, self.obs.track, self.obs.frame_index)
        first[first == np.iinfo(np.int64).max] = -1
        return first
