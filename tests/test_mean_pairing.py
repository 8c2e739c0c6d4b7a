"""The "mean" pairing's intervals are not independent: two consecutive intervals share a
velocity sample, so white samples give interval errors correlated by a half and a long-run
variance twice the interval's (ekf.model.white_sample_ratio). The estimators, which treat
intervals as independent, take the long-run sigma (model_config); the per-interval data check
takes the white one back (per_interval_config)."""

from __future__ import annotations

import numpy as np
import pytest

from vislam.ekf.config import FilterConfig
from vislam.ekf.dead_reckoning import run_dead_reckoning
from vislam.ekf.model import (apply_model, interval_sigma_factor, model_config,
                              per_interval_config, white_sample_ratio)
from vislam.eval.consistency import pose_nees
from vislam.eval.simulate import DEFAULT_SIM, SimConfig, simulate, true_model


@pytest.mark.parametrize("pairing, ratio", [("mean", 2.0), ("current", 1.0), ("next", 1.0)])
def test_white_samples_long_run_ratio(pairing, ratio):
    assert white_sample_ratio(pairing) == pytest.approx(ratio, rel=1e-12)
    # what white samples give: the interval's share of a sample's variance, times 1 + 2 rho
    rho = 0.5 if pairing == "mean" else 0.0
    assert interval_sigma_factor(pairing) ** 2 * (1 + 2 * rho) == pytest.approx(1.0)


def _model(pairing="mean", **changes):
    sim = simulate(SimConfig(seed=1, n_frames=20, velocity_sigma=0.3, gyro_sigma=0.02,
                             velocity_pairing=pairing))
    return true_model(sim).replace(**changes)


def test_the_estimators_take_the_samples_sigma_under_mean_and_the_check_the_intervals():
    model = _model()
    config = model_config(FilterConfig(), model)
    np.testing.assert_allclose(config.velocity_sigmas, 0.3, rtol=1e-12)  # the sample's
    np.testing.assert_allclose(config.gyro_sigmas, 0.02, rtol=1e-12)
    check = per_interval_config(config, model)
    np.testing.assert_allclose(check.velocity_sigmas, 0.3 * np.sqrt(0.5), rtol=1e-12)
    np.testing.assert_allclose(check.gyro_sigmas, 0.02 * np.sqrt(0.5), rtol=1e-12)


def test_a_longer_correlation_than_the_null_is_kept_and_other_pairings_are_untouched():
    model = _model(velocity_correlation_time=(5.0, 1.0, 2.0))
    config = model_config(FilterConfig(), model)
    np.testing.assert_allclose(config.velocity_sigmas,
                               0.3 * np.sqrt(0.5) * np.sqrt([5.0, 2.0, 2.0]), rtol=1e-12)
    check = per_interval_config(config, model)
    np.testing.assert_allclose(check.velocity_sigmas,
                               0.3 * np.sqrt(0.5) * np.sqrt([5.0, 1.0, 2.0]), rtol=1e-12)
    other = _model("current")
    c = model_config(FilterConfig(), other)
    np.testing.assert_allclose(c.velocity_sigmas, 0.3, rtol=1e-12)
    assert per_interval_config(c, other) == c


def test_dead_reckoning_is_consistent_on_default_drives_under_their_true_model():
    """Eight default drives (white samples, "mean"): dead reckoning's mean pose NEES over the
    drives is inside [3, 9] (measured 4.6; with the intervals read as independent it was 9.2,
    twice that: the long run's half the variance)."""
    nees = []
    for seed in range(8):
        sim = simulate(SimConfig(**{**DEFAULT_SIM.__dict__, "seed": seed, "n_frames": 400}))
        seq, config = apply_model(sim.sequence, FilterConfig(), true_model(sim))
        est = run_dead_reckoning(seq, config)
        nees.append(np.nanmean(pose_nees(est, np.arange(len(sim.poses)), sim.poses)))
    assert 3.0 < np.mean(nees) < 9.0, nees
