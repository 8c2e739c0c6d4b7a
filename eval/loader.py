"""Read and write drives in the data format of ``data/kitti-pr3`` (see its README).

File layout (edition 1, what :func:`write_npz` writes):

=====================  ==========  ==============================================
key                    shape       meaning
=====================  ==========  ==============================================
``time_stamps``        (1, T)      UNIX time, s, strictly increasing
``features``           (4, M, T)   ``[uL, vL, uR, vR]``; all four -1 where unobserved
``linear_velocity``    (3, T)      m/s, IMU body frame
``rotational_velocity`` (3, T)     rad/s, IMU body frame
``K``                  (3, 3)      left intrinsics
``b``                  ()          stereo baseline, m
``cam_T_imu``          (4, 4)      ``p_cam = cam_T_imu @ p_imu``
=====================  ==========  ==============================================

The other published edition names the angular velocity ``angular_velocity`` and stores the
inverse transform ``imu_T_cam``; both load to identical :class:`~ekf.sequence.Sequence` objects.
Unknown keys are ignored. Every fault raises :class:`~ekf.errors.InputError` naming the file,
the key and what is wrong.
"""

from __future__ import annotations

import os
import tempfile
import zipfile
from pathlib import Path

import numpy as np

from ekf.errors import InputError
from ekf.geometry import is_rigid, se3_inv
from ekf.sequence import Calibration, Observations, Sequence

#: Velocity key names, edition 1 first.
ANGULAR_KEYS = ("rotational_velocity", "angular_velocity")
#: Transform key names: edition 1 stores cam_T_imu, the other edition its inverse imu_T_cam.
TRANSFORM_KEYS = ("cam_T_imu", "imu_T_cam")
#: Tolerance of the rigidity check (orthonormality, det, last row).
RIGID_TOL = 1e-5


def load_sequence(path: str | os.PathLike, clean: bool = False) -> Sequence:
    """Read and validate one drive. ``clean=True`` also applies
    :func:`ekf.cleaning.clean_sequence` with its defaults (the cleaning report is logged)."""
    path = Path(path)
    arrays = read_arrays(path)
    seq = sequence_from_arrays(arrays, name=path.stem, source=str(path))
    if clean:
        from ekf.cleaning import clean_sequence

        seq, _ = clean_sequence(seq)
    return seq


