"""`vislam convert` (issue 37): ASL folders, the eqvio csv and course drives into vislam's file
form, the ground truth beside it, nothing replaced, every fault one line and exit 2."""

from __future__ import annotations

import numpy as np
import pytest

from vislam.eval.cli import main
from vislam.eval.inertial_files import is_inertial_file, load_inertial_drive, save_inertial_drive
from vislam.eval.trajectory_files import read_trajectory
from tests.test_inertial_readers import STEP, T0, write_asl


def convert(*argv: str) -> int:
    return main(["convert", *argv])


def write_gt(path, n=40):
    rows = ["#time(ns),px,py,pz,qw,qx,qy,qz,vx,vy,vz,bwx,bwy,bwz,bax,bay,baz"]
    for i in range(n):
        rows.append(",".join([str(T0 + i * 2 * STEP), f"{0.01 * i}", "0", "1", "1", "0", "0", "0"]
                             + ["0.2", "0", "0", "0.001", "0", "0", "0", "0.01", "0"]))
    path.write_text("\n".join(rows) + "\n")
    return path


def test_asl_folder_with_tracks_and_ground_truth(tmp_path, capsys):
    root, tracks = write_asl(tmp_path / "asl")
    gt = write_gt(tmp_path / "gt.csv")
    out = tmp_path / "drives" / "flight.npz"
    assert convert(str(root), "--tracks", str(tracks), "--gt", str(gt), "--out", str(out)) == 0
    assert "monocular tracks" in capsys.readouterr().out
    assert is_inertial_file(out)
    drive = load_inertial_drive(out)
    assert drive.n_tracks == 5 and not drive.stereo and drive.calibration.distortion_model == "radtan"
    # the IMU is cut to the frames' span: one sample at or before the first frame, after the last
    assert drive.imu.time[0] <= drive.timestamps[0] and drive.imu.time[-1] >= drive.timestamps[-1]
    assert drive.imu.time.size == int(round((drive.timestamps[-1] - drive.timestamps[0]) / (STEP * 1e-9))) + 1
    truth = read_trajectory(tmp_path / "drives" / "groundtruth" / "flight.csv")
    assert truth.state is not None and len(truth) > 0
    np.testing.assert_allclose(truth.velocity[:, 0], 0.2)


def test_refuses_to_replace_and_leaves_nothing(tmp_path, capsys):
    root, tracks = write_asl(tmp_path / "asl")
    out = tmp_path / "flight.npz"
    out.write_bytes(b"the user's file")
    assert convert(str(root), "--tracks", str(tracks), "--out", str(out)) == 2
    assert "already exists" in capsys.readouterr().err and out.read_bytes() == b"the user's file"
    # a ground truth that fails leaves no drive file behind
    bad_gt = tmp_path / "gt.csv"
    bad_gt.write_text("#t\n1,0,0,0,1,0,0,0\n1,0,0,0,1,0,0,0\n")
    out2 = tmp_path / "other.npz"
    assert convert(str(root), "--tracks", str(tracks), "--gt", str(bad_gt), "--out", str(out2)) == 2
    err = capsys.readouterr().err
    assert "gt.csv: line 3" in err and err.count("\n") == 1
    assert not out2.exists() and not (tmp_path / "groundtruth").exists()


@pytest.mark.parametrize("argv, fragment", [
    (["nowhere", "--out", "x.npz"], "not an ASL folder, a .npz drive or an eqvio csv"),
    (["eqvio", "--out", "x.txt"], "--out must name a .npz file"),
    (["eqvio", "--tracks", "t.csv", "--out", "x.npz"], "--tracks is for an ASL folder"),
])
def test_bad_arguments(tmp_path, capsys, monkeypatch, argv, fragment):
    monkeypatch.chdir(tmp_path)
    assert convert(*argv) == 2
    err = capsys.readouterr().err
    assert fragment in err and err.count("\n") == 1
    assert list(tmp_path.iterdir()) == []


def test_asl_folder_without_tracks_says_how(tmp_path, capsys):
    root, _ = write_asl(tmp_path / "asl")
    assert convert(str(root), "--out", str(tmp_path / "f.npz")) == 2
    assert "--tracks FILE" in capsys.readouterr().err


def test_eqvio_round_trip(tmp_path, capsys):
    out = tmp_path / "eqvio.npz"
    assert convert("eqvio", "--out", str(out)) == 0
    assert "601 frames, 307 monocular tracks, 13316 observations" in capsys.readouterr().out
    drive = load_inertial_drive(out)
    again = tmp_path / "again.npz"
    save_inertial_drive(again, drive)
    assert again.read_bytes() == out.read_bytes()  # byte-reproducible


