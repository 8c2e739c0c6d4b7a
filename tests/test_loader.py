"""vislam.eval.loader: both editions of the data format, validation of every fault, the real drives."""

from __future__ import annotations

import errno
import io
import logging
import os
import signal
import struct
import tracemalloc
import warnings
import zipfile

import numpy as np
import pytest

from vislam.ekf.errors import InputError
from vislam.ekf.geometry import se3_exp, se3_inv
from vislam.ekf.sequence import Sequence
from vislam.eval.loader import (
    load_sequence,
    load_sequence_with_report,
    read_calibration,
    save_sequence,
    write_npz,
)
from tests.sequence_asserts import assert_same_sequence

T, M = 6, 5


def valid_arrays(seed: int = 0) -> dict[str, np.ndarray]:
    """A small valid drive in edition-1 layout."""
    rng = np.random.default_rng(seed)
    feats = -np.ones((4, M, T))
    for j in range(M):
        a = j % 3
        for t in range(a, min(T, a + 3)):
            u, v, d = 300 + 10 * j + t, 150 + 5 * j, 5.0 + j
            feats[:, j, t] = [u, v, u - d, v]
    return {
        "time_stamps": (1.3e9 + 0.1 * np.arange(T))[None, :],
        "features": feats,
        "linear_velocity": rng.normal(size=(3, T)),
        "rotational_velocity": 0.1 * rng.normal(size=(3, T)),
        "K": np.array([[700.0, 0, 600], [0, 700, 180], [0, 0, 1]]),
        "b": np.array(0.54),
        "cam_T_imu": se3_exp(np.array([0.1, -0.3, 0.7, 1.2, -1.2, 1.2])),
    }


def write(tmp_path, arrays, name="drive.npz"):
    path = tmp_path / name
    np.savez(path, **arrays)
    return path


def other_edition(arrays):
    out = dict(arrays)
    out["angular_velocity"] = out.pop("rotational_velocity")
    out["imu_T_cam"] = se3_inv(out.pop("cam_T_imu"))
    return out


def test_valid_file_loads_with_layout_and_names(tmp_path):
    arrays = valid_arrays()
    path = write(tmp_path, arrays, "0099.npz")
    seq = load_sequence(path)
    assert seq.name == "0099" and seq.source == str(path)
    assert seq.timestamps.shape == (T,)
    assert seq.linear_velocity.shape == (T, 3) and seq.angular_velocity.shape == (T, 3)
    np.testing.assert_array_equal(seq.linear_velocity, arrays["linear_velocity"].T)
    assert seq.n_tracks == M
    assert len(seq.obs) == int(np.sum(~np.all(arrays["features"] == -1, axis=0)))
    np.testing.assert_array_equal(seq.obs.to_dense(M), arrays["features"])
    np.testing.assert_array_equal(seq.track_origin, np.arange(M))
    cal, n = read_calibration(path)
    assert n == T and cal.baseline == 0.54


def test_both_editions_load_identically(tmp_path):
    arrays = valid_arrays()
    a = load_sequence(write(tmp_path, arrays, "a.npz"))
    b = load_sequence(write(tmp_path, other_edition(arrays), "b.npz"))
    assert_same_sequence(a, b, name=False)


def test_unknown_keys_are_ignored(tmp_path):
    arrays = valid_arrays()
    a = load_sequence(write(tmp_path, arrays, "a.npz"))
    b = load_sequence(write(tmp_path, {**arrays, "notes": np.array("hello"), "x": np.ones(3)},
                            "b.npz"))
    assert_same_sequence(a, b, name=False)


