"""Checks and cuts shared by every reader of a raw-IMU stream and its camera tracks
(:mod:`eval.asl`, :mod:`eval.eqvio`, :mod:`eval.inertial_files`): gaps in the IMU stamps,
one observation per track and frame, camera frames inside the IMU's span, the IMU cut to the
frames, and the sparse observations built from rows."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from vislam.ekf.errors import InputError
from vislam.ekf.filter import ImuSamples
from vislam.ekf.sequence import Observations

#: An IMU interval longer than this many median intervals is a gap (a dropped stretch).
MAX_GAP_FACTOR = 5.0
#: A camera stamp this close to an IMU stamp (ns) is the same instant, printed with fewer digits.
SNAP_NS = 1000


def first_gap(steps: np.ndarray) -> tuple[int, float] | None:
    """The first IMU interval of ``steps`` longer than :data:`MAX_GAP_FACTOR` median intervals
    (its index) and the median, or None: the gap rule of every reader of an IMU stream."""
    median = float(np.median(steps))
    bad = np.flatnonzero(steps > MAX_GAP_FACTOR * median)
    return None if bad.size == 0 else (int(bad[0]), median)


def check_gaps(path: Path, time_ns: np.ndarray, lines: np.ndarray) -> None:
    """No IMU interval longer than :data:`MAX_GAP_FACTOR` median intervals."""
    if time_ns.size < 3:
        raise InputError(f"{path}: {time_ns.size} IMU sample(s); a drive needs more")
    steps = np.diff(time_ns)
    gap = first_gap(steps)
    if gap is not None:
        i, median = gap
        raise InputError(f"{path}: line {int(lines[i + 1])}: a gap of {steps[i] * 1e-9:.4g} s in the "
                         f"IMU stamps after line {int(lines[i])} (the median interval is "
                         f"{median * 1e-9:.4g} s); samples are never interpolated over a gap: "
                         "cut the drive there")


def check_unique_observations(path: Path, time_ns, track_id, lines) -> None:
    order = np.lexsort((track_id, time_ns))
    same = (np.diff(time_ns[order]) == 0) & (np.diff(track_id[order]) == 0)
    if np.any(same):
        i = int(np.flatnonzero(same)[0])
        a, b = sorted((int(lines[order[i]]), int(lines[order[i + 1]])))
        raise InputError(f"{path}: line {b}: track {int(track_id[order[i]])} is observed twice at "
                         f"the same frame (also line {a})")


def observations(frame: np.ndarray, track_id: np.ndarray, z: np.ndarray, n_frames: int
                 ) -> tuple[Observations, int, np.ndarray]:
    """Observations with dense track indices (0..M-1 in order of id), M, and the ids."""
    ids, track = np.unique(track_id, return_inverse=True)
    return Observations.from_rows(frame, track, z, n_frames), int(ids.size), ids


def snap_to_samples(frame_ns: np.ndarray, imu_ns: np.ndarray) -> np.ndarray:
    """Frame stamps within :data:`SNAP_NS` of an IMU stamp moved onto it: a file that prints
    seconds with 7 decimals (the eqvio csv) puts a frame taken with an IMU sample 100 ns off it."""
    i = np.clip(np.searchsorted(imu_ns, frame_ns), 1, imu_ns.size - 1)
    nearest = np.where(frame_ns - imu_ns[i - 1] <= imu_ns[i] - frame_ns, imu_ns[i - 1], imu_ns[i])
    return np.where(np.abs(nearest - frame_ns) <= SNAP_NS, nearest, frame_ns)


def frames_inside_imu(path: Path, frame_ns: np.ndarray, imu_ns: np.ndarray) -> None:
    """Every camera frame inside the IMU's span (an estimator integrates up to each frame)."""
    outside = np.flatnonzero((frame_ns < imu_ns[0]) | (frame_ns > imu_ns[-1]))
    if outside.size:
        t = int(frame_ns[outside[0]])
        raise InputError(f"{path}: camera frame at {t} ns is outside the IMU's span "
                         f"[{int(imu_ns[0])}, {int(imu_ns[-1])}] ns ({outside.size} frame(s) outside); "
                         "cut the tracks to the IMU's span")


def cut_to_frames(imu_ns: np.ndarray, imu: ImuSamples, frame_ns: np.ndarray
                  ) -> tuple[np.ndarray, ImuSamples]:
    """The IMU samples from the last at or before the first frame to the first at or after the
    last frame (times re-based on the first kept sample): a track file that covers part of a
    flight makes a drive of that part."""
    a = max(int(np.searchsorted(imu_ns, frame_ns[0], side="right")) - 1, 0)
    b = min(int(np.searchsorted(imu_ns, frame_ns[-1], side="left")) + 1, imu_ns.size)
    kept = imu_ns[a:b]
    return kept, ImuSamples((kept - kept[0]) * 1e-9, imu.accel[a:b], imu.gyro[a:b])
