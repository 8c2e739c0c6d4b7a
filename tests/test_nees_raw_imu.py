"""`vislam nees --imu` (issue 37 item 2): the Monte Carlo consistency study on the raw-IMU
simulator's drives, each run with its own simulator seed on one scene, the raw-IMU estimators
scored against the truth in each estimate's own gauge as `vislam bench` scores them."""

from __future__ import annotations

import json

import numpy as np
import pytest

from vislam.eval.bench_scores import truth_in_gauge
from vislam.eval.cli import main
from vislam.eval.commands.nees import nees_estimators
from vislam.eval.groundtruth import GroundTruth
from vislam.eval.imu_sim import simulate_imu
from vislam.eval.imu_sim_config import ImuSimConfig
from vislam.eval.metrics import pose_errors
from vislam.eval.montecarlo_imu import (
    imu_monte_carlo_drives,
    imu_nees_config,
    run_seed,
    truth_in_estimate_gauge,
)
from vislam.eval.registry import DEFAULT_BENCH_INERTIAL, INERTIAL_ESTIMATOR_NAMES, estimator_kind

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def test_runs_share_the_scene_and_draw_their_own_noise():
    config = imu_nees_config(4, "room", "mono", 21)
    assert config.scene == 4 and config.n_frames == 21
    truth, free, drives = imu_monte_carlo_drives(config, 3)
    seeds = [run_seed(4, i) for i in range(3)]
    assert len(set(seeds)) == 3 and seeds == [run_seed(4, i) for i in range(3)]  # deterministic
    assert run_seed(5, 0) != seeds[0]
    for i, (key, drive) in enumerate(drives.items()):
        assert key == f"run{i:03d}"
        same, run_truth = simulate_imu(ImuSimConfig(seed=seeds[i], scene_seed=4, n_frames=21))
        assert np.array_equal(drive.imu.gyro, same.imu.gyro)  # run i is the simulator's seed i
        assert np.array_equal(run_truth.frame_poses, truth.frame_poses)
        assert np.array_equal(run_truth.landmarks, truth.landmarks)
        assert np.array_equal(drive.obs.track, free.obs.track)
        assert np.array_equal(drive.timestamps, free.timestamps)
    a, b = drives["run000"], drives["run001"]
    assert not np.array_equal(a.imu.accel, b.imu.accel)
    assert not np.array_equal(a.obs.z, b.obs.z)


