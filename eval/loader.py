"""Read and write drives in the data format of ``data/kitti-pr3`` (see its README), with the
observations in either of two layouts.

File layout (edition 1; :func:`write_npz` writes either observation layout, :func:`save_sequence`
and the simulator the sparse one):

=====================  ==========  ==============================================
key                    shape       meaning
=====================  ==========  ==============================================
``time_stamps``        (1, T)      UNIX time, s, strictly increasing
``linear_velocity``    (3, T)      m/s, IMU body frame
``rotational_velocity`` (3, T)     rad/s, IMU body frame
``K``                  (3, 3)      left intrinsics
``b``                  ()          stereo baseline, m (optional for monocular tracks)
``cam_T_imu``          (4, 4)      ``p_cam = cam_T_imu @ p_imu``
=====================  ==========  ==============================================

and the observations, dense (the published files) **or** sparse, never both:

=====================  ==========  ==============================================
key                    shape       meaning
=====================  ==========  ==============================================
``features``           (4, M, T)   dense: ``[uL, vL, uR, vR]``; all four -1 where unobserved
``obs_frame``          (N,)        sparse: frame index of each observation, 0 to T-1
``obs_track``          (N,)        sparse: track id, a non-negative integer
``obs_pixels``         (N, 4)      sparse: ``[uL, vL, uR, vR]``, or (N, 2) monocular ``[u, v]``
``n_tracks``           ()          sparse, optional: number of track ids (default largest + 1)
=====================  ==========  ==============================================

The dense array takes 32 bytes per track and frame whether observed or not (6.2 GiB for a
4,800-frame simulated drive); the sparse rows take 48 bytes per observation. Sparse rows may
come in any order: the loader sorts them by frame, then track. Track ids are kept as given
(the track index of every output); ids need not be contiguous, but every id below the largest
gets per-track arrays, so ids count against ``VISLAM_MAX_ARRAY_BYTES`` like the dense array
does (72 bytes an id). The frame and track columns take any integer dtype, or floats of
integer value. A sparse file is refused, naming the key, the row and the value, for a frame
index out of range, a negative or non-integer frame or track id, a (frame, track) pair given
twice, NaN/inf pixels, a column count other than 4 or 2, or columns of different lengths; a
file with both ``features`` and a sparse key, or with only part of the sparse keys, is refused
too. Monocular tracks (two columns) are read, and ``b`` may then be left out (the calibration's
baseline is NaN), but :func:`load_sequence` refuses them unless ``monocular=True``: every
estimator of today is stereo (`vislam inspect` reads them).

The other published edition names the angular velocity ``angular_velocity`` and stores the
inverse transform ``imu_T_cam``; both load to identical :class:`~ekf.sequence.Sequence` objects,
and so do a drive's dense and sparse files.
Unknown keys are ignored (their members are never decompressed). Every fault raises
:class:`~ekf.errors.InputError` naming the file, the key and what is wrong.

Hostile or damaged files
------------------------
Members are read by :mod:`eval.safe_reading`, not by ``numpy.load``: each member's ``.npy`` header
is parsed and checked against the zip directory **before** any array is allocated. A member is
refused when

* its header is malformed, or it is not a ``.npy`` array at all;
* it holds Python objects (pickles are never loaded), a structured, complex, string or other
  non-numeric dtype;
* the data its header declares (shape x item size) is not exactly the data the member holds
  (a truncated member, a huge declared shape, trailing bytes);
* it is compressed other than stored or deflate (what ``numpy.savez`` writes), or its
  uncompressed size exceeds what deflate can give from its compressed size
  (:data:`eval.safe_reading.MAX_DEFLATE_RATIO`; a zip bomb);
* it is larger than :data:`eval.safe_reading.MAX_ARRAY_BYTES` once converted to float64 (4 GiB by default;
  the environment variable ``VISLAM_MAX_ARRAY_BYTES`` sets another limit in bytes).

A key stored twice (``K.npy`` twice, or ``K`` and ``K.npy``) is an error: there is no telling
which one is meant. Big-endian, Fortran-ordered, integer, boolean, float16/32 and long double
arrays are accepted and converted to float64 (values that overflow become inf, which the
finiteness checks then report).

Observations
------------
Pixel coordinates are positions in the image, so they are never negative; -1 in all four rows
is the "not observed" marker. An observation is valid only when all four coordinates are
>= 0. Invalid ones, partial (one to three coordinates -1) or with another negative coordinate
(e.g. -5), are treated as unobserved: they are dropped, counted in the :class:`LoadReport` that
:func:`load_sequence_with_report` returns (``vislam inspect`` prints the count), and logged
as one warning with their count and the first (track, frame). Dropping rather than refusing
keeps the rest of such a file usable; the warning keeps it from being silent. Non-positive or
tiny disparities (``uR >= uL``) are valid observations here: :mod:`ekf.cleaning` rejects them
and counts them in its report. The sparse layout follows the same rule row by row: a row of
all -1 is no observation (dropped silently, as the dense marker), a row with some -1 (e.g. a
missing right pixel) or another negative coordinate is dropped and counted (for monocular rows,
"partial" is one of ``u, v`` -1).

Both editions' keys in one file
-------------------------------
If both ``rotational_velocity`` and ``angular_velocity`` are present, or both ``cam_T_imu`` and
``imu_T_cam``, they must agree (velocities within :data:`eval.drive_keys.VELOCITY_RTOL` relative to the
largest value, ``imu_T_cam`` the inverse of ``cam_T_imu`` within :data:`eval.drive_keys.TRANSFORM_TOL`); then
the edition-1 key is used. If they disagree the file is refused, naming both keys and the
largest difference.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from vislam.ekf.errors import InputError
from vislam.ekf.sequence import Calibration, Observations, Sequence
from vislam.eval.drive_keys import (
    KNOWN_KEYS,
    TRANSFORM_KEYS,
    LoadReport,
    check_calibration,
    check_time_stamps,
    is_monocular,
    validate_arrays,
)
from vislam.eval.safe_reading import read_npz


def load_sequence(path: str | os.PathLike, clean: bool = False, *,
                  monocular: bool = False) -> Sequence:
    """Read and validate one drive. ``clean=True`` also applies
    :func:`ekf.cleaning.clean_sequence` with its defaults (the cleaning report is logged).
    A drive of monocular tracks is an :class:`InputError` unless ``monocular=True`` (today's
    estimators are stereo; cleaning needs stereo pixels)."""
    return load_sequence_with_report(path, clean=clean, monocular=monocular)[0]


def load_sequence_with_report(
    path: str | os.PathLike, clean: bool = False, *, monocular: bool = False
) -> tuple[Sequence, LoadReport]:
    """:func:`load_sequence` and the :class:`LoadReport` of the observations it dropped."""
    path = Path(path)
    arrays, report = _read_validated(path)
    seq = sequence_from_arrays(arrays, name=path.stem, source=str(path))
    if not monocular:
        require_stereo(seq, path)
    if clean:
        from vislam.ekf.cleaning import clean_sequence

        seq, _ = clean_sequence(seq)
    return seq, report


def require_stereo(seq: Sequence, path: str | os.PathLike) -> None:
    """Refuse a drive of monocular tracks (read from ``path``): every estimator of today is
    stereo."""
    if not seq.obs.is_stereo:
        raise InputError(
            f"{path}: key 'obs_pixels' holds monocular tracks (two columns [u, v]); vislam's "
            "estimators are stereo: monocular tracks need a raw-IMU estimator (issues 37-38). "
            "`vislam inspect` reads the file")


def read_arrays(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Validated arrays in edition-1 layout (keys as written by :func:`write_npz`): the
    observations as the file holds them, ``features`` (dense; invalid observations set to -1,
    unobserved) or ``obs_frame``, ``obs_track``, ``obs_pixels`` and ``n_tracks`` (sparse; rows
    sorted by frame then track, invalid rows dropped), as in :func:`load_sequence`."""
    return _read_validated(Path(path))[0]


