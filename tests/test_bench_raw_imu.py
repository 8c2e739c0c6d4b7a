"""`vislam bench` on raw-IMU drives (issue 37 item 5): each drive runs the estimators of its
kind, a raw-IMU drive is aligned in yaw and translation, scored against its ground truth in the
estimate's own gauge, and compared with the raw-IMU smoother."""

from __future__ import annotations

import json

import numpy as np
import pytest

from vislam.eval.cli import main
from vislam.eval.imu_sim import simulate_imu
from vislam.eval.imu_sim_config import ImuSimConfig
from vislam.eval.imu_sim_files import write_imu_simulation
from vislam.eval.registry import DEFAULT_BENCH, DEFAULT_BENCH_INERTIAL, applicable, estimator_kind


@pytest.fixture(scope="module")
def drives(tmp_path_factory):
    """A short simulated raw-IMU room drive and a short velocity drive, in one folder."""
    from vislam.eval.loader import save_sequence
    from vislam.eval.simulate import SimConfig, simulate

    folder = tmp_path_factory.mktemp("drives")
    drive, truth = simulate_imu(ImuSimConfig(n_frames=61, seed=2))
    write_imu_simulation(folder, drive, truth)
    save_sequence(folder / "velocity.npz", simulate(SimConfig(n_frames=20, seed=1)).sequence)
    return folder, drive


def test_each_kind_of_drive_runs_its_estimators(drives):
    _, drive = drives
    assert estimator_kind("smoother-imu") == "raw-imu" and estimator_kind("ekf-joint") == "velocity"
    assert applicable(DEFAULT_BENCH + DEFAULT_BENCH_INERTIAL, drive) == list(DEFAULT_BENCH_INERTIAL)


def test_bench_a_folder_of_both_kinds(drives, tmp_path, capsys, monkeypatch):
    from vislam.eval import plots

    drawn = {}
    draw_nees = plots.plot_nees

    def capture(path, series, **kwargs):  # the NEES figure's series, as drawn
        drawn[path.parent.name] = series
        return draw_nees(path, series, **kwargs)

    monkeypatch.setattr(plots, "plot_nees", capture)
    folder, _ = drives
    out = tmp_path / "res"
    rc = main(["bench", str(folder), "-e", "dead-reckoning,dead-reckoning-imu", "--model", "as-given",
               "--out", str(out), "-q", "--jobs", "1"])
    assert rc == 0, capsys.readouterr().err
    results = json.loads((out / "results.json").read_text())
    assert results["estimators"] == ["dead-reckoning", "dead-reckoning-imu"]
    by_name = {s["name"]: s for s in results["sequences"]}
    raw = by_name["imu-room-mono-2"]
    assert [e["name"] for e in raw["estimators"]] == ["dead-reckoning-imu"]
    assert [e["name"] for e in by_name["velocity"]["estimators"]] == ["dead-reckoning"]
    row = raw["estimators"][0]
    assert row["error"] is None and raw["alignment"] == "yaw"
    assert by_name["velocity"]["alignment"] == "se3"
    # dead reckoning from a rest on a noise-consistent drive: a pose NEES of its order
    assert 0.5 < row["nees_pose_mean"] < 15 and row["ate_aligned_m"] < 0.05
    # the figure shows what summary.md and results.json say: the truth in the estimate's gauge
    figure_mean = float(np.nanmean(drawn["imu-room-mono-2"]["dead-reckoning-imu"]))
    assert figure_mean == pytest.approx(row["nees_pose_mean"], rel=1e-6)
    # and so does the results folder read back (the notebook's way): the drive made again, its
    # truth in the estimate's gauge
    from vislam.eval.consistency import pose_nees
    from vislam.eval.results import load_results

    drive = load_results(out).bench.drives["imu-room-mono-2"]
    data = drive.load_drive()
    est = drive.estimators["dead-reckoning-imu"].load_estimate()
    assert float(np.nanmean(pose_nees(est, *data.truth_for(est)))) == pytest.approx(
        row["nees_pose_mean"], rel=1e-6)
    assert (out / "imu-room-mono-2" / "dead-reckoning-imu.estimate.npz").is_file()
    # the simulated truth turns as its gyro does (noise as the sheet says): no warning in words
    check = raw["truth_check"]
    assert check["pairs"] > 10 and 0.5 < check["ratio"] < 2.0, check
    assert by_name["velocity"]["truth_check"] is None
    assert "departs from the gyro" not in (out / "summary.md").read_text()


def test_an_estimator_of_the_other_kind_only_is_refused(drives, tmp_path, capsys):
    folder, _ = drives
    raw_only = tmp_path / "raw"
    raw_only.mkdir()
    for f in folder.glob("imu-room-mono-2*"):
        (raw_only / f.name).write_bytes(f.read_bytes())
    (raw_only / "groundtruth").mkdir()
    src = folder / "groundtruth" / "imu-room-mono-2.csv"
    (raw_only / "groundtruth" / src.name).write_bytes(src.read_bytes())
    rc = main(["bench", str(raw_only), "-e", "ekf-joint", "--out", str(tmp_path / "o"), "-q"])
    assert rc == 2
    err = capsys.readouterr().err
    assert "no estimator given runs on these drives" in err and not (tmp_path / "o").exists()


