"""What a drive's keys must hold, and the two published editions' names for them: the
validation of the arrays read from a drive's file (shapes, finiteness, strictly increasing
time stamps, rigid transforms, valid intrinsics, agreement of both editions' keys where a file
has both; the observations in the dense layout ``features`` or the sparse one ``obs_frame``,
``obs_track``, ``obs_pixels``) and the observations dropped as invalid (:class:`LoadReport`).
The layout and the rules: :mod:`eval.loader`'s docstring."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vislam.ekf.errors import InputError
from vislam.ekf.geometry import is_rigid, se3_inv
from vislam.eval.safe_reading import MAX_ARRAY_BYTES_ENV, max_array_bytes

#: The loader's warnings keep the loader's name (a user's logging set-up filters on it).
log = logging.getLogger("vislam.eval.loader")

#: Velocity key names, edition 1 first.
ANGULAR_KEYS = ("rotational_velocity", "angular_velocity")
#: Transform key names: edition 1 stores cam_T_imu, the other edition its inverse imu_T_cam.
TRANSFORM_KEYS = ("cam_T_imu", "imu_T_cam")
#: The dense layout's observation key: (4, M, T), -1 where unobserved.
DENSE_KEY = "features"
#: The sparse layout's keys, one row per observation: frame index (N,), track id (N,), pixels
#: (N, 4) stereo ``[uL, vL, uR, vR]`` or (N, 2) monocular ``[u, v]``.
SPARSE_KEYS = ("obs_frame", "obs_track", "obs_pixels")
#: The sparse layout's optional number of track ids (a scalar; default the largest id + 1).
N_TRACKS_KEY = "n_tracks"
#: Every key the loader reads; other members are ignored.
KNOWN_KEYS = (
    ("time_stamps", DENSE_KEY) + SPARSE_KEYS + (N_TRACKS_KEY, "linear_velocity", "K", "b")
    + ANGULAR_KEYS + TRANSFORM_KEYS
)
#: Pixel columns of the sparse layout's ``obs_pixels``: stereo and monocular.
STEREO_COLUMNS, MONO_COLUMNS = 4, 2
#: Bytes per track id of the largest per-track array the estimators hold (the landmark
#: covariances, (n_tracks, 3, 3) float64): the sparse layout's track ids are checked against
#: ``VISLAM_MAX_ARRAY_BYTES`` with it, as the dense layout's (4, M, T) array is.
BYTES_PER_TRACK = 9 * 8
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

    ``n_partial``: observations with some but not all coordinates -1 (one to three of the four
    stereo ones, one of the two monocular ones); ``n_negative``: the other observations with a
    negative coordinate; ``first_invalid``: (track, frame) of the first of either, in (track,
    frame) order, or None. The same for both layouts.
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


def observation_layout(raw: dict[str, np.ndarray], path: Path) -> str:
    """``"dense"`` (key ``features``) or ``"sparse"`` (keys ``obs_frame``, ``obs_track``,
    ``obs_pixels``, optionally ``n_tracks``); a file with both, with part of the sparse keys or
    with neither is an :class:`InputError`."""
    sparse = [k for k in SPARSE_KEYS + (N_TRACKS_KEY,) if k in raw]
    names = ", ".join(repr(k) for k in SPARSE_KEYS)
    if DENSE_KEY in raw:
        if sparse:
            given = ", ".join(repr(k) for k in sparse)
            raise InputError(f"{path}: holds both the dense key {DENSE_KEY!r} and the sparse "
                             f"key(s) {given}: a file holds one layout of the observations; "
                             "keep one of them")
        return "dense"
    if not sparse:
        raise InputError(f"{path}: missing key {DENSE_KEY!r} (the dense layout) or the keys "
                         f"{names} (the sparse layout): no observations")
    missing = [k for k in SPARSE_KEYS if k not in raw]
    if missing:
        raise InputError(f"{path}: the sparse layout needs the keys {names}; missing "
                         + ", ".join(repr(k) for k in missing))
    return "sparse"


def is_monocular(raw: dict[str, np.ndarray]) -> bool:
    """Whether read (unvalidated) arrays hold monocular tracks: ``obs_pixels`` of two columns."""
    pixels = raw.get("obs_pixels")
    return pixels is not None and pixels.ndim == 2 and pixels.shape[1] == MONO_COLUMNS


def validate_arrays(raw: dict[str, np.ndarray], path: Path) -> tuple[dict[str, np.ndarray], LoadReport]:
    """The validated arrays in edition-1 layout: the observations as the file holds them,
    ``features`` (dense) or ``obs_frame``, ``obs_track``, ``obs_pixels`` and ``n_tracks``
    (sparse; rows sorted by frame, then track, invalid rows dropped); and the
    :class:`LoadReport` of the dropped observations."""
    layout = observation_layout(raw, path)
    needed = ("time_stamps", "linear_velocity", "K") + (("b",) if not is_monocular(raw) else ())
    for key in needed:
        if key not in raw:
            raise InputError(f"{path}: missing key {key!r}")

    ts = check_time_stamps(raw, path)
    T = ts.size

    if layout == "sparse":
        lin = _velocity(path, "linear_velocity", raw["linear_velocity"], T)
        ang = _angular_velocity(raw, path, T)
        obs, report = validate_sparse(raw, path, T)
        K, b, cam_T_imu = check_calibration(raw, path)
        return {
            "time_stamps": ts[None, :],
            **obs,
            "linear_velocity": lin,
            "rotational_velocity": ang,
            "K": K,
            "b": np.array(b),
            "cam_T_imu": cam_T_imu,
        }, report

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


def validate_sparse(
    raw: dict[str, np.ndarray], path: Path, T: int, negative_is_invalid: bool = True
) -> tuple[dict[str, np.ndarray], LoadReport]:
    """The sparse layout's observations, checked: ``obs_frame`` (N,) integers in [0, T),
    ``obs_track`` (N,) non-negative integers, ``obs_pixels`` (N, 4) or (N, 2) finite, the three
    of one length, no (frame, track) pair twice, ``n_tracks`` (optional) an integer above every
    track id, and the per-track arrays within ``VISLAM_MAX_ARRAY_BYTES``. Every fault names the
    file, the key, the row and the value. Returns ``obs_frame``, ``obs_track`` (int64),
    ``obs_pixels`` (float64) sorted by (frame, track) with the invalid rows dropped (the dense
    layout's rule: :mod:`eval.loader`), ``n_tracks`` (an int64 scalar), and the
    :class:`LoadReport`. ``negative_is_invalid`` False keeps rows with negative pixels (tracks
    of an undistorted ideal pinhole, as raw-IMU drives may hold, reach outside the image)."""
    pixels = raw["obs_pixels"]
    if pixels.dtype.kind not in "biuf":
        raise InputError(f"{path}: key 'obs_pixels' has non-numeric dtype {pixels.dtype}")
    if pixels.ndim != 2 or pixels.shape[1] not in (STEREO_COLUMNS, MONO_COLUMNS):
        raise InputError(
            f"{path}: key 'obs_pixels' has shape {pixels.shape}, expected (N, 4) stereo pixels "
            "[uL, vL, uR, vR] or (N, 2) monocular pixels [u, v], one row per observation")
    frame = _id_column(path, "obs_frame", raw["obs_frame"], "frame index")
    track = _id_column(path, "obs_track", raw["obs_track"], "track id")
    lengths = {"obs_frame": frame.size, "obs_track": track.size, "obs_pixels": pixels.shape[0]}
    if len(set(lengths.values())) > 1:
        n = min(lengths.values())
        longer = [k for k, v in lengths.items() if v > n]
        raise InputError(
            f"{path}: keys " + ", ".join(f"{k!r} ({v} rows)" for k, v in lengths.items())
            + f" differ in length: row {n} is in {' and '.join(repr(k) for k in longer)} only; "
            "the sparse layout has one row per observation in each")
    if frame.size:
        beyond = frame >= T
        if beyond.any():
            r = int(np.argmax(beyond))
            raise InputError(f"{path}: key 'obs_frame' row {r}: frame index {frame[r].item()!r} "
                             f"is out of range: 'time_stamps' has {T} frames (0 to {T - 1})")
    limit = max_array_bytes(path)
    n_tracks = _n_tracks(raw, path, track, limit)
    frame = frame.astype(np.int64)
    track = track.astype(np.int64)
    with np.errstate(over="ignore", invalid="ignore"):  # overflow -> inf, reported below
        pixels = pixels.astype(float, copy=False)
    bad = ~np.isfinite(pixels)
    if bad.any():
        r, c = (int(i) for i in np.argwhere(bad)[0])
        raise InputError(f"{path}: key 'obs_pixels' row {r}, column {c}: value "
                         f"{pixels[r, c].item()!r} is not finite ({int(bad.any(axis=1).sum())} "
                         "row(s) with NaN/inf)")

    order = np.lexsort((track, frame))
    frame, track, pixels = frame[order], track[order], pixels[order]
    same = (frame[1:] == frame[:-1]) & (track[1:] == track[:-1])
    if same.any():
        k = int(np.argmax(same))
        r1, r2 = sorted((int(order[k]), int(order[k + 1])))
        raise InputError(f"{path}: keys 'obs_frame' and 'obs_track': rows {r1} and {r2} both "
                         f"observe track {int(track[k])} at frame {int(frame[k])}; a track has "
                         "at most one observation per frame")

    unobserved = np.all(pixels == -1, axis=1)  # the dense layout's marker: not an observation
    invalid = np.any(pixels < 0, axis=1) & ~unobserved
    if not negative_is_invalid:
        unobserved[:] = False
        invalid[:] = False
    report = LoadReport()
    if invalid.any():
        partial = invalid & np.any(pixels == -1, axis=1)
        n_partial = int(partial.sum())
        first = np.lexsort((frame[invalid], track[invalid]))[0]
        j, t = int(track[invalid][first]), int(frame[invalid][first])
        report = LoadReport(n_partial=n_partial, n_negative=int(invalid.sum()) - n_partial,
                            first_invalid=(j, t))
        coords = "uL, vL, uR, vR" if pixels.shape[1] == STEREO_COLUMNS else "u, v"
        log.warning(
            "%s: key 'obs_pixels': %d observation(s) treated as unobserved: %d partial (some "
            "but not all of %s are -1) and %d with another negative coordinate; the first at "
            "track %d, frame %d (file row %d)",
            path, report.n_invalid, n_partial, coords, report.n_negative, j, t,
            int(order[invalid][first]),
        )
    keep = ~(unobserved | invalid)
    if not keep.all():
        frame, track, pixels = frame[keep], track[keep], pixels[keep]
    return {"obs_frame": frame, "obs_track": track, "obs_pixels": pixels,
            "n_tracks": np.array(n_tracks, dtype=np.int64)}, report


def _id_column(path: Path, key: str, a: np.ndarray, what: str) -> np.ndarray:
    """A (N,) column of non-negative integers (integer dtype, or floats of integer value), in
    its own dtype; every fault names the row and the value."""
    if a.dtype.kind not in "iuf":
        raise InputError(f"{path}: key {key!r} has dtype {a.dtype}, expected integers "
                         f"(one {what} per observation)")
    if a.ndim != 1:
        raise InputError(f"{path}: key {key!r} has shape {a.shape}, expected (N,): one {what} "
                         "per observation")
    if a.dtype.kind == "f":
        with np.errstate(invalid="ignore"):
            bad = ~np.isfinite(a) | (a != np.floor(a))
        if bad.any():
            r = int(np.argmax(bad))
            raise InputError(f"{path}: key {key!r} row {r}: {what} {a[r].item()!r} is not an "
                             "integer")
    if a.dtype.kind != "u":
        negative = a < 0
        if negative.any():
            r = int(np.argmax(negative))
            raise InputError(f"{path}: key {key!r} row {r}: {what} {a[r].item()!r} is negative")
    return a


def _n_tracks(raw: dict[str, np.ndarray], path: Path, track: np.ndarray, limit: int) -> int:
    """The number of track ids: ``n_tracks`` where given (an integer above every id), the largest
    id + 1 otherwise; refused where the per-track arrays would pass ``limit`` bytes."""
    top, where = 0, f"{path}: key 'obs_track'"
    if track.size:
        r = int(np.argmax(track))
        top, where = int(track[r]) + 1, f"{where} row {r}: track id {track[r].item()!r} means"
    if N_TRACKS_KEY in raw:
        a = raw[N_TRACKS_KEY]
        value = a.reshape(()).item() if a.dtype.kind in "iuf" and a.size == 1 else None
        if not (isinstance(value, int) or (isinstance(value, float) and np.isfinite(value)
                                           and value == int(value))):
            raise InputError(f"{path}: key {N_TRACKS_KEY!r} (dtype {a.dtype}, shape {a.shape}"
                             f"{'' if value is None else f', value {value!r}'}) is not an "
                             "integer scalar (the number of track ids)")
        if int(value) < 0:
            raise InputError(f"{path}: key {N_TRACKS_KEY!r}: {int(value)} is negative")
        if int(value) < top:
            raise InputError(f"{path}: key {N_TRACKS_KEY!r}: {int(value)} track ids, but "
                             f"'obs_track' holds track id {top - 1} (row {r})")
        top, where = int(value), f"{path}: key {N_TRACKS_KEY!r}:"
    if top * BYTES_PER_TRACK > limit:
        raise InputError(f"{where} {top} track ids, whose per-track arrays ((n_tracks, 3, 3) "
                         f"float64) would take {top * BYTES_PER_TRACK} bytes, more than the "
                         f"limit of {limit} bytes (set {MAX_ARRAY_BYTES_ENV} to allow more)")
    return top


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
    """Validated ``K`` (3, 3), baseline ``b`` > 0 (NaN where the file has no ``b``: allowed for
    monocular drives only, which the callers check) and ``cam_T_imu`` (from either edition;
    both present must agree)."""
    present = [k for k in TRANSFORM_KEYS if k in raw]
    if not present:
        raise InputError(f"{path}: missing key {' or '.join(repr(n) for n in TRANSFORM_KEYS)}")
    K = _numeric(path, "K", raw["K"], "(3, 3)", raw["K"].ndim)
    if K.shape != (3, 3):
        raise InputError(f"{path}: key 'K' has shape {K.shape}, expected (3, 3)")
    _check_intrinsics(K, path)

    b = float("nan")  # no baseline: a monocular drive (the callers require 'b' otherwise)
    if "b" in raw:
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