def _read_validated(path: Path) -> tuple[dict[str, np.ndarray], LoadReport]:
    return validate_arrays(read_npz(path, KNOWN_KEYS), path)


def read_calibration(path: str | os.PathLike) -> tuple[Calibration, int]:
    """The calibration and number of frames of a drive, reading only the small keys (the
    observations are never decompressed, except a file without ``b``'s ``obs_pixels``, to
    tell a monocular drive, whose baseline is NaN). Faults as in :func:`read_arrays`."""
    path = Path(path)
    raw = read_npz(path, ("time_stamps", "K", "b") + TRANSFORM_KEYS)
    for key in ("time_stamps", "K"):
        if key not in raw:
            raise InputError(f"{path}: missing key {key!r}")
    if "b" not in raw and not is_monocular(read_npz(path, ("obs_pixels",))):
        raise InputError(f"{path}: missing key 'b'")
    ts = check_time_stamps(raw, path)
    K, b, cam_T_imu = check_calibration(raw, path)
    return Calibration(K=K, baseline=b, cam_T_imu=cam_T_imu), int(ts.size)


def sequence_from_arrays(
    arrays: dict[str, np.ndarray], name: str, source: str | None = None
) -> Sequence:
    """Build a :class:`Sequence` from validated edition-1 arrays of either observation layout
    (see :func:`read_arrays`)."""
    ts = np.ascontiguousarray(arrays["time_stamps"].reshape(-1))
    if "features" in arrays:
        feats = arrays["features"]
        obs, n_tracks = Observations.from_dense(feats), int(feats.shape[1])
    else:
        obs = Observations.from_rows(arrays["obs_frame"], arrays["obs_track"],
                                     arrays["obs_pixels"], ts.size)
        n_tracks = int(arrays["n_tracks"])
    return Sequence(
        name=name,
        timestamps=ts,
        linear_velocity=np.ascontiguousarray(arrays["linear_velocity"].T),
        angular_velocity=np.ascontiguousarray(arrays["rotational_velocity"].T),
        obs=obs,
        n_tracks=n_tracks,
        calibration=Calibration(
            K=arrays["K"], baseline=float(arrays["b"]), cam_T_imu=arrays["cam_T_imu"]
        ),
        source=source,
    )


