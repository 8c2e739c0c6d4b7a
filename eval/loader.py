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
and counts them in its report.

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
    validate_arrays,
)
from vislam.eval.safe_reading import read_npz



def load_sequence(path: str | os.PathLike, clean: bool = False) -> Sequence:
    """Read and validate one drive. ``clean=True`` also applies
    :func:`ekf.cleaning.clean_sequence` with its defaults (the cleaning report is logged)."""
    return load_sequence_with_report(path, clean=clean)[0]


def load_sequence_with_report(
    path: str | os.PathLike, clean: bool = False
) -> tuple[Sequence, LoadReport]:
    """:func:`load_sequence` and the :class:`LoadReport` of the observations it dropped."""
    path = Path(path)
    arrays, report = _read_validated(path)
    seq = sequence_from_arrays(arrays, name=path.stem, source=str(path))
    if clean:
        from vislam.ekf.cleaning import clean_sequence

        seq, _ = clean_sequence(seq)
    return seq, report


def read_arrays(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Validated arrays in edition-1 layout (keys as written by :func:`write_npz`); invalid
    observations are set to -1 (unobserved), as in :func:`load_sequence`."""
    return _read_validated(Path(path))[0]


def _read_validated(path: Path) -> tuple[dict[str, np.ndarray], LoadReport]:
    return validate_arrays(read_npz(path, KNOWN_KEYS), path)


def read_calibration(path: str | os.PathLike) -> tuple[Calibration, int]:
    """The calibration and number of frames of a drive, reading only the small keys (the
    feature array is never decompressed). Faults as in :func:`read_arrays`."""
    path = Path(path)
    raw = read_npz(path, ("time_stamps", "K", "b") + TRANSFORM_KEYS)
    for key in ("time_stamps", "K", "b"):
        if key not in raw:
            raise InputError(f"{path}: missing key {key!r}")
    ts = check_time_stamps(raw, path)
    K, b, cam_T_imu = check_calibration(raw, path)
    return Calibration(K=K, baseline=b, cam_T_imu=cam_T_imu), int(ts.size)


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
