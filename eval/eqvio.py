"""gtsam's eqvio csv (``eqvio_processed_30s.csv`` in the gtsam 4.3 package: EuRoC V1_01's first
30 s, from the EqVIO pipeline): one file with ``meta``, ``imu`` and ``vision_feature`` rows.

Columns (header row): ``row_type, t_abs, t_rel, seq, frame_idx, landmark_id, gx, gy, gz, ax,
ay, az, bgx, bgy, bgz, bax, bay, baz, u_norm, v_norm, key, value``.

- ``meta`` rows: ``key, value`` pairs; the camera's ``camera_fx/fy/cx/cy`` and ``T_ci_t*`` /
  ``T_ci_q*`` (the camera's pose in the IMU frame: ``p_imu = T_ci p_cam``);
- ``imu`` rows: ``t_abs`` (s), gyro ``gx, gy, gz`` (rad/s), accelerometer ``ax, ay, az``
  (m/s^2), IMU frame;
- ``vision_feature`` rows: ``t_abs``, ``frame_idx``, ``landmark_id`` and the undistorted
  normalised coordinates ``u_norm, v_norm``, converted here to pixels of the ideal pinhole
  ``K`` of the meta rows (so pixel noise is in pixels, as for every other drive).

Stamps are parsed from their decimal text to integer nanoseconds (a float keeps only 0.2 us at
1.4e9 s). The file carries no IMU noise figures (its ``eqf.input_var_*`` are one filter's tuned
values, not the sensor's): :data:`EUROC_IMU_NOISE`, the data sheet of the EuRoC IMU it
was recorded with, is used, or the noise of an ASL folder read with it.
"""

from __future__ import annotations

import csv
import io
import os
import stat
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation
from vislam.ekf.errors import InputError
from vislam.ekf.filter import ImuSamples
from vislam.ekf.geometry import se3_inv
from vislam.ekf.inertial import STANDARD_GRAVITY, ImuNoise, InertialCalibration, InertialDrive
from vislam.eval.export import MAX_TEXT_BYTES, check_increasing
from vislam.eval.safe_reading import read_text
from vislam.eval.imu_streams import (check_gaps, check_unique_observations, frames_inside_imu,
                                     observations)

#: The file's name inside the gtsam package (``vislam convert eqvio``).
EQVIO_FILE = "eqvio_processed_30s.csv"
COLUMNS = ("row_type", "t_abs", "t_rel", "seq", "frame_idx", "landmark_id", "gx", "gy", "gz",
           "ax", "ay", "az", "bgx", "bgy", "bgz", "bax", "bay", "baz", "u_norm", "v_norm", "key",
           "value")
META_CAMERA = ("camera_fx", "camera_fy", "camera_cx", "camera_cy")
#: The eqvio csv's sensor (EuRoC's ADIS16448): its noise figures from EuRoC's
#: ``mav0/imu0/sensor.yaml`` (the manufacturer's), used when the csv is read without its folder.
EUROC_IMU_NOISE = ImuNoise(1.6968e-04, 1.9393e-05, 2.0e-3, 3.0e-3)
META_T_CI = ("T_ci_tx", "T_ci_ty", "T_ci_tz", "T_ci_qw", "T_ci_qx", "T_ci_qy", "T_ci_qz")


def packaged_eqvio() -> Path:
    """The eqvio csv shipped inside the gtsam package (gtsam >= 4.3)."""
    from gtsam.utils import findExampleDataFile

    try:
        return Path(findExampleDataFile(EQVIO_FILE))
    except (OSError, ValueError, RuntimeError):
        raise InputError(f"{EQVIO_FILE} is not in the installed gtsam package (it ships with "
                         "gtsam 4.3 and later)") from None


