"""Reading a raw-IMU drive recorded in the ASL folder layout (EuRoC, TUM-VI, Kalibr's bags
exported), or given as gtsam's eqvio csv, into an :class:`ekf.inertial.InertialDrive`.

**ASL folder** (``FOLDER/mav0/`` or ``FOLDER`` itself holding):

- ``imu0/data.csv``: ``timestamp [ns], wx, wy, wz [rad/s], ax, ay, az [m/s^2]`` (IMU frame);
- ``imu0/sensor.yaml``: ``T_BS`` (the IMU's pose in the body frame), the noise densities and
  random walks (``gyroscope_noise_density``, ``gyroscope_random_walk``,
  ``accelerometer_noise_density``, ``accelerometer_random_walk``);
- ``cam0/sensor.yaml`` (``cam1/sensor.yaml`` for stereo): ``T_BS`` (the camera's pose in the
  body frame, ``p_B = T_BS p_cam``), ``intrinsics: [fu, fv, cu, cv]``, ``distortion_model``
  (``radial-tangential`` or ``equidistant``) and ``distortion_coefficients``;
- ``state_groundtruth_estimate0/data.csv`` where present: the ground truth (or ``--gt FILE``).

Images are not read: the camera tracks come from a **track file** (``--tracks FILE``), a csv of
``timestamp [ns], track id, u, v`` (one camera: pixels of cam0's distorted image) or
``timestamp [ns], track id, uL, vL, uR, vR`` (a rectified stereo pair: cam1 must then be
cam0 moved along its own x axis with the same rotation and intrinsics), one row per
observation; or gtsam's eqvio csv, whose tracks are undistorted normalised coordinates
(converted here to pixels of cam0's ideal pinhole). The camera frames are the track file's
distinct stamps, and the drive is the IMU's stretch that covers them (:func:`cut_to_frames`).

**Checks**, each fault one line naming the file, line and column: IMU stamps strictly
increasing (duplicates and steps back named), no gap longer than
:data:`eval.imu_streams.MAX_GAP_FACTOR` times the median interval (named, never interpolated over), every camera frame inside the IMU's
span, one observation per track and frame, finite values.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
from vislam.ekf.errors import InputError
from vislam.ekf.filter import ImuSamples
from vislam.ekf.geometry import is_rigid, se3_inv
from vislam.ekf.inertial import (
    DISTORTION_MODELS,
    STANDARD_GRAVITY,
    ImuNoise,
    InertialCalibration,
    InertialDrive,
)
from vislam.eval.eqvio import is_eqvio_csv, read_eqvio_tracks
from vislam.eval.imu_streams import (check_gaps, check_unique_observations, cut_to_frames,
                                     frames_inside_imu, observations, snap_to_samples)
from vislam.eval.safe_reading import read_text
from vislam.eval.export import check_increasing
from vislam.eval.text_tables import read_table

#: Largest sensor.yaml read.
MAX_YAML_BYTES = 2**20
#: ASL's names of the distortion models -> vislam's (:data:`ekf.inertial.DISTORTION_MODELS`).
DISTORTION_NAMES = {"radial-tangential": "radtan", "radtan": "radtan", "equidistant": "equidistant",
                    "none": "none"}
#: A stereo pair counts as rectified when cam1's rotation against cam0 is below this (rad).
RECTIFIED_ROTATION = 1e-3
NOISE_KEYS = ("gyroscope_noise_density", "gyroscope_random_walk",
              "accelerometer_noise_density", "accelerometer_random_walk")


def mav_folder(folder: Path) -> Path:
    """``FOLDER/mav0`` where it exists, else ``FOLDER`` when it holds ``imu0``."""
    folder = Path(folder)
    for candidate in (folder / "mav0", folder):
        if (candidate / "imu0").is_dir():
            return candidate
    raise InputError(f"{folder}: not an ASL folder (no mav0/imu0/ or imu0/ inside)")


def read_sensor_yaml(path: Path) -> dict:
    """The mapping of an ASL ``sensor.yaml`` (OpenCV's ``%YAML:1.0`` first line allowed)."""
    import yaml

    text = read_text(path, "sensor.yaml", MAX_YAML_BYTES)
    text = re.sub(r"^%YAML:1\.0[^\n]*\n", "", text)
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 2}: " if mark is not None else ""
        reason = " ".join(str(getattr(exc, "problem", None) or exc).split())[:120]
        raise InputError(f"{path}: {where}not readable YAML ({reason})") from None
    if not isinstance(data, dict):
        raise InputError(f"{path}: not a YAML mapping of sensor keys")
    return data