def test_write_npz_and_save_sequence_round_trip(tmp_path):
    arrays = valid_arrays()
    path = tmp_path / "sub" / "w.npz"
    write_npz(path, time_stamps=arrays["time_stamps"], features=arrays["features"],
              linear_velocity=arrays["linear_velocity"],
              angular_velocity=arrays["rotational_velocity"], K=arrays["K"], b=0.54,
              cam_T_imu=arrays["cam_T_imu"])
    with np.load(path) as d:
        assert sorted(d.files) == sorted(arrays)
        assert d["time_stamps"].shape == (1, T) and d["b"].shape == ()
    seq = load_sequence(path)
    save_sequence(tmp_path / "w2.npz", seq)
    assert_same_sequence(seq, load_sequence(tmp_path / "w2.npz"), name=False)
    assert not list(tmp_path.rglob("*.tmp"))


def _bad_cases():
    rigid_bad = se3_exp(np.array([0.1, 0.2, 0.3, 0.1, 0.2, 0.3]))
    rigid_bad[0, 0] += 0.1
    k_bad = np.array([[700.0, 0, 600], [0, 700, 180], [0, 0, 2]])
    k_neg = np.array([[-700.0, 0, 600], [0, 700, 180], [0, 0, 1]])
    feats_nan = valid_arrays()["features"].copy()
    feats_nan[1, 0, 0] = np.nan
    ts_back = valid_arrays()["time_stamps"].copy()
    ts_back[0, 3] = ts_back[0, 2]
    vel_inf = valid_arrays()["linear_velocity"].copy()
    vel_inf[2, 4] = np.inf
    return [
        ("missing features", lambda a: a.pop("features"), "missing key 'features'"),
        ("missing K", lambda a: a.pop("K"), "missing key 'K'"),
        ("missing velocity", lambda a: a.pop("rotational_velocity"),
         "missing key 'rotational_velocity' or 'angular_velocity'"),
        ("missing transform", lambda a: a.pop("cam_T_imu"), "missing key 'cam_T_imu' or"),
        ("features 3-d", lambda a: a.update(features=np.zeros((3, M, T))), "'features' has shape"),
        ("features T", lambda a: a.update(features=-np.ones((4, M, T + 1))),
         "'features' has shape (4, 5, 7): 7 steps, but 'time_stamps' has 6"),
        ("velocity T", lambda a: a.update(linear_velocity=np.zeros((3, T - 1))),
         "'linear_velocity' has shape (3, 5)"),
        ("velocity rows", lambda a: a.update(rotational_velocity=np.zeros((2, T))),
         "'rotational_velocity' has shape (2, 6), expected (3, T)"),
        ("time stamps shape", lambda a: a.update(time_stamps=np.zeros((2, T))),
         "'time_stamps' has shape (2, 6)"),
        ("K shape", lambda a: a.update(K=np.eye(4)), "'K' has shape (4, 4)"),
        ("transform shape", lambda a: a.update(cam_T_imu=np.eye(3)), "'cam_T_imu' has shape"),
        ("b shape", lambda a: a.update(b=np.ones(2)), "'b' has shape (2,)"),
        ("NaN feature", lambda a: a.update(features=feats_nan), "'features' has 1 NaN/inf"),
        ("inf velocity", lambda a: a.update(linear_velocity=vel_inf),
         "'linear_velocity' has 1 NaN/inf value(s), first at index (2, 4)"),
        ("time not increasing", lambda a: a.update(time_stamps=ts_back),
         "'time_stamps' is not strictly increasing (step 2 -> 3"),
        ("not rigid", lambda a: a.update(cam_T_imu=rigid_bad), "'cam_T_imu' is not a rigid"),
        ("not rigid edition 2", lambda a: (a.pop("cam_T_imu"), a.update(imu_T_cam=rigid_bad)),
         "'imu_T_cam' is not a rigid"),
        ("zero baseline", lambda a: a.update(b=np.array(0.0)), "'b' (baseline) must be a positive"),
        ("negative baseline", lambda a: a.update(b=np.array(-0.5)), "must be a positive number"),
        ("K last row", lambda a: a.update(K=k_bad), "'K' is not a valid intrinsic matrix: last row"),
        ("K focal", lambda a: a.update(K=k_neg), "focal lengths must be positive"),
        ("string key", lambda a: a.update(K=np.array(["a", "b"])), "'K' has non-numeric dtype"),
    ]


