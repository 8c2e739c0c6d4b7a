"""Pose covariances made by other tools (``vislam score``): :func:`read_pose_covariances` reads a
vislam ``.estimate.npz``, a ``.npy`` (N, 6, 6) or text lines of ``t`` and 36 numbers, every
matrix checked (finite, symmetric, positive definite), every fault a one-line InputError naming
the file and the line or entry; :func:`write_covariances_text` writes the text form."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vislam.ekf.errors import InputError
from vislam.eval.export import _numeric_lines, _write_text, check_increasing

#: How far from symmetric a covariance may be, relative to sqrt(C_ii C_jj) (text with 7 digits).
SYMMETRY_TOL = 1e-6


@dataclass(frozen=True)
class PoseCovariances:
    """Pose covariances read from a file: ``cov`` (N, 6, 6) in vislam's convention (the
    covariance of ``xi = [rho; phi]``, translation first, m and rad, in a right perturbation
    ``world_T_body_true = world_T_body_est @ se3_exp(xi)``); ``times`` (N,) seconds, or None
    for a file without times (then entry i belongs to pose i of the trajectory);
    ``kind`` "estimate" (a vislam ``.estimate.npz``), "npy" or "text"; ``rows`` how each entry
    is named in messages ("line 7", "entry 3")."""

    path: str
    kind: str
    cov: np.ndarray
    times: np.ndarray | None
    rows: tuple[str, ...]


def read_pose_covariances(path: str | os.PathLike) -> PoseCovariances:
    """Pose covariances (see :class:`PoseCovariances` for the convention) from

    * a vislam estimate ``<estimator>.estimate.npz`` (``Estimate.save_npz``, as ``vislam
      bench`` and ``vislam run`` write it): its ``pose_cov`` with its ``timestamps``;
    * a ``.npy`` array (N, 6, 6), entry i for pose i of the trajectory (no times);
    * a text file, per line ``timestamp`` and the 36 numbers of the 6x6 matrix, row-major.

    Every matrix is checked: finite, symmetric (within :data:`SYMMETRY_TOL` relative) and
    positive definite (Cholesky); a fault is a one-line InputError naming the file and the
    line or entry. Text times must increase."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".npz":
        times, cov = _covariances_npz(path)
        rows = tuple(f"entry {i}" for i in range(cov.shape[0]))
        kind = "estimate"
    elif suffix == ".npy":
        cov, times = _covariances_npy(path), None
        rows = tuple(f"entry {i}" for i in range(cov.shape[0]))
        kind = "npy"
    else:
        times, cov, lines = _covariances_text(path)
        rows = tuple(f"line {n}" for n in lines)
        kind = "text"
    check_covariances(path, cov, rows)
    return PoseCovariances(str(path), kind, cov, times, rows)


def check_covariances(path, cov: np.ndarray, rows) -> None:
    """InputError naming ``path`` and the row (``rows[i]``) of the first 6x6 matrix of ``cov``
    that is not finite, not symmetric or not positive definite."""
    cov = np.asarray(cov, dtype=float)
    n = cov.shape[0]
    flat = cov.reshape(n, -1)
    bad = np.flatnonzero(~np.all(np.isfinite(flat), axis=1))
    if bad.size:
        raise InputError(f"{path}: {rows[int(bad[0])]}: covariance has a NaN or infinite value")
    d = np.sqrt(np.abs(np.einsum("nii->ni", cov)))
    scale = d[:, :, None] * d[:, None, :]
    asym = np.abs(cov - np.swapaxes(cov, 1, 2))
    bad = np.flatnonzero(np.any(asym > SYMMETRY_TOL * scale + 1e-300, axis=(1, 2)))
    if bad.size:
        i = int(bad[0])
        j, k = np.unravel_index(int(np.argmax(asym[i] - SYMMETRY_TOL * scale[i])), (6, 6))
        raise InputError(f"{path}: {rows[i]}: covariance is not symmetric (element ({j},{k}) "
                         f"{cov[i, j, k]:.6g}, ({k},{j}) {cov[i, k, j]:.6g})")
    for i in range(n):
        try:
            np.linalg.cholesky(0.5 * (cov[i] + cov[i].T))
        except np.linalg.LinAlgError:
            low = float(np.linalg.eigvalsh(0.5 * (cov[i] + cov[i].T))[0])
            raise InputError(f"{path}: {rows[i]}: covariance is not positive definite "
                             f"(smallest eigenvalue {low:.3g})") from None