def test_truth_moves_into_the_estimates_gauge_with_its_landmarks():
    """Poses as `vislam bench` takes them (truth_in_gauge); the landmarks by the same move."""
    _, truth = simulate_imu(ImuSimConfig(n_frames=21, seed=1))
    drive, _ = simulate_imu(ImuSimConfig(n_frames=21, seed=2, scene_seed=1))
    move = np.eye(4)
    c, s = np.cos(0.7), np.sin(0.7)
    move[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    move[:3, 3] = [1.0, -2.0, 0.5]
    from vislam.ekf.estimate import Estimate

    est = Estimate.empty("x", drive.timestamps, drive.n_tracks)
    est.poses = move @ truth.frame_poses
    poses, landmarks = truth_in_estimate_gauge(drive, est, truth.frame_poses, truth.landmarks)
    bench = truth_in_gauge(GroundTruth(np.arange(21), truth.frame_poses, "sim"), drive, est)
    assert np.array_equal(poses, bench.poses)
    np.testing.assert_allclose(poses, est.poses, atol=1e-9)
    np.testing.assert_allclose(landmarks, truth.landmarks @ move[:3, :3].T + move[:3, 3], atol=1e-9)


def test_nees_imu_writes_the_study(tmp_path, capsys):
    out = tmp_path / "nees"
    assert main(["nees", "--imu", "--runs", "2", "--frames", "41", "--seed", "3",
                 "-e", "dead-reckoning-imu", "-j", "1", "--out", str(out)]) == 0
    table = capsys.readouterr().out
    assert "ANEES over 2 runs (41 frames, raw IMU: room, mono)" in table
    assert "| dead-reckoning-imu |" in table
    data = json.loads((out / "nees.json").read_text())
    assert data["drive_kind"] == "raw-imu" and data["frames"] == 41 and data["runs"] == 2
    assert data["simulation"]["scene_seed"] == 3 and data["simulation"]["scenario"] == "room"
    assert data["noise_seeds"] == [run_seed(3, 0), run_seed(3, 1)]
    r = data["estimators"]["dead-reckoning-imu"]
    assert r["runs_failed"] == 0 and r["anees_landmark"] is None
    assert len(r["nees_pose_over_time"]) == 41 and r["nees_pose_over_time"][0] is None
    assert r["bounds_pose"][0] < 6 < r["bounds_pose"][1] and r["anees_pose"] > 0
    assert (out / "nees.png").read_bytes().startswith(PNG_MAGIC)

    # the pose NEES of frames 1..T-1 against the truth in the estimate's gauge, by hand
    from vislam.eval.builtin import dead_reckoning_imu

    config = imu_nees_config(3, "room", "mono", 41)
    truth, _, drives = imu_monte_carlo_drives(config, 2)
    for i, drive in enumerate(drives.values()):
        est = dead_reckoning_imu(drive, None)
        gt = truth_in_gauge(GroundTruth(np.arange(41), truth.frame_poses, "sim"), drive, est)
        err = pose_errors(est.poses, gt.poses)[1:]
        nees = [e @ np.linalg.solve(C, e) for e, C in zip(err, est.pose_cov[1:])]
        assert r["nees_pose_per_run_mean"][i] == pytest.approx(np.mean(nees), rel=1e-12)


@pytest.mark.slow
def test_nees_imu_scores_the_smoothers_landmarks(tmp_path, capsys):
    out = tmp_path / "nees"
    assert main(["nees", "--imu", "--runs", "2", "--frames", "61", "-e", "smoother-imu",
                 "-j", "2", "--out", str(out), "-q"]) == 0
    r = json.loads((out / "nees.json").read_text())["estimators"]["smoother-imu"]
    assert r["runs_failed"] == 0 and r["landmarks_scored"] > 20
    assert np.isfinite(r["anees_landmark"]) and np.isfinite(r["anees_pose"])


def test_with_imu_the_estimators_are_the_raw_imu_group():
    assert nees_estimators(None, True) == list(DEFAULT_BENCH_INERTIAL)
    assert nees_estimators("all", True) == [n for n in INERTIAL_ESTIMATOR_NAMES]
    assert all(estimator_kind(n) == "velocity" for n in nees_estimators("all", False))
    assert nees_estimators("smoother-imu", True) == ["smoother-imu"]


@pytest.mark.parametrize("argv, flag", [
    (["--imu", "--velocity-sigma", "0.1"], "--velocity-sigma"),
    (["--imu", "--sim-max-depth", "15"], "--sim-max-depth"),
    (["--imu", "--gyro-bias"], "--gyro-bias"),
    (["--imu", "--config", "settings.toml"], "--config"),
    (["--camera", "stereo"], "--camera"),
    (["--scenario", "road"], "--scenario"),
    (["--imu", "-e", "ekf-joint"], "'ekf-joint'"),
    (["--imu", "-e", "smoother-imu,dead-reckoning"], "'dead-reckoning'"),
    (["-e", "dead-reckoning-imu"], "'dead-reckoning-imu'"),
    (["--imu", "--frames", "12001"], "--frames"),
])
def test_flags_of_the_other_kind_are_one_line_exit_2(argv, flag, tmp_path, capsys):
    out = tmp_path / "nees"
    assert main(["nees", "--runs", "2", "--frames", "41", *argv, "--out", str(out), "-q"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("vislam nees: error: ") and flag in err
    assert not out.exists()