@pytest.mark.parametrize("label,change,message", _bad_cases(), ids=[c[0] for c in _bad_cases()])
def test_each_fault_raises_input_error_naming_it(tmp_path, label, change, message):
    arrays = valid_arrays()
    change(arrays)
    path = write(tmp_path, arrays)
    with pytest.raises(InputError) as info:
        load_sequence(path)
    text = str(info.value)
    assert str(path) in text
    assert message in text


def test_missing_and_non_npz_files(tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        load_sequence(tmp_path / "nothing.npz")
    text = tmp_path / "notes.npz"
    text.write_text("not a zip file\n")
    with pytest.raises(InputError, match="not an .npz file"):
        load_sequence(text)
    with pytest.raises(InputError, match="is a directory"):
        load_sequence(tmp_path)
    npy = tmp_path / "plain.npy"
    np.save(npy, np.zeros(3))
    with pytest.raises(InputError, match="not an .npz file"):
        load_sequence(npy)


def test_truncated_npz_is_an_input_error(tmp_path):
    path = write(tmp_path, valid_arrays())
    data = path.read_bytes()
    broken = tmp_path / "broken.npz"
    broken.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match=str(broken)):
        load_sequence(broken)


def test_clean_flag_applies_cleaning(tmp_path):
    arrays = valid_arrays()
    arrays["features"][:, 0, 1] = arrays["features"][:, 0, 0]  # a repeat in track 0
    path = write(tmp_path, arrays)
    raw = load_sequence(path)
    cleaned = load_sequence(path, clean=True)
    assert len(cleaned.obs) == len(raw.obs) - 1
    assert cleaned.n_tracks == M + 1
    assert cleaned.track_origin[-1] == 0


@pytest.mark.regression
@pytest.mark.realdata
def test_shared_drive_loads_consistently(shared_drive):
    seq = load_sequence(shared_drive)
    T_ = seq.n_frames
    assert seq.name == shared_drive.stem
    assert isinstance(seq, Sequence)
    assert seq.timestamps.shape == (T_,) and np.all(np.diff(seq.timestamps) > 0)
    assert seq.linear_velocity.shape == (T_, 3) and seq.angular_velocity.shape == (T_, 3)
    assert seq.obs.frame_ptr.shape == (T_ + 1,) and seq.obs.frame_ptr[-1] == len(seq.obs)
    assert seq.obs.z.shape == (len(seq.obs), 4)
    assert seq.obs.track.dtype == np.int64 and seq.obs.track.max() < seq.n_tracks
    assert seq.calibration.K.shape == (3, 3) and seq.calibration.cam_T_imu.shape == (4, 4)
    assert isinstance(seq.calibration.baseline, float)
    assert abs(seq.calibration.baseline - 0.537) < 0.01
    expected = {"0022": (800, 3220), "0027": (1106, 3950), "0034": (1224, 4815)}
    assert (T_, seq.n_tracks) == expected[seq.name]


# --------------------------------------------------------------------------- issue 11, item 3:
# hostile .npz members. Each builds a zip by hand: the valid drive's members plus one member
# whose bytes are given, so the header can say anything.


def npy_bytes(array, **kwargs) -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array(buf, np.asanyarray(array), **kwargs)
    return buf.getvalue()


def npy_with_header(header: str, data: bytes = b"", version=(1, 0)) -> bytes:
    """A .npy member with a literal header text (padded as numpy pads it)."""
    body = header.encode("latin1")
    pad = -(10 + len(body) + 1) % 64
    body = body + b" " * pad + b"\n"
    size = struct.pack("<H", len(body)) if version == (1, 0) else struct.pack("<I", len(body))
    return b"\x93NUMPY" + bytes(version) + size + body + data