def is_eqvio_csv(path: str | os.PathLike) -> bool:
    """Whether ``path`` names the eqvio csv: the word ``eqvio`` or a regular file whose first
    line is its header (a FIFO or device is never opened: reading it could block)."""
    if str(path) == "eqvio":
        return True
    try:
        if not stat.S_ISREG(os.stat(path).st_mode):
            return False
        with open(path, "rb") as fh:
            return fh.readline(256).decode("utf-8", "replace").strip().startswith("row_type,t_abs")
    except (OSError, ValueError):
        return False


def _stamp_ns(path: Path, line: int, text: str) -> int:
    """Integer nanoseconds of a decimal seconds stamp, exactly."""
    whole, _, frac = text.strip().partition(".")
    if not whole.isdigit() or (frac and not frac.isdigit()):
        raise InputError(f"{path}: line {line}, column t_abs: {text[:40]!r} is not a time in seconds")
    return int(whole) * 10**9 + int((frac + "000000000")[:9])


class _Rows:
    """The eqvio file split by row type, each row with its line number."""

    def __init__(self, path: Path):
        self.path = path
        text = read_text(path, "eqvio csv", MAX_TEXT_BYTES)
        reader = csv.reader(io.StringIO(text))
        header = next(reader, None)
        if header is None or tuple(h.strip() for h in header) != COLUMNS:
            raise InputError(f"{path}: line 1: not the eqvio csv header ({', '.join(COLUMNS[:6])}, ...)")
        self.meta: dict[str, str] = {}
        self.imu: list[tuple[int, list[str]]] = []
        self.features: list[tuple[int, list[str]]] = []
        for number, row in enumerate(reader, start=2):
            if not row:
                continue
            if len(row) != len(COLUMNS):
                raise InputError(f"{path}: line {number} has {len(row)} columns, expected {len(COLUMNS)}")
            kind = row[0]
            if kind == "meta":
                self.meta[row[20]] = row[21]
            elif kind == "imu":
                self.imu.append((number, row))
            elif kind == "vision_feature":
                self.features.append((number, row))
            else:
                raise InputError(f"{path}: line {number}, column row_type: unknown row type {kind[:40]!r} "
                                 "(expected meta, imu or vision_feature)")

    def number(self, line: int, row: list[str], column: str) -> float:
        text = row[COLUMNS.index(column)]
        try:
            value = float(text)
        except ValueError:
            raise InputError(f"{self.path}: line {line}, column {column}: non-numeric value "
                             f"{text[:40]!r}") from None
        if not np.isfinite(value):
            raise InputError(f"{self.path}: line {line}, column {column}: {text[:40]!r} is not finite")
        return value

    def meta_number(self, key: str) -> float:
        if key not in self.meta:
            raise InputError(f"{self.path}: no meta row for key '{key}'")
        try:
            value = float(self.meta[key])
        except ValueError:
            value = float("nan")
        if not np.isfinite(value):
            raise InputError(f"{self.path}: meta key '{key}' is {self.meta[key][:40]!r}, not a finite number")
        return value

    def camera(self) -> tuple[np.ndarray, np.ndarray]:
        """``K`` (3, 3) and ``cam_T_imu`` (4, 4) from the meta rows."""
        fx, fy, cx, cy = (self.meta_number(k) for k in META_CAMERA)
        if fx <= 0 or fy <= 0:
            raise InputError(f"{self.path}: meta camera focal lengths must be positive ({fx}, {fy})")
        tx, ty, tz, qw, qx, qy, qz = (self.meta_number(k) for k in META_T_CI)
        norm = float(np.linalg.norm([qw, qx, qy, qz]))
        if abs(norm - 1) > 1e-3:
            raise InputError(f"{self.path}: meta T_ci quaternion has norm {norm:.6g}, not 1")
        imu_T_cam = np.eye(4)
        imu_T_cam[:3, :3] = Rotation.from_quat([qx, qy, qz, qw]).as_matrix()
        imu_T_cam[:3, 3] = (tx, ty, tz)
        return np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]]), se3_inv(imu_T_cam)


