"""eval.groundtruth: KITTI pose files (12 and 13 columns), camera -> IMU poses, lookup."""

from __future__ import annotations

import os

import numpy as np
import pytest

from vislam.ekf.errors import InputError
from vislam.ekf.geometry import se3_exp, se3_inv
from vislam.ekf.sequence import Calibration
from vislam.eval.groundtruth import (
    camera_to_imu_poses,
    find_ground_truth,
    ground_truth_path,
    imu_to_camera_poses,
    load_ground_truth,
    read_kitti_poses,
    write_kitti_poses,
)

CAL = Calibration(K=np.array([[700.0, 0, 600], [0, 700, 180], [0, 0, 1]]), baseline=0.54,
                  cam_T_imu=se3_exp(np.array([1.1, -0.3, 0.7, 1.2, -1.2, 1.2])))


def imu_trajectory(n=5, seed=0):
    rng = np.random.default_rng(seed)
    xi = np.cumsum(rng.normal(scale=[1, 0.1, 0.05, 0.01, 0.01, 0.05], size=(n, 6)), axis=0)
    xi[0] = 0
    return se3_exp(xi)


def test_12_and_13_columns_read_the_same(tmp_path):
    T_imu = imu_trajectory()
    P = imu_to_camera_poses(T_imu, CAL.cam_T_imu)
    write_kitti_poses(tmp_path / "a.txt", P)
    write_kitti_poses(tmp_path / "b.txt", P, times=0.1 * np.arange(5))
    assert len((tmp_path / "a.txt").read_text().splitlines()[0].split()) == 12
    assert len((tmp_path / "b.txt").read_text().splitlines()[0].split()) == 13
    Pa, ta = read_kitti_poses(tmp_path / "a.txt")
    Pb, tb = read_kitti_poses(tmp_path / "b.txt")
    assert ta is None
    np.testing.assert_allclose(tb, 0.1 * np.arange(5))
    np.testing.assert_allclose(Pa, P, atol=1e-11)
    np.testing.assert_allclose(Pb, P, atol=1e-11)


def test_conversion_gives_imu_poses_in_frame0_imu(tmp_path):
    T_imu = imu_trajectory(n=7, seed=3)
    P = imu_to_camera_poses(T_imu, CAL.cam_T_imu)
    # The camera pose really is the camera's motion: P(k) = cam_T_imu T_imu(k) imu_T_cam.
    k = 4
    p_imu = np.array([1.0, 2.0, 3.0, 1.0])
    np.testing.assert_allclose(P[k] @ CAL.cam_T_imu @ p_imu,
                               CAL.cam_T_imu @ T_imu[k] @ p_imu, atol=1e-12)
    np.testing.assert_allclose(camera_to_imu_poses(P, CAL.cam_T_imu), T_imu, atol=1e-12)
    write_kitti_poses(tmp_path / "gt.txt", P, times=np.arange(7.0))
    gt = load_ground_truth(tmp_path / "gt.txt", CAL, n_frames=10)
    np.testing.assert_array_equal(gt.frames, np.arange(7))
    np.testing.assert_allclose(gt.poses, T_imu, atol=1e-10)
    np.testing.assert_allclose(gt.poses[0], np.eye(4), atol=1e-12)
    assert gt.covers(10) == "7 of 10 frames"
    assert gt.source == str(tmp_path / "gt.txt")


def test_lookup_next_to_the_data_and_override(tmp_path):
    from vislam.eval.loader import write_npz

    T = 8
    feats = -np.ones((4, 2, T))
    write_npz(tmp_path / "drive.npz", time_stamps=np.arange(T) * 0.1, features=feats,
              linear_velocity=np.zeros((3, T)), angular_velocity=np.zeros((3, T)), K=CAL.K,
              b=CAL.baseline, cam_T_imu=CAL.cam_T_imu)
    assert find_ground_truth(tmp_path / "drive.npz") is None
    T_imu = imu_trajectory(n=6)
    P = imu_to_camera_poses(T_imu, CAL.cam_T_imu)
    write_kitti_poses(ground_truth_path(tmp_path / "drive.npz"), P)
    gt = find_ground_truth(tmp_path / "drive.npz")
    assert gt is not None and gt.n == 6
    np.testing.assert_allclose(gt.poses, T_imu, atol=1e-10)
    other = tmp_path / "elsewhere.txt"
    write_kitti_poses(other, P[:3], times=np.arange(3.0))
    gt2 = find_ground_truth(tmp_path / "drive.npz", override=other)
    assert gt2.n == 3 and gt2.source == str(other)
    with pytest.raises(InputError, match="does not exist"):
        find_ground_truth(tmp_path / "drive.npz", override=tmp_path / "missing.txt")


def _pose_line(n_cols=12):
    vals = [1, 0, 0, 0.5, 0, 1, 0, 0.2, 0, 0, 1, 0.1]
    if n_cols == 13:
        vals = [0.0] + vals
    return " ".join(str(v) for v in vals)


@pytest.mark.parametrize(
    "lines,message",
    [
        ([_pose_line(), "1 2 3"], "line 2 has 3 columns, expected 12"),
        ([_pose_line(), _pose_line(13)], "line 2 has 13 columns, earlier lines 12"),
        ([_pose_line(), _pose_line().replace("0.5", "abc")], "line 2: non-numeric value 'abc'"),
        ([_pose_line().replace("1 0 0 0.5", "2 0 0 0.5")], "line 1: the pose's rotation is not"),
        ([_pose_line(), _pose_line().replace("0.2", "nan")], "line 2: NaN or infinite"),
        ([], "no pose lines"),
    ],
)
def test_bad_files_name_file_and_line(tmp_path, lines, message):
    path = tmp_path / "gt.txt"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError) as info:
        load_ground_truth(path, CAL, n_frames=10)
    assert str(path) in str(info.value) and message in str(info.value)


