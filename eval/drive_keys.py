"""What a drive's keys must hold, and the two published editions' names for them: the
validation of the arrays read from a drive's file (shapes, finiteness, strictly increasing
time stamps, rigid transforms, valid intrinsics, agreement of both editions' keys where a file
has both) and the observations dropped as invalid (:class:`LoadReport`). The layout and the
rules: :mod:`eval.loader`'s docstring."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vislam.ekf.errors import InputError
from vislam.ekf.geometry import is_rigid, se3_inv

#: The loader's warnings keep the loader's name (a user's logging set-up filters on it).
log = logging.getLogger("vislam.eval.loader")

#: Velocity key names, edition 1 first.
ANGULAR_KEYS = ("rotational_velocity", "angular_velocity")
#: Transform key names: edition 1 stores cam_T_imu, the other edition its inverse imu_T_cam.
TRANSFORM_KEYS = ("cam_T_imu", "imu_T_cam")
#: Every key the loader reads; other members are ignored.
KNOWN_KEYS = (
    ("time_stamps", "features", "linear_velocity", "K", "b") + ANGULAR_KEYS + TRANSFORM_KEYS
)
#: Tolerance of the rigidity check (orthonormality, det, last row).
RIGID_TOL = 1e-5
#: Largest velocity component accepted (m/s and rad/s): beyond it a value is no measurement
#: (a corrupt sample of +300 rad/s is still read, and the estimators cope with it).
MAX_VELOCITY = 1e4
#: Largest camera-IMU distance accepted (m), as ekf.model's.
MAX_LEVER_ARM = 1e3
#: Both editions' velocity keys agree when they differ by at most this, relative to the
#: largest absolute value (at least 1).
VELOCITY_RTOL = 1e-6
#: cam_T_imu and inv(imu_T_cam) agree when no entry differs by more than this.
TRANSFORM_TOL = 1e-5

#: Tracks per block when scanning the feature array.
_SCAN_TRACKS = 64


@dataclass(frozen=True)
class LoadReport:
    """What the loader dropped from the feature array (see the module notes).

    ``n_partial``: observations with one to three of the four coordinates -1; ``n_negative``:
    the other observations with a negative coordinate; ``first_invalid``: (track, frame) of the
    first of either, in (track, frame) order, or None.
    """

    n_partial: int = 0
    n_negative: int = 0
    first_invalid: tuple[int, int] | None = None

    @property
    def n_invalid(self) -> int:
        return self.n_partial + self.n_negative


def _numeric(path: Path, key: str, a: np.ndarray, shape_text: str, ndim: int) -> np.ndarray:
    if a.dtype.kind not in "biuf":
        raise InputError(f"{path}: key {key!r} has non-numeric dtype {a.dtype}")
    if a.ndim != ndim:
        raise InputError(f"{path}: key {key!r} has shape {a.shape}, expected {shape_text}")
    with np.errstate(over="ignore", invalid="ignore"):  # overflow -> inf, reported by callers
        return a.astype(float, copy=False)


def validate_arrays(raw: dict[str, np.ndarray], path: Path) -> tuple[dict[str, np.ndarray], LoadReport]:
    for key in ("time_stamps", "features", "linear_velocity", "K", "b"):
        if key not in raw:
            raise InputError(f"{path}: missing key {key!r}")

    ts = check_time_stamps(raw, path)
    T = ts.size

    feats = _numeric(path, "features", raw["features"], "(4, M, T)", 3)
    if feats.shape[0] != 4:
        raise InputError(f"{path}: key 'features' has shape {feats.shape}, expected (4, M, T)")
    lin = _velocity(path, "linear_velocity", raw["linear_velocity"], T)
    ang = _angular_velocity(raw, path, T)
    if feats.shape[-1] != T:
        raise InputError(
            f"{path}: key 'features' has shape {feats.shape}: {feats.shape[-1]} steps, "
            f"but 'time_stamps' has {T}"
        )
    invalid = _scan_features(feats, path)

    K, b, cam_T_imu = check_calibration(raw, path)
    feats, report = _drop_invalid_observations(feats, invalid, path)

    return {
        "time_stamps": ts[None, :],
        "features": feats,
        "linear_velocity": lin,
        "rotational_velocity": ang,
        "K": K,
        "b": np.array(b),
        "cam_T_imu": cam_T_imu,
    }, report


def _check_finite(path: Path, key: str, a: np.ndarray) -> None:
    bad = ~np.isfinite(a)
    if bad.any():
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        raise InputError(f"{path}: key {key!r} has {int(bad.sum())} NaN/inf value(s), "
                         f"first at index {idx}")


def _velocity(path: Path, key: str, a: np.ndarray, T: int) -> np.ndarray:
    """A validated (3, T) velocity array, finite."""
    a = _numeric(path, key, a, "(3, T)", 2)
    if a.shape[0] != 3:
        raise InputError(f"{path}: key {key!r} has shape {a.shape}, expected (3, T)")
    if a.shape[-1] != T:
        raise InputError(
            f"{path}: key {key!r} has shape {a.shape}: {a.shape[-1]} steps, "
            f"but 'time_stamps' has {T}"
        )
    _check_finite(path, key, a)
    big = np.abs(a) > MAX_VELOCITY
    if big.any():
        idx = tuple(int(i) for i in np.argwhere(big)[0])
        raise InputError(f"{path}: key {key!r} has {int(big.sum())} value(s) beyond "
                         f"{MAX_VELOCITY:g} in magnitude, first {a[idx]!r} at index {idx}: not a "
                         "velocity (m/s, rad/s)")
    return a


def _angular_velocity(raw: dict[str, np.ndarray], path: Path, T: int) -> np.ndarray:
    """The angular velocity from either edition's key; both present must agree."""
    present = [k for k in ANGULAR_KEYS if k in raw]
    if not present:
        raise InputError(f"{path}: missing key {' or '.join(repr(n) for n in ANGULAR_KEYS)}")
    if len(present) == 2 and raw[present[0]].shape != raw[present[1]].shape:
        raise InputError(
            f"{path}: keys {present[0]!r} and {present[1]!r} are both present (the two "
            f"editions' names) but have different shapes {raw[present[0]].shape} and "
            f"{raw[present[1]].shape}"
        )
    arrays = [_velocity(path, k, raw[k], T) for k in present]
    if len(arrays) == 2:
        diff = np.abs(arrays[0] - arrays[1])
        scale = max(1.0, float(np.max(np.abs(arrays[0]), initial=0.0)),
                    float(np.max(np.abs(arrays[1]), initial=0.0)))
        worst = float(np.max(diff, initial=0.0))
        if worst > VELOCITY_RTOL * scale:
            idx = tuple(int(i) for i in np.unravel_index(np.argmax(diff), diff.shape))
            raise InputError(
                f"{path}: keys {present[0]!r} and {present[1]!r} are both present (the two "
                f"editions' names) but disagree: largest difference {worst:.6g} rad/s at index "
                f"{idx}; keep one of them"
            )
    return arrays[0]


