"""Ground-truth trajectories in the KITTI odometry pose format.

A pose file has one line per frame: 12 numbers ``r11 r12 r13 tx r21 r22 r23 ty r31 r32 r33 tz``
(the 3x4 pose ``P(k)`` of the left camera at frame k in the left-camera frame of frame 0), or
13 numbers with the time since the first frame in front. Line k belongs to frame k of the
drive; a file may cover fewer frames than the drive (0027: 1101 lines for 1106 frames), and
only the frames both have are scored.

The IMU poses, in the frame of the IMU at frame 0 (the world frame of every estimate), are

    T_imu(k) = inv(cam_T_imu) @ P(k) @ cam_T_imu.

The extrinsic is the data file's unless another is given (``cam_T_imu`` of
:func:`load_ground_truth` / :func:`find_ground_truth`, or :meth:`GroundTruth.with_extrinsic`,
e.g. an identified model's: ekf.model). A wrong extrinsic corrupts the IMU ground truth as much
as the estimate (the shared data's README), so every GroundTruth records the extrinsic it was
converted with (``cam_T_imu``) and where that came from (``extrinsic_source``: "file" or what
the caller names, e.g. "model").

For ``DIR/NAME.npz`` the ground truth is looked up at ``DIR/groundtruth/NAME.txt`` unless a
file is given explicitly (``--gt FILE``). Only a path with nothing there means "no ground
truth": a folder, a FIFO or device, a broken link, an unreadable file, a file that is not
UTF-8 text or is larger than :data:`MAX_GROUND_TRUTH_BYTES` at that path is an
:class:`~ekf.errors.InputError`, as for a file given explicitly.
"""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from vislam.ekf.errors import InputError
from vislam.ekf.geometry import is_rigid
from vislam.ekf.sequence import Calibration

#: Rigidity tolerance for the rotation part of a pose line (files carry ~7 digits).
RIGID_TOL = 1e-4
#: Largest pose file read (about a million poses; 0027's is 0.2 MB).
MAX_GROUND_TRUTH_BYTES = 256 * 2**20
#: Largest translation accepted in a pose line, m (far beyond any drive; larger values are
#: not metres, and overflow the conversion to IMU poses).
MAX_TRANSLATION = 1e7


@dataclass(frozen=True)
class GroundTruth:
    """``poses[i]`` is world_T_imu at frame ``frames[i]`` (world = IMU at frame 0);
    ``times`` (n,) the file's time column where it has one, else None; ``camera_poses``
    (n, 4, 4) the file's left-camera poses (orthonormalised) they were converted from;
    ``cam_T_imu`` the extrinsic of that conversion and ``extrinsic_source`` where it came from
    ("file": the data file's calibration)."""

    frames: np.ndarray
    poses: np.ndarray
    source: str
    times: np.ndarray | None = None
    camera_poses: np.ndarray | None = None
    cam_T_imu: np.ndarray | None = None
    extrinsic_source: str = "file"

    def with_extrinsic(self, cam_T_imu: np.ndarray, source: str = "model") -> "GroundTruth":
        """The same ground truth converted to IMU poses with another extrinsic ``cam_T_imu``
        (4x4), ``source`` naming it (recorded as ``extrinsic_source``)."""
        if self.camera_poses is None:
            raise InputError(f"{self.source}: ground truth without its camera poses cannot be "
                             "converted with another extrinsic")
        cam_T_imu = np.array(cam_T_imu, dtype=float)
        return replace(self, poses=_imu_poses(self.source, self.camera_poses, cam_T_imu),
                       cam_T_imu=cam_T_imu, extrinsic_source=str(source))

    @property
    def n(self) -> int:
        return int(self.frames.size)

    def covers(self, n_frames: int) -> str:
        """A short phrase like ``1101 of 1106 frames``."""
        return f"{self.n} of {n_frames} frames"