def _covariances_npz(path: Path) -> tuple[np.ndarray, np.ndarray]:
    from vislam.eval.safe_reading import read_npz

    d = read_npz(path, ("pose_cov", "timestamps"))
    missing = [k for k in ("pose_cov", "timestamps") if k not in d]
    if missing:
        raise InputError(f"{path}: no {missing[0]!r} array; expected a vislam estimate file "
                         "(<estimator>.estimate.npz, written by vislam bench / vislam run)")
    cov, times = np.asarray(d["pose_cov"]), np.asarray(d["timestamps"])
    if cov.ndim != 3 or cov.shape[1:] != (6, 6) or times.shape != (cov.shape[0],):
        raise InputError(f"{path}: pose_cov has shape {cov.shape} and timestamps "
                         f"{times.shape}; expected (N, 6, 6) and (N,)")
    if not np.issubdtype(cov.dtype, np.number) or np.iscomplexobj(cov):
        raise InputError(f"{path}: pose_cov is of type {cov.dtype}, not real numbers")
    times = times.astype(float)
    if not np.all(np.isfinite(times)):
        raise InputError(f"{path}: timestamps hold a NaN or infinite value")
    bad = np.flatnonzero(~(np.diff(times) > 0))
    if bad.size:
        raise InputError(f"{path}: timestamps do not increase at entry {int(bad[0]) + 1}")
    return times, cov.astype(float)


def _covariances_npy(path: Path) -> np.ndarray:
    from vislam.eval.safe_reading import check_regular_file, max_array_bytes

    check_regular_file(path, ".npy file")
    limit = max_array_bytes(path)
    if os.path.getsize(path) > limit + 10000:
        raise InputError(f"{path}: larger than {limit} bytes; not a covariance array?")
    try:
        cov = np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        raise InputError(f"{path}: not a readable .npy array ({' '.join(str(exc).split())[:120]})") from None
    if not isinstance(cov, np.ndarray) or cov.ndim != 3 or cov.shape[1:] != (6, 6):
        raise InputError(f"{path}: array has shape {getattr(cov, 'shape', None)}; expected "
                         "(N, 6, 6), one 6x6 pose covariance per trajectory pose")
    if not np.issubdtype(cov.dtype, np.number) or np.iscomplexobj(cov):
        raise InputError(f"{path}: array is of type {cov.dtype}, not real numbers")
    return cov.astype(float)


def _covariances_text(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    data, lines = _numeric_lines(path, "covariance file", 37,
                                 "37 (timestamp and the 6x6 covariance, row-major)", empty="no lines")
    check_increasing(path, "covariance file", data[:, 0], lines)
    return data[:, 0].copy(), data[:, 1:].reshape(-1, 6, 6), lines


def write_covariances_text(path: str | os.PathLike, timestamps: np.ndarray, cov: np.ndarray) -> Path:
    """Write pose covariances (T, 6, 6) with their times (T,) as lines of ``t`` and the 36
    numbers row-major (what :func:`read_pose_covariances` reads)."""
    cov = np.asarray(cov, dtype=float)
    timestamps = np.asarray(timestamps, dtype=float).reshape(-1)
    if cov.ndim != 3 or cov.shape[1:] != (6, 6) or cov.shape[0] != timestamps.size:
        raise InputError(f"{path}: need (T, 6, 6) covariances and T times, got {cov.shape} "
                         f"and {timestamps.size}")
    return _write_text(path, np.concatenate([timestamps[:, None], cov.reshape(-1, 36)], axis=1))