def _scan_features(feats: np.ndarray, path: Path) -> np.ndarray | None:
    """Check ``features`` (4, M, T) for NaN/inf and find its invalid observations (M, T), or
    None if there are none; a few tracks at a time, so that the 190 MB arrays of the shared
    drives are read once, from cache, for both checks."""
    invalid = None
    for j0 in range(0, feats.shape[1], _SCAN_TRACKS):
        block = feats[:, j0:j0 + _SCAN_TRACKS]
        if not np.isfinite(block).all():
            _check_finite(path, "features", feats)
        bad = np.any(block < 0, axis=0) & ~np.all(block == -1, axis=0)
        if bad.any():
            if invalid is None:
                invalid = np.zeros(feats.shape[1:], dtype=bool)
            invalid[j0:j0 + _SCAN_TRACKS] = bad
    return invalid


def _drop_invalid_observations(
    feats: np.ndarray, invalid: np.ndarray | None, path: Path
) -> tuple[np.ndarray, LoadReport]:
    """Set the ``invalid`` observations (see the module notes) to -1, count and log them."""
    if invalid is None:
        return feats, LoadReport()
    partial = invalid & np.any(feats == -1, axis=0)
    n_partial = int(partial.sum())
    n_negative = int(invalid.sum()) - n_partial
    j, t = (int(i) for i in np.argwhere(invalid)[0])
    if not feats.flags.writeable:
        feats = feats.copy()
    feats[:, invalid] = -1.0
    report = LoadReport(n_partial=n_partial, n_negative=n_negative, first_invalid=(j, t))
    log.warning(
        "%s: key 'features': %d observation(s) treated as unobserved: %d partial (one to three "
        "of uL, vL, uR, vR are -1, the others not) and %d with another negative coordinate; "
        "the first at track %d, frame %d",
        path, report.n_invalid, n_partial, n_negative, j, t,
    )
    return feats, report


def check_time_stamps(raw: dict[str, np.ndarray], path: Path) -> np.ndarray:
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


def check_calibration(raw: dict[str, np.ndarray], path: Path) -> tuple[np.ndarray, float, np.ndarray]:
    """Validated ``K`` (3, 3), baseline ``b`` > 0 and ``cam_T_imu`` (from either edition;
    both present must agree)."""
    present = [k for k in TRANSFORM_KEYS if k in raw]
    if not present:
        raise InputError(f"{path}: missing key {' or '.join(repr(n) for n in TRANSFORM_KEYS)}")
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

    transforms = {}
    for tf_key in present:
        tf = _numeric(path, tf_key, raw[tf_key], "(4, 4)", raw[tf_key].ndim)
        if tf.shape != (4, 4):
            raise InputError(f"{path}: key {tf_key!r} has shape {tf.shape}, expected (4, 4)")
        with np.errstate(over="ignore", invalid="ignore"):
            rigid = bool(np.all(np.isfinite(tf))) and is_rigid(tf, tol=RIGID_TOL)
        if not rigid:
            raise InputError(f"{path}: key {tf_key!r} is not a rigid transform "
                             "(rotation not orthonormal with det +1, or last row not 0 0 0 1)")
        lever = float(np.max(np.abs(tf[:3, 3])))
        if lever > MAX_LEVER_ARM:
            raise InputError(f"{path}: key {tf_key!r} has a translation component of {lever:.4g} "
                             f"m (more than {MAX_LEVER_ARM:g} m between camera and IMU)")
        transforms[tf_key] = tf
    if len(transforms) == 2:
        a, b_key = TRANSFORM_KEYS
        diff = np.abs(transforms[b_key] - np.linalg.inv(transforms[a]))
        worst = float(diff.max())
        if not worst <= TRANSFORM_TOL:
            idx = tuple(int(i) for i in np.unravel_index(np.argmax(diff), diff.shape))
            raise InputError(
                f"{path}: keys {a!r} and {b_key!r} are both present (the two editions' "
                f"names) but {b_key!r} is not the inverse of {a!r}: largest difference "
                f"{worst:.6g} at index {idx}; keep one of them"
            )
    if "cam_T_imu" in transforms:
        cam_T_imu = transforms["cam_T_imu"]
    else:
        cam_T_imu = se3_inv(transforms["imu_T_cam"])

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