def _number(path: Path, data: dict, key: str, positive: bool = True) -> float:
    if key not in data:
        raise InputError(f"{path}: missing key '{key}'")
    value = data[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
        raise InputError(f"{path}: key '{key}' is {value!r}, expected a finite number")
    if positive and value <= 0:
        raise InputError(f"{path}: key '{key}' is {value!r}, expected a positive number")
    return float(value)


def _numbers(path: Path, value, key: str, n: int) -> np.ndarray:
    try:
        out = np.asarray(value, dtype=float).ravel()
    except (TypeError, ValueError):
        raise InputError(f"{path}: key '{key}' is not a list of numbers") from None
    if out.size != n or not np.all(np.isfinite(out)):
        raise InputError(f"{path}: key '{key}' has {out.size} value(s), expected {n} finite numbers")
    return out


def _transform(path: Path, data: dict, key: str = "T_BS") -> np.ndarray:
    if key not in data:
        raise InputError(f"{path}: missing key '{key}'")
    entry = data[key]
    values = entry.get("data") if isinstance(entry, dict) else entry
    T = _numbers(path, values, key, 16).reshape(4, 4)
    if not is_rigid(T, tol=1e-4):
        raise InputError(f"{path}: key '{key}' is not a rigid transform (rotation not orthonormal "
                         "with determinant +1, or last row not 0 0 0 1)")
    return T


def read_imu_noise(path: Path) -> ImuNoise:
    data = read_sensor_yaml(path)
    return ImuNoise(*(_number(path, data, k) for k in NOISE_KEYS))


def read_camera_yaml(path: Path) -> tuple[np.ndarray, np.ndarray, str, tuple[float, ...]]:
    """``body_T_cam`` (4, 4), ``K`` (3, 3), the distortion model and its coefficients."""
    data = read_sensor_yaml(path)
    body_T_cam = _transform(path, data)
    if "intrinsics" not in data:
        raise InputError(f"{path}: missing key 'intrinsics'")
    fu, fv, cu, cv = _numbers(path, data["intrinsics"], "intrinsics", 4)
    if fu <= 0 or fv <= 0:
        raise InputError(f"{path}: key 'intrinsics': focal lengths must be positive ({fu}, {fv})")
    model = str(data.get("camera_model", "pinhole"))
    if model != "pinhole":
        raise InputError(f"{path}: key 'camera_model' is {model!r}; only 'pinhole' is supported")
    name = str(data.get("distortion_model", "none"))
    if name not in DISTORTION_NAMES:
        raise InputError(f"{path}: key 'distortion_model' is {name!r}, expected one of "
                         f"{', '.join(sorted(DISTORTION_NAMES))}")
    distortion = DISTORTION_NAMES[name]
    coeffs = _numbers(path, data.get("distortion_coefficients", []), "distortion_coefficients",
                      DISTORTION_MODELS[distortion])
    K = np.array([[fu, 0.0, cu], [0.0, fv, cv], [0.0, 0.0, 1.0]])
    return body_T_cam, K, distortion, tuple(float(c) for c in coeffs)


def read_imu_csv(path: Path) -> tuple[np.ndarray, ImuSamples]:
    """``time_ns`` (n,) int64 and the samples (times in s since the first) of an ASL IMU csv."""
    what = "IMU csv: timestamp [ns], wx, wy, wz [rad/s], ax, ay, az [m/s^2]"
    table = read_table(path, what, (7,), ",", integer_columns=(0,))
    time_ns = table.exact[:, 0]
    check_increasing(path, what, time_ns, table.lines)
    check_gaps(path, time_ns, table.lines)
    t = (time_ns - time_ns[0]) * 1e-9
    return time_ns, ImuSamples(t, table.values[:, 4:7].copy(), table.values[:, 1:4].copy())


def read_track_csv(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A track file: ``time_ns`` (N,), ``track_id`` (N,), ``z`` (N, 2 or 4) pixels, and the
    file line of each row, plus the distinct frame stamps (F,)."""
    what = "track csv: timestamp [ns], track id, u, v[, uR, vR]"
    table = read_table(path, what, (4, 6), ",", integer_columns=(0, 1))
    time_ns, track_id = table.exact[:, 0], table.exact[:, 1]
    if np.any(track_id < 0):
        i = int(np.flatnonzero(track_id < 0)[0])
        raise InputError(f"{path}: line {int(table.lines[i])}, column 2: negative track id "
                         f"{int(track_id[i])} ({what})")
    check_unique_observations(path, time_ns, track_id, table.lines)
    return time_ns, track_id, table.values[:, 2:].copy(), table.lines, np.unique(time_ns)


def read_asl_folder(folder: Path, tracks: Path | None) -> InertialDrive:
    """The drive of an ASL folder with its track file (module docstring)."""
    mav = mav_folder(folder)
    imu_yaml, imu_csv, cam0 = mav / "imu0" / "sensor.yaml", mav / "imu0" / "data.csv", mav / "cam0" / "sensor.yaml"
    imu_ns, imu = read_imu_csv(imu_csv)
    noise = read_imu_noise(imu_yaml)
    body_T_imu = _transform(imu_yaml, read_sensor_yaml(imu_yaml))
    body_T_cam, K, distortion, coeffs = read_camera_yaml(cam0)
    cam_T_imu = se3_inv(body_T_cam) @ body_T_imu
    if tracks is None:
        raise InputError(f"{folder}: an ASL folder holds no tracks (images are not read): give a "
                         "track file with --tracks FILE (or --tracks eqvio)")
    if is_eqvio_csv(tracks):
        frame_ns, frame_of_row, track_id, z, K_eqvio = read_eqvio_tracks(tracks)
        K, distortion, coeffs = K_eqvio, "none", ()  # undistorted: the ideal pinhole's pixels
        frame_ns = snap_to_samples(frame_ns, imu_ns)
    else:
        time_ns, track_id, z, _, frame_ns = read_track_csv(tracks)
        frame_of_row = np.searchsorted(frame_ns, time_ns)
    frames_inside_imu(tracks, frame_ns, imu_ns)
    imu_ns, imu = cut_to_frames(imu_ns, imu, frame_ns)
    baseline = None
    if z.shape[1] == 4:
        baseline = _rectified_baseline(mav, body_T_cam, K, tracks)
    obs, n_tracks, ids = observations(frame_of_row, track_id, z, frame_ns.size)
    calib = InertialCalibration(K, cam_T_imu, noise, baseline, distortion, coeffs, STANDARD_GRAVITY)
    return InertialDrive(Path(folder).name, (frame_ns - imu_ns[0]) * 1e-9,
                         imu, obs, n_tracks, calib, int(imu_ns[0]), ids, str(folder))


def _rectified_baseline(mav: Path, body_T_cam0: np.ndarray, K0: np.ndarray, tracks: Path) -> float:
    cam1 = mav / "cam1" / "sensor.yaml"
    if not cam1.is_file():
        raise InputError(f"{tracks}: stereo tracks (six columns) need {cam1}")
    body_T_cam1, K1, _, _ = read_camera_yaml(cam1)
    cam0_T_cam1 = se3_inv(body_T_cam0) @ body_T_cam1
    angle = float(np.arccos(np.clip((np.trace(cam0_T_cam1[:3, :3]) - 1) / 2, -1, 1)))
    t = cam0_T_cam1[:3, 3]
    if t[0] <= 0 or angle > RECTIFIED_ROTATION or np.linalg.norm(t[1:]) > 1e-3 * abs(t[0]) or not np.allclose(K0, K1):
        raise InputError(f"{cam1}: stereo tracks need a rectified pair (cam1 = cam0 moved along "
                         f"its x axis, same intrinsics); this pair is rotated {np.degrees(angle):.3g} deg "
                         f"and offset {np.round(t, 4).tolist()} m: give the left camera's tracks "
                         "(four columns) instead")
    return float(t[0])
