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
Members are read by :func:`_read_member`, not by ``numpy.load``: each member's ``.npy`` header
is parsed and checked against the zip directory **before** any array is allocated. A member is
refused when

* its header is malformed, or it is not a ``.npy`` array at all;
* it holds Python objects (pickles are never loaded), a structured, complex, string or other
  non-numeric dtype;
* the data its header declares (shape x item size) is not exactly the data the member holds
  (a truncated member, a huge declared shape, trailing bytes);
* it is compressed other than stored or deflate (what ``numpy.savez`` writes), or its
  uncompressed size exceeds what deflate can give from its compressed size
  (:data:`MAX_DEFLATE_RATIO`; a zip bomb);
* it is larger than :data:`MAX_ARRAY_BYTES` once converted to float64 (4 GiB by default;
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
``imu_T_cam``, they must agree (velocities within :data:`VELOCITY_RTOL` relative to the
largest value, ``imu_T_cam`` the inverse of ``cam_T_imu`` within :data:`TRANSFORM_TOL`); then
the edition-1 key is used. If they disagree the file is refused, naming both keys and the
largest difference.
"""

from __future__ import annotations

import logging
import math
import os
import stat
import struct
import tempfile
import tokenize
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vislam.ekf.errors import InputError
from vislam.ekf.geometry import is_rigid, se3_inv
from vislam.ekf.sequence import Calibration, Observations, Sequence

log = logging.getLogger(__name__)

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
#: Largest array accepted, in bytes once converted to float64 (the shared drives' largest,
#: 0034's features, is 189 MB). ``$VISLAM_MAX_ARRAY_BYTES`` overrides it.
MAX_ARRAY_BYTES = 4 * 2**30
#: Environment variable overriding :data:`MAX_ARRAY_BYTES`.
MAX_ARRAY_BYTES_ENV = "VISLAM_MAX_ARRAY_BYTES"
#: Deflate cannot expand its input by more than about 1032:1 (258 bytes per 2-bit code).
MAX_DEFLATE_RATIO = 1032
#: Largest .npy header accepted (numpy's own default).
MAX_HEADER_BYTES = 10000

#: Tracks per block when scanning the feature array.
_SCAN_TRACKS = 64

#: Exceptions numpy's and zipfile's readers raise on damaged or hostile input.
_READ_ERRORS = (
    OSError, EOFError, ValueError, TypeError, KeyError, IndexError, OverflowError,
    SyntaxError, RecursionError, tokenize.TokenError, struct.error, zlib.error,
    zipfile.BadZipFile, NotImplementedError, MemoryError,
)

#: Of those, the ones that mean damaged compressed data rather than a bad .npy header.
_ZIP_ERRORS = (OSError, EOFError, zlib.error, zipfile.BadZipFile, NotImplementedError)


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


def max_array_bytes(path: Path | None = None) -> int:
    """:data:`MAX_ARRAY_BYTES`, or ``$VISLAM_MAX_ARRAY_BYTES`` where set (a bad value is an
    :class:`InputError`, naming ``path``, the file being read, where given)."""
    text = os.environ.get(MAX_ARRAY_BYTES_ENV)
    if text is None or not text.strip():
        return MAX_ARRAY_BYTES
    try:
        value = int(text.strip().replace("_", ""))
    except ValueError:
        value = -1
    if value <= 0:
        where = f"{path}: " if path is not None else ""
        raise InputError(f"{where}environment variable {MAX_ARRAY_BYTES_ENV}: expected a positive "
                         f"number of bytes, got {text!r}")
    return value


def check_regular_file(path: Path, what: str = "file") -> None:
    """Raise :class:`InputError` unless ``path`` is an existing regular file (following
    links). Directories, FIFOs and devices are refused before anything opens them (a FIFO
    would block the reader forever)."""
    try:
        st = os.stat(path)
    except (FileNotFoundError, NotADirectoryError):
        if os.path.islink(path):
            raise InputError(f"{path}: {what} is a broken symbolic link") from None
        raise InputError(f"{path}: {what} does not exist") from None
    except PermissionError:
        raise InputError(f"{path}: permission denied (cannot look up the {what})") from None
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: cannot access the {what} ({_reason(exc)})") from None
    if stat.S_ISDIR(st.st_mode):
        raise InputError(f"{path}: is a directory, expected a {what}")
    if not stat.S_ISREG(st.st_mode):
        raise InputError(f"{path}: not a regular file (a FIFO, socket or device), "
                         f"expected a {what}")


def open_for_reading(path: Path, what: str = "file"):
    """``open(path, "rb")`` with a one-line :class:`InputError` (permission denied, ...)."""
    try:
        return open(path, "rb")
    except PermissionError:
        raise InputError(f"{path}: permission denied (cannot read the {what})") from None
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: cannot read the {what} ({_reason(exc)})") from None


def read_text(path: Path, what: str, max_bytes: int, too_large: str | None = None) -> str:
    """The UTF-8 text of the regular file ``path`` (a ``what``: named in every message), at
    most ``max_bytes`` long (``too_large`` the message beyond); a file that cannot be read, is
    too large or is not UTF-8 (the line of the first bad byte named) is an :class:`InputError`."""
    path = Path(path)
    check_regular_file(path, what)
    too_large = too_large or f"{path}: {what} is larger than {max_bytes} bytes; not a {what}?"
    with open_for_reading(path, what) as fh:
        try:
            size = os.fstat(fh.fileno()).st_size
            if size > max_bytes:
                raise InputError(too_large)
            data = fh.read(size + 1)  # read(n) allocates n bytes: never the limit itself
        except OSError as exc:
            raise InputError(f"{path}: cannot read the {what} ({_reason(exc)})") from None
    if len(data) > max_bytes:  # grown since fstat
        raise InputError(too_large)
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise InputError(f"{path}: line {line}: {what} is not UTF-8 text (byte "
                         f"0x{data[exc.start]:02x} at offset {exc.start})") from None


def _reason(exc: BaseException) -> str:
    if isinstance(exc, OSError) and exc.strerror:
        return exc.strerror
    return str(exc) or type(exc).__name__


def read_npz(path: str | os.PathLike, keys: tuple[str, ...]) -> dict[str, np.ndarray]:
    """The arrays of ``keys`` that the .npz file ``path`` holds (absent keys are left out),
    read with every check of a drive's file (hostile headers, zip bombs, pickles): for the
    other .npz files vislam reads, e.g. a simulated drive's true landmarks."""
    return _read_npz(Path(path), tuple(keys))


def _read_npz(path: Path, keys: tuple[str, ...] | None = None) -> dict[str, np.ndarray]:
    """The arrays of the known keys (or of ``keys``) that ``path`` holds, each checked by
    :func:`_read_member`."""
    wanted = KNOWN_KEYS if keys is None else keys
    check_regular_file(path, "file")
    limit = max_array_bytes(path)
    with open_for_reading(path, ".npz file") as fh:
        try:
            zf = zipfile.ZipFile(fh)
        except zipfile.BadZipFile as exc:
            raise InputError(f"{path}: not an .npz file (not a zip archive, or one cut short: "
                             f"{exc})") from None
        except _READ_ERRORS as exc:
            raise InputError(f"{path}: unreadable .npz file (zip directory: "
                             f"{_reason(exc)})") from None
        with zf:
            members: dict[str, list[zipfile.ZipInfo]] = {}
            for info in zf.infolist():
                name = info.filename
                key = name[:-4] if name.endswith(".npy") else name
                if key in wanted:
                    members.setdefault(key, []).append(info)
            out = {}
            for key, infos in members.items():
                if len(infos) > 1:
                    names = ", ".join(repr(i.filename) for i in infos)
                    raise InputError(f"{path}: key {key!r} is stored more than once "
                                     f"(members {names}); there is no telling which is meant")
                out[key] = _read_member(zf, infos[0], key, path, limit)
            return out


def _read_member(
    zf: zipfile.ZipFile, info: zipfile.ZipInfo, key: str, path: Path, limit: int
) -> np.ndarray:
    """One member as an array, refusing (before allocating) anything hostile; see the module
    notes."""
    where = f"{path}: key {key!r}"
    if info.flag_bits & 0x1:
        raise InputError(f"{where}: the member is encrypted")
    if info.compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED):
        raise InputError(f"{where}: the member is compressed with zip method "
                         f"{info.compress_type}; only stored and deflate-compressed members "
                         "(what numpy.savez and savez_compressed write) are read")
    size, packed = info.file_size, info.compress_size
    if size > limit + MAX_HEADER_BYTES:
        raise InputError(f"{where}: the member is {size} bytes uncompressed, more than the "
                         f"limit of {limit} bytes (set {MAX_ARRAY_BYTES_ENV} to allow more)")
    if info.compress_type == zipfile.ZIP_STORED and size != packed:
        raise InputError(f"{where}: the zip directory says the stored member has {size} bytes "
                         f"but {packed} stored bytes (a damaged zip)")
    if info.compress_type == zipfile.ZIP_DEFLATED and size > MAX_DEFLATE_RATIO * packed:
        raise InputError(f"{where}: the member claims {size} bytes uncompressed from "
                         f"{packed} compressed bytes, more than deflate can give "
                         f"({MAX_DEFLATE_RATIO}:1); a damaged file or a zip bomb")
    try:
        with zf.open(info) as f:
            magic = f.read(np.lib.format.MAGIC_LEN)
            if len(magic) < np.lib.format.MAGIC_LEN or not magic.startswith(
                np.lib.format.MAGIC_PREFIX
            ):
                raise InputError(f"{where}: the member is not a .npy array (it does not start "
                                 "with the .npy magic string)")
            version = (magic[-2], magic[-1])
            if version == (1, 0):
                shape, fortran, dtype = np.lib.format.read_array_header_1_0(
                    f, max_header_size=MAX_HEADER_BYTES)
            elif version == (2, 0):
                shape, fortran, dtype = np.lib.format.read_array_header_2_0(
                    f, max_header_size=MAX_HEADER_BYTES)
            else:
                raise InputError(f"{where}: .npy format version {version[0]}.{version[1]} is "
                                 "not supported (1.0 and 2.0 are; 3.0 is only for structured "
                                 "dtypes)")
            header_len = f.tell()
    except InputError:
        raise
    except _ZIP_ERRORS as exc:
        raise InputError(f"{where}: unreadable member ({_short(exc)})") from None
    except _READ_ERRORS as exc:
        raise InputError(f"{where}: malformed .npy header ({_short(exc)})") from None
    _check_dtype(dtype, where)
    count = math.prod(shape)
    declared = count * dtype.itemsize
    if header_len + declared != size:
        raise InputError(
            f"{where}: the header declares shape {tuple(shape)} of {dtype} ({declared} bytes) "
            f"but the member holds {size - header_len} bytes of data (truncated or damaged)")
    if count * 8 > limit:
        raise InputError(f"{where}: shape {tuple(shape)} is {count * 8} bytes as float64, more "
                         f"than the limit of {limit} bytes (set {MAX_ARRAY_BYTES_ENV} to "
                         "allow more)")
    try:
        with zf.open(info) as f:
            array = np.lib.format.read_array(f, allow_pickle=False,
                                             max_header_size=MAX_HEADER_BYTES)
    except _READ_ERRORS as exc:
        raise InputError(f"{where}: unreadable member ({_short(exc)})") from None
    if array.shape != tuple(shape) or array.dtype != dtype:
        raise InputError(f"{where}: the member changed while it was read")
    return array