def sparse_arrays(obs: Observations, n_tracks: int) -> dict[str, np.ndarray]:
    """The sparse layout's keys of ``obs`` (rows in frame, then track order): ``obs_frame``,
    ``obs_track`` (int64), ``obs_pixels`` (float64, four or two columns) and ``n_tracks``."""
    return {
        "obs_frame": obs.frame_index.astype(np.int64),
        "obs_track": np.asarray(obs.track, dtype=np.int64),
        "obs_pixels": np.asarray(obs.z, dtype=float),
        "n_tracks": np.array(int(n_tracks), dtype=np.int64),
    }


def write_npz(
    path: str | os.PathLike,
    *,
    time_stamps: np.ndarray,
    features: np.ndarray | None = None,
    obs_frame: np.ndarray | None = None,
    obs_track: np.ndarray | None = None,
    obs_pixels: np.ndarray | None = None,
    n_tracks: int | None = None,
    linear_velocity: np.ndarray,
    angular_velocity: np.ndarray,
    K: np.ndarray,
    b: float | None,
    cam_T_imu: np.ndarray,
) -> None:
    """Write a drive in edition-1 layout, atomically (temporary file, then ``os.replace``).

    Shapes as in the file: ``time_stamps`` (1, T) (or (T,)), the observations either dense,
    ``features`` (4, M, T), or sparse, ``obs_frame`` (N,), ``obs_track`` (N,), ``obs_pixels``
    (N, 4) or (N, 2) and optionally ``n_tracks``; velocities (3, T), ``K`` (3, 3), ``b``
    scalar (None: no baseline, for monocular tracks), ``cam_T_imu`` (4, 4). The angular
    velocity is stored under the edition-1 key ``rotational_velocity``. Nothing is checked
    here: :func:`load_sequence` checks what it reads.
    """
    path = Path(path)
    sparse = {"obs_frame": obs_frame, "obs_track": obs_track, "obs_pixels": obs_pixels}
    given = [k for k, v in sparse.items() if v is not None]
    if (features is None) == (not given) or (given and len(given) != len(sparse)):
        raise ValueError("write_npz takes either features (dense) or all of obs_frame, "
                         "obs_track and obs_pixels (sparse)")
    if features is not None:
        observations = {"features": np.asarray(features, dtype=float)}
    else:
        observations = {
            "obs_frame": np.asarray(obs_frame, dtype=np.int64),
            "obs_track": np.asarray(obs_track, dtype=np.int64),
            "obs_pixels": np.asarray(obs_pixels, dtype=float),
        }
        if n_tracks is not None:
            observations["n_tracks"] = np.array(int(n_tracks), dtype=np.int64)
    arrays = {
        "time_stamps": np.asarray(time_stamps, dtype=float).reshape(1, -1),
        **observations,
        "linear_velocity": np.asarray(linear_velocity, dtype=float),
        "rotational_velocity": np.asarray(angular_velocity, dtype=float),
        "K": np.asarray(K, dtype=float),
        **({} if b is None else {"b": np.array(float(b))}),
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
    """Write ``seq`` in edition-1 layout with sparse observations (one row per observation,
    its track index as track id; see :func:`write_npz`). It loads back to the same sequence.

    Tracks split by cleaning are written as separate track ids; ``track_origin`` is not kept.
    A monocular sequence (NaN baseline) is written without ``b``.
    """
    cal = seq.calibration
    write_npz(
        path,
        time_stamps=seq.timestamps,
        **sparse_arrays(seq.obs, seq.n_tracks),
        linear_velocity=np.asarray(seq.linear_velocity).T,
        angular_velocity=np.asarray(seq.angular_velocity).T,
        K=cal.K,
        b=None if np.isnan(cal.baseline) else cal.baseline,
        cam_T_imu=cal.cam_T_imu,
    )
