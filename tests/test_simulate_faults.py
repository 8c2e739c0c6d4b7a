"""The simulator makes the faults a model identification must find (issue 12, item 5): per-axis
velocity noise, a gyro bias, the velocity pairing of the samples, a wrong extrinsic in the
file; each present in the written files with its known magnitude, and the true model written
beside the data. The defaults are unchanged."""

from __future__ import annotations

import hashlib
from dataclasses import replace

import numpy as np
import pytest

from vislam.ekf.errors import InputError
from vislam.ekf.geometry import se3_exp, se3_inv, so3_exp
from vislam.ekf.model import Model
from vislam.ekf.prediction import paired_velocities
from vislam.eval.groundtruth import find_ground_truth
from vislam.eval.loader import load_sequence
from vislam.eval.sim_config import KITTI_CAM_T_IMU, SimConfig
from vislam.eval.sim_files import write_simulation
from vislam.eval.simulate import simulate

BASE = SimConfig(seed=21, n_frames=120)


def _digest(paths) -> dict:
    return {role: hashlib.sha256(p.read_bytes()).hexdigest() for role, p in paths.items()}


def test_neutral_values_of_the_new_options_change_no_byte(tmp_path):
    """The options at their neutral values (written out explicitly) give the default drive's
    bytes: no new random stream, no changed arithmetic."""
    default = _digest(write_simulation(simulate(BASE), tmp_path / "a", "x"))
    explicit = replace(BASE, velocity_sigma=(0.5, 0.5, 0.5), gyro_sigma=(0.05, 0.05, 0.05),
                       velocity_pairing="mean", file_extrinsic_fault="none",
                       file_extrinsic_offset=(0.0,) * 6, radial_k1=0.0)
    same = _digest(write_simulation(simulate(explicit), tmp_path / "b", "x"))
    assert set(default) == {"data", "groundtruth", "landmarks", "model"}
    for role in ("data", "groundtruth", "landmarks"):
        assert same[role] == default[role], role


def test_per_axis_velocity_noise_has_the_given_sigmas():
    sv, sg = (0.3, 0.1, 0.02), (0.02, 0.01, 0.004)
    r = simulate(replace(BASE, n_frames=3000, velocity_sigma=sv, gyro_sigma=sg,
                         landmark_density=0.05))
    res = r.sequence.velocities - r.true_velocities
    np.testing.assert_allclose(res.std(axis=0), np.r_[sv, sg], rtol=0.05)
    assert r.model.velocity_sigma == sv and r.model.gyro_sigma == sg


def test_gyro_bias_is_in_the_data_and_in_the_model():
    bias = (0.004, -0.002, 0.001)
    r = simulate(replace(BASE, velocity_sigma=0.0, gyro_sigma=0.0, gyro_bias=bias))
    diff = r.sequence.angular_velocity - r.true_velocities[:, 3:]
    np.testing.assert_allclose(diff, np.tile(bias, (BASE.n_frames, 1)), rtol=0, atol=1e-15)
    assert r.model.gyro_bias == bias
    assert simulate(BASE).model.gyro_bias is None  # no bias: the model says none


@pytest.mark.parametrize("pairing", ["current", "next", "mean"])
def test_each_pairing_integrates_the_noise_free_samples_into_the_true_poses(pairing):
    r = simulate(replace(BASE, noise_free=True, velocity_pairing=pairing))
    seq = r.sequence
    np.testing.assert_array_equal(seq.velocities, r.true_velocities)
    steps = se3_exp(seq.dt[:, None] * paired_velocities(seq.velocities, pairing))
    poses = [np.eye(4)]
    for step in steps:
        poses.append(poses[-1] @ step)
    np.testing.assert_allclose(np.array(poses), r.poses, rtol=0, atol=1e-9)
    # the other pairings do not: the pairing has a known answer
    for other in {"current", "next", "mean"} - {pairing}:
        u = paired_velocities(seq.velocities, other)
        assert np.abs(u - paired_velocities(seq.velocities, pairing)).max() > 1e-3
    assert r.model.velocity_pairing == pairing
    # the trajectory, landmarks and tracks do not depend on the pairing
    ref = simulate(replace(BASE, noise_free=True))
    np.testing.assert_array_equal(r.poses, ref.poses)
    np.testing.assert_array_equal(seq.obs.z, ref.sequence.obs.z)


def _written(tmp_path, config):
    result = simulate(config)
    paths = write_simulation(result, tmp_path, "drive")
    with np.load(paths["data"]) as d:
        file_cam_T_imu = np.array(d["cam_T_imu"])
    return result, paths, file_cam_T_imu


