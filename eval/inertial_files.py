"""vislam's file form of a raw-IMU drive: the velocity drives' ``.npz`` container and checks,
with the IMU stream in place of the velocities.

| key | shape | what |
| --- | --- | --- |
| ``imu_time`` | (n,) | IMU sample times, s since ``time_origin_ns``, strictly increasing |
| ``imu_gyro`` | (n, 3) | angular rate, rad/s, IMU frame |
| ``imu_accel`` | (n, 3) | specific force, m/s^2, IMU frame (gravity not removed) |
| ``imu_noise`` | (4,) | gyro noise density (rad/s/sqrt(Hz)), gyro random walk (rad/s^2/sqrt(Hz)), accelerometer noise density (m/s^2/sqrt(Hz)), accelerometer random walk (m/s^3/sqrt(Hz)) |
| ``gravity`` | () | gravity's magnitude, m/s^2 (default 9.80665) |
| ``time_stamps`` | (T,) or (1, T) | camera frame times, s since ``time_origin_ns``, inside the IMU's span |
| ``time_origin_ns`` | () | the absolute time of 0, integer ns (default 0) |
| ``obs_frame``, ``obs_track``, ``obs_pixels``, ``n_tracks`` | | the tracks in the sparse layout of :mod:`eval.loader` (two pixel columns: one camera; four: a rectified stereo pair) |
| ``K``, ``b``, ``cam_T_imu`` (or ``imu_T_cam``) | | as in a velocity drive; ``b`` only for stereo |
| ``distortion_radtan`` or ``distortion_equidistant`` | (4,) | the tracks' lens distortion, where the pixels are not undistorted |
| ``track_id`` | (M,) | each track's id in the source (optional) |

A file with ``imu_time`` is a raw-IMU drive (:func:`is_inertial_file`); its observations are
always sparse. IMU faults are named as in the text readers (:mod:`eval.asl`): duplicated or
unsorted stamps, gaps, frames outside the IMU's span.
"""

from __future__ import annotations

import os
import zipfile
from pathlib import Path

import numpy as np

from vislam.ekf.errors import InputError
from vislam.ekf.filter import ImuSamples
from vislam.ekf.inertial import STANDARD_GRAVITY, ImuNoise, InertialCalibration, InertialDrive
from vislam.ekf.sequence import Observations
from vislam.eval.imu_streams import first_gap
from vislam.eval.drive_keys import (SPARSE_KEYS, TRANSFORM_KEYS, _numeric, check_calibration,
                                    check_time_stamps, validate_sparse)
from vislam.eval.export import save_npz_reproducible
from vislam.eval.loader import sparse_arrays
from vislam.eval.safe_reading import read_npz

IMU_KEYS = ("imu_time", "imu_gyro", "imu_accel", "imu_noise")
DISTORTION_KEYS = {"distortion_radtan": "radtan", "distortion_equidistant": "equidistant"}
KEYS = (IMU_KEYS + ("gravity", "time_stamps", "time_origin_ns", "n_tracks", "K", "b", "track_id")
        + SPARSE_KEYS + TRANSFORM_KEYS + tuple(DISTORTION_KEYS) + ("features",))
#: Largest |gyro| (rad/s) and |accel| (m/s^2) accepted: beyond them a value is no measurement.
MAX_GYRO = 1e3
MAX_ACCEL = 1e4


def is_inertial_file(path: str | os.PathLike) -> bool:
    """Whether the ``.npz`` at ``path`` holds a raw-IMU drive (an ``imu_time`` member); False
    for anything that cannot be read as a zip (the velocity reader names the fault)."""
    try:
        with zipfile.ZipFile(path) as zf:
            return "imu_time.npy" in zf.namelist()
    except (OSError, zipfile.BadZipFile, ValueError):
        return False