def read_kitti_poses(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray | None]:
    """Camera poses ``P`` (n, 4, 4) and the time column (n,) or None, from a 12- or
    13-column KITTI pose file. Faults raise :class:`InputError` naming file and line."""
    from vislam.eval.safe_reading import read_text

    path = Path(path)
    what = "ground-truth file"
    text = read_text(path, what, MAX_GROUND_TRUTH_BYTES,
                     f"{path}: {what} is larger than {MAX_GROUND_TRUTH_BYTES} bytes (about a "
                     "million poses); not a KITTI pose file?")
    rows: list[list[float]] = []
    line_numbers: list[int] = []
    width = None
    for number, line in enumerate(text.splitlines(), start=1):
        fields = line.split()
        if not fields or line.lstrip().startswith("#"):
            continue
        if len(fields) not in (12, 13):
            raise InputError(
                f"{path}: line {number} has {len(fields)} columns, expected 12 (3x4 pose) "
                "or 13 (time and 3x4 pose)"
            )
        if width is not None and len(fields) != width:
            raise InputError(
                f"{path}: line {number} has {len(fields)} columns, earlier lines {width}"
            )
        width = len(fields)
        try:
            values = [float(f) for f in fields]
        except ValueError:
            bad = next(f for f in fields if not _is_float(f))
            raise InputError(f"{path}: line {number}: non-numeric value {bad!r}") from None
        if not np.all(np.isfinite(values)):
            raise InputError(f"{path}: line {number}: NaN or infinite value")
        t = np.abs(values[-12:][3::4])
        if np.any(t > MAX_TRANSLATION):
            raise InputError(f"{path}: line {number}: translation {float(t.max()):.6g} m is "
                             f"beyond {MAX_TRANSLATION:g} m (not metres?)")
        rows.append(values)
        line_numbers.append(number)
    if not rows:
        raise InputError(f"{path}: ground-truth file has no pose lines")
    data = np.asarray(rows)
    times = data[:, 0] if width == 13 else None
    n = data.shape[0]
    P = np.tile(np.eye(4), (n, 1, 1))
    P[:, :3, :] = data[:, -12:].reshape(n, 3, 4)
    for i in range(n):
        with np.errstate(over="ignore", invalid="ignore"):  # 1e308 entries: not rigid
            rigid = is_rigid(P[i], tol=RIGID_TOL)
        if not rigid:
            raise InputError(
                f"{path}: line {line_numbers[i]}: the pose's rotation is not orthonormal "
                "with determinant +1"
            )
    return P, times


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def orthonormalise(P: np.ndarray) -> np.ndarray:
    """The nearest rotation (SVD) in each pose (n, 4, 4): files carry ~7 digits, so their
    rotations are orthonormal only to ~1e-7, which rigid inverses (transposes) would carry."""
    P = np.array(P, dtype=float)
    U, _, Vt = np.linalg.svd(P[:, :3, :3])
    D = np.ones((P.shape[0], 3))
    D[:, 2] = np.sign(np.linalg.det(U @ Vt))
    P[:, :3, :3] = (U * D[:, None, :]) @ Vt
    return P


def camera_to_imu_poses(P: np.ndarray, cam_T_imu: np.ndarray) -> np.ndarray:
    """``T_imu(k) = inv(cam_T_imu) @ P(k) @ cam_T_imu`` for camera poses P (n, 4, 4)."""
    # The general inverse, as the formula says: the files' cam_T_imu is orthonormal only to
    # ~1e-7, and a transpose-inverse would leave T_imu(0) that far from the identity.
    return np.linalg.inv(cam_T_imu) @ np.asarray(P, dtype=float) @ cam_T_imu


def imu_to_camera_poses(T_imu: np.ndarray, cam_T_imu: np.ndarray) -> np.ndarray:
    """Inverse of :func:`camera_to_imu_poses`: ``P(k) = cam_T_imu @ T_imu(k) @ inv(cam_T_imu)``."""
    return cam_T_imu @ np.asarray(T_imu, dtype=float) @ np.linalg.inv(cam_T_imu)


