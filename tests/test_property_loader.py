"""Property-based tests of the loader and the ground-truth reader (issue 11).

Files are generated from a small simulated drive (:mod:`eval.simulate`), in the dense and in
the sparse observation layout, and then damaged:
keys dropped, added, or given other shapes, dtypes and values; NaN/inf; partial observations;
frame and track ids out of range, negative, fractional or duplicated;
both editions' keys; hostile .npy headers; zip members lying about their size; flipped,
inserted or cut bytes. Ground-truth files get random text and bytes. The property: the reader
returns a valid object or raises :class:`~ekf.errors.InputError` with a one-line message naming
the file, never another exception, never a hang, never a large allocation.

``VISLAM_PROPERTY_EXAMPLES=3000`` runs a larger sweep than CI's bounded one.
"""

from __future__ import annotations

import io
import os
import signal
import struct
import tracemalloc
import warnings
import zipfile
from contextlib import contextmanager
from functools import lru_cache

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vislam.ekf.errors import InputError
from vislam.ekf.geometry import se3_inv
from vislam.ekf.sequence import Calibration, Sequence
from vislam.eval.groundtruth import GroundTruth, find_ground_truth, load_ground_truth
from vislam.eval.loader import load_sequence_with_report, read_calibration

#: Examples per property in CI (1,600 in all; 1,200 of them took about 5 s on two idle cores,
#: and a sparse example costs what a dense one does).
EXAMPLES = int(os.environ.get("VISLAM_PROPERTY_EXAMPLES", "0")) or None
#: No reader may allocate more than this for these files of a few kB (tracemalloc peak).
MAX_PEAK_BYTES = 32 * 2**20
#: Nor take longer than this (a hang is a failure, not a stuck CI job).
MAX_SECONDS = 20


def examples(ci: int) -> int:
    return EXAMPLES or ci


@lru_cache(maxsize=2)
def base_arrays(layout: str = "dense") -> dict[str, np.ndarray]:
    """A small valid drive in edition-1 layout (8 frames, a few dozen tracks), its observations
    dense or sparse."""
    from vislam.eval.loader import sparse_arrays
    from vislam.eval.simulate import SimConfig, simulate

    seq = simulate(SimConfig(n_frames=8, seed=5, landmark_density=0.6)).sequence
    cal = seq.calibration
    observations = ({"features": seq.obs.to_dense(seq.n_tracks)} if layout == "dense"
                    else sparse_arrays(seq.obs, seq.n_tracks))
    return {
        "time_stamps": seq.timestamps[None, :],
        **observations,
        "linear_velocity": seq.linear_velocity.T.copy(),
        "rotational_velocity": seq.angular_velocity.T.copy(),
        "K": cal.K.copy(),
        "b": np.array(cal.baseline),
        "cam_T_imu": cal.cam_T_imu.copy(),
    }


KEYS = ("time_stamps", "features", "linear_velocity", "rotational_velocity", "K", "b",
        "cam_T_imu", "angular_velocity", "imu_T_cam")
DTYPES = ("<f8", ">f8", "<f4", "<f2", "<i8", ">i4", "<u1", "<u8", "?", "<c16", "<U3", "S2",
          "O", "<M8[s]", "<m8[s]", "V8", np.dtype([("a", "<f8")]), np.dtype(("<f8", (2,))),
          np.longdouble)
SPECIAL = (np.nan, np.inf, -np.inf, -1.0, -5.0, 0.0, 1e308, -1e308, 1e-320, 2.0**63, -0.0)
#: The sparse layout's keys, mutated as KEYS[:7] are in a dense file.
SPARSE_KEYS = ("time_stamps", "obs_frame", "obs_track", "obs_pixels", "n_tracks",
               "linear_velocity", "rotational_velocity", "K", "b", "cam_T_imu")
#: Values put into a sparse file's frame and track columns.
IDS = (-1, 0, 7, 8, 9, 10**6, 2**40, 2**63 - 1, 1.5, np.nan, -0.5)