def write_zip(tmp_path, members: dict[str, bytes], name="hostile.npz",
              method=zipfile.ZIP_DEFLATED, extra: list[tuple[str, bytes]] = ()):
    """A zip of ``members`` (member name -> bytes), then ``extra`` (duplicates allowed)."""
    path = tmp_path / name
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # zipfile warns on duplicate names
        with zipfile.ZipFile(path, "w", compression=method) as zf:
            for member, data in list(members.items()) + list(extra):
                zf.writestr(member, data)
    return path


def drive_members(arrays=None, **replace: bytes) -> dict[str, bytes]:
    """The valid drive's members as .npy bytes, with some replaced (key -> member bytes)."""
    members = {f"{k}.npy": npy_bytes(v) for k, v in (arrays or valid_arrays()).items()}
    members.update({f"{k}.npy": v for k, v in replace.items()})
    return members


def patch_sizes(path, member: str, file_size: int) -> None:
    """Rewrite the uncompressed size of ``member`` in the local and central headers."""
    data = bytearray(path.read_bytes())
    name = member.encode()
    for sig, offset in ((b"PK\x03\x04", 22), (b"PK\x01\x02", 24)):
        start = 0
        while True:
            i = data.find(sig, start)
            if i < 0:
                break
            name_at = i + (30 if sig == b"PK\x03\x04" else 46)
            if data[name_at:name_at + len(name)] == name:
                data[i + offset:i + offset + 4] = struct.pack("<I", file_size)
            start = i + 4
    path.write_bytes(bytes(data))


def assert_input_error(path, *fragments, loader=None):
    with pytest.raises(InputError) as info:
        (loader or load_sequence)(path)
    text = str(info.value)
    assert "\n" not in text
    assert str(path) in text, text
    for fragment in fragments:
        assert fragment in text, text
    return text


def test_huge_declared_shape_is_refused_before_allocating(tmp_path):
    # Reproduces item 3: "_ArrayMemoryError: Unable to allocate 29.1 TiB".
    header = "{'descr': '<f8', 'fortran_order': False, 'shape': (4, 2000000, 500000), }"
    path = write_zip(tmp_path, drive_members(features=npy_with_header(header, b"\0" * 64)))
    tracemalloc.start()
    try:
        assert_input_error(path, "'features'", "(4, 2000000, 500000)")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 20e6


def test_malformed_header_is_an_input_error(tmp_path):
    # Reproduces item 3: "tokenize.TokenError" from an unterminated header.
    header = "{'descr': '<f8', 'fortran_order': False, 'shape': (3, "
    path = write_zip(tmp_path, drive_members(K=npy_with_header(header, b"\0" * 72)))
    assert_input_error(path, "'K'", "header")


