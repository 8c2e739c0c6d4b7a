"""Trajectory files for other tools, and byte-reproducible ``.npz`` archives.

* TUM format (``evo``, the TUM RGB-D benchmark): one line per pose,
  ``timestamp tx ty tz qx qy qz qw`` (quaternion scalar last, as scipy's ``Rotation.as_quat``).
* KITTI odometry format: one line per pose, the 3x4 matrix ``[R | t]`` row-major (12 numbers).
* EuRoC CSV (:func:`read_euroc`, :func:`write_euroc`): ``timestamp [ns], p_x, p_y, p_z, q_w,
  q_x, q_y, q_z[, ...]`` (quaternion scalar first; EuRoC's ground truth, OpenVINS).
* Checked readers for files made by other tools (:func:`read_tum_checked`,
  :func:`read_kitti_checked`, :func:`read_euroc`): every fault a one-line InputError naming the
  file and line (pose covariances: :mod:`eval.covariance_files`).
  :func:`read_tum` and :func:`read_kitti` stay the plain readers they were.
* :func:`save_npz_reproducible`: ``numpy.savez_compressed`` stamps every zip member with the
  current time, so writing the same arrays twice gives different bytes; this writer fixes the
  member time and compression level so the same arrays always give the same file.

Every writer is atomic: it writes a temporary file next to the target and renames it.
"""

from __future__ import annotations

import io
import os
import tempfile
import zipfile
from pathlib import Path
from typing import Callable, Mapping

import numpy as np
from scipy.spatial.transform import Rotation

from vislam.ekf.errors import InputError

#: Number format of the text writers: 17 significant digits round-trip a float64 exactly.
FLOAT_FORMAT = "%.17g"
#: The fixed modification time of every member of a reproducible archive (the zip epoch).
_ZIP_EPOCH = (1980, 1, 1, 0, 0, 0)


def atomic_write(path: str | os.PathLike, write: Callable[[io.BufferedWriter], None]) -> Path:
    """Call ``write(fh)`` on a temporary file in the target folder, then rename it to ``path``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            write(fh)
        os.chmod(tmp, 0o644)  # mkstemp makes 0600; outputs are ordinary readable files
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def save_npz_reproducible(
    path: str | os.PathLike, arrays: Mapping[str, np.ndarray], compress: bool = True, level: int = 1
) -> Path:
    """Write ``arrays`` as an ``.npz`` that ``numpy.load`` reads, byte-identical for equal input.

    Members are written in the given order, each with the zip epoch as its time stamp and
    deflate ``level`` (1 by default: the simulator's mostly -1 feature arrays compress to within
    30 % of level 6 in a third of the time), or stored when ``compress`` is false.
    """
    method = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED

    def write(fh) -> None:
        with zipfile.ZipFile(fh, mode="w", compression=method, allowZip64=True) as zf:
            for key, value in arrays.items():
                buf = io.BytesIO()
                np.lib.format.write_array(buf, np.asanyarray(value), allow_pickle=False)
                info = zipfile.ZipInfo(f"{key}.npy", date_time=_ZIP_EPOCH)
                info.compress_type = method
                info.external_attr = 0o600 << 16
                zf.writestr(info, buf.getvalue(), compress_type=method, compresslevel=level)

    return atomic_write(path, write)


def _check_poses(poses: np.ndarray, what: str) -> np.ndarray:
    poses = np.asarray(poses, dtype=float)
    if poses.ndim != 3 or poses.shape[1:] not in ((4, 4), (3, 4)):
        raise InputError(f"{what}: poses must have shape (T, 4, 4) or (T, 3, 4), got {poses.shape}")
    if not np.all(np.isfinite(poses)):
        raise InputError(f"{what}: poses contain non-finite values")
    return poses


def _write_text(path: str | os.PathLike, rows: np.ndarray) -> Path:
    def write(fh) -> None:
        np.savetxt(fh, rows, fmt=FLOAT_FORMAT, delimiter=" ")

    return atomic_write(path, write)


def write_tum(path: str | os.PathLike, timestamps: np.ndarray, poses: np.ndarray) -> Path:
    """Write poses (T, 4, 4) with their times (T,) as ``t tx ty tz qx qy qz qw`` lines."""
    poses = _check_poses(poses, str(path))
    timestamps = _times_for(path, timestamps, poses)
    quat = Rotation.from_matrix(poses[:, :3, :3]).as_quat()  # x, y, z, w
    rows = np.concatenate([timestamps[:, None], poses[:, :3, 3], quat], axis=1)
    return _write_text(path, rows)


def _times_for(path, timestamps, poses: np.ndarray) -> np.ndarray:
    """``timestamps`` as a flat float array, one per pose, or an InputError naming ``path``."""
    timestamps = np.asarray(timestamps, dtype=float).reshape(-1)
    if timestamps.size != poses.shape[0]:
        raise InputError(
            f"{path}: {timestamps.size} timestamps for {poses.shape[0]} poses; they must match"
        )
    return timestamps


def write_kitti(path: str | os.PathLike, poses: np.ndarray) -> Path:
    """Write poses (T, 4, 4) as KITTI lines: the 3x4 ``[R | t]`` row-major."""
    poses = _check_poses(poses, str(path))
    return _write_text(path, poses[:, :3, :4].reshape(-1, 12))


def _read_rows(path: str | os.PathLike, n_cols: int) -> np.ndarray:
    path = Path(path)
    try:
        rows = np.loadtxt(path, dtype=float, ndmin=2)
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc})") from exc
    except ValueError as exc:
        raise InputError(f"{path}: not a table of numbers ({exc})") from exc
    if rows.size == 0:
        return np.zeros((0, n_cols))
    if rows.shape[1] != n_cols:
        raise InputError(f"{path}: expected {n_cols} columns per line, got {rows.shape[1]}")
    return rows


def _to_4x4(top: np.ndarray) -> np.ndarray:
    out = np.zeros((top.shape[0], 4, 4))
    out[:, :3, :4] = top
    out[:, 3, 3] = 1.0
    return out


def read_tum(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Read a TUM file: times (T,) and poses (T, 4, 4)."""
    rows = _read_rows(path, 8)
    top = np.zeros((rows.shape[0], 3, 4))
    if rows.shape[0]:
        top[:, :, :3] = Rotation.from_quat(rows[:, 4:8]).as_matrix()
    top[:, :, 3] = rows[:, 1:4]
    return rows[:, 0].copy(), _to_4x4(top)