# --------------------------------------------------------------------------- array mutations


@st.composite
def array_mutation(draw, arrays: dict) -> str:
    """Change ``arrays`` in place; returns a label (for failure reports)."""
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore")  # complex -> real, NaN -> int, ...: meant
        try:
            return _mutate(draw, arrays)
        except (TypeError, ValueError):  # an earlier mutation left a string/date/... array
            return "skipped"


def _mutate(draw, arrays: dict) -> str:
    sparse = "obs_frame" in arrays or "obs_pixels" in arrays
    kind = draw(st.sampled_from(["drop", "extra", "shape", "dtype", "special", "partial",
                                 "edition", "both", "scalar", "empty", "transpose"]
                                + ["ids", "ids", "duplicate", "partial"] * sparse))
    key = draw(st.sampled_from(SPARSE_KEYS if sparse else KEYS[:7]))
    if kind in ("ids", "duplicate"):
        return _mutate_ids(draw, arrays, kind)
    if key not in arrays:
        return "noop"
    a = arrays[key]
    if kind == "drop":
        arrays.pop(key)
    elif kind == "extra":
        name = draw(st.sampled_from(["notes", "x", "features2", "imu_T_cam", "angular_velocity",
                                     "features", "obs_frame", "n_tracks"]))
        arrays[name] = draw(small_arrays())
    elif kind == "shape":
        arrays[key] = draw(small_arrays())
    elif kind == "dtype":
        dtype = draw(st.sampled_from(DTYPES))
        try:
            arrays[key] = a.astype(dtype)
        except (TypeError, ValueError):
            arrays[key] = np.zeros(a.shape, dtype=dtype)
    elif kind == "special" and a.size:
        a = a.astype(float)
        flat = a.reshape(-1)
        for _ in range(draw(st.integers(1, 3))):
            flat[draw(st.integers(0, flat.size - 1))] = draw(st.sampled_from(SPECIAL))
        arrays[key] = a
    elif kind == "partial" and "features" in arrays and arrays["features"].ndim == 3:
        f = arrays["features"].astype(float)
        if f.size:
            for _ in range(draw(st.integers(1, 4))):
                r = draw(st.integers(0, f.shape[0] - 1))
                j = draw(st.integers(0, max(f.shape[1] - 1, 0)))
                t = draw(st.integers(0, max(f.shape[2] - 1, 0)))
                if f.shape[1] and f.shape[2]:
                    f[r, j, t] = draw(st.sampled_from([-1.0, -1.0, -5.0, -0.25, 1e9]))
        arrays["features"] = f
    elif kind == "partial" and "obs_pixels" in arrays and arrays["obs_pixels"].ndim == 2:
        f = arrays["obs_pixels"].astype(float)
        if f.size:
            for _ in range(draw(st.integers(1, 4))):
                f[draw(st.integers(0, f.shape[0] - 1)), draw(st.integers(0, f.shape[1] - 1))] = \
                    draw(st.sampled_from([-1.0, -1.0, -5.0, -0.25, 1e9]))
            if draw(st.booleans()):  # a whole row -1: no observation
                f[draw(st.integers(0, f.shape[0] - 1))] = -1.0
        arrays["obs_pixels"] = f
    elif kind in ("edition", "both"):
        for one, two in (("rotational_velocity", "angular_velocity"),
                         ("cam_T_imu", "imu_T_cam")):
            if one not in arrays:
                continue
            value = arrays[one]
            if two == "imu_T_cam" and value.shape == (4, 4):
                value = se3_inv(value)
            if draw(st.booleans()):
                value = value + draw(st.sampled_from([1e-12, 1e-3, 0.5]))
            arrays[two] = value
            if kind == "edition":
                arrays.pop(one)
    elif kind == "scalar":
        arrays[key] = np.array(draw(st.sampled_from(SPECIAL + (1, 0.54, True))))
    elif kind == "empty":
        shape = list(a.shape) or [0]
        shape[draw(st.integers(0, len(shape) - 1))] = 0
        arrays[key] = np.zeros(shape)
    elif kind == "transpose" and a.ndim >= 2:
        arrays[key] = np.asfortranarray(a.T)
    return f"{kind} {key}"


