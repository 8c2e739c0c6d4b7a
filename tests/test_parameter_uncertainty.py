"""Issue 34, items 1 and 3: each identified noise level carries its uncertainty from the data;
one the drive cannot determine takes a documented conservative value and is named in the model
file; a determined one keeps its estimate, and the estimators widen it by its own uncertainty."""

from __future__ import annotations

import math
import tomllib

import numpy as np
import pytest

from vislam.ekf.config import FilterConfig
from vislam.ekf.errors import InputError
from vislam.ekf.model import NOISE_LEVELS, Model, model_config, sigma_widening
from vislam.eval.simulate import KITTI_CAM_T_IMU
from vislam.graph.parameter_uncertainty import (SPEED_SCALE_PRIOR, UNDETERMINED_LOG_SD, UPPER_Z,
                                                conservative_level, log_sigma_sd,
                                                missing_fraction, speed_scale_prior_sigma,
                                                white_sigma_bound)


def _model(**changes) -> Model:
    values = dict(velocity_sigma=(0.05, 0.06, 0.07), gyro_sigma=(0.005, 0.004, 0.003),
                  pixel_sigma=0.3, velocity_pairing="next", cam_T_imu=KITTI_CAM_T_IMU)
    values.update(changes)
    return Model(**values)


def test_sd_of_log_sigma_follows_the_missing_information():
    """sd = 1 / sqrt(2 n (1 - r)): complete data (r = 0) give the textbook 1 / sqrt(2 n); a
    level the data leave wholly to the posterior (r = 1) is as uncertain as reported at most."""
    assert log_sigma_sd(200, 0.0) == pytest.approx(1.0 / math.sqrt(400))
    assert log_sigma_sd(200, 0.75) == pytest.approx(2.0 / math.sqrt(400))
    assert log_sigma_sd(200, 1.0) == 10.0
    np.testing.assert_allclose(missing_fraction([1.0, 0.0, 2.0], [4.0, 3.0, 0.0]), [0.25, 0.0, 1.0])


def test_determined_level_keeps_its_estimate():
    level = conservative_level("velocity_sigma_x", 0.02, 0.05, 0.0, 0.5, "a bound")
    assert level.determined and level.value == 0.02
    assert "determined" in level.why and "undetermined" not in level.why


def test_undetermined_level_takes_the_upper_end_capped_and_says_why():
    sd = 2 * UNDETERMINED_LOG_SD
    level = conservative_level("velocity_sigma_x", 0.01, sd, 0.99, 1.0, "the bound")
    assert not level.determined
    assert level.value == pytest.approx(0.01 * math.exp(UPPER_Z * sd))
    assert "undetermined" in level.why and "upper end" in level.why
    capped = conservative_level("velocity_sigma_x", 0.01, 5.0, 1.0, 0.05, "the bound")
    assert capped.value == 0.05 and "the bound (0.05" in capped.why
    # never below the estimate, whatever the cap
    low_cap = conservative_level("velocity_sigma_x", 0.01, 5.0, 1.0, 0.001, "the bound")
    assert low_cap.value == 0.01 and "the estimate" in low_cap.why
    assert low_cap.to_dict()["determined"] is False
    # a bound the data themselves give is taken whole where the level is undetermined
    bound = conservative_level("gyro_sigma_x", 0.001, 0.2, 0.9, 0.004, "the bound", bound=True)
    assert bound.value == 0.004 and "the bound (0.004)" in bound.why


def test_second_differences_bound_white_noise_from_above():
    rng = np.random.default_rng(0)
    t = np.arange(2000) * 0.1
    smooth = np.c_[8.0 + np.sin(0.1 * t), 0.2 * np.cos(0.05 * t), np.zeros_like(t)]
    noisy = smooth + rng.normal(0.0, [0.01, 0.02, 0.5], (len(t), 3))
    bound = white_sigma_bound(noisy)
    assert np.all(bound >= [0.01, 0.02, 0.5] * np.array(0.95))
    np.testing.assert_allclose(bound, [0.01, 0.02, 0.5], rtol=0.1)
    assert np.all(np.isinf(white_sigma_bound(noisy[:2])))


def test_speed_scale_prior_is_a_relative_error_over_its_time():
    v = np.c_[np.full(300, 10.0), np.zeros(300), np.zeros(300)]
    prior = speed_scale_prior_sigma(v, 0.1, 299)
    assert prior[1] == prior[2] == 0.0
    assert prior[0] == pytest.approx(SPEED_SCALE_PRIOR * 10.0 * math.sqrt(200))
    short = speed_scale_prior_sigma(v[:51], 0.1, 50)  # a drive shorter than the prior's time
    assert short[0] == pytest.approx(SPEED_SCALE_PRIOR * 10.0 * math.sqrt(50))


