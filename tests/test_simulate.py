"""The simulator: determinism, exact noise-free consistency, realistic statistics, file layout."""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
import pytest

from vislam.ekf.camera import project
from vislam.ekf.errors import InputError
from vislam.ekf.geometry import homogeneous, is_rigid, se3_exp, se3_inv
from vislam.eval.cli import main as cli_main
from vislam.eval.sim_config import DEFAULT_SIM, KITTI_CAM_T_IMU, SimConfig
from vislam.eval.sim_drawing import integrate_mean_pairing
from vislam.eval.sim_files import write_simulation
from vislam.eval.simulate import default_sequence, simulate, simulation_stats
from tests.sequence_asserts import assert_same_sequence

SMALL = SimConfig(seed=7, n_frames=200)


@pytest.fixture(scope="module")
def default_result():
    return simulate(DEFAULT_SIM)


@pytest.fixture(scope="module")
def clean_result():
    return simulate(replace(SMALL, noise_free=True))


def _file_bytes(paths):
    return {role: p.read_bytes() for role, p in paths.items()}


def test_same_seed_same_bytes_different_seed_different(tmp_path):
    a = write_simulation(simulate(SMALL), tmp_path / "a", "x")
    b = write_simulation(simulate(SMALL), tmp_path / "b", "x")
    c = write_simulation(simulate(replace(SMALL, seed=8)), tmp_path / "c", "x")
    fa, fb, fc = _file_bytes(a), _file_bytes(b), _file_bytes(c)
    assert set(fa) == {"data", "groundtruth", "landmarks", "model"}
    for role in fa:
        assert fa[role] == fb[role], role
        assert fa[role] != fc[role], role


def test_written_layout_matches_the_shared_data(tmp_path):
    result = simulate(SMALL)
    paths = write_simulation(result, tmp_path, "drive")
    assert paths["data"] == tmp_path / "drive.npz"
    assert paths["groundtruth"] == tmp_path / "groundtruth" / "drive.txt"
    assert paths["landmarks"] == tmp_path / "drive_landmarks.npz"
    seq = result.sequence
    T, M, N = seq.n_frames, seq.n_tracks, len(seq.obs)
    with np.load(paths["data"]) as d:
        shapes = {k: d[k].shape for k in d.files}
        assert shapes == {  # the sparse observation layout: nothing of size tracks x frames
            "time_stamps": (1, T),
            "obs_frame": (N,),
            "obs_track": (N,),
            "obs_pixels": (N, 4),
            "n_tracks": (),
            "linear_velocity": (3, T),
            "rotational_velocity": (3, T),
            "K": (3, 3),
            "b": (),
            "cam_T_imu": (4, 4),
        }
        np.testing.assert_array_equal(d["cam_T_imu"], KITTI_CAM_T_IMU)
        assert d["obs_frame"].dtype == np.int64 and d["obs_track"].dtype == np.int64
        assert int(d["n_tracks"]) == M
        np.testing.assert_array_equal(d["obs_frame"], seq.obs.frame_index)
        np.testing.assert_array_equal(d["obs_track"], seq.obs.track)
        np.testing.assert_array_equal(d["obs_pixels"], seq.obs.z)
        assert np.all(d["obs_pixels"] >= 0)
        np.testing.assert_array_equal(d["linear_velocity"], seq.linear_velocity.T)
    # Ground truth: 13 columns, time since frame 0, left-camera poses; P(0) = I.
    gt = np.loadtxt(paths["groundtruth"])
    assert gt.shape == (T, 13)
    np.testing.assert_allclose(gt[:, 0], seq.timestamps - seq.timestamps[0])
    P = np.tile(np.eye(4), (T, 1, 1))
    P[:, :3, :4] = gt[:, 1:].reshape(-1, 3, 4)
    np.testing.assert_allclose(P[0], np.eye(4), atol=1e-15)
    T_imu = np.linalg.inv(KITTI_CAM_T_IMU) @ P @ KITTI_CAM_T_IMU  # the README's formula
    np.testing.assert_allclose(T_imu, result.poses, atol=1e-9)
    with np.load(paths["landmarks"]) as d:
        np.testing.assert_array_equal(d["landmarks"], result.landmarks)
        np.testing.assert_array_equal(d["poses"], result.poses)
        assert d["landmarks"].shape == (M, 3)