def test_kitti_extrinsic_fault_in_the_file_ground_truth_true(tmp_path):
    result, paths, file_T = _written(tmp_path, replace(BASE, file_extrinsic_fault="kitti"))
    true_T = KITTI_CAM_T_IMU
    np.testing.assert_array_equal(result.true_cam_T_imu, true_T)
    # the file: the true rotation, the translation of imu_T_cam where cam_T_imu's belongs
    np.testing.assert_array_equal(file_T[:3, :3], true_T[:3, :3])
    np.testing.assert_allclose(file_T[:3, 3], se3_inv(true_T)[:3, 3], rtol=0, atol=1e-12)
    np.testing.assert_allclose(-file_T[:3, :3] @ file_T[:3, 3], true_T[:3, 3], atol=1e-6)
    assert np.linalg.norm(file_T[:3, 3] - true_T[:3, 3]) > 1.5  # metres, like the shared data
    # the loader reads the file's matrix; the data itself was made with the true one
    seq = load_sequence(paths["data"], clean=False)
    np.testing.assert_array_equal(seq.calibration.cam_T_imu, file_T)
    np.testing.assert_array_equal(seq.obs.z, simulate(BASE).sequence.obs.z)
    # ground truth: the true IMU poses with the true extrinsic, wrong ones with the file's
    gt = find_ground_truth(paths["data"])
    assert gt.extrinsic_source == "file"
    assert np.abs(gt.poses[:, :3, 3] - result.poses[:, :3, 3]).max() > 0.5
    good = gt.with_extrinsic(true_T, source="true")
    assert good.extrinsic_source == "true"
    np.testing.assert_allclose(good.poses, result.poses, rtol=0, atol=1e-6)
    same = find_ground_truth(paths["data"], cam_T_imu=true_T)
    np.testing.assert_array_equal(same.poses, good.poses)
    # the true model beside the data: the true extrinsic, the file's under [file]
    model = Model.from_toml(paths["model"])
    assert model == result.model
    np.testing.assert_array_equal(model.cam_T_imu, true_T)
    np.testing.assert_array_equal(model.file["cam_T_imu"], file_T)


def test_extrinsic_offset_in_the_file(tmp_path):
    offset = (0.1, -0.05, 0.2, 0.01, -0.02, 0.005)
    result, paths, file_T = _written(tmp_path, replace(BASE, file_extrinsic_offset=offset))
    true_T = result.true_cam_T_imu
    np.testing.assert_allclose(file_T[:3, 3] - true_T[:3, 3], offset[:3], rtol=0, atol=1e-12)
    np.testing.assert_allclose(file_T[:3, :3], so3_exp(np.array(offset[3:])) @ true_T[:3, :3],
                               rtol=0, atol=1e-15)
    gt = find_ground_truth(paths["data"], cam_T_imu=true_T)
    np.testing.assert_allclose(gt.poses, result.poses, rtol=0, atol=1e-6)
    # both faults together: kitti first, then the offset
    both = simulate(replace(BASE, file_extrinsic_fault="kitti", file_extrinsic_offset=offset))
    kitti = simulate(replace(BASE, file_extrinsic_fault="kitti")).sequence.calibration.cam_T_imu
    np.testing.assert_allclose(both.sequence.calibration.cam_T_imu[:3, 3] - kitti[:3, 3],
                               offset[:3], atol=1e-12)


def test_the_written_model_is_the_true_one(tmp_path):
    config = replace(BASE, velocity_sigma=(0.05, 0.04, 0.03), gyro_sigma=0.005, pixel_sigma=0.4,
                     gyro_bias=(0.001, 0.0, -0.001), velocity_pairing="current")
    result, paths, _ = _written(tmp_path, config)
    model = Model.from_toml(paths["model"])
    assert model == result.model
    assert model.velocity_sigma == (0.05, 0.04, 0.03) and model.gyro_sigma == (0.005,) * 3
    assert model.pixel_sigma == 0.4 and model.gyro_bias == (0.001, 0.0, -0.001)
    assert model.velocity_pairing == "current" and model.cam_T_imu_sigma is None


@pytest.mark.parametrize("change, needle", [
    ({"velocity_sigma": (0.1, 0.2)}, "velocity_sigma must be one number or three"),
    ({"gyro_sigma": (0.1, -0.2, 0.1)}, "gyro_sigma must be >= 0"),
    ({"velocity_sigma": (0.1, 1e300, 0.1)}, "velocity_sigma must be at most"),
    ({"velocity_pairing": "previous"}, "velocity_pairing must be one of"),
    ({"file_extrinsic_fault": "swap"}, "file_extrinsic_fault must be one of"),
    ({"file_extrinsic_offset": (0.0,) * 5}, "file_extrinsic_offset must be 6 numbers"),
    ({"file_extrinsic_offset": (0, 0, 0, 0, 0, float("nan"))}, "file_extrinsic_offset"),
    ({"file_extrinsic_offset": (0, 0, 0, 0, 0, 4.0)}, "file_extrinsic_offset"),
])
def test_bad_fault_settings(change, needle):
    with pytest.raises(InputError, match=needle):
        replace(BASE, **change)


def test_cli_makes_the_faults(tmp_path, capsys):
    from vislam.eval.cli import main

    out = tmp_path / "sim"
    rc = main(["simulate", "--out", str(out), "--frames", "40", "--seed", "3",
               "--velocity-sigma", "0.05,0.04,0.03", "--gyro-sigma", "0.01", "0.02", "0.03",
               "--velocity-pairing", "next", "--file-extrinsic-fault", "kitti",
               "--file-extrinsic-offset", "0", "0", "0.1", "0", "0", "0.01", "--gyro-bias", "0.002"])
    assert rc == 0
    assert "wrote model" in capsys.readouterr().out
    model = Model.from_toml(out / "sim-seed3_model.toml")
    assert model.velocity_sigma == (0.05, 0.04, 0.03) and model.gyro_sigma == (0.01, 0.02, 0.03)
    assert model.velocity_pairing == "next" and model.gyro_bias == (0.002,) * 3
    np.testing.assert_array_equal(model.cam_T_imu, KITTI_CAM_T_IMU)
    assert not np.allclose(model.file["cam_T_imu"], KITTI_CAM_T_IMU)
    for flags in (["--velocity-sigma", "0.1,0.2"], ["--gyro-sigma", "1", "2"],
                  ["--file-extrinsic-offset", "0", "0", "0", "0", "0", "9"]):
        bad = tmp_path / "bad"
        assert main(["simulate", "--out", str(bad), "--frames", "20", *flags]) == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and not bad.exists(), err