def load_ground_truth(
    path: str | os.PathLike, calibration: Calibration, n_frames: int,
    cam_T_imu: np.ndarray | None = None, extrinsic_source: str = "model",
) -> GroundTruth:
    """Read a KITTI pose file for a drive of ``n_frames`` frames and convert it to IMU poses
    with ``calibration.cam_T_imu`` (extrinsic source "file") or, when given, ``cam_T_imu``
    (extrinsic source ``extrinsic_source``).

    Line k is frame k; a file with more pose lines than the drive has frames is an error.
    """
    path = Path(path)
    P, times = read_kitti_poses(path)
    if P.shape[0] > n_frames:
        raise InputError(
            f"{path}: line {n_frames + 1}: {P.shape[0]} pose lines for a drive of "
            f"{n_frames} frames"
        )
    if cam_T_imu is None:
        extrinsic = np.array(calibration.cam_T_imu, dtype=float)
        extrinsic_source = "file"
    else:
        extrinsic = np.array(cam_T_imu, dtype=float)
    P = orthonormalise(P)
    return GroundTruth(
        frames=np.arange(P.shape[0], dtype=np.int64), poses=_imu_poses(path, P, extrinsic),
        source=str(path), times=times, camera_poses=P, cam_T_imu=extrinsic,
        extrinsic_source=str(extrinsic_source),
    )


def _imu_poses(path, P: np.ndarray, cam_T_imu: np.ndarray) -> np.ndarray:
    """IMU poses (n, 4, 4) in the IMU frame of frame 0 from camera poses P."""
    with np.errstate(over="ignore", invalid="ignore"):
        poses = camera_to_imu_poses(P, cam_T_imu)
        # World = IMU at frame 0 (a no-op for KITTI files, whose first pose is the identity).
        poses = np.linalg.inv(poses[0]) @ poses
    bad = ~np.all(np.isfinite(poses), axis=(1, 2))
    if bad.any():
        k = int(np.argmax(bad))
        raise InputError(f"{path}: pose {k} (frame {k}): its translation is too large to "
                         "convert to an IMU pose (overflow)")
    return poses


def ground_truth_path(npz_path: str | os.PathLike) -> Path:
    """Where the ground truth of ``DIR/NAME.npz`` is looked for: ``DIR/groundtruth/NAME.txt``."""
    npz_path = Path(npz_path)
    return npz_path.parent / "groundtruth" / f"{npz_path.stem}.txt"


def find_ground_truth(
    npz_path: str | os.PathLike,
    override: str | os.PathLike | None = None,
    calibration: Calibration | None = None,
    n_frames: int | None = None,
    cam_T_imu: np.ndarray | None = None,
    extrinsic_source: str = "model",
) -> GroundTruth | None:
    """The ground truth of a drive: ``override`` if given (it must exist), else
    ``DIR/groundtruth/NAME.txt`` if anything is there (it must be a readable pose file: a
    folder or an unreadable file there is an error, not "no ground truth"), else None.

    Calibration and frame count are read from the .npz unless given. The IMU poses are
    converted with the file's extrinsic, or with ``cam_T_imu`` when given (recorded with
    ``extrinsic_source``).
    """
    path = Path(override) if override is not None else ground_truth_path(npz_path)
    if override is None:
        try:
            os.lstat(path)
        except (FileNotFoundError, NotADirectoryError):
            return None
        except PermissionError:
            raise InputError(f"{path}: permission denied (cannot look up the ground-truth "
                             "file)") from None
        except (OSError, ValueError) as exc:
            raise InputError(f"{path}: cannot access the ground-truth file ({exc})") from None
    if calibration is None or n_frames is None:
        from vislam.eval.loader import read_calibration

        calibration, n_frames = read_calibration(npz_path)
    return load_ground_truth(path, calibration, n_frames, cam_T_imu=cam_T_imu,
                             extrinsic_source=extrinsic_source)


def write_kitti_poses(
    path: str | os.PathLike, poses_cam: np.ndarray, times: np.ndarray | None = None
) -> None:
    """Write camera poses (n, 4, 4) as a KITTI pose file, 13 columns with ``times`` (n,) in
    front, else 12; atomically (temporary file, then ``os.replace``)."""
    path = Path(path)
    P = np.asarray(poses_cam, dtype=float)
    if P.ndim != 3 or P.shape[1:] not in ((4, 4), (3, 4)):
        raise InputError(f"poses for {path} have shape {P.shape}, expected (n, 4, 4)")
    data = P[:, :3, :].reshape(P.shape[0], 12)
    if times is not None:
        times = np.asarray(times, dtype=float).reshape(-1)
        if times.size != P.shape[0]:
            raise InputError(f"{path}: {times.size} times for {P.shape[0]} poses")
        data = np.concatenate([times[:, None], data], axis=1)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=".txt.tmp")
    try:
        with os.fdopen(fd, "w") as fh:
            np.savetxt(fh, data, fmt="%.12g")
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