def _mutate_ids(draw, arrays: dict, kind: str) -> str:
    """A sparse file's frame or track ids set to ``IDS`` values, or a row duplicated."""
    key = draw(st.sampled_from(["obs_frame", "obs_track"]))
    if key not in arrays or arrays[key].ndim != 1 or not arrays[key].size:
        return "noop"
    a = arrays[key]
    if kind == "duplicate":
        i = draw(st.integers(0, a.size - 1))
        for k in ("obs_frame", "obs_track", "obs_pixels"):
            if k in arrays and arrays[k].ndim >= 1 and arrays[k].shape[0] > i:
                arrays[k] = np.concatenate([arrays[k], arrays[k][i:i + 1]])
        return f"duplicate row {i}"
    value = draw(st.sampled_from(IDS))
    a = a.astype(float) if isinstance(value, float) or a.dtype.kind == "f" else a.copy()
    a[draw(st.integers(0, a.size - 1))] = value
    arrays[key] = a
    return f"ids {key} {value!r}"


@st.composite
def small_arrays(draw) -> np.ndarray:
    shape = tuple(draw(st.lists(st.integers(0, 5), max_size=4)))
    dtype = draw(st.sampled_from(["<f8", "<i4", "?", ">f8"]))
    if dtype in ("?", "<i4"):
        return np.full(shape, draw(st.integers(-2, 2)), dtype=dtype)
    return np.full(shape, draw(st.sampled_from(SPECIAL + (1.0, 700.0))), dtype=dtype)


# --------------------------------------------------------------------------- byte mutations


def npy_header(header: str, data: bytes = b"", version: tuple[int, int] = (1, 0)) -> bytes:
    body = header.encode("latin1", "replace")
    pad = -(10 + len(body) + 1) % 64
    body = body + b" " * pad + b"\n"
    size = struct.pack("<H", len(body) % 65536) if version[0] == 1 else struct.pack(
        "<I", len(body))
    return b"\x93NUMPY" + bytes(version) + size + body + data


@st.composite
def hostile_header(draw) -> bytes:
    descr = draw(st.sampled_from(["<f8", ">f8", "|b1", "<c16", "|O", "<U4", "x9", "", "<f8'",
                                  "[('a', '<f8')]", "<f16", "|V0", "<i8"]))
    shape = tuple(draw(st.lists(st.one_of(st.integers(-3, 8), st.integers(0, 2**62)),
                                max_size=4)))
    fortran = draw(st.sampled_from(["False", "True", "0", "None", "'x'"]))
    shape_text = draw(st.sampled_from([repr(shape), "(3, ", "(2**40,)", "()", "(1e3,)", "None",
                                       "(" * 300 + ")" * 300, "(-1,)"]))
    descr_text = descr if descr.startswith("[") else repr(descr)
    header = f"{{'descr': {descr_text}, 'fortran_order': {fortran}, 'shape': {shape_text}, }}"
    if draw(st.booleans()):
        header = draw(st.text(max_size=80))
    version = draw(st.sampled_from([(1, 0), (2, 0), (3, 0), (0, 0), (1, 9)]))
    data = draw(st.binary(max_size=200))
    return npy_header(header, data, version)


def zip_bytes(members: list[tuple[str, bytes]], method: int) -> bytes:
    buf = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with zipfile.ZipFile(buf, "w", compression=method) as zf:
            for name, data in members:
                zf.writestr(name, data)
    return buf.getvalue()


