"""`vislam inspect`: the summary on synthetic and real drives, and bad files."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from vislam.ekf.geometry import se3_exp
from vislam.eval.cli import main
from vislam.eval.groundtruth import imu_to_camera_poses, write_kitti_poses
from vislam.eval.loader import write_npz

REPO = Path(__file__).resolve().parent.parent
CAM_T_IMU = se3_exp(np.array([1.1, -0.3, 0.7, 1.2, -1.2, 1.2]))


def small_drive(tmp_path: Path, name="tiny") -> Path:
    T, M = 6, 4
    feats = -np.ones((4, M, T))
    spans = [(0, 5), (0, 5), (0, 5), (2, 6)]  # frames [a, b) of each track
    for j, (a, b) in enumerate(spans):
        for t in range(a, b):
            feats[:, j, t] = [300 + t, 100 + j, 290 + t, 100 + j]
    feats[:, :3, 2] = feats[:, :3, 1]  # tracks 0-2 repeat as track 3 starts: an event
    feats[2, 3, 4] = feats[0, 3, 4] + 2  # a negative disparity
    path = tmp_path / f"{name}.npz"
    write_npz(path, time_stamps=1.0 + 0.1 * np.arange(T), features=feats,
              linear_velocity=np.tile([[5.0], [0], [0]], T), angular_velocity=np.zeros((3, T)),
              K=np.array([[700.0, 0, 600], [0, 700, 180], [0, 0, 1]]), b=0.5,
              cam_T_imu=CAM_T_IMU)
    return path


def test_inspect_small_drive(tmp_path, capsys):
    path = small_drive(tmp_path)
    assert main(["inspect", str(path)]) == 0
    out = capsys.readouterr().out
    assert "frames: 6, duration 0.50 s" in out
    assert "tracks: 4 (4 observed)" in out
    assert "repeated-observation events: 1 frames, 3 repeats" in out
    assert "event frames: 2" in out
    assert "bad disparities: 1 non-positive" in out
    assert "|v| (m/s): mean 5.000" in out
    assert "ground truth: none found" in out


def test_inspect_reports_ground_truth_and_override(tmp_path, capsys):
    path = small_drive(tmp_path)
    P = imu_to_camera_poses(se3_exp(np.c_[np.arange(5.0), np.zeros((5, 5))]), CAM_T_IMU)
    write_kitti_poses(tmp_path / "groundtruth" / "tiny.txt", P, times=0.1 * np.arange(5))
    assert main(["inspect", str(path)]) == 0
    assert "covers 5 of 6 frames" in capsys.readouterr().out
    write_kitti_poses(tmp_path / "other.txt", P[:3])
    assert main(["inspect", str(path), "--gt", str(tmp_path / "other.txt")]) == 0
    out = capsys.readouterr().out
    assert "other.txt, covers 3 of 6 frames" in out


def test_inspect_bad_files_exit_2_with_one_line(tmp_path, capsys):
    bad = tmp_path / "bad.npz"
    bad.write_text("hello")
    assert main(["inspect", str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not an .npz file" in err and str(bad) in err
    path = small_drive(tmp_path)
    gt = tmp_path / "gt.txt"
    gt.write_text("1 2 3\n")
    assert main(["inspect", str(path), "--gt", str(gt)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "line 1 has 3 columns" in err


def test_inspect_subprocess_exit_code_and_stderr(tmp_path):
    bad = tmp_path / "missing.npz"
    proc = subprocess.run([sys.executable, "-m", "vislam.eval.cli", "inspect", str(bad)],
                          capture_output=True, text=True, cwd=REPO, timeout=120)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "does not exist" in lines[0] and "Traceback" not in proc.stderr
    assert proc.stdout == ""


EXPECTED = {  # frames, repeat events, repeats, ground truth
    "0022": (800, 66, 3100, "ground truth: none found"),
    "0027": (1106, 91, 4196, "covers 1101 of 1106 frames"),
    "0034": (1224, 135, 6255, "ground truth: none found"),
}


@pytest.mark.regression
@pytest.mark.realdata
@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_inspect_shared_drives(name, drive_path, capsys):
    frames, events, repeats, gt = EXPECTED[name]
    assert main(["inspect", str(drive_path(name))]) == 0
    out = capsys.readouterr().out
    assert f"frames: {frames}," in out
    assert f"repeated-observation events: {events} frames, {repeats} repeats" in out
    assert "0 more outside events" in out
    assert gt in out
    assert "bad disparities:" in out and "far points:" in out


def test_inspect_reports_dropped_partial_observations(tmp_path, capsys, caplog):
    # Issue 11, item 6: a half-missing observation is dropped, and inspect says so.
    path = small_drive(tmp_path)
    with np.load(path) as data:
        arrays = dict(data)
    arrays["features"][2:, 1, 3] = -1  # track 1, frame 3: the right image's pixels missing
    arrays["features"][1, 0, 0] = -7.5  # track 0, frame 0: a negative coordinate
    np.savez(path, **arrays)
    assert main(["inspect", str(path)]) == 0
    captured = capsys.readouterr()
    assert ("invalid observations: 2 dropped as unobserved (1 partial: one to three of uL, vL, "
            "uR, vR are -1; 1 with another negative coordinate), first at track 0, frame 0"
            ) in captured.out
    assert "tracks: 4 (4 observed), observations 17" in captured.out
    # The loader's warning (on stderr outside pytest), once, naming the file.
    warned = [r.getMessage() for r in caplog.records if "treated as unobserved" in r.getMessage()]
    assert len(warned) == 1 and str(path) in warned[0]
    small_drive(tmp_path)
    assert main(["inspect", str(path)]) == 0
    assert "invalid observations: none" in capsys.readouterr().out


def test_inspect_ground_truth_folder_is_an_error(tmp_path, capsys):
    path = small_drive(tmp_path)
    (tmp_path / "groundtruth" / "tiny.txt").mkdir(parents=True)
    assert main(["inspect", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "tiny.txt: is a directory" in err