def test_frame0_gauge_puts_truth_on_the_estimate_at_frame_0():
    from scipy.spatial.transform import Rotation

    from vislam.eval.groundtruth import GroundTruth
    from vislam.eval.inertial_truth import frame0_gauge

    rng = np.random.default_rng(0)
    poses = np.tile(np.eye(4), (5, 1, 1))
    poses[:, :3, :3] = Rotation.from_rotvec(rng.normal(0, 0.5, (5, 3))).as_matrix()
    poses[:, :3, 3] = rng.normal(0, 2, (5, 3))
    G = np.eye(4)
    G[:3, :3] = Rotation.from_euler("z", 0.7).as_matrix()
    G[:3, 3] = [1, -2, 0.5]
    est0 = G @ poses[0]
    moved = frame0_gauge(GroundTruth(np.arange(5), poses, "t"), est0)
    np.testing.assert_allclose(moved.poses, G @ poses, atol=1e-12)


def test_simulate_imu_writes_a_drive_every_command_reads(tmp_path, capsys):
    from vislam.eval.inertial_files import load_inertial_drive
    from vislam.eval.inertial_truth import find_inertial_truth

    out = tmp_path / "sim"
    assert main(["simulate", "--imu", "--scenario", "road", "--camera", "stereo", "--frames", "41",
                 "--seed", "3", "--out", str(out)]) == 0
    assert "raw IMU" in capsys.readouterr().out
    path = out / "imu-road-stereo-seed3.npz"
    drive = load_inertial_drive(path)
    assert drive.n_frames == 41 and drive.stereo and drive.imu.time.size == 401  # 2 s at 200 Hz
    truth = find_inertial_truth(path, drive)
    assert truth.truth.n == 41 and truth.velocity is not None
    np.testing.assert_allclose(truth.truth.poses[0, :3, 3], 0, atol=1e-12)
    # the same seed, the same bytes
    again = tmp_path / "again"
    assert main(["simulate", "--imu", "--scenario", "road", "--camera", "stereo", "--frames", "41",
                 "--seed", "3", "--out", str(again)]) == 0
    assert (again / path.name).read_bytes() == path.read_bytes()


@pytest.mark.parametrize("argv, fragment", [
    (["--imu", "--scenario", "loop"], "--imu simulates room, handheld, road"),
    (["--imu", "--radial-k1", "0.01"], "--radial-k1: a setting of velocity drives"),
    (["--camera", "stereo"], "--camera: a setting of raw-IMU simulations"),
    (["--scenario", "handheld"], "a raw-IMU scenario; add --imu"),
])
def test_simulate_imu_flags_of_the_other_kind_are_refused(tmp_path, capsys, argv, fragment):
    assert main(["simulate", *argv, "--out", str(tmp_path / "x")]) == 2
    assert fragment in capsys.readouterr().err and not (tmp_path / "x").exists()


def _truth_turned(truth, rate: float, seed: int = 0):
    """``truth`` whose rotations carry a slow error: a random walk of ``rate`` rad/sqrt(s) per
    axis about the body axes, one step per frame."""
    import dataclasses

    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(seed)
    t = truth.truth.times
    steps = rng.normal(0.0, rate, (t.size, 3)) * np.sqrt(np.r_[0.0, np.diff(t)])[:, None]
    poses = truth.truth.poses.copy()
    poses[:, :3, :3] = poses[:, :3, :3] @ Rotation.from_rotvec(np.cumsum(steps, axis=0)).as_matrix()
    return dataclasses.replace(truth, truth=dataclasses.replace(truth.truth, poses=poses))


def test_gyro_agreement_tells_a_truth_that_turns_away_from_its_gyro(drives, capsys):
    """A simulated truth agrees with its gyro within the sheet's noise, with its own gyro bias or
    with one fitted; the same truth with a slow rotation error of 1 mrad/sqrt(s) (EuRoC's
    measured disagreement, docs/findings.md 2026-12-03) does not, and the reading says so."""
    import dataclasses

    from vislam.eval.inertial_files import load_inertial_drive
    from vislam.eval.inertial_truth import AGREEMENT_RATIO, find_inertial_truth, gyro_agreement
    from vislam.eval.readings import truth_check_sentence, truth_turns_away

    folder, _ = drives
    path = folder / "imu-room-mono-2.npz"
    drive = load_inertial_drive(path)
    truth = find_inertial_truth(path, drive)
    own = gyro_agreement(drive, truth)
    fitted = gyro_agreement(drive, dataclasses.replace(truth, gyro_bias=None))
    assert own.truth_bias and not fitted.truth_bias
    assert own.interval_s == pytest.approx(1.0, abs=0.05)
    for check in (own, fitted):
        assert 0.5 < check.ratio < 2.0, check
        assert not truth_turns_away(check.to_dict())
    bad = gyro_agreement(drive, _truth_turned(truth, 1e-3))
    assert bad.ratio > 2 * AGREEMENT_RATIO and truth_turns_away(bad.to_dict())
    words = truth_check_sentence(bad.to_dict())
    assert "departs from the gyro" in words and f"{bad.ratio:.1f}x" in words
    # too short a truth for one pair of frames a second apart: no figure
    short = dataclasses.replace(truth, truth=dataclasses.replace(
        truth.truth, frames=truth.truth.frames[:10], poses=truth.truth.poses[:10],
        times=truth.truth.times[:10]), gyro_bias=truth.gyro_bias[:10])
    assert gyro_agreement(drive, short) is None
    # an IMU that starts after the first frame: only the intervals it covers are read
    late = dataclasses.replace(drive, imu=dataclasses.replace(
        drive.imu, time=drive.imu.time[100:], gyro=drive.imu.gyro[100:], accel=drive.imu.accel[100:]))
    cut = gyro_agreement(late, truth)
    assert cut.pairs < own.pairs and 0.5 < cut.ratio < 2.0
    # vislam inspect prints the same figures
    assert main(["inspect", str(path)]) == 0
    line = next(x for x in capsys.readouterr().out.splitlines() if x.startswith("ground truth against the gyro"))
    assert f"{own.ratio:.1f}x what the IMU's data sheet allows" in line