def read_kitti(path: str | os.PathLike) -> np.ndarray:
    """Read a KITTI pose file (12 columns): poses (T, 4, 4)."""
    rows = _read_rows(path, 12)
    return _to_4x4(rows.reshape(-1, 3, 4))


# --- checked readers: trajectories and covariances made by other tools -------------------------
#
# The readers below check every line and raise a one-line InputError naming the file and the
# line (or entry) at the first fault. Lines that are blank or start with "#" are skipped.
# Poses are ``world_T_body`` (T, 4, 4); times in seconds.

#: Largest text file read by the checked readers (about a million TUM lines is 100 MB).
MAX_TEXT_BYTES = 256 * 2**20
#: How far a quaternion's norm may be from 1 (files written with 4 or more digits); a
#: quaternion within it is normalised, one beyond it is an error.
QUATERNION_NORM_TOL = 1e-3
#: Orthonormality tolerance of a KITTI line's rotation (files carry ~7 digits).
ROTATION_TOL = 1e-4
#: Largest translation accepted in a pose line, m (larger values are not metres).
MAX_TRANSLATION = 1e7

_TUM_COLUMNS = "t x y z qx qy qz qw"
_EUROC_COLUMNS = "timestamp [ns], p_x, p_y, p_z, q_w, q_x, q_y, q_z"


def text_lines(path: str | os.PathLike, what: str, delimiter: str | None = None):
    """(line number, fields) of every line of the text file ``path`` that is neither blank nor
    a ``#`` comment; fields split at ``delimiter`` (whitespace when None) and stripped."""
    from vislam.eval.safe_reading import read_text

    path = Path(path)
    text = read_text(path, what, MAX_TEXT_BYTES)
    for number, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        if delimiter is None:
            fields = stripped.split()
        else:
            fields = [f.strip() for f in stripped.split(delimiter)]
            if fields and fields[-1] == "":  # a trailing delimiter
                fields.pop()
        yield number, fields


def _numbers(path, number: int, fields: list[str]) -> list[float]:
    """The fields of line ``number`` as finite floats; InputError naming the bad value."""
    values = []
    for f in fields:
        try:
            x = float(f)
        except ValueError:
            raise InputError(f"{path}: line {number}: not a number: {f[:40]!r}") from None
        if not np.isfinite(x):
            raise InputError(f"{path}: line {number}: {f!r} is not a finite number")
        values.append(x)
    return values


def _column_error(path, number: int, got: int, expected: str, hint: str = "") -> InputError:
    return InputError(f"{path}: line {number} has {got} columns, expected {expected}{hint}")