def test_noise_free_observations_are_exact_projections(clean_result):
    r = clean_result
    seq = r.sequence
    frames = seq.obs.frame_index
    cam_T_world = seq.calibration.cam_T_imu @ se3_inv(r.poses)  # (T, 4, 4)
    q = (cam_T_world[frames] @ homogeneous(r.landmarks[seq.obs.track])[..., None])[..., 0]
    np.testing.assert_allclose(project(seq.calibration.M, q), seq.obs.z, rtol=0, atol=1e-9)
    assert np.all(np.isfinite(r.landmarks))


def test_noise_free_velocities_integrate_to_true_poses_with_mean_pairing(clean_result):
    r = clean_result
    seq = r.sequence
    np.testing.assert_array_equal(seq.velocities, r.true_velocities)
    poses = np.empty_like(r.poses)
    poses[0] = np.eye(4)
    u = seq.velocities
    for k in range(seq.n_frames - 1):  # the filter's prediction, "mean" pairing
        poses[k + 1] = poses[k] @ se3_exp(seq.dt[k] * 0.5 * (u[k] + u[k + 1]))
    np.testing.assert_allclose(poses, r.poses, rtol=0, atol=1e-9)
    np.testing.assert_allclose(integrate_mean_pairing(u, seq.dt), r.poses, rtol=0, atol=1e-12)
    assert all(is_rigid(T, tol=1e-9) for T in r.poses)
    # The "current" pairing is measurably different: the pairing matters.
    cur = np.eye(4)
    for k in range(seq.n_frames - 1):
        cur = cur @ se3_exp(seq.dt[k] * u[k])
    assert np.linalg.norm(cur[:3, 3] - r.poses[-1, :3, 3]) > 1e-3


def test_noise_free_is_the_ground_truth_of_the_noisy_drive(clean_result):
    noisy = simulate(SMALL)
    np.testing.assert_array_equal(noisy.poses, clean_result.poses)
    np.testing.assert_array_equal(noisy.true_velocities, clean_result.true_velocities)
    res = noisy.sequence.velocities - noisy.true_velocities
    assert 0.4 < res[:, :3].std() < 0.6
    assert 0.04 < res[:, 3:].std() < 0.06
    # Tracks match (no disparity drop happens this far from the 0.5 px threshold).
    np.testing.assert_array_equal(noisy.sequence.obs.track, clean_result.sequence.obs.track)
    pix = noisy.sequence.obs.z - clean_result.sequence.obs.z
    assert 0.95 < pix.std() < 1.05


def test_gyro_bias_is_added_to_the_angular_velocity():
    r = simulate(replace(SMALL, gyro_sigma=0.0, velocity_sigma=0.0, gyro_bias=(0.01, -0.005, 0.002)))
    diff = r.sequence.angular_velocity - r.true_velocities[:, 3:]
    np.testing.assert_allclose(diff, np.tile([0.01, -0.005, 0.002], (SMALL.n_frames, 1)), atol=1e-15)
    np.testing.assert_array_equal(r.sequence.linear_velocity, r.true_velocities[:, :3])


def test_default_drive_statistics(default_result):
    r = default_result
    stats = simulation_stats(r)
    assert 50 <= stats["obs_per_frame_mean"] <= 100
    assert stats["obs_per_frame_min"] >= 20
    assert 5.0 <= stats["speed_min"] and stats["speed_max"] <= 12.0
    assert stats["yaw_rate_max_abs"] <= 0.3 + 1e-12
    assert 4.0 <= stats["track_length_mean"] <= 12.0
    # The car moves forward along body x; pitch stays within a few degrees.
    v = r.true_velocities
    np.testing.assert_array_equal(v[:, 1:3], 0.0)
    forward_z = r.poses[:, 2, 0]  # world z component of the body x axis
    assert np.all(np.abs(np.degrees(np.arcsin(forward_z))) < 5.0)


def test_landmark_depths_are_3_to_60_m(default_result):
    r = default_result
    seq = r.sequence
    frames = seq.obs.frame_index
    cam_T_world = seq.calibration.cam_T_imu @ se3_inv(r.poses)
    q = (cam_T_world[frames] @ homogeneous(r.landmarks[seq.obs.track])[..., None])[..., 0]
    assert q[:, 2].min() >= 3.0 and q[:, 2].max() <= 60.0
    assert np.all(seq.obs.z[:, 0] - seq.obs.z[:, 2] >= 0.5)