def test_course_drive_to_sparse_layout(tmp_path, capsys):
    from vislam.eval.loader import load_sequence, save_sequence
    from vislam.eval.simulate import SimConfig, simulate

    seq = simulate(SimConfig(n_frames=12, seed=3)).sequence
    source = tmp_path / "in" / "drive.npz"
    save_sequence(source, seq)
    (tmp_path / "in" / "groundtruth").mkdir()
    (tmp_path / "in" / "groundtruth" / "drive.txt").write_text("1 0 0 0 0 1 0 0 0 0 1 0\n")
    out = tmp_path / "out" / "drive.npz"
    assert convert(str(source), "--out", str(out)) == 0
    back = load_sequence(out)
    np.testing.assert_array_equal(back.obs.z, seq.obs.z)
    np.testing.assert_array_equal(back.linear_velocity, seq.linear_velocity)
    assert (tmp_path / "out" / "groundtruth" / "drive.txt").read_text().startswith("1 0 0 0")
    assert not is_inertial_file(out)


def test_inspect_a_raw_imu_drive(tmp_path, capsys):
    root, tracks = write_asl(tmp_path / "asl")
    gt = write_gt(tmp_path / "gt.csv")
    out = tmp_path / "drives" / "flight.npz"
    assert convert(str(root), "--tracks", str(tracks), "--gt", str(gt), "--out", str(out)) == 0
    capsys.readouterr()
    assert main(["inspect", str(out)]) == 0
    text = capsys.readouterr().out
    assert "drive: raw IMU" in text and "200.0 Hz" in text and "monocular" in text
    assert "ground truth: " in text and "covers 7 of 10 frames" in text and "with velocity and biases" in text
    assert "against the gyro" not in text  # under a second of truth: no pair to check it on
    assert main(["inspect", str(out), "--check"]) == 2
    assert "raw-IMU drive" in capsys.readouterr().err


def test_ground_truth_at_frames_in_the_estimates_world():
    from scipy.spatial.transform import Rotation

    from vislam.eval.inertial_truth import at_frames, world_from_file
    from vislam.eval.trajectory_files import TimedTrajectory

    times = np.array([10.0, 10.1, 10.2, 10.5])
    poses = np.tile(np.eye(4), (4, 1, 1))
    poses[:, :3, :3] = Rotation.from_euler("ZYX", [[0.3, 0.1, 0.0], [0.5, 0.1, 0.0],
                                                   [0.7, 0.1, 0.0], [0.9, 0.1, 0.0]]).as_matrix()
    poses[:, :3, 3] = [[1, 2, 3], [2, 2, 3], [3, 2, 3], [4, 2, 3]]
    traj = TimedTrajectory(times, poses, "gt", "asl", np.tile(np.arange(9.0), (4, 1)))
    frames, got, state = at_frames(traj, np.array([10.0, 10.05, 10.2 + 4e-6, 10.35, 11.0]))
    # exact, interpolated, the same instant, a gap of 0.3 s (not interpolated), beyond the end
    assert list(frames) == [0, 1, 2]
    np.testing.assert_allclose(got[1, :3, 3], [1.5, 2, 3])
    np.testing.assert_allclose(Rotation.from_matrix(got[1, :3, :3]).as_euler("ZYX"), [0.4, 0.1, 0.0],
                               atol=1e-12)
    np.testing.assert_allclose(got[2], poses[2])
    local = world_from_file(poses[0]) @ poses
    # in the estimates' world the first pose sits at the origin, tilted as before (the least
    # rotation from its up direction to z: no turn about it), and relative motion is kept
    np.testing.assert_allclose(local[0, :3, 3], 0, atol=1e-12)
    up = local[0, :3, :3].T @ [0, 0, 1.0]
    np.testing.assert_allclose(up, poses[0, :3, :3].T @ [0, 0, 1.0], atol=1e-12)
    axis = Rotation.from_matrix(local[0, :3, :3]).as_rotvec()
    assert abs(axis[2]) < 1e-12  # the least rotation turns about a horizontal axis
    np.testing.assert_allclose(np.linalg.inv(local[0]) @ local[3], np.linalg.inv(poses[0]) @ poses[3],
                               atol=1e-12)


def test_a_fifo_as_source_or_tracks_is_refused_without_blocking(tmp_path, capsys):
    import os

    fifo = tmp_path / "pipe.csv"
    os.mkfifo(fifo)
    assert convert(str(fifo), "--out", str(tmp_path / "x.npz")) == 2
    assert "not an ASL folder" in capsys.readouterr().err
    root, _ = write_asl(tmp_path / "asl")
    assert convert(str(root), "--tracks", str(fifo), "--out", str(tmp_path / "y.npz")) == 2
    err = capsys.readouterr().err
    assert "pipe.csv" in err and err.count("\n") == 1 and not (tmp_path / "y.npz").exists()