def check_increasing(path, what: str, stamps: np.ndarray, lines: np.ndarray,
                     column: str = "time stamp") -> None:
    """Stamps strictly increasing: the first duplicate, step back or non-number is named by
    its line, its value and the line before it (every text reader of stamped rows uses this
    rule: ASL, eqvio, TUM and covariance files)."""
    steps = np.diff(stamps)
    bad = np.flatnonzero(~(steps > 0))
    if bad.size:
        i = int(bad[0])
        kind = "duplicates" if steps[i] == 0 else "is earlier than" if steps[i] < 0 else "is not after"
        raise InputError(f"{path}: line {int(lines[i + 1])}: {column} {stamps[i + 1]!r} {kind} "
                         f"the one on line {int(lines[i])} ({stamps[i]!r}) ({what}; stamps must "
                         "be strictly increasing)")


def _numeric_lines(path, what: str, n_cols: int, expected: str, hint=None, empty: str = "no pose lines"
                   ) -> tuple[np.ndarray, np.ndarray]:
    """The numbers (N, n_cols) of the data lines of the text file ``path`` (a ``what``) and
    their line numbers (N,); a line of another width is an InputError saying ``expected``
    (and ``hint(fields)``), a file without data lines one saying it has ``empty``."""
    rows, lines = [], []
    for number, fields in text_lines(path, what):
        if len(fields) != n_cols:
            raise _column_error(path, number, len(fields), expected,
                                hint(fields) if hint else "")
        rows.append(_numbers(path, number, fields))
        lines.append(number)
    if not rows:
        raise InputError(f"{path}: {what} has {empty}")
    return np.asarray(rows), np.asarray(lines, dtype=np.int64)


def _check_translations(path, t: np.ndarray, lines: np.ndarray) -> None:
    big = np.flatnonzero(np.max(np.abs(t), axis=1) > MAX_TRANSLATION)
    if big.size:
        i = int(big[0])
        raise InputError(f"{path}: line {int(lines[i])}: translation "
                         f"{float(np.max(np.abs(t[i]))):.6g} m is beyond {MAX_TRANSLATION:g} m "
                         "(not metres?)")


def quaternion_rotations(path, q_xyzw: np.ndarray, lines: np.ndarray) -> np.ndarray:
    """Rotation matrices (N, 3, 3) of quaternions (N, 4) in scalar-last order, each normalised;
    a zero quaternion or one whose norm is more than :data:`QUATERNION_NORM_TOL` from 1 is an
    InputError naming its line."""
    q = np.asarray(q_xyzw, dtype=float).reshape(-1, 4)
    norm = np.linalg.norm(q, axis=1)
    bad = np.flatnonzero(~(np.abs(norm - 1.0) <= QUATERNION_NORM_TOL))
    if bad.size:
        i = int(bad[0])
        what = ("zero quaternion" if norm[i] == 0 else
                f"quaternion of norm {norm[i]:.6g}, not a unit quaternion")
        raise InputError(f"{path}: line {int(lines[i])}: {what} (norm must be 1 within "
                         f"{QUATERNION_NORM_TOL:g})")
    if q.shape[0] == 0:
        return np.zeros((0, 3, 3))
    return Rotation.from_quat(q / norm[:, None]).as_matrix()