def read_eqvio_tracks(path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """From the eqvio csv (``path`` or the word ``eqvio``): the frames' stamps ``frame_ns``
    (F,), each observation's frame index (N,), track id (N,), pixels (N, 2), and ``K``."""
    path = packaged_eqvio() if str(path) == "eqvio" else Path(path)
    rows = _Rows(path)
    K, _ = rows.camera()
    return _tracks(rows, K) + (K,)


def _tracks(rows: _Rows, K: np.ndarray):
    if not rows.features:
        raise InputError(f"{rows.path}: no vision_feature rows")
    n = len(rows.features)
    stamp = np.empty(n, dtype=np.int64)
    frame_idx = np.empty(n, dtype=np.int64)
    track_id = np.empty(n, dtype=np.int64)
    uv = np.empty((n, 2))
    lines = np.empty(n, dtype=np.int64)
    for i, (line, row) in enumerate(rows.features):
        lines[i] = line
        stamp[i] = _stamp_ns(rows.path, line, row[1])
        for column, target in (("frame_idx", frame_idx), ("landmark_id", track_id)):
            value = rows.number(line, row, column)
            if value != int(value) or value < 0:
                raise InputError(f"{rows.path}: line {line}, column {column}: {value!r} is not a "
                                 "non-negative integer")
            target[i] = int(value)
        uv[i] = rows.number(line, row, "u_norm"), rows.number(line, row, "v_norm")
    frame_ns, first = np.unique(stamp, return_index=True)
    frame_of_row = np.searchsorted(frame_ns, stamp)
    # One frame index per stamp, in order: the file's own frame_idx must agree.
    if np.any(frame_idx[first] != frame_idx[first][0] + np.arange(frame_ns.size)):
        bad = int(np.flatnonzero(frame_idx[first] != frame_idx[first][0] + np.arange(frame_ns.size))[0])
        raise InputError(f"{rows.path}: line {int(lines[first[bad]])}, column frame_idx: frame "
                         f"{int(frame_idx[first[bad]])} does not follow its stamps' order")
    check_unique_observations(rows.path, stamp, track_id, lines)
    pixels = uv * np.array([K[0, 0], K[1, 1]]) + np.array([K[0, 2], K[1, 2]])
    return frame_ns, frame_of_row, track_id, pixels


def read_eqvio_drive(path="eqvio") -> InertialDrive:
    """The whole drive of the eqvio csv: its IMU rows, tracks and camera (module docstring)."""
    path = packaged_eqvio() if str(path) == "eqvio" else Path(path)
    rows = _Rows(path)
    K, cam_T_imu = rows.camera()
    if not rows.imu:
        raise InputError(f"{path}: no imu rows")
    lines = np.array([line for line, _ in rows.imu], dtype=np.int64)
    imu_ns = np.array([_stamp_ns(path, line, row[1]) for line, row in rows.imu], dtype=np.int64)
    what = "eqvio csv imu rows"
    check_increasing(path, what, imu_ns, lines)
    check_gaps(path, imu_ns, lines)
    values = np.array([[rows.number(line, row, c) for c in ("gx", "gy", "gz", "ax", "ay", "az")]
                       for line, row in rows.imu])
    frame_ns, frame_of_row, track_id, pixels = _tracks(rows, K)
    frames_inside_imu(path, frame_ns, imu_ns)
    obs, n_tracks, ids = observations(frame_of_row, track_id, pixels, frame_ns.size)
    imu = ImuSamples((imu_ns - imu_ns[0]) * 1e-9, values[:, 3:6].copy(), values[:, 0:3].copy())
    calib = InertialCalibration(K, cam_T_imu, EUROC_IMU_NOISE, None, "none", (), STANDARD_GRAVITY)
    return InertialDrive(path.stem, (frame_ns - imu_ns[0]) * 1e-9, imu, obs, n_tracks, calib,
                         int(imu_ns[0]), ids, str(path))