def test_tracks_are_contiguous_end_and_never_resume(default_result):
    seq = default_result.sequence
    first, last = seq.track_first_frame(), seq.track_last_frame()
    lengths = seq.track_lengths()
    assert np.all(lengths >= 1)
    np.testing.assert_array_equal(last - first + 1, lengths)  # no gaps, no resumption
    assert np.all(np.diff(first) >= 0)  # numbered in order of appearance
    # A landmark re-seen later gets a new track index, never an old one back.
    tl = default_result.track_landmark
    assert np.unique(tl).size < tl.size
    order = np.lexsort((first, tl))
    same = tl[order][1:] == tl[order][:-1]
    assert np.all(first[order][1:][same] > last[order][:-1][same])


def test_bad_settings_raise_input_error():
    with pytest.raises(InputError, match="n_frames"):
        SimConfig(n_frames=1)
    with pytest.raises(InputError, match="gyro_bias"):
        SimConfig(gyro_bias=(0.0, 0.0))
    with pytest.raises(InputError, match="pixel_sigma"):
        SimConfig(pixel_sigma=-1.0)


def test_default_simulation_is_quick():
    start = time.perf_counter()
    simulate(DEFAULT_SIM)
    assert time.perf_counter() - start < 2.0


def test_default_sequence_matches_simulate():
    seq = default_sequence(seed=2)
    ref = simulate(replace(DEFAULT_SIM, seed=2)).sequence
    np.testing.assert_array_equal(seq.obs.z, ref.obs.z)
    np.testing.assert_array_equal(seq.velocities, ref.velocities)


def test_cli_writes_the_files(tmp_path, capsys):
    rc = cli_main(["simulate", "--out", str(tmp_path), "--seed", "4", "--frames", "50"])
    assert rc == 0
    out = capsys.readouterr().out
    assert "wrote data" in out
    assert (tmp_path / "sim-seed4.npz").exists()
    assert (tmp_path / "groundtruth" / "sim-seed4.txt").exists()
    assert (tmp_path / "sim-seed4_landmarks.npz").exists()
    rc = cli_main(["simulate", "--out", str(tmp_path), "--gyro-bias", "1", "2"])
    assert rc == 2
    assert "--gyro-bias" in capsys.readouterr().err


def test_written_file_loads_back_as_the_same_sequence(tmp_path):
    from vislam.eval.loader import load_sequence

    result = simulate(SMALL)
    paths = write_simulation(result, tmp_path, "drive")
    loaded = load_sequence(paths["data"])
    seq = result.sequence
    assert_same_sequence(loaded, seq, name=False)
    np.testing.assert_array_equal(loaded.calibration.cam_T_imu, seq.calibration.cam_T_imu)


def test_default_drive_read_back_is_the_drive_in_memory(default_result, tmp_path):
    from vislam.eval.loader import load_sequence

    paths = write_simulation(default_result, tmp_path)
    seq = default_result.sequence
    loaded = load_sequence(paths["data"])
    assert_same_sequence(loaded, seq)
    np.testing.assert_array_equal(loaded.track_origin, seq.track_origin)
    # the file grows with the observations: 48 bytes a row before compression, against the
    # dense layout's 32 bytes a track and frame
    assert paths["data"].stat().st_size < 48 * len(seq.obs)


def test_a_drive_the_reader_would_refuse_is_not_written(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("VISLAM_MAX_ARRAY_BYTES", str(200 * 32))  # 200 stereo rows
    out = tmp_path / "sim"
    assert cli_main(["simulate", "--out", str(out), "--frames", "20"]) == 2
    err = capsys.readouterr().err
    assert "VISLAM_MAX_ARRAY_BYTES" in err and "observations" in err
    assert len(err.strip().splitlines()) == 1
    assert not out.exists() or not any(out.iterdir())


@pytest.mark.parametrize("flags, message", [
    (["--seed", "-1"], "seed"),
    (["--frames", "1"], "n_frames"),
    (["--frames", "100000"], "n_frames"),
    (["--velocity-sigma", "1e300"], "velocity_sigma"),
    (["--gyro-sigma", "nan"], "gyro_sigma"),
    (["--gyro-bias", "1e308"], "gyro_bias"),
    (["--pixel-sigma", "inf"], "pixel_sigma"),
    (["--landmark-density", "1e9"], "landmark_density"),
    (["--repeat-event-rate", "-0.1"], "repeat_event_rate"),
])
def test_hostile_simulation_settings_one_line_exit_2_nothing_written(flags, message, tmp_path, capsys):
    from vislam.eval.cli import main

    out = tmp_path / "sim"
    frames = [] if "--frames" in flags else ["--frames", "20"]
    assert main(["simulate", "--out", str(out), *frames, *flags]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1
    assert list(tmp_path.iterdir()) == []