def _poses_from(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    out = np.tile(np.eye(4), (R.shape[0], 1, 1))
    out[:, :3, :3] = R
    out[:, :3, 3] = t
    return out


def read_tum_checked(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A TUM trajectory ``t x y z qx qy qz qw`` (what :func:`write_tum` and evo write), every
    line checked: times (T,) strictly increasing, poses (T, 4, 4) and the line numbers (T,).
    Unlike :func:`read_tum`, every fault is a one-line InputError naming the line."""
    def hint(fields):
        return ("; a KITTI pose file? give --format kitti" if len(fields) == 12 else
                "; an EuRoC CSV file? give --format euroc" if "," in fields[0] else "")

    data, lines = _numeric_lines(path, "TUM trajectory file", 8, f"8 ({_TUM_COLUMNS})", hint)
    check_increasing(path, "TUM trajectory file", data[:, 0], lines)
    _check_translations(path, data[:, 1:4], lines)
    R = quaternion_rotations(path, data[:, 4:8], lines)
    return data[:, 0].copy(), _poses_from(R, data[:, 1:4]), lines


def read_kitti_checked(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """A KITTI pose file (12 numbers per line, the 3x4 ``[R | t]`` row-major, no times), every
    line checked (12 columns, finite, the rotation orthonormal with determinant +1 within
    :data:`ROTATION_TOL`): poses (T, 4, 4) and line numbers (T,)."""
    from vislam.ekf.geometry import is_rigid

    rows, lines = _numeric_lines(
        path, "KITTI pose file", 12, "12 (the 3x4 pose, row-major)",
        lambda fields: "; a TUM file? give --format tum" if len(fields) == 8 else "")
    poses = _to_4x4(rows.reshape(-1, 3, 4))
    _check_translations(path, poses[:, :3, 3], lines)
    for i in range(poses.shape[0]):
        if not is_rigid(poses[i], tol=ROTATION_TOL):
            raise InputError(f"{path}: line {int(lines[i])}: the rotation is not orthonormal "
                             "with determinant +1")
    return poses, lines


def read_euroc(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An EuRoC-style CSV trajectory (EuRoC's state ground truth, OpenVINS and others):
    ``timestamp [ns], p_x, p_y, p_z, q_w, q_x, q_y, q_z[, ...]`` (times in nanoseconds,
    quaternion scalar first; further columns, e.g. velocities and biases, are ignored; lines
    starting with ``#`` are headers). Returns times in seconds (T,) strictly increasing, poses
    (T, 4, 4) and line numbers (T,); every fault is a one-line InputError naming the line."""
    times, poses, lines, _ = read_euroc_state(path)
    return times, poses, lines


def read_euroc_state(path: str | os.PathLike
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """:func:`read_euroc` and, where every line has the 17 columns of EuRoC's state ground
    truth (and OpenVINS's), the state (T, 9): velocity ``v_x, v_y, v_z`` (m/s, world frame),
    gyro bias ``b_w`` (rad/s) and accelerometer bias ``b_a`` (m/s^2); else None."""
    times, rows, lines = [], [], []
    widths = set()
    for number, fields in text_lines(path, "EuRoC CSV file", delimiter=","):
        if len(fields) < 8:
            hint = "; a TUM file? give --format tum" if len(fields) == 1 else ""
            raise _column_error(path, number, len(fields), f"at least 8 ({_EUROC_COLUMNS})", hint)
        stamp = fields[0]
        try:
            t = int(stamp) / 10**9  # integer nanoseconds: exact division, correctly rounded
        except ValueError:
            t = _numbers(path, number, [stamp])[0] / 1e9
        width = 17 if len(fields) >= 17 else 8
        widths.add(width)
        rows.append(_numbers(path, number, fields[1:width]) + [np.nan] * (17 - width))
        times.append(t)
        lines.append(number)
    if not rows:
        raise InputError(f"{path}: EuRoC CSV file has no pose lines")
    data, lines = np.asarray(rows), np.asarray(lines, dtype=np.int64)
    times = np.asarray(times, dtype=float)
    check_increasing(path, "EuRoC/ASL trajectory file", times, lines)
    _check_translations(path, data[:, 0:3], lines)
    R = quaternion_rotations(path, data[:, [4, 5, 6, 3]], lines)  # w x y z -> x y z w
    state = data[:, 7:16].copy() if widths == {17} else None
    return times, _poses_from(R, data[:, 0:3]), lines, state


def write_euroc(path: str | os.PathLike, timestamps: np.ndarray, poses: np.ndarray,
                state: np.ndarray | None = None) -> Path:
    """Write poses (T, 4, 4) with their times (T,, seconds) as an EuRoC CSV (header line, then
    ``timestamp [ns], p_x, p_y, p_z, q_w, q_x, q_y, q_z``; times rounded to whole ns), and with
    ``state`` (T, 9) the 17 columns of EuRoC's state ground truth (velocity, gyro bias,
    accelerometer bias: :func:`read_euroc_state`)."""
    poses = _check_poses(poses, str(path))
    timestamps = _times_for(path, timestamps, poses)
    q = Rotation.from_matrix(poses[:, :3, :3]).as_quat()
    q *= np.where(q[:, 3:] < 0, -1.0, 1.0)  # the same rotation, written with q_w >= 0
    header = "#timestamp [ns],p_x [m],p_y [m],p_z [m],q_w [],q_x [],q_y [],q_z []"
    if state is not None:
        state = np.asarray(state, dtype=float).reshape(poses.shape[0], 9)
        header += (",v_x [m s^-1],v_y [m s^-1],v_z [m s^-1],b_w_x [rad s^-1],b_w_y [rad s^-1],"
                   "b_w_z [rad s^-1],b_a_x [m s^-2],b_a_y [m s^-2],b_a_z [m s^-2]")
    lines = [header]
    for i, (t, p, qq) in enumerate(zip(timestamps, poses[:, :3, 3], q)):
        numbers = [*p, qq[3], qq[0], qq[1], qq[2]] + ([] if state is None else list(state[i]))
        lines.append(",".join([str(round(t * 1e9))] + [repr(float(x)) for x in numbers]))
    text = "\n".join(lines) + "\n"
    return atomic_write(path, lambda fh: fh.write(text.encode()))