def position(draw, n: int) -> int:
    """An index in ``range(n)`` drawn independently of ``n``.

    The lengths of serialised members are not a pure function of the draws (numpy pickles an
    object array's scalars with their dtypes, and how many of those pickle shares differs from
    process to process), so a strategy that drew ``integers(0, len(data))`` drew with different
    bounds on a replay, which hypothesis reports as a flaky strategy (CI at 1d5c3aa). A fraction
    of the length is drawn instead; it shrinks towards 0 as before.
    """
    return min(n - 1, draw(st.integers(0, 2**16 - 1)) * n // 2**16)


def npy(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array(buf, np.asanyarray(a), allow_pickle=a.dtype.hasobject)
    return buf.getvalue()


@st.composite
def npz_file(draw, layout: str = "dense") -> tuple[bytes, list[str]]:
    """The bytes of a (damaged) .npz file and what was done to it."""
    arrays = {k: v.copy() for k, v in base_arrays(layout).items()}
    labels = [draw(array_mutation(arrays)) for _ in range(draw(st.integers(0, 3)))]
    members = []
    for key, value in arrays.items():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            members.append((f"{key}.npy", npy(value)))
    byte_ops = draw(st.lists(st.sampled_from(
        ["hostile", "not_npy", "duplicate", "no_suffix", "truncate_member", "pad_member"]),
        max_size=2))
    for op in byte_ops:
        i = draw(st.integers(0, len(members) - 1)) if members else 0
        if not members:
            break
        name, data = members[i]
        if op == "hostile":
            members[i] = (name, draw(hostile_header()))
        elif op == "not_npy":
            members[i] = (name, draw(st.binary(max_size=64)))
        elif op == "duplicate":
            members.append((draw(st.sampled_from([name, name.removesuffix(".npy")])), data))
        elif op == "no_suffix":
            members[i] = (name.removesuffix(".npy") or name, data)
        elif op == "truncate_member":
            members[i] = (name, data[: position(draw, len(data) + 1)])
        elif op == "pad_member":
            members[i] = (name, data + draw(st.binary(min_size=1, max_size=32)))
        labels.append(f"{op} {name}")
    method = draw(st.sampled_from([zipfile.ZIP_DEFLATED] * 3 + [zipfile.ZIP_STORED] * 2
                                  + [zipfile.ZIP_BZIP2, zipfile.ZIP_LZMA]))
    raw = bytearray(zip_bytes(members, method))
    for op in draw(st.lists(st.sampled_from(["flip", "truncate", "insert", "size"]),
                            max_size=2)):
        if not raw:
            break
        if op == "flip":
            for _ in range(draw(st.integers(1, 8))):
                raw[position(draw, len(raw))] ^= draw(st.integers(1, 255))
        elif op == "truncate":
            del raw[position(draw, len(raw)):]
        elif op == "insert":
            at = position(draw, len(raw) + 1)
            raw[at:at] = draw(st.binary(min_size=1, max_size=16))
        elif op == "size":  # a member's directory entry lies about its uncompressed size
            at = raw.find(b"PK\x01\x02", position(draw, len(raw)))
            if at >= 0 and at + 28 <= len(raw):
                raw[at + 24:at + 28] = struct.pack("<I", draw(st.sampled_from(
                    [0, 1, 2**20, 2**31, 0xFFFFFFFE, 0xFFFFFFFF])))
        labels.append(f"bytes {op}")
    return bytes(raw), labels


# --------------------------------------------------------------------------- the checks


@contextmanager
def bounded():
    """Fail on a hang (SIGALRM) or an allocation beyond MAX_PEAK_BYTES."""

    def on_alarm(*_):
        raise TimeoutError(f"reader took more than {MAX_SECONDS} s")

    old = signal.signal(signal.SIGALRM, on_alarm)
    signal.alarm(MAX_SECONDS)
    tracemalloc.start()
    try:
        yield
        peak = tracemalloc.get_traced_memory()[1]
        assert peak < MAX_PEAK_BYTES, f"allocated {peak} bytes"
    finally:
        tracemalloc.stop()
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


def check_error(exc: InputError, path) -> None:
    text = str(exc)
    assert "\n" not in text, text
    assert str(path) in text, text


def check_sequence(seq: Sequence) -> None:
    T = seq.n_frames
    assert T >= 1 and seq.timestamps.shape == (T,) and np.all(np.diff(seq.timestamps) > 0)
    assert np.all(np.isfinite(seq.timestamps))
    for v in (seq.linear_velocity, seq.angular_velocity):
        assert v.shape == (T, 3) and v.dtype == float and np.all(np.isfinite(v))
    obs = seq.obs
    assert obs.frame_ptr.shape == (T + 1,) and obs.frame_ptr[-1] == len(obs)
    assert obs.z.shape == (len(obs), 4) and np.all(np.isfinite(obs.z))
    assert np.all(obs.z >= 0), "an invalid observation was kept"
    assert len(obs) == 0 or (0 <= obs.track.min() and obs.track.max() < seq.n_tracks)
    check_calibration(seq.calibration)


def check_calibration(cal: Calibration, monocular: bool = False) -> None:
    assert cal.K.shape == (3, 3) and np.all(np.isfinite(cal.K))
    assert cal.K[0, 0] > 0 and cal.K[1, 1] > 0
    assert (monocular and np.isnan(cal.baseline)) or (np.isfinite(cal.baseline)
                                                      and cal.baseline > 0)
    assert cal.cam_T_imu.shape == (4, 4) and np.all(np.isfinite(cal.cam_T_imu))


def check_drive_file(path, monocular: bool = False) -> None:
    """The loader and the calibration reader on ``path``: a valid drive (its observations
    sorted, one row per (frame, track)) or an InputError naming the file, within bounds."""
    with bounded():
        try:
            seq, report = load_sequence_with_report(path)
        except InputError as exc:
            check_error(exc, path)
        else:
            check_sequence(seq)
            assert report.n_invalid >= 0
            frame = seq.obs.frame_index  # sorted, one row per (frame, track)
            key = frame * max(seq.n_tracks, 1) + seq.obs.track
            assert np.all(np.diff(key) > 0)
        try:
            cal, n = read_calibration(path)
        except InputError as exc:
            check_error(exc, path)
        else:
            check_calibration(cal, monocular=monocular)
            assert n >= 1


def loads_or_refuses(tmp_path, case, monocular: bool = False):
    data, labels = case
    path = tmp_path / "drive.npz"
    path.write_bytes(data)
    check_drive_file(path, monocular=monocular)


# The fast tier draws a few hundred files of each layout; the regression tier sweeps more
# (other examples: hypothesis derandomizes each test by its own name).
@settings(max_examples=examples(200))
@given(npz_file())
def test_load_sequence_returns_a_valid_drive_or_input_error(tmp_path, case):
    loads_or_refuses(tmp_path, case)


@settings(max_examples=examples(150))
@given(npz_file("sparse"))
def test_sparse_file_loads_as_a_valid_drive_or_input_error(tmp_path, case):
    loads_or_refuses(tmp_path, case, monocular=True)


@pytest.mark.regression
@settings(max_examples=examples(600))
@given(npz_file())
def test_load_sequence_sweep(tmp_path, case):
    loads_or_refuses(tmp_path, case)


@pytest.mark.regression
@settings(max_examples=examples(400))
@given(npz_file("sparse"))
def test_sparse_file_sweep(tmp_path, case):
    loads_or_refuses(tmp_path, case, monocular=True)


# --------------------------------------------------------------------------- ground truth

CAL = Calibration(K=np.array([[700.0, 0, 600], [0, 700, 180], [0, 0, 1]]), baseline=0.54,
                  cam_T_imu=base_arrays()["cam_T_imu"])
TOKENS = ("1", "0", "-1", "0.5", "1e-3", "nan", "inf", "-inf", "1e400", "1e308", "-0", "0x1",
          "1_0", "\u0661", "abc", "#", "", "1.0000001", "0.7071068", "-0.7071068", "\x00",
          "1e7", "3")


@st.composite
def pose_text(draw) -> bytes:
    """Random bytes, random text, or lines of numbers close to (or far from) pose lines."""
    kind = draw(st.sampled_from(["bytes", "text", "lines", "lines"]))
    if kind == "bytes":
        return draw(st.binary(max_size=400))
    if kind == "text":
        return draw(st.text(max_size=300)).encode("utf-8", "surrogatepass")
    lines = []
    width = draw(st.sampled_from([12, 13]))
    damage = draw(st.booleans())
    for _ in range(draw(st.integers(0, 12))):
        n = draw(st.sampled_from([width] * 8 + [11, 14, 0, 25 - width])) if damage else width
        identity = ["1", "0", "0", "0", "0", "1", "0", "0", "0", "0", "1", "0"]
        fields = (["0.1"] if n == 13 else []) + identity
        fields = fields[:n] if n <= 13 else fields + ["1"]
        for _ in range(draw(st.sampled_from([0, 0, 0, 1, 2])) if damage else 0):
            if fields:
                fields[draw(st.integers(0, len(fields) - 1))] = draw(st.sampled_from(TOKENS))
        sep = draw(st.sampled_from([" ", "\t", "  ", ",", " \x0b "]))
        lines.append(sep.join(fields))
    end = draw(st.sampled_from(["\n", "\r\n", "\r", ""]))
    return (end.join(lines) + end).encode()


@settings(max_examples=examples(500))
@given(pose_text(), st.integers(1, 15))
def test_ground_truth_reader_returns_valid_poses_or_input_error(tmp_path, data, n_frames):
    path = tmp_path / "gt.txt"
    path.write_bytes(data)
    with bounded():
        try:
            gt = load_ground_truth(path, CAL, n_frames)
        except InputError as exc:
            check_error(exc, path)
        else:
            assert isinstance(gt, GroundTruth)
            assert 1 <= gt.n <= n_frames and gt.poses.shape == (gt.n, 4, 4)
            assert np.all(np.isfinite(gt.poses))
            np.testing.assert_allclose(gt.poses[0], np.eye(4), atol=1e-6)
            assert gt.times is None or (gt.times.shape == (gt.n,)
                                        and np.all(np.isfinite(gt.times)))


@pytest.fixture(scope="module")
def drive_dir(tmp_path_factory):
    folder = tmp_path_factory.mktemp("drive")
    arrays = base_arrays()
    np.savez(folder / "drive.npz", **arrays)
    return folder


@settings(max_examples=examples(100))
@given(st.sampled_from(["none", "file", "dir", "fifo", "broken_link", "link_to_dir"]),
       pose_text())
def test_find_ground_truth_reads_or_refuses_whatever_is_there(drive_dir, what, data):
    npz = drive_dir / "drive.npz"
    gt = drive_dir / "groundtruth" / "drive.txt"
    gt.parent.mkdir(exist_ok=True)
    if gt.is_symlink() or gt.is_file() or gt.is_fifo():
        gt.unlink()
    elif gt.is_dir():
        gt.rmdir()
    if what == "file":
        gt.write_bytes(data)
    elif what == "dir":
        gt.mkdir()
    elif what == "fifo":
        os.mkfifo(gt)
    elif what == "broken_link":
        gt.symlink_to(drive_dir / "nowhere.txt")
    elif what == "link_to_dir":
        gt.symlink_to(drive_dir)
    with bounded():
        try:
            found = find_ground_truth(npz)
        except InputError as exc:
            check_error(exc, gt)
            assert what != "none"
        else:
            assert (found is None) == (what == "none")
            if found is not None:
                assert np.all(np.isfinite(found.poses))