def _hostile_members():
    good = npy_bytes(valid_arrays()["features"])
    return [
        ("header not a dict", {"K": npy_with_header("[1, 2, 3]", b"\0" * 72)}, "header"),
        ("header bad descr", {"K": npy_with_header(
            "{'descr': 'x9', 'fortran_order': False, 'shape': (3, 3), }", b"\0" * 72)},
         "header"),
        ("header negative shape", {"K": npy_with_header(
            "{'descr': '<f8', 'fortran_order': False, 'shape': (-3, 3), }", b"\0" * 72)},
         "header"),
        ("header huge header_len", {"K": b"\x93NUMPY\x02\x00" + struct.pack("<I", 2**31)
                                    + b"{" * 100}, "header"),
        ("not npy", {"K": b"hello, this is not a .npy member at all"}, "not a .npy array"),
        ("empty member", {"K": b""}, "not a .npy array"),
        ("bad magic version", {"K": b"\x93NUMPY\x09\x00" + b"\0" * 100}, "'K'"),
        ("truncated data", {"features": good[: len(good) // 2]}, "holds"),
        ("trailing data", {"features": good + b"\0" * 16}, "holds"),
        ("pickled objects", {"K": npy_bytes(np.array([{"a": 1}, None], dtype=object),
                                           allow_pickle=True)}, "pickle"),
        ("structured", {"K": npy_bytes(np.zeros(3, dtype=[("a", "<f8"), ("b", "<i4")]))},
         "structured"),
        ("complex", {"K": npy_bytes(np.eye(3) + 0j)}, "complex"),
        ("string", {"K": npy_bytes(np.array(["a", "b"]))}, "non-numeric dtype"),
        ("version 3", {"K": npy_with_header(
            "{'descr': '<f8', 'fortran_order': False, 'shape': (3, 3), }", b"\0" * 72,
            version=(3, 0))}, "'K'"),
    ]


@pytest.mark.parametrize("label,replace,message", _hostile_members(),
                         ids=[c[0] for c in _hostile_members()])
def test_hostile_member_is_one_line_input_error(tmp_path, label, replace, message):
    path = write_zip(tmp_path, drive_members(**replace))
    key = next(iter(replace))
    assert_input_error(path, repr(key), message)
    if key in ("K", "b"):  # read_calibration reads the same members the same way
        assert_input_error(path, repr(key), message, loader=read_calibration)


@pytest.mark.parametrize("method", [zipfile.ZIP_DEFLATED, zipfile.ZIP_STORED])
def test_damaged_compressed_data_is_an_input_error(tmp_path, method):
    path = write_zip(tmp_path, drive_members(), method=method)
    with zipfile.ZipFile(path) as zf:
        info = zf.getinfo("features.npy")
    data = bytearray(path.read_bytes())
    data[info.header_offset + 30 + len("features.npy") + info.compress_size // 2] ^= 0x5A
    path.write_bytes(bytes(data))
    assert_input_error(path, "'features'", "unreadable member")


def test_unknown_hostile_members_are_not_read(tmp_path):
    header = "{'descr': '<f8', 'fortran_order': False, 'shape': (10000000000, ), }"
    path = write_zip(tmp_path, {**drive_members(), "junk.npy": npy_with_header(header),
                                "notes.txt": b"\xff\xfe not npy"})
    assert_same_sequence(load_sequence(path), load_sequence(write(tmp_path, valid_arrays())),
                         name=False)


def test_duplicated_member_is_refused(tmp_path):
    arrays = valid_arrays()
    other = npy_bytes(2 * arrays["K"])
    path = write_zip(tmp_path, drive_members(), extra=[("K.npy", other)])
    assert_input_error(path, "'K'", "more than once")
    # "K" and "K.npy" are the same key to numpy.load: refused as well.
    path = write_zip(tmp_path, drive_members(), name="b.npz", extra=[("K", other)])
    assert_input_error(path, "'K'", "more than once")


def test_member_lying_about_its_size_is_refused_before_allocating(tmp_path):
    # A zip bomb: the directory promises ~4 GB from a few hundred compressed bytes.
    n = (0xF0000000 - 128) // 8
    header = f"{{'descr': '<f8', 'fortran_order': False, 'shape': ({n},), }}"
    path = write_zip(tmp_path, drive_members(b=npy_with_header(header, b"\0" * 4096)))
    patch_sizes(path, "b.npy", 0xF0000000)
    tracemalloc.start()
    try:
        assert_input_error(path, "'b'", "compressed")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 20e6


def test_members_beyond_the_size_limit_are_refused(tmp_path, monkeypatch):
    path = write_zip(tmp_path, drive_members())
    monkeypatch.setenv("VISLAM_MAX_ARRAY_BYTES", "500")
    assert_input_error(path, "'features'", "VISLAM_MAX_ARRAY_BYTES")
    monkeypatch.setenv("VISLAM_MAX_ARRAY_BYTES", "lots")
    assert_input_error(path, "VISLAM_MAX_ARRAY_BYTES", "'lots'")
    monkeypatch.delenv("VISLAM_MAX_ARRAY_BYTES")
    load_sequence(path)


def test_unsupported_compression_is_refused(tmp_path):
    path = write_zip(tmp_path, drive_members(), method=zipfile.ZIP_BZIP2)
    assert_input_error(path, "compress")


@pytest.mark.parametrize(
    "label,convert",
    [
        ("big-endian", lambda a: a.astype(a.dtype.newbyteorder(">"))),
        ("fortran order", np.asfortranarray),
        ("float32", lambda a: a.astype(np.float32)),
        ("int", lambda a: a.astype(np.int64) if np.all(a == np.round(a)) else a),
    ],
)
def test_unusual_but_numeric_layouts_load_identically(tmp_path, label, convert):
    arrays = valid_arrays()
    arrays["features"] = np.round(arrays["features"])
    arrays["b"] = np.array(0.5)  # exact in every dtype tried
    ref = load_sequence(write(tmp_path, arrays, "ref.npz"))
    changed = {k: (convert(v) if k in ("features", "K", "b") else v) for k, v in arrays.items()}
    assert_same_sequence(ref, load_sequence(write(tmp_path, changed)), name=False)


def test_empty_and_zero_d_arrays(tmp_path):
    arrays = valid_arrays()
    arrays["features"] = np.zeros((4, 0, T))  # no tracks at all: a valid (blind) drive
    seq = load_sequence(write(tmp_path, arrays))
    assert seq.n_tracks == 0 and len(seq.obs) == 0
    arrays = valid_arrays()
    arrays["time_stamps"] = np.zeros((1, 0))
    assert_input_error(write(tmp_path, arrays, "e.npz"), "'time_stamps' is empty")
    arrays = valid_arrays()
    arrays["b"] = np.array([0.54])  # one element, shape (1,): accepted as the scalar
    assert load_sequence(write(tmp_path, arrays, "b1.npz")).calibration.baseline == 0.54
    arrays["K"] = np.array(3.0)
    assert_input_error(write(tmp_path, arrays, "k0.npz"), "'K' has shape ()")


def test_bool_and_extreme_dtypes(tmp_path):
    arrays = valid_arrays()
    arrays["K"] = np.array([[700.0, 0, 600], [0, 700, 180], [0, 0, 1]], dtype=np.longdouble)
    arrays["linear_velocity"] = arrays["linear_velocity"].astype(np.float16)
    load_sequence(write(tmp_path, arrays))
    arrays["time_stamps"] = np.array([[0, 1, 2, 3, 4, 2**63 - 1]], dtype=np.int64)
    load_sequence(write(tmp_path, arrays, "big.npz"))
    arrays["time_stamps"] = np.ones((1, T), dtype=bool)
    assert_input_error(write(tmp_path, arrays, "bool.npz"), "not strictly increasing")
    arrays = valid_arrays()
    arrays["linear_velocity"] = np.full((3, T), 1e300, dtype=np.longdouble) ** 2
    assert_input_error(write(tmp_path, arrays, "ld.npz"), "'linear_velocity'", "NaN/inf")


def test_fifo_is_refused_without_hanging(tmp_path):
    fifo = tmp_path / "drive.npz"
    os.mkfifo(fifo)
    old = signal.signal(signal.SIGALRM, lambda *a: (_ for _ in ()).throw(TimeoutError("hang")))
    signal.alarm(5)
    try:
        assert_input_error(fifo, "not a regular file")
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


# --------------------------------------------------------------------------- issue 11, item 6


def test_partial_observations_are_dropped_counted_and_logged(tmp_path, caplog):
    # Reproduces item 6: one to three of the four rows -1 were used as a measurement.
    arrays = valid_arrays()
    ref = load_sequence(write(tmp_path, arrays, "ref.npz"))
    observed = np.argwhere(~np.all(arrays["features"] == -1, axis=0))
    (j1, t1), (j2, t2), (j3, t3), (j4, t4) = observed[[1, 4, 6, 7]]
    arrays["features"][2, j1, t1] = -1           # uR missing
    arrays["features"][[0, 1, 3], j2, t2] = -1    # only uR left
    arrays["features"][1, j3, t3] = -5.0          # a negative coordinate, not the marker
    arrays["features"][0, j4, t4] = -0.5
    path = write(tmp_path, arrays)
    with caplog.at_level(logging.WARNING, logger="vislam.eval.loader"):
        seq, report = load_sequence_with_report(path)
    assert report.n_partial == 2 and report.n_negative == 2 and report.n_invalid == 4
    assert report.first_invalid == (int(j1), int(t1))  # the first in (track, frame) order
    assert len(seq.obs) == len(ref.obs) - 4
    assert not np.any(seq.obs.z < 0)
    dense = ref.obs.to_dense(M)
    for j, t in ((j1, t1), (j2, t2), (j3, t3), (j4, t4)):
        dense[:, j, t] = -1
    np.testing.assert_array_equal(seq.obs.to_dense(M), dense)
    messages = [r.getMessage() for r in caplog.records if r.name == "vislam.eval.loader"]
    assert len(messages) == 1
    assert str(path) in messages[0] and "4 observation" in messages[0]
    assert f"track {j1}, frame {t1}" in messages[0]
    # load_sequence is the same without the report; a valid file gives no warning.
    assert_same_sequence(load_sequence(path), seq)
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="vislam.eval.loader"):
        _, report = load_sequence_with_report(write(tmp_path, valid_arrays(), "ok.npz"))
    assert report.n_invalid == 0
    assert not caplog.records


def test_both_editions_consistent_is_accepted(tmp_path):
    arrays = valid_arrays()
    both = {**arrays, **other_edition(arrays)}
    both["angular_velocity"] = both["angular_velocity"] * (1 + 1e-9)
    assert_same_sequence(load_sequence(write(tmp_path, arrays, "a.npz")),
                         load_sequence(write(tmp_path, both, "b.npz")), name=False)


@pytest.mark.parametrize("which", ["velocity", "transform", "velocity shape"])
def test_both_editions_inconsistent_is_an_error(tmp_path, which):
    # Reproduces item 6: one of the two silently won.
    arrays = valid_arrays()
    both = {**arrays, **other_edition(arrays)}
    if which == "velocity":
        both["angular_velocity"] = both["angular_velocity"].copy()
        both["angular_velocity"][1, 3] += 0.25
        keys, diff = ("'rotational_velocity'", "'angular_velocity'"), "0.25"
    elif which == "velocity shape":
        both["angular_velocity"] = both["angular_velocity"][:, :-1]
        keys, diff = ("'rotational_velocity'", "'angular_velocity'"), "shape"
    else:
        both["imu_T_cam"] = both["imu_T_cam"].copy()
        both["imu_T_cam"][1, 3] += 0.2
        keys, diff = ("'cam_T_imu'", "'imu_T_cam'"), "largest difference 0.2 at index (1, 3)"
    path = write(tmp_path, both)
    text = assert_input_error(path, *keys, "largest difference" if "shape" not in which
                              else "shape")
    assert diff in text
    if which == "transform":
        assert_input_error(path, *keys, loader=read_calibration)


def test_permission_denied_is_reported_as_such(tmp_path, monkeypatch):
    # Reproduces item 6: reported as "not a zip archive". Root reads anything, so the denial
    # is simulated where the loader opens the file (this runs everywhere, CI included) ...
    path = write(tmp_path, valid_arrays())
    import builtins

    real_open = builtins.open

    def denying_open(file, *args, **kwargs):
        if os.fspath(file) == str(path):
            raise PermissionError(errno.EACCES, "Permission denied", str(path))
        return real_open(file, *args, **kwargs)

    monkeypatch.setattr(builtins, "open", denying_open)
    monkeypatch.setattr(io, "open", denying_open)
    for loader in (load_sequence, read_calibration):
        text = assert_input_error(path, "permission denied", loader=loader)
        assert "zip" not in text