def test_more_lines_than_frames_is_an_error(tmp_path):
    path = tmp_path / "gt.txt"
    path.write_text("\n".join([_pose_line()] * 5) + "\n")
    with pytest.raises(InputError, match=r"line 4: 5 pose lines for a drive of 3 frames"):
        load_ground_truth(path, CAL, n_frames=3)


@pytest.mark.regression
@pytest.mark.realdata
def test_0027_ground_truth(drive_path):
    gt = find_ground_truth(drive_path("0027"))
    assert gt is not None
    assert gt.n == 1101 and gt.frames[-1] == 1100 and gt.times is not None
    np.testing.assert_allclose(gt.poses[0], np.eye(4), atol=1e-9)
    # Forward along the IMU x axis (x forward, z up): the car drives, it does not fly.
    step = se3_inv(gt.poses[:-1]) @ gt.poses[1:]
    assert np.median(step[:, 0, 3]) > 0.3
    assert np.max(np.abs(gt.poses[:, 2, 3])) < 10
    assert find_ground_truth(drive_path("0034")) is None


# --------------------------------------------------------------------------- issue 11, item 6:
# whatever is at DIR/groundtruth/NAME.txt is either read or an InputError, never ignored.


def _drive_with_gt_slot(tmp_path):
    from vislam.eval.loader import write_npz

    T = 8
    write_npz(tmp_path / "drive.npz", time_stamps=np.arange(T) * 0.1,
              features=-np.ones((4, 2, T)), linear_velocity=np.zeros((3, T)),
              angular_velocity=np.zeros((3, T)), K=CAL.K, b=CAL.baseline,
              cam_T_imu=CAL.cam_T_imu)
    gt = ground_truth_path(tmp_path / "drive.npz")
    gt.parent.mkdir()
    return tmp_path / "drive.npz", gt


def _assert_gt_error(npz, gt, *fragments, override=None):
    with pytest.raises(InputError) as info:
        find_ground_truth(npz, override=override)
    text = str(info.value)
    assert "\n" not in text and str(gt) in text, text
    for fragment in fragments:
        assert fragment in text, text


def test_folder_at_the_ground_truth_path_is_an_error(tmp_path):
    # Reproduces item 6: silently ignored (find_ground_truth returned None).
    npz, gt = _drive_with_gt_slot(tmp_path)
    gt.mkdir()
    _assert_gt_error(npz, gt, "is a directory")
    _assert_gt_error(npz, gt, "is a directory", override=gt)


def test_non_utf8_and_binary_ground_truth(tmp_path):
    npz, gt = _drive_with_gt_slot(tmp_path)
    gt.write_bytes((_pose_line() + "\n").encode() + b"1 0 0 \xff\xfe 0\n")
    _assert_gt_error(npz, gt, "line 2", "not UTF-8", "0xff")
    gt.write_bytes(b"\x00" * 100)
    _assert_gt_error(npz, gt, "line 1")
    # A byte-order mark is not an error.
    gt.write_bytes(("\ufeff" + _pose_line() + "\n").encode())
    assert find_ground_truth(npz).n == 1


def test_unreadable_ground_truth_says_permission_denied(tmp_path, monkeypatch):
    npz, gt = _drive_with_gt_slot(tmp_path)
    gt.write_text(_pose_line() + "\n")
    import builtins
    import errno
    import io

    real_open = builtins.open

    def denying_open(file, *args, **kwargs):
        if os.fspath(file) == str(gt):
            raise PermissionError(errno.EACCES, "Permission denied", str(gt))
        return real_open(file, *args, **kwargs)

    monkeypatch.setattr(builtins, "open", denying_open)
    monkeypatch.setattr(io, "open", denying_open)
    _assert_gt_error(npz, gt, "permission denied")


def test_fifo_and_broken_link_at_the_ground_truth_path(tmp_path):
    npz, gt = _drive_with_gt_slot(tmp_path)
    os.mkfifo(gt)
    _assert_gt_error(npz, gt, "not a regular file")  # refused without opening it (no hang)
    gt.unlink()
    gt.symlink_to(tmp_path / "nowhere.txt")
    _assert_gt_error(npz, gt, "broken symbolic link")


def test_huge_translation_is_an_error_not_inf(tmp_path):
    path = tmp_path / "gt.txt"
    path.write_text(_pose_line() + "\n" + _pose_line().replace("0.2", "-1.7e308") + "\n")
    with pytest.raises(InputError, match=r"line 2: translation 1.7e\+308 m is beyond"):
        load_ground_truth(path, CAL, n_frames=10)


def test_oversized_ground_truth_is_refused(tmp_path, monkeypatch):
    import vislam.eval.groundtruth as groundtruth
    path = tmp_path / "gt.txt"
    path.write_text((_pose_line() + "\n") * 10)
    monkeypatch.setattr(groundtruth, "MAX_GROUND_TRUTH_BYTES", 100)
    with pytest.raises(InputError, match="larger than 100 bytes"):
        load_ground_truth(path, CAL, n_frames=10)
