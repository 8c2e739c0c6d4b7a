"""The sparse track format (issue 36, item 1): one row per observation (obs_frame, obs_track,
obs_pixels), read beside the dense ``features``: round trips, the same drive in both layouts
gives the same Sequence and the same estimates, every hostile input is one line and exit 2,
and monocular tracks are read but refused by the (stereo) estimators."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from vislam.ekf.errors import InputError
from vislam.ekf.estimate import Estimate
from vislam.eval.cli import main
from vislam.eval.loader import (
    load_sequence,
    load_sequence_with_report,
    read_arrays,
    read_calibration,
    save_sequence,
    write_npz,
)
from vislam.eval.simulate import SimConfig, simulate
from tests.sequence_asserts import assert_same_sequence
from tests.test_loader import M, T  # the size of that drive
from tests.test_loader import valid_arrays as dense_arrays  # a small valid drive, dense layout



def to_sparse(arrays: dict[str, np.ndarray], shuffle: int | None = None) -> dict[str, np.ndarray]:
    """The same drive with its observations as sparse rows (in a random order for ``shuffle``,
    a seed); every (track, frame) with any coordinate other than -1 is a row."""
    out = dict(arrays)
    feats = out.pop("features")
    track, frame = np.nonzero(~np.all(feats == -1, axis=0))
    rows = np.arange(track.size)
    if shuffle is not None:
        rows = np.random.default_rng(shuffle).permutation(rows)
    out.update(obs_frame=frame[rows], obs_track=track[rows], obs_pixels=feats[:, track, frame].T[rows])
    return out


def write(tmp_path, arrays, name="drive.npz"):
    path = tmp_path / name
    np.savez(path, **arrays)
    return path


def refused(path, *fragments, capsys=None):
    """load_sequence raises one line naming the file and the fragments; `vislam inspect` exits
    2 with that line."""
    with pytest.raises(InputError) as info:
        load_sequence(path)
    text = str(info.value)
    assert "\n" not in text and str(path) in text, text
    for fragment in fragments:
        assert fragment in text, text
    if capsys is not None:
        capsys.readouterr()
        assert main(["inspect", str(path)]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and str(path) in err, err
        for fragment in fragments:
            assert fragment in err, err
    return text


# --------------------------------------------------------------------------- reading both


def test_sparse_and_dense_files_of_one_drive_load_identically(tmp_path):
    arrays = dense_arrays()
    dense = load_sequence(write(tmp_path, arrays, "dense.npz"))
    sparse = load_sequence(write(tmp_path, to_sparse(arrays), "sparse.npz"))
    assert_same_sequence(dense, sparse, name=False)
    np.testing.assert_array_equal(dense.track_origin, sparse.track_origin)
    assert sparse.obs.camera == "stereo" and sparse.obs.is_stereo


def test_rows_in_any_order_are_sorted(tmp_path):
    arrays = dense_arrays()
    ref = load_sequence(write(tmp_path, to_sparse(arrays), "a.npz"))
    for seed in range(3):
        got = load_sequence(write(tmp_path, to_sparse(arrays, shuffle=seed), f"s{seed}.npz"))
        assert_same_sequence(ref, got, name=False)
    got = read_arrays(tmp_path / "s0.npz")  # read_arrays gives the sorted rows
    assert np.all(np.diff(got["obs_frame"]) >= 0) and got["obs_track"].dtype == np.int64
    assert int(got["n_tracks"]) == M and "features" not in got


@pytest.mark.parametrize("dtype", [np.int32, np.uint16, np.float64, np.float32])
def test_id_columns_take_any_integer_dtype_or_integer_floats(tmp_path, dtype):
    arrays = to_sparse(dense_arrays())
    ref = load_sequence(write(tmp_path, arrays, "ref.npz"))
    arrays.update(obs_frame=arrays["obs_frame"].astype(dtype),
                  obs_track=arrays["obs_track"].astype(dtype))
    assert_same_sequence(ref, load_sequence(write(tmp_path, arrays)), name=False)


def test_n_tracks_keeps_track_ids_beyond_the_observed_ones(tmp_path):
    arrays = to_sparse(dense_arrays())
    assert load_sequence(write(tmp_path, arrays, "a.npz")).n_tracks == M
    seq = load_sequence(write(tmp_path, {**arrays, "n_tracks": np.array(M + 3)}, "b.npz"))
    assert seq.n_tracks == M + 3 and np.all(seq.track_lengths()[M:] == 0)
    empty = {**arrays, "obs_frame": np.zeros(0, int), "obs_track": np.zeros(0, int),
             "obs_pixels": np.zeros((0, 4))}
    blind = load_sequence(write(tmp_path, empty, "blind.npz"))  # no observations: a valid drive
    assert blind.n_tracks == 0 and len(blind.obs) == 0 and blind.obs.frame_ptr.size == T + 1


def test_save_sequence_round_trip_is_the_identical_sequence(tmp_path):
    seq = load_sequence(write(tmp_path, dense_arrays(), "dense.npz"))
    seq = type(seq)(**{**seq.__dict__, "n_tracks": M + 2})  # trailing unobserved track ids
    save_sequence(tmp_path / "saved.npz", seq)
    with np.load(tmp_path / "saved.npz") as f:
        assert "features" not in f.files and f["obs_pixels"].shape == (len(seq.obs), 4)
    assert_same_sequence(seq, load_sequence(tmp_path / "saved.npz"), name=False)
    assert not list(tmp_path.glob("*.tmp"))


def test_write_npz_takes_one_layout(tmp_path):
    a = to_sparse(dense_arrays())
    common = dict(time_stamps=a["time_stamps"], linear_velocity=a["linear_velocity"],
                  angular_velocity=a["rotational_velocity"], K=a["K"], b=0.54,
                  cam_T_imu=a["cam_T_imu"])
    write_npz(tmp_path / "w.npz", obs_frame=a["obs_frame"], obs_track=a["obs_track"],
              obs_pixels=a["obs_pixels"], **common)
    assert_same_sequence(load_sequence(tmp_path / "w.npz"),
                         load_sequence(write(tmp_path, a, "ref.npz")), name=False)
    with pytest.raises(ValueError):
        write_npz(tmp_path / "x.npz", obs_frame=a["obs_frame"], **common)
    with pytest.raises(ValueError):
        write_npz(tmp_path / "y.npz", features=np.zeros((4, 1, T)), obs_frame=a["obs_frame"],
                  obs_track=a["obs_track"], obs_pixels=a["obs_pixels"], **common)


def test_partial_rows_follow_the_dense_rule(tmp_path, caplog):
    arrays = dense_arrays()
    observed = np.argwhere(~np.all(arrays["features"] == -1, axis=0))
    (j1, t1), (j2, t2), (j3, t3) = observed[[1, 4, 6]]
    arrays["features"][2, j1, t1] = -1         # a missing right pixel
    arrays["features"][[0, 1, 3], j2, t2] = -1  # only uR left
    arrays["features"][1, j3, t3] = -5.0        # a negative coordinate, not the marker
    with caplog.at_level(logging.WARNING, logger="vislam.eval.loader"):
        dense, dense_report = load_sequence_with_report(write(tmp_path, arrays, "dense.npz"))
        sparse, report = load_sequence_with_report(
            write(tmp_path, to_sparse(arrays, shuffle=1), "sparse.npz"))
    assert report == dense_report
    assert report.n_partial == 2 and report.n_negative == 1
    assert report.first_invalid == (int(j1), int(t1))
    assert_same_sequence(dense, sparse, name=False)
    (message,) = [r.getMessage() for r in caplog.records if "sparse.npz" in r.getMessage()]
    assert "'obs_pixels'" in message and f"track {j1}, frame {t1}" in message


def test_rows_of_all_minus_one_are_no_observation(tmp_path, caplog):
    arrays = to_sparse(dense_arrays())
    ref = load_sequence(write(tmp_path, arrays, "ref.npz"))
    extra = {**arrays, "obs_frame": np.r_[arrays["obs_frame"], 5],
             "obs_track": np.r_[arrays["obs_track"], 0],
             "obs_pixels": np.r_[arrays["obs_pixels"], -np.ones((1, 4))]}
    with caplog.at_level(logging.WARNING, logger="vislam.eval.loader"):
        seq, report = load_sequence_with_report(write(tmp_path, extra))
    assert report.n_invalid == 0 and not caplog.records
    assert_same_sequence(ref, seq, name=False)


# --------------------------------------------------------------------------- hostile input


def _hostile_cases():
    def with_row(key, index, value):
        def change(a):
            a[key] = a[key].astype(float) if isinstance(value, float) else a[key].copy()
            a[key][index] = value
        return change

    return [
        ("frame out of range", with_row("obs_frame", 3, T), ("'obs_frame'", "row 3", f"{T}",
                                                             "out of range")),
        ("frame negative", with_row("obs_frame", 2, -1), ("'obs_frame'", "row 2", "-1",
                                                          "negative")),
        ("frame not integer", with_row("obs_frame", 4, 2.5), ("'obs_frame'", "row 4", "2.5",
                                                              "not an integer")),
        ("frame NaN", with_row("obs_frame", 1, np.nan), ("'obs_frame'", "row 1", "nan")),
        ("track negative", with_row("obs_track", 5, -3), ("'obs_track'", "row 5", "-3",
                                                          "negative")),
        ("track not integer", with_row("obs_track", 0, 1.25), ("'obs_track'", "row 0", "1.25",
                                                               "not an integer")),
        ("pixel NaN", with_row("obs_pixels", (7, 2), np.nan), ("'obs_pixels'", "row 7",
                                                               "column 2", "nan")),
        ("pixel inf", with_row("obs_pixels", (0, 1), np.inf), ("'obs_pixels'", "row 0", "inf")),
        ("duplicated pair", lambda a: a.update(
            obs_frame=np.r_[a["obs_frame"], a["obs_frame"][2]],
            obs_track=np.r_[a["obs_track"], a["obs_track"][2]],
            obs_pixels=np.r_[a["obs_pixels"], a["obs_pixels"][2:3] + 1]),
         ("'obs_frame'", "'obs_track'", "rows 2 and 15", "both observe")),
        ("three columns", lambda a: a.update(obs_pixels=a["obs_pixels"][:, :3]),
         ("'obs_pixels'", "shape (15, 3)", "(N, 4)", "(N, 2)")),
        ("one-d pixels", lambda a: a.update(obs_pixels=a["obs_pixels"].ravel()),
         ("'obs_pixels'", "shape (60,)")),
        ("lengths differ", lambda a: a.update(obs_track=a["obs_track"][:-1]),
         ("'obs_frame' (15 rows)", "'obs_track' (14 rows)", "'obs_pixels' (15 rows)", "row 14")),
        ("frame 2-d", lambda a: a.update(obs_frame=a["obs_frame"][:, None]),
         ("'obs_frame'", "shape (15, 1)", "expected (N,)")),
        ("track strings", lambda a: a.update(obs_track=a["obs_track"].astype(str)),
         ("'obs_track'", "non-numeric dtype")),
        ("track bool", lambda a: a.update(obs_track=a["obs_track"] > 2),
         ("'obs_track'", "expected integers")),
        ("pixels strings", lambda a: a.update(obs_pixels=a["obs_pixels"].astype(str)),
         ("'obs_pixels'", "non-numeric")),
        ("both layouts", lambda a: a.update(features=dense_arrays()["features"]),
         ("'features'", "'obs_frame'", "one layout")),
        ("part of the sparse keys", lambda a: a.pop("obs_pixels"),
         ("sparse layout", "missing 'obs_pixels'")),
        ("only n_tracks", lambda a: [a.pop(k) for k in ("obs_frame", "obs_track", "obs_pixels")]
         + [a.update(n_tracks=np.array(3))], ("missing 'obs_frame', 'obs_track', 'obs_pixels'",)),
        ("no observations at all", lambda a: [a.pop(k) for k in
                                              ("obs_frame", "obs_track", "obs_pixels")],
         ("missing key 'features'", "'obs_frame'")),
        ("n_tracks too small", lambda a: a.update(n_tracks=np.array(2)),
         ("'n_tracks'", "2 track ids", f"track id {M - 1}")),
        ("n_tracks negative", lambda a: a.update(n_tracks=np.array(-1)),
         ("'n_tracks'", "negative")),
        ("n_tracks not integer", lambda a: a.update(n_tracks=np.array(7.5)),
         ("'n_tracks'", "7.5", "not an integer")),
        ("n_tracks array", lambda a: a.update(n_tracks=np.arange(3)), ("'n_tracks'", "(3,)")),
        ("stereo without b", lambda a: a.pop("b"), ("missing key 'b'",)),
    ]


@pytest.mark.parametrize("label,change,fragments", _hostile_cases(),
                         ids=[c[0] for c in _hostile_cases()])
def test_each_sparse_fault_is_one_line_exit_2_naming_key_and_row(tmp_path, capsys, label,
                                                                   change, fragments):
    arrays = to_sparse(dense_arrays())
    assert arrays["obs_frame"].size == 15
    change(arrays)
    refused(write(tmp_path, arrays), *fragments, capsys=capsys)


def test_huge_track_ids_are_refused_before_allocating(tmp_path, monkeypatch):
    arrays = to_sparse(dense_arrays())
    arrays["obs_track"] = arrays["obs_track"].astype(np.uint64)
    arrays["obs_track"][9] = np.uint64(2**63 + 5)
    refused(write(tmp_path, arrays), "'obs_track'", "row 9", str(2**63 + 5),
            "VISLAM_MAX_ARRAY_BYTES")
    arrays = to_sparse(dense_arrays())
    arrays["obs_track"][4] = 10**9  # 72 GB of per-track covariances
    refused(write(tmp_path, arrays, "b.npz"), "'obs_track'", "row 4", str(10**9))
    monkeypatch.setenv("VISLAM_MAX_ARRAY_BYTES", str(100 * 72))
    arrays = to_sparse(dense_arrays())
    load_sequence(write(tmp_path, {**arrays, "n_tracks": np.array(100)}, "c.npz"))
    refused(write(tmp_path, {**arrays, "n_tracks": np.array(101)}, "d.npz"), "'n_tracks'",
            "101 track ids", "VISLAM_MAX_ARRAY_BYTES")
    monkeypatch.setenv("VISLAM_MAX_ARRAY_BYTES", "200")  # the rows themselves: safe_reading's
    refused(write(tmp_path, arrays, "e.npz"), "'obs_pixels'", "VISLAM_MAX_ARRAY_BYTES")


# --------------------------------------------------------------------------- monocular


def mono_arrays() -> dict[str, np.ndarray]:
    arrays = to_sparse(dense_arrays())
    arrays["obs_pixels"] = arrays["obs_pixels"][:, :2]
    arrays.pop("b")  # a monocular drive has no baseline
    return arrays


def test_monocular_tracks_are_read_but_refused_by_the_estimators(tmp_path, capsys):
    path = write(tmp_path, mono_arrays(), "mono.npz")
    seq = load_sequence(path, monocular=True)
    assert seq.obs.z.shape == (15, 2) and seq.obs.camera == "monocular" and not seq.obs.is_stereo
    assert np.isnan(seq.calibration.baseline)
    ref = load_sequence(write(tmp_path, to_sparse(dense_arrays()), "stereo.npz"))
    np.testing.assert_array_equal(seq.obs.z, ref.obs.z[:, :2])
    np.testing.assert_array_equal(seq.obs.frame_ptr, ref.obs.frame_ptr)
    cal, n = read_calibration(path)
    assert n == T and np.isnan(cal.baseline)

    text = refused(path, "'obs_pixels'", "monocular", "raw-IMU estimator")
    for estimator in ("ekf-invariant", "dead-reckoning"):
        capsys.readouterr()
        assert main(["run", str(path), "-e", estimator, "--out", str(tmp_path / estimator),
                     "-q"]) == 2
        assert capsys.readouterr().err.strip().endswith(text)
        assert not (tmp_path / estimator).exists()
    assert main(["calibrate", str(path)]) == 2
    assert main(["inspect", str(path), "--check"]) == 2
    assert "monocular" in capsys.readouterr().err

    assert main(["inspect", str(path)]) == 0
    out = capsys.readouterr().out
    assert "camera: monocular" in out and "no baseline" in out and "observations 15" in out

    save_sequence(tmp_path / "again.npz", seq)  # written back without b
    with np.load(tmp_path / "again.npz") as f:
        assert "b" not in f.files and f["obs_pixels"].shape == (15, 2)
    again = load_sequence(tmp_path / "again.npz", monocular=True)
    for field in ("timestamps", "linear_velocity", "angular_velocity"):
        np.testing.assert_array_equal(getattr(seq, field), getattr(again, field))
    for field in ("frame_ptr", "track", "z"):
        np.testing.assert_array_equal(getattr(seq.obs, field), getattr(again.obs, field))
    assert again.n_tracks == seq.n_tracks and np.isnan(again.calibration.baseline)


def test_monocular_partial_rows_and_a_given_baseline(tmp_path):
    arrays = mono_arrays()
    arrays["obs_pixels"] = arrays["obs_pixels"].copy()
    arrays["obs_pixels"][3, 1] = -1  # one of u, v missing: dropped, counted
    seq, report = load_sequence_with_report(write(tmp_path, {**arrays, "b": np.array(0.3)}),
                                            monocular=True)
    assert report.n_partial == 1 and len(seq.obs) == 14 and seq.calibration.baseline == 0.3
    refused(write(tmp_path, {**arrays, "b": np.array(-1.0)}, "b.npz"), "'b'", "positive")


# --------------------------------------------------------------------------- estimates


@pytest.fixture(scope="module")
def both_files(tmp_path_factory):
    """One short simulated drive written dense and sparse."""
    from vislam.eval.sim_files import write_simulation

    folder = tmp_path_factory.mktemp("layouts")
    result = simulate(SimConfig(seed=5, n_frames=40, name="sparse"))
    sparse = write_simulation(result, folder)["data"]
    seq = result.sequence
    dense = folder / "dense.npz"
    write_npz(dense, time_stamps=seq.timestamps, features=seq.obs.to_dense(seq.n_tracks),
              linear_velocity=seq.linear_velocity.T, angular_velocity=seq.angular_velocity.T,
              K=seq.calibration.K, b=seq.calibration.baseline, cam_T_imu=seq.calibration.cam_T_imu)
    gt = folder / "groundtruth"
    (gt / "dense.txt").write_bytes((gt / "sparse.txt").read_bytes())
    return result, dense, sparse


def test_dense_and_sparse_files_give_the_same_sequence_and_estimates(both_files, tmp_path):
    result, dense, sparse = both_files
    a, b = load_sequence(dense), load_sequence(sparse)
    assert_same_sequence(a, b, name=False)
    assert_same_sequence(b, result.sequence, name=False)
    for estimator in ("ekf-invariant", "smoother"):
        estimates = []
        for path in (dense, sparse):
            out = tmp_path / f"{estimator}-{path.stem}"
            assert main(["run", str(path), "-e", estimator, "--out", str(out), "-q",
                         "--no-plots"]) == 0
            estimates.append(Estimate.load_npz(out / "estimate.npz"))
        x, y = estimates
        for field in ("poses", "pose_cov", "landmarks", "landmark_cov"):
            np.testing.assert_array_equal(getattr(x, field), getattr(y, field), err_msg=field)


def test_inspect_reads_both_layouts_alike(both_files, capsys):
    _, dense, sparse = both_files
    outs = []
    for path in (dense, sparse):
        assert main(["inspect", str(path)]) == 0
        out = capsys.readouterr().out
        outs.append(out.replace(str(path), "FILE").replace(f"{path.stem}.txt", "GT"))
    assert outs[0] == outs[1]
