"""The model of a drive (ekf/model.py, issue 12 item 2): TOML round trip, strict validation
naming the file, table and key, the settings file's [model] table, and apply_model on a
simulated drive with known faults."""

from __future__ import annotations

import argparse
import math
import tomllib

import numpy as np
import pytest

from vislam.ekf.config import FilterConfig
from vislam.ekf.errors import InputError
from vislam.ekf.geometry import se3_exp
from vislam.ekf.model import (
    EXTRINSIC_COMPONENTS,
    Model,
    apply_model,
    ar1_coefficient,
    long_run_pixel_sigma,
    model_config,
    model_sequence,
)
from vislam.eval.commands.options import add_filter_arguments, filter_config_from_args, model_from_args
from vislam.eval.simulate import KITTI_CAM_T_IMU, SimConfig, simulate, write_simulation


def _model(**changes) -> Model:
    values = dict(
        velocity_sigma=(0.05, 0.06, 0.07), gyro_sigma=(0.005, 0.004, 0.003), pixel_sigma=0.3,
        velocity_pairing="next", cam_T_imu=KITTI_CAM_T_IMU, gyro_bias=(1e-3, -2e-3, 5e-4),
        gyro_bias_sigma=(1e-4, 1e-4, 2e-4), radial_k1=0.01, radial_k1_sigma=1e-3,
        cam_T_imu_sigma=(0.01, 0.02, 0.5, 1e-3, 1e-3, 2e-3), cam_T_imu_undetermined=("tz",),
        source='vislam calibrate "0027.npz"\nsecond line \\ tab\t é', file={"cam_T_imu": np.eye(4)},
    )
    values.update(changes)
    return Model(**values)


