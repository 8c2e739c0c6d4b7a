"""Reading files that may be damaged or hostile: the members of an ``.npz`` file (each member's
``.npy`` header parsed and checked against the zip directory before any array is allocated:
pickles, non-numeric dtypes, truncated members, zip bombs and oversized arrays refused) and
small text files (regular file, size limit, UTF-8). Every fault is an
:class:`~ekf.errors.InputError` naming the file, the key and what is wrong. What a drive's keys
must hold: :mod:`eval.drive_keys`."""

from __future__ import annotations

import math
import os
import stat
import struct
import tokenize
import zipfile
import zlib
from pathlib import Path

import numpy as np

from vislam.ekf.errors import InputError

#: Largest array accepted, in bytes once converted to float64 (the shared drives' largest,
#: 0034's features, is 189 MB). ``$VISLAM_MAX_ARRAY_BYTES`` overrides it.
MAX_ARRAY_BYTES = 4 * 2**30
#: Environment variable overriding :data:`MAX_ARRAY_BYTES`.
MAX_ARRAY_BYTES_ENV = "VISLAM_MAX_ARRAY_BYTES"
#: Deflate cannot expand its input by more than about 1032:1 (258 bytes per 2-bit code).
MAX_DEFLATE_RATIO = 1032
#: Largest .npy header accepted (numpy's own default).
MAX_HEADER_BYTES = 10000

#: Exceptions numpy's and zipfile's readers raise on damaged or hostile input.
_READ_ERRORS = (
    OSError, EOFError, ValueError, TypeError, KeyError, IndexError, OverflowError,
    SyntaxError, RecursionError, tokenize.TokenError, struct.error, zlib.error,
    zipfile.BadZipFile, NotImplementedError, MemoryError,
)

#: Of those, the ones that mean damaged compressed data rather than a bad .npy header.
_ZIP_ERRORS = (OSError, EOFError, zlib.error, zipfile.BadZipFile, NotImplementedError)


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


def _read_npz(path: Path, wanted: tuple[str, ...]) -> dict[str, np.ndarray]:
    """The arrays of ``wanted`` that ``path`` holds, each checked by :func:`_read_member`."""
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