def load_inertial_drive(path: str | os.PathLike) -> InertialDrive:
    """The raw-IMU drive in ``path``, every key checked (module docstring)."""
    path = Path(path)
    raw = read_npz(path, KEYS)
    for key in IMU_KEYS + ("time_stamps", "K", "obs_frame", "obs_track", "obs_pixels"):
        if key not in raw:
            raise InputError(f"{path}: missing key {key!r} (a raw-IMU drive; keys: see "
                             "`vislam convert --help`)")
    if "features" in raw:
        raise InputError(f"{path}: a raw-IMU drive holds its tracks in the sparse layout "
                         "('obs_frame', 'obs_track', 'obs_pixels'), not 'features'")
    imu = _imu(raw, path)
    times = check_time_stamps(raw, path)
    outside = np.flatnonzero((times < imu.time[0]) | (times > imu.time[-1]))
    if outside.size:
        k = int(outside[0])
        raise InputError(f"{path}: key 'time_stamps' frame {k} at {times[k]!r} s is outside the "
                         f"IMU's span [{imu.time[0]!r}, {imu.time[-1]!r}] s ({outside.size} frame(s))")
    arrays, _ = validate_sparse(raw, path, times.size, negative_is_invalid=False)
    K, b, cam_T_imu = check_calibration(raw, path)
    stereo = arrays["obs_pixels"].shape[1] == 4
    if stereo and np.isnan(b):
        raise InputError(f"{path}: stereo tracks (four pixel columns) need the baseline 'b'")
    if not stereo and not np.isnan(b):
        raise InputError(f"{path}: key 'b' is given but the tracks are monocular (two pixel columns)")
    n_tracks = int(arrays["n_tracks"])
    obs = Observations.from_rows(arrays["obs_frame"], arrays["obs_track"], arrays["obs_pixels"],
                                 times.size)
    calib = InertialCalibration(K, cam_T_imu, _noise(raw, path), None if np.isnan(b) else b,
                                *_distortion(raw, path), _gravity(raw, path))
    track_id = _track_id(raw, path, n_tracks)
    origin = 0
    if "time_origin_ns" in raw:
        o = raw["time_origin_ns"]
        if o.dtype.kind not in "iu" or o.size != 1:
            raise InputError(f"{path}: key 'time_origin_ns' must be one integer (ns), got dtype "
                             f"{o.dtype} shape {o.shape}")
        origin = int(o.reshape(()))
    return InertialDrive(path.stem, times, imu, obs, n_tracks, calib, origin, track_id, str(path))


def _imu(raw: dict, path: Path) -> ImuSamples:
    t = _numeric(path, "imu_time", raw["imu_time"], "(n,)", 1)
    n = t.size
    if n < 3:
        raise InputError(f"{path}: key 'imu_time' has {n} sample(s); a drive needs more")
    columns = {}
    for key, limit, unit in (("imu_gyro", MAX_GYRO, "rad/s"), ("imu_accel", MAX_ACCEL, "m/s^2")):
        a = _numeric(path, key, raw[key], f"({n}, 3)", 2)
        if a.shape != (n, 3):
            raise InputError(f"{path}: key {key!r} has shape {a.shape}, expected ({n}, 3) (one row "
                             "per 'imu_time')")
        bad = ~np.isfinite(a) | (np.abs(a) > limit)
        if bad.any():
            r, c = (int(i) for i in np.argwhere(bad)[0])
            raise InputError(f"{path}: key {key!r} row {r}, column {c}: {a[r, c]!r} is not a "
                             f"finite value within {limit:g} {unit}")
        columns[key] = a
    if not np.all(np.isfinite(t)):
        raise InputError(f"{path}: key 'imu_time' row {int(np.argmax(~np.isfinite(t)))} is not finite")
    steps = np.diff(t)
    if np.any(steps <= 0):
        k = int(np.argmax(steps <= 0))
        kind = "duplicates" if steps[k] == 0 else "is earlier than"
        raise InputError(f"{path}: key 'imu_time' row {k + 1} ({t[k + 1]!r} s) {kind} row {k}; "
                         "IMU stamps must be strictly increasing")
    gap = first_gap(steps)
    if gap is not None:
        k, median = gap
        raise InputError(f"{path}: key 'imu_time': a gap of {steps[k]:.4g} s after row {k} (the "
                         f"median interval is {median:.4g} s); samples are never interpolated over "
                         "a gap: cut the drive there")
    return ImuSamples(t, columns["imu_accel"], columns["imu_gyro"])