def test_model_file_names_the_undetermined_levels_and_reads_back(tmp_path):
    m = _model(velocity_sigma_log_sd=(0.05, 0.6, 10.0), gyro_sigma_log_sd=(0.01, 0.02, 0.03),
               noise_undetermined=("velocity_correlation_time_x", "velocity_sigma_y"))
    assert m.noise_undetermined == ("velocity_sigma_y", "velocity_correlation_time_x")
    path = tmp_path / "m.toml"
    path.write_text(m.to_toml())
    back = Model.from_toml(path)
    assert back == m
    doc = tomllib.loads(m.to_toml())["model"]
    assert doc["noise_undetermined"] == ["velocity_sigma_y", "velocity_correlation_time_x"]
    assert "noise_undetermined" not in tomllib.loads(_model().to_toml())["model"]
    with pytest.raises(InputError, match="'noise_undetermined' must be an array of distinct"):
        _model(noise_undetermined=("velocity_sigma_w",))
    with pytest.raises(InputError, match="'velocity_sigma_log_sd'"):
        _model(velocity_sigma_log_sd=(0.1, -1.0, 0.1))
    assert set(NOISE_LEVELS) >= {"velocity_sigma_x", "gyro_correlation_time_z"}


def test_estimators_widen_a_determined_sigma_by_its_uncertainty_only():
    """exp(sd^2) on a determined axis; an undetermined one (its value already the upper end)
    and a model without sds are used as they are."""
    plain = _model()
    assert model_config(FilterConfig(), plain).velocity_sigma == plain.velocity_sigma
    m = _model(velocity_sigma_log_sd=(0.1, 0.1, 3.0), gyro_sigma_log_sd=(0.0, 0.0, 0.0),
               noise_undetermined=("velocity_sigma_z",))
    wide = sigma_widening(m, "velocity")
    assert wide[0] == pytest.approx(math.exp(0.01)) and wide[2] == 1.0
    cfg = model_config(FilterConfig(), m)
    assert cfg.velocity_sigma[0] == pytest.approx(0.05 * math.exp(0.01))
    assert cfg.velocity_sigma[2] == 0.07
    assert cfg.gyro_sigma == m.gyro_sigma
    long_run = m.replace(noise_undetermined=("velocity_correlation_time_x",))
    assert sigma_widening(long_run, "velocity")[0] == 1.0


# --- on simulated drives -------------------------------------------------------------------------


def _identify(**sim):
    from vislam.eval.simulate import SimConfig, simulate
    from vislam.graph.identification import identify_model

    result = simulate(SimConfig(seed=2, n_frames=120, **sim))
    return identify_model(result.sequence, extrinsic=False, radial=False, pairings=("mean",))


@pytest.fixture(scope="module")
def sparse_fit():
    """Clean velocities, about half an observation a frame: vision barely constrains motion."""
    return _identify(velocity_sigma=0.01, gyro_sigma=0.002, landmark_density=0.05,
                     detect_probability=0.1)


@pytest.fixture(scope="module")
def dense_fit():
    """Noisy velocities and dense tracks: vision determines the velocity noise."""
    return _identify(velocity_sigma=0.5, gyro_sigma=0.05)


def test_an_undetermined_level_is_named_and_takes_the_conservative_value(sparse_fit):
    from vislam.eval.commands.calibrate import undetermined_lines

    fit = sparse_fit
    white = {lv.name: lv for lv in fit.noise_levels}
    open_white = [lv for lv in white.values() if not lv.determined]
    assert open_white, [lv.why for lv in fit.noise_levels]
    for lv in open_white:
        assert lv.name in fit.noise_undetermined
        assert lv.value >= lv.estimate and lv.log_sd > UNDETERMINED_LOG_SD
        assert lv.value == pytest.approx(max(lv.cap, lv.estimate))  # the samples' bound
    np.testing.assert_allclose(fit.velocity_sigma, [white[f"velocity_sigma_{a}"].value
                                                    for a in "xyz"])
    # A 12 s drive has two blocks of 5 s at most: the forward long-run ratio is undetermined and
    # takes the prior on slow speed errors (never "white").
    assert "velocity_correlation_time_x" in fit.noise_undetermined
    model = fit.to_model("test")
    assert model.velocity_correlation_time is not None and model.velocity_correlation_time[0] > 1
    assert model.noise_undetermined == fit.noise_undetermined
    words = "\n".join(undetermined_lines(fit))
    assert "velocity_sigma" in words or "velocity x long-run" in words
    assert "the model takes" in words and "undetermined" in words


def test_a_determined_level_keeps_its_estimate(dense_fit):
    fit = dense_fit
    for name in ("velocity_sigma_y", "gyro_sigma_z"):
        lv = next(lv for lv in fit.noise_levels if lv.name == name)
        assert lv.determined and lv.value == lv.estimate, lv.why
        assert name not in fit.noise_undetermined
    model = fit.to_model("test")
    cfg = model_config(FilterConfig(), model)
    # the estimators' sigma is the estimate widened by exp(sd^2): at most a few per cent
    ratio = np.asarray(cfg.velocity_sigma) / (np.asarray(model.velocity_sigma) * math.sqrt(0.5)
                                               * np.sqrt(model.velocity_correlation_time
                                                         or (1.0, 1.0, 1.0)))
    assert np.all(ratio >= 1.0) and np.all(ratio < 1.03), ratio