def _check_dtype(dtype: np.dtype, where: str) -> None:
    if dtype.hasobject:
        raise InputError(f"{where} holds Python objects (a pickle), which are never loaded; "
                         "expected numbers")
    if dtype.names is not None:
        raise InputError(f"{where} has a structured dtype {dtype}, expected plain numbers")
    if dtype.subdtype is not None:
        raise InputError(f"{where} has a sub-array dtype {dtype}, expected plain numbers")
    if dtype.kind == "c":
        raise InputError(f"{where} has complex dtype {dtype}, expected real numbers")
    if dtype.kind not in "biuf":
        raise InputError(f"{where} has non-numeric dtype {dtype}")


def _short(exc: BaseException, limit: int = 120) -> str:
    """A one-line description of a reader's exception."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    if len(text) > limit:
        text = text[:limit] + "..."
    return f"{type(exc).__name__}: {text}"


def _numeric(path: Path, key: str, a: np.ndarray, shape_text: str, ndim: int) -> np.ndarray:
    if a.dtype.kind not in "biuf":
        raise InputError(f"{path}: key {key!r} has non-numeric dtype {a.dtype}")
    if a.ndim != ndim:
        raise InputError(f"{path}: key {key!r} has shape {a.shape}, expected {shape_text}")
    with np.errstate(over="ignore", invalid="ignore"):  # overflow -> inf, reported by callers
        return a.astype(float, copy=False)


def _validate(raw: dict[str, np.ndarray], path: Path) -> tuple[dict[str, np.ndarray], LoadReport]:
    for key in ("time_stamps", "features", "linear_velocity", "K", "b"):
        if key not in raw:
            raise InputError(f"{path}: missing key {key!r}")

    ts = _time_stamps(raw, path)
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

    K, b, cam_T_imu = _calibration(raw, path)
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