def _noise(raw: dict, path: Path) -> ImuNoise:
    a = _numeric(path, "imu_noise", raw["imu_noise"], "(4,)", 1)
    if a.shape != (4,) or not np.all(np.isfinite(a)) or np.any(a <= 0):
        raise InputError(f"{path}: key 'imu_noise' must hold 4 positive numbers (gyro noise density, "
                         f"gyro random walk, accelerometer noise density, accelerometer random walk), "
                         f"got {np.asarray(a).ravel()[:6].tolist()}")
    return ImuNoise.from_array(a)


def _gravity(raw: dict, path: Path) -> float:
    if "gravity" not in raw:
        return STANDARD_GRAVITY
    g = _numeric(path, "gravity", raw["gravity"], "()", raw["gravity"].ndim)
    value = float(g.reshape(-1)[0]) if g.size == 1 else float("nan")
    if not (1.0 < value < 100.0):
        raise InputError(f"{path}: key 'gravity' must be one number of m/s^2 (about 9.81), got "
                         f"{g.ravel()[:3].tolist()}")
    return value


def _distortion(raw: dict, path: Path) -> tuple[str, tuple[float, ...]]:
    given = [k for k in DISTORTION_KEYS if k in raw]
    if len(given) > 1:
        raise InputError(f"{path}: keys {given[0]!r} and {given[1]!r}: one distortion model at most")
    if not given:
        return "none", ()
    key = given[0]
    a = _numeric(path, key, raw[key], "(4,)", 1)
    if a.shape != (4,) or not np.all(np.isfinite(a)):
        raise InputError(f"{path}: key {key!r} must hold 4 finite coefficients, got shape {a.shape}")
    return DISTORTION_KEYS[key], tuple(float(x) for x in a)


def _track_id(raw: dict, path: Path, n_tracks: int) -> np.ndarray:
    if "track_id" not in raw:
        return np.arange(n_tracks, dtype=np.int64)
    a = raw["track_id"]
    if a.dtype.kind not in "iu" or a.shape != (n_tracks,):
        raise InputError(f"{path}: key 'track_id' must be {n_tracks} integers (one per track), got "
                         f"dtype {a.dtype} shape {a.shape}")
    return a.astype(np.int64)


def inertial_arrays(drive: InertialDrive) -> dict[str, np.ndarray]:
    """The file form's arrays of ``drive`` (module docstring), in a fixed order."""
    cal = drive.calibration
    arrays = {
        "time_stamps": np.asarray(drive.timestamps, dtype=float),
        "time_origin_ns": np.array(int(drive.time_origin_ns), dtype=np.int64),
        "imu_time": np.asarray(drive.imu.time, dtype=float),
        "imu_gyro": np.asarray(drive.imu.gyro, dtype=float),
        "imu_accel": np.asarray(drive.imu.accel, dtype=float),
        "imu_noise": cal.noise.as_array(),
        "gravity": np.array(float(cal.gravity)),
        **sparse_arrays(drive.obs, drive.n_tracks),
        "K": np.asarray(cal.K, dtype=float),
        "cam_T_imu": np.asarray(cal.cam_T_imu, dtype=float),
    }
    if cal.baseline is not None:
        arrays["b"] = np.array(float(cal.baseline))
    if cal.distortion_model != "none":
        arrays[f"distortion_{cal.distortion_model}"] = np.asarray(cal.distortion, dtype=float)
    if drive.track_id is not None:
        arrays["track_id"] = np.asarray(drive.track_id, dtype=np.int64)
    return arrays


def save_inertial_drive(path: str | os.PathLike, drive: InertialDrive) -> Path:
    """Write ``drive`` in the file form, atomically and byte-reproducibly."""
    return save_npz_reproducible(path, inertial_arrays(drive))