def read_arrays(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Validated arrays in edition-1 layout (keys as written by :func:`write_npz`)."""
    path = Path(path)
    raw = _read_npz(path)
    return _validate(raw, path)


def read_calibration(path: str | os.PathLike) -> tuple[Calibration, int]:
    """The calibration and number of frames of a drive, reading only the small keys (the
    feature array is never decompressed). Faults as in :func:`read_arrays`."""
    path = Path(path)
    raw = _read_npz(path, keys=("time_stamps", "K", "b") + TRANSFORM_KEYS)
    for key in ("time_stamps", "K", "b"):
        if key not in raw:
            raise InputError(f"{path}: missing key {key!r}")
    ts = _time_stamps(raw, path)
    K, b, cam_T_imu = _calibration(raw, path)
    return Calibration(K=K, baseline=b, cam_T_imu=cam_T_imu), int(ts.size)


def _read_npz(path: Path, keys: tuple[str, ...] | None = None) -> dict[str, np.ndarray]:
    if not path.exists():
        raise InputError(f"{path}: file does not exist")
    if path.is_dir():
        raise InputError(f"{path}: is a directory, expected an .npz file")
    if not zipfile.is_zipfile(path):
        raise InputError(f"{path}: not an .npz file (not a zip archive)")
    try:
        with np.load(path, allow_pickle=False) as data:
            return {
                k: np.asarray(data[k]) for k in data.files if keys is None or k in keys
            }
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise InputError(f"{path}: unreadable .npz file ({exc})") from None


def _pick(raw: dict, path: Path, names: tuple[str, ...]) -> tuple[str, np.ndarray]:
    for name in names:
        if name in raw:
            return name, raw[name]
    raise InputError(f"{path}: missing key {' or '.join(repr(n) for n in names)}")


def _numeric(path: Path, key: str, a: np.ndarray, shape_text: str, ndim: int) -> np.ndarray:
    if a.dtype.kind not in "biuf":
        raise InputError(f"{path}: key {key!r} has non-numeric dtype {a.dtype}")
    if a.ndim != ndim:
        raise InputError(f"{path}: key {key!r} has shape {a.shape}, expected {shape_text}")
    return a.astype(float, copy=False)


def _validate(raw: dict[str, np.ndarray], path: Path) -> dict[str, np.ndarray]:
    for key in ("time_stamps", "features", "linear_velocity", "K", "b"):
        if key not in raw:
            raise InputError(f"{path}: missing key {key!r}")
    ang_key, ang = _pick(raw, path, ANGULAR_KEYS)

    ts = _time_stamps(raw, path)
    T = ts.size

    feats = _numeric(path, "features", raw["features"], "(4, M, T)", 3)
    if feats.shape[0] != 4:
        raise InputError(f"{path}: key 'features' has shape {feats.shape}, expected (4, M, T)")
    lin = _numeric(path, "linear_velocity", raw["linear_velocity"], "(3, T)", 2)
    ang = _numeric(path, ang_key, ang, "(3, T)", 2)
    for key, a in (("linear_velocity", lin), (ang_key, ang)):
        if a.shape[0] != 3:
            raise InputError(f"{path}: key {key!r} has shape {a.shape}, expected (3, T)")
    for key, a in (("features", feats), ("linear_velocity", lin), (ang_key, ang)):
        if a.shape[-1] != T:
            raise InputError(
                f"{path}: key {key!r} has shape {a.shape}: {a.shape[-1]} steps, "
                f"but 'time_stamps' has {T}"
            )

    for key, a in (("linear_velocity", lin), (ang_key, ang), ("features", feats)):
        bad = ~np.isfinite(a)
        if bad.any():
            idx = tuple(int(i) for i in np.argwhere(bad)[0])
            raise InputError(f"{path}: key {key!r} has {int(bad.sum())} NaN/inf value(s), "
                             f"first at index {idx}")

    K, b, cam_T_imu = _calibration(raw, path)

    return {
        "time_stamps": ts[None, :],
        "features": feats,
        "linear_velocity": lin,
        "rotational_velocity": ang,
        "K": K,
        "b": np.array(b),
        "cam_T_imu": cam_T_imu,
    }


def _time_stamps(raw: dict[str, np.ndarray], path: Path) -> np.ndarray:
    """Validated time stamps (T,): shape (1, T) (or (T,)), finite, strictly increasing."""
    ts = _numeric(path, "time_stamps", raw["time_stamps"], "(1, T)", raw["time_stamps"].ndim)
    if ts.ndim == 2 and ts.shape[0] == 1:
        ts = ts[0]
    elif ts.ndim != 1:
        raise InputError(f"{path}: key 'time_stamps' has shape {ts.shape}, expected (1, T)")
    if ts.size < 1:
        raise InputError(f"{path}: key 'time_stamps' is empty")
    bad = ~np.isfinite(ts)
    if bad.any():
        raise InputError(f"{path}: key 'time_stamps' has {int(bad.sum())} NaN/inf value(s), "
                         f"first at step {int(np.argmax(bad))}")
    steps = np.diff(ts)
    if np.any(steps <= 0):
        k = int(np.argmax(steps <= 0))
        raise InputError(
            f"{path}: key 'time_stamps' is not strictly increasing "
            f"(step {k} -> {k + 1}: {ts[k]!r} -> {ts[k + 1]!r})"
        )
    return ts


def _calibration(raw: dict[str, np.ndarray], path: Path) -> tuple[np.ndarray, float, np.ndarray]:
    """Validated ``K`` (3, 3), baseline ``b`` > 0 and ``cam_T_imu`` (from either edition)."""
    tf_key, tf = _pick(raw, path, TRANSFORM_KEYS)
    K = _numeric(path, "K", raw["K"], "(3, 3)", raw["K"].ndim)
    if K.shape != (3, 3):
        raise InputError(f"{path}: key 'K' has shape {K.shape}, expected (3, 3)")
    _check_intrinsics(K, path)

    b_arr = _numeric(path, "b", raw["b"], "()", raw["b"].ndim)
    if b_arr.size != 1:
        raise InputError(f"{path}: key 'b' has shape {b_arr.shape}, expected () (a scalar)")
    b = float(b_arr.reshape(()))
    if not np.isfinite(b) or b <= 0:
        raise InputError(f"{path}: key 'b' (baseline) must be a positive number, got {b!r}")

    tf = _numeric(path, tf_key, tf, "(4, 4)", tf.ndim)
    if tf.shape != (4, 4):
        raise InputError(f"{path}: key {tf_key!r} has shape {tf.shape}, expected (4, 4)")
    if not is_rigid(tf, tol=RIGID_TOL):
        raise InputError(f"{path}: key {tf_key!r} is not a rigid transform "
                         "(rotation not orthonormal with det +1, or last row not 0 0 0 1)")
    cam_T_imu = tf if tf_key == "cam_T_imu" else se3_inv(tf)

    return K, b, cam_T_imu


def _check_intrinsics(K: np.ndarray, path: Path) -> None:
    where = f"{path}: key 'K' is not a valid intrinsic matrix"
    if not np.all(np.isfinite(K)):
        raise InputError(f"{where}: it has NaN/inf entries")
    if not np.allclose(K[2], [0.0, 0.0, 1.0], atol=1e-9):
        raise InputError(f"{where}: last row is {K[2].tolist()}, expected [0, 0, 1]")
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise InputError(f"{where}: focal lengths must be positive, got {K[0, 0]!r}, {K[1, 1]!r}")
    if abs(K[1, 0]) > 1e-9:
        raise InputError(f"{where}: entry [1, 0] must be 0, got {K[1, 0]!r}")
    if abs(K[0, 1]) > 1e-6 * K[0, 0]:
        raise InputError(f"{where}: skew K[0, 1] = {K[0, 1]!r}, the stereo model has none")


def sequence_from_arrays(
    arrays: dict[str, np.ndarray], name: str, source: str | None = None
) -> Sequence:
    """Build a :class:`Sequence` from validated edition-1 arrays (see :func:`read_arrays`)."""
    feats = arrays["features"]
    return Sequence(
        name=name,
        timestamps=np.ascontiguousarray(arrays["time_stamps"].reshape(-1)),
        linear_velocity=np.ascontiguousarray(arrays["linear_velocity"].T),
        angular_velocity=np.ascontiguousarray(arrays["rotational_velocity"].T),
        obs=Observations.from_dense(feats),
        n_tracks=int(feats.shape[1]),
        calibration=Calibration(
            K=arrays["K"], baseline=float(arrays["b"]), cam_T_imu=arrays["cam_T_imu"]
        ),
        source=source,
    )


def write_npz(
    path: str | os.PathLike,
    *,
    time_stamps: np.ndarray,
    features: np.ndarray,
    linear_velocity: np.ndarray,
    angular_velocity: np.ndarray,
    K: np.ndarray,
    b: float,
    cam_T_imu: np.ndarray,
) -> None:
    """Write a drive in edition-1 layout, atomically (temporary file, then ``os.replace``).

    Shapes as in the file: ``time_stamps`` (1, T) (or (T,)), ``features`` (4, M, T),
    velocities (3, T), ``K`` (3, 3), ``b`` scalar, ``cam_T_imu`` (4, 4). The angular velocity
    is stored under the edition-1 key ``rotational_velocity``.
    """
    path = Path(path)
    arrays = {
        "time_stamps": np.asarray(time_stamps, dtype=float).reshape(1, -1),
        "features": np.asarray(features, dtype=float),
        "linear_velocity": np.asarray(linear_velocity, dtype=float),
        "rotational_velocity": np.asarray(angular_velocity, dtype=float),
        "K": np.asarray(K, dtype=float),
        "b": np.array(float(b)),
        "cam_T_imu": np.asarray(cam_T_imu, dtype=float),
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=".npz.tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            np.savez_compressed(fh, **arrays)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def save_sequence(path: str | os.PathLike, seq: Sequence) -> None:
    """Write ``seq`` in edition-1 layout (one column per track index; see :func:`write_npz`).

    Tracks split by cleaning are written as separate columns; ``track_origin`` is not kept.
    """
    cal = seq.calibration
    write_npz(
        path,
        time_stamps=seq.timestamps,
        features=seq.obs.to_dense(seq.n_tracks),
        linear_velocity=np.asarray(seq.linear_velocity).T,
        angular_velocity=np.asarray(seq.angular_velocity).T,
        K=cal.K,
        b=cal.baseline,
        cam_T_imu=cal.cam_T_imu,
    )
