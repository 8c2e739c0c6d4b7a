"""eval.loader: both editions of the data format, validation of every fault, the real drives."""

from __future__ import annotations

import numpy as np
import pytest

from ekf.errors import InputError
from ekf.geometry import se3_exp, se3_inv
from ekf.sequence import Sequence
from eval.loader import load_sequence, read_calibration, save_sequence, write_npz
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