def _args(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    add_filter_arguments(parser)
    return parser.parse_args(list(argv))


# --- TOML round trip ---------------------------------------------------------------------------


@pytest.mark.parametrize("changes", [
    {},
    {"gyro_bias": None, "gyro_bias_sigma": None, "cam_T_imu_sigma": None,
     "cam_T_imu_undetermined": (), "file": {}, "source": ""},
    {"radial_k1": None, "radial_k1_sigma": None},
    {"velocity_sigma": 0.5, "gyro_sigma": [1e-12, 1e3, 0.1 + 0.2], "pixel_sigma": 1,
     "cam_T_imu": se3_exp(np.array([0.1, -0.2, 0.3, 0.01, -0.02, 3.0])),
     "file": {"cam_T_imu": KITTI_CAM_T_IMU, "pixel_sigma": 1.0, "velocity_sigma": [0.5] * 3,
              "velocity_pairing": "mean"}},
])
def test_toml_round_trip_is_exact(tmp_path, changes):
    m = _model(**changes)
    text = m.to_toml()
    path = tmp_path / "model.toml"
    path.write_text(text, encoding="utf-8")
    back = Model.from_toml(path)
    assert back == m
    np.testing.assert_array_equal(back.cam_T_imu, m.cam_T_imu)  # bit for bit
    assert back.to_toml() == text
    doc = tomllib.loads(text)
    assert set(doc) <= {"model", "file"}
    assert len(doc["model"]["cam_T_imu"]) == 4 and all(len(r) == 4 for r in doc["model"]["cam_T_imu"])
    assert ("gyro_bias" in doc["model"]) == (m.gyro_bias is not None)
    # JSON-able, for results.json / settings.json
    import json

    assert json.loads(json.dumps(m.to_dict()))["velocity_sigma"] == list(m.velocity_sigma)


def test_model_values_are_normalised_and_undetermined_is_inf():
    m = _model(velocity_sigma=0.5, cam_T_imu_undetermined=["rz", "tz"])
    assert m.velocity_sigma == (0.5, 0.5, 0.5) and m.cam_T_imu_undetermined == ("tz", "rz")
    assert not m.cam_T_imu.flags.writeable
    sig = m.extrinsic_sigmas()
    assert math.isinf(sig[2]) and math.isinf(sig[5]) and sig[0] == 0.01
    assert np.all(np.isnan(_model(cam_T_imu_sigma=None, cam_T_imu_undetermined=()).extrinsic_sigmas()))
    assert EXTRINSIC_COMPONENTS == ("tx", "ty", "tz", "rx", "ry", "rz")
    assert m != _model() and _model() == _model()


# --- validation --------------------------------------------------------------------------------

GOOD = _model().to_toml()


def _replace_line(key: str, line: str | None) -> str:
    """GOOD with the (first) ``key = ...`` line of [model] replaced (None: removed)."""
    out, done = [], False
    lines = GOOD.splitlines()
    i = 0
    while i < len(lines):
        text = lines[i]
        if not done and text.startswith(f"{key} = "):
            done = True
            if text.endswith("["):  # a multi-line matrix
                while lines[i] != "]":
                    i += 1
            if line is not None:
                out.append(line)
        else:
            out.append(text)
        i += 1
    assert done, key
    return "\n".join(out) + "\n"


@pytest.mark.parametrize("key, line, needle", [
    ("pixel_sigma", "pixel_sigma = -1", "[model]: setting 'pixel_sigma' must be a positive number from 1e-12 to 10000, got -1"),
    ("pixel_sigma", "pixel_sigma = nan", "'pixel_sigma' must be a positive number"),
    ("pixel_sigma", None, "[model]: missing setting 'pixel_sigma'"),
    ("velocity_sigma", "velocity_sigma = [0.1, 0.2]", "[model]: setting 'velocity_sigma' must be an array of 3 positive numbers"),
    ("velocity_sigma", "velocity_sigma = [0.1, 0.2, inf]", "got an array [0.1, 0.2, inf]"),
    ("gyro_sigma", 'gyro_sigma = "small"', "'gyro_sigma' must be an array of 3"),
    ("gyro_bias", "gyro_bias = [0.1, 0.2]", "[model]: setting 'gyro_bias' must be an array of 3 numbers within +-10 rad/s"),
    ("gyro_bias", "gyro_bias = [0.1, true, 0.2]", "'gyro_bias'"),
    ("gyro_bias", "gyro_bias = [0.1, 0.2, 1e400]", "'gyro_bias'"),
    ("velocity_pairing", 'velocity_pairing = "previous"', "'velocity_pairing' must be one of 'current', 'next', 'mean'"),
    ("cam_T_imu", "cam_T_imu = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]]", "[model]: setting 'cam_T_imu' must be a rigid 4x4 transform"),
    ("cam_T_imu", "cam_T_imu = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 2, 0], [0, 0, 0, 1]]", "got a matrix that is not rigid"),
    ("cam_T_imu", "cam_T_imu = [[1, 0, 0, nan], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]", "'cam_T_imu' must be a rigid"),
    ("cam_T_imu", "cam_T_imu = [[1, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]", "'cam_T_imu' must be a rigid"),
    ("cam_T_imu", "cam_T_imu = 1", "'cam_T_imu' must be a rigid"),
    ("cam_T_imu_sigma", "cam_T_imu_sigma = [0.1, 0.1, 0.1, 0.1, 0.1]", "'cam_T_imu_sigma' must be an array of 6 positive numbers"),
    ("cam_T_imu_sigma", "cam_T_imu_sigma = [0.1, 0.1, 0.1, 0.1, 0.1, -1]", "'cam_T_imu_sigma'"),
    ("cam_T_imu_undetermined", 'cam_T_imu_undetermined = ["z"]', "'cam_T_imu_undetermined' must be an array of distinct names from 'tx'"),
    ("cam_T_imu_undetermined", 'cam_T_imu_undetermined = ["tz", "tz"]', "'cam_T_imu_undetermined'"),
    ("source", "source = 3", "'source' must be text"),
    ("radial_k1", "radial_k1 = 2.5", "[model]: setting 'radial_k1' must be a number from -1 to 1, got 2.5"),
    ("radial_k1", 'radial_k1 = "0.01"', "'radial_k1'"),
    ("radial_k1_sigma", "radial_k1_sigma = 0", "'radial_k1_sigma' must be a positive number"),
    ("source", "bogus = 3", "[model]: unknown setting 'bogus' (valid model settings: source, velocity_sigma"),
])
def test_bad_model_files_name_the_file_table_and_key(tmp_path, key, line, needle):
    path = tmp_path / "m.toml"
    path.write_text(_replace_line(key, line))
    with pytest.raises(InputError) as info:
        Model.from_toml(path)
    msg = str(info.value)
    assert msg.startswith(str(path)) and needle in msg and len(msg.splitlines()) == 1, msg
    # the same file as --config: one line naming it
    with pytest.raises(InputError, match=needle[:20].replace("[", r"\[")):
        filter_config_from_args(_args("--config", str(path)))


@pytest.mark.parametrize("text, needle", [
    ("[filter]\npixel_sigma = 1.0\n", "no [model] table"),
    ("[file]\npixel_sigma = 1.0\n", "[file]: a [file] table needs a [model] table"),
    (GOOD + "extra = 1\n", "[file]: unknown setting 'extra'"),
    (GOOD.replace("[file]", "[file]\npixel_sigma = 0"), "[file]: setting 'pixel_sigma' must be"),
    ("model = 1\n", "[model] must be a table of settings"),
    (GOOD + "[modle]\n", "unknown table [modle]"),
    ("pixel_sigma = -1\n" + GOOD, "setting 'pixel_sigma' must be"),
])
def test_bad_model_file_layouts(tmp_path, text, needle):
    path = tmp_path / "m.toml"
    path.write_text(text)
    with pytest.raises(InputError) as info:
        Model.from_toml(path)
    assert str(path) in str(info.value) and needle in str(info.value), str(info.value)


def test_constructor_validates():
    with pytest.raises(InputError, match="model setting 'pixel_sigma'"):
        _model(pixel_sigma=0.0)
    with pytest.raises(InputError, match="model setting 'cam_T_imu'"):
        _model(cam_T_imu=np.eye(3))
    with pytest.raises(InputError, match=r"model \[file\] setting 'cam_T_imu'"):
        _model(file={"cam_T_imu": 2 * np.eye(4)})
    with pytest.raises(InputError, match="unknown setting 'K'"):
        _model(file={"K": np.eye(3)})
    with pytest.raises(InputError, match="unknown model setting"):
        _model().replace(bogus=1)


# --- the settings file: [model] beside [filter] and [smoother] -----------------------------------


def test_config_reads_the_model_and_flags_override_it(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text("[filter]\nmax_depth = 50.0\n[smoother]\nhuber_k = 2.0\n" + GOOD)
    args = _args("--config", str(path))
    model = model_from_args(args)
    assert model == _model()
    cfg = filter_config_from_args(args)
    assert cfg.velocity_sigma == (0.05, 0.06, 0.07) and cfg.gyro_sigma == (0.005, 0.004, 0.003)
    assert cfg.pixel_sigma == 0.3 and cfg.velocity_pairing == "next" and cfg.max_depth == 50.0
    assert cfg.gyro_bias is True  # a model with a bias leaves the bias state as configured
    # ... whose prior is the model's own bias uncertainty (the largest axis), not the default
    assert cfg.gyro_bias_sigma == 2e-4 and FilterConfig().gyro_bias_sigma == 0.01
    assert model_config(FilterConfig(), _model(gyro_bias_sigma=None)).gyro_bias_sigma == 0.01
    cfg = filter_config_from_args(_args("--config", str(path), "--velocity-sigma", "0.2",
                                        "--velocity-pairing", "mean"))
    assert cfg.velocity_sigma == 0.2 and cfg.velocity_pairing == "mean"
    assert model_from_args(_args()) is None
    # no bias in the model: no bias state, unless a flag asks for one
    path.write_text(_replace_line("gyro_bias", None))
    assert filter_config_from_args(_args("--config", str(path))).gyro_bias is False
    assert filter_config_from_args(_args("--config", str(path), "--gyro-bias")).gyro_bias is True
    # a setting in both [filter] and [model] is ambiguous
    path.write_text("[filter]\npixel_sigma = 2.0\n" + GOOD)
    with pytest.raises(InputError, match="'pixel_sigma' is in both the \\[filter\\] and the \\[model\\]"):
        filter_config_from_args(_args("--config", str(path)))
    path.write_text("[filter]\ngyro_bias_sigma = 0.02\n" + GOOD)
    with pytest.raises(InputError, match="'gyro_bias_sigma' is in both"):
        filter_config_from_args(_args("--config", str(path)))
    # a settings file without a model is read as before
    path.write_text("[filter]\npixel_sigma = 2.0\n")
    assert model_from_args(_args("--config", str(path))) is None


# --- applying a model --------------------------------------------------------------------------


def test_apply_model_replaces_the_extrinsic_and_removes_the_bias():
    seq = simulate(SimConfig(seed=2, n_frames=30)).sequence
    m = _model(cam_T_imu=se3_exp(np.array([0.1, 0.2, 0.3, 0.0, 0.1, 0.0])) @ KITTI_CAM_T_IMU,
               radial_k1=None, radial_k1_sigma=None)  # the lens term: the next test
    s2, c2 = apply_model(seq, FilterConfig(), m)
    np.testing.assert_array_equal(s2.calibration.cam_T_imu, m.cam_T_imu)
    np.testing.assert_array_equal(s2.calibration.K, seq.calibration.K)
    np.testing.assert_allclose(s2.angular_velocity, seq.angular_velocity - np.array(m.gyro_bias),
                               rtol=0, atol=1e-15)
    np.testing.assert_array_equal(s2.linear_velocity, seq.linear_velocity)
    assert s2.obs is seq.obs and s2.n_frames == seq.n_frames
    np.testing.assert_array_equal(seq.calibration.cam_T_imu, KITTI_CAM_T_IMU)  # input untouched
    assert c2 == model_config(FilterConfig(), m)
    np.testing.assert_allclose(np.diag(c2.velocity_cov),
                               np.r_[m.velocity_sigma, m.gyro_sigma] ** 2, rtol=1e-15)
    s3 = model_sequence(seq, m.replace(gyro_bias=None))
    np.testing.assert_array_equal(s3.angular_velocity, seq.angular_velocity)


def test_apply_model_removes_the_radial_lens_term_of_the_pixels():
    """A drive made through a lens k1: its model's radial term gives back the pinhole pixels
    (the simulator's before the noise, here noise-free); a term that folds the image over is
    an InputError naming the key."""
    from vislam.ekf.camera import project
    from vislam.ekf.geometry import homogeneous, se3_inv

    lens = simulate(SimConfig(seed=2, n_frames=30, noise_free=True, radial_k1=0.02))
    pinhole = simulate(SimConfig(seed=2, n_frames=30, noise_free=True))
    assert lens.model.radial_k1 == 0.02 and pinhole.model.radial_k1 is None
    seq = lens.sequence
    frame, track = seq.obs.frame_index, seq.obs.track
    cam_T_world = seq.calibration.cam_T_imu @ se3_inv(lens.poses[frame])
    q = np.einsum("nij,nj->ni", cam_T_world[:, :3, :3], lens.landmarks[track]) + cam_T_world[:, :3, 3]
    truth = project(seq.calibration.M, homogeneous(q))  # the pinhole pixels of every row
    s2 = model_sequence(seq, lens.model)
    np.testing.assert_allclose(s2.obs.z, truth, rtol=0, atol=1e-8)
    assert np.abs(seq.obs.z - truth).max() > 1.0
    assert model_sequence(pinhole.sequence, pinhole.model).obs is pinhole.sequence.obs
    with pytest.raises(InputError, match="'radial_k1'.*folds the image over"):
        model_sequence(lens.sequence, lens.model.replace(radial_k1=-1.0))


def test_the_true_model_of_a_faulty_drive_makes_estimates_much_better(tmp_path):
    """A drive with the shared data's faults (the KITTI extrinsic fault, clean velocities with
    another pairing, a gyro bias): the file as given, scored as a user would score it (ground
    truth converted with the file's extrinsic), against the true model (ground truth converted
    with the model's extrinsic)."""
    from vislam.eval.consistency import ate_or_none
    from vislam.eval.groundtruth import find_ground_truth
    from vislam.eval.loader import load_sequence
    from vislam.eval.study import run_estimator

    cfg = SimConfig(seed=11, n_frames=250, velocity_sigma=0.05, gyro_sigma=0.005,
                    gyro_bias=(0.004, -0.003, 0.006), velocity_pairing="next",
                    file_extrinsic_fault="kitti", pixel_sigma=0.5)
    result = simulate(cfg)
    paths = write_simulation(result, tmp_path, "drive")
    seq = load_sequence(paths["data"], clean=False)
    model = Model.from_toml(paths["model"])
    assert model == result.model
    gt_file = find_ground_truth(paths["data"])
    gt_model = gt_file.with_extrinsic(model.cam_T_imu)
    assert gt_file.extrinsic_source == "file" and gt_model.extrinsic_source == "model"
    np.testing.assert_allclose(gt_model.poses, result.poses, rtol=0, atol=1e-6)
    assert np.abs(gt_file.poses[:, :3, 3] - result.poses[:, :3, 3]).max() > 0.5

    seq_m, cfg_m = apply_model(seq, FilterConfig(), model)
    ate = {}
    for name in ("dead-reckoning", "ekf-invariant"):
        given = run_estimator(seq, name, FilterConfig()).estimate
        modelled = run_estimator(seq_m, name, cfg_m).estimate
        ate[name] = (ate_or_none(given.poses, gt_file.poses, align="se3"),
                     ate_or_none(given.poses, gt_model.poses, align="se3"),
                     ate_or_none(modelled.poses, gt_model.poses, align="se3"))
    # measured: dead reckoning 1.78 / 1.56 -> 0.20 m; ekf-invariant 0.045 / 0.47 -> 0.023 m
    # (with Euclidean landmarks 0.071 / 0.47 -> 0.025 m: inverse depth copes better with the
    # wrong file, against the file's own ground truth)
    dr_given, dr_given_true, dr_model = ate["dead-reckoning"]
    assert dr_model < 0.25 * dr_given and dr_model < 0.25 * dr_given_true, ate
    inv_given, inv_given_true, inv_model = ate["ekf-invariant"]
    assert inv_model < 0.6 * inv_given and inv_model < 0.15 * inv_given_true, ate
    assert inv_model < 0.05, ate


def test_ar1_coefficient_inverts_the_correlation_time():
    """``a`` of AR(1) errors from their integrated correlation time ``tau = (1 + a) / (1 - a)``,
    white at ``tau <= 1``; their long-run variance ``sigma^2 (1 + a) / (1 - a)`` is the square of
    the long-run sigma the estimators use."""
    for a in (0.0, 0.3, 0.8731, 0.99):
        tau = (1.0 + a) / (1.0 - a)
        assert ar1_coefficient(tau) == pytest.approx(a, abs=1e-12)
        assert long_run_pixel_sigma(0.9, tau) ** 2 == pytest.approx(0.81 * (1 + a) / (1 - a))
    assert ar1_coefficient(None) == 0.0 and ar1_coefficient(1.0) == 0.0 and ar1_coefficient(0.5) == 0.0
