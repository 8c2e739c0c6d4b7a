"""Pixel errors correlated along tracks (issues 12 and 13): the integrated correlation time from
residuals (graph.track_correlation), the model key that carries it, the simulator's drifting
tracker, and its identification on simulated drives."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from vislam.ekf.config import FilterConfig
from vislam.ekf.errors import InputError
from vislam.ekf.model import Model, long_run_pixel_sigma, model_config
from vislam.eval.benchmark import _drift_along_tracks
from vislam.eval.simulate import DEFAULT_SIM, SimConfig, drifting_noise, simulate
from vislam.graph.factors import StereoRows
from vislam.graph.track_correlation import (
    along_track_correlation,
    correlation_time,
    track_correlation,
)


def ar1_tracks(a: float, n_tracks: int, length: int, seed: int = 0):
    """(residuals (N, 3), frame, track): tracks of ``length`` consecutive frames with unit AR(1)
    errors of correlation ``a``."""
    rng = np.random.default_rng(seed)
    e = np.empty((n_tracks, length, 3))
    e[:, 0] = rng.standard_normal((n_tracks, 3))
    for k in range(1, length):
        e[:, k] = a * e[:, k - 1] + math.sqrt(1 - a * a) * rng.standard_normal((n_tracks, 3))
    start = rng.integers(0, 1000, n_tracks)
    frame = (start[:, None] + np.arange(length)[None, :]).ravel()
    track = np.repeat(np.arange(n_tracks), length)
    return e.reshape(-1, 3), frame, track


@pytest.mark.parametrize("a", [0.3, 0.6, 0.8])
def test_correlation_time_of_ar1_errors_is_one_plus_a_over_one_minus_a(a):
    residuals, frame, track = ar1_tracks(a, 3000, 60)
    rho, pairs = along_track_correlation(residuals, frame, track)
    assert rho[0] == pytest.approx(a, abs=0.02)
    assert rho[2] == pytest.approx(a**3, abs=0.03)
    assert pairs[0] == 3000 * 59
    tau, lags = correlation_time(rho)
    assert tau == pytest.approx((1 + a) / (1 - a), rel=0.12)
    assert lags >= 3


def test_white_errors_have_no_correlation_time():
    residuals, frame, track = ar1_tracks(0.0, 3000, 20)
    rows = StereoRows(frame, track, np.zeros((frame.size, 4)))
    c = track_correlation(residuals, rows)
    assert abs(c.correlation[0]) < 0.02
    assert c.time is None and c.to_dict()["decision"] == "none"


def test_the_sum_stops_at_the_first_non_positive_lag():
    tau, lags = correlation_time(np.array([0.5, 0.25, -0.01, 0.3]))
    assert lags == 2 and tau == pytest.approx(2.5)
    assert correlation_time(np.array([-0.1, 0.5])) == (1.0, 0)
    assert correlation_time(np.array([])) == (1.0, 0)


def test_only_observations_of_the_same_track_in_consecutive_frames_pair_up():
    # Two tracks interleaved in time, one gap: lag 1 pairs only within a track, across no gap.
    frame = np.array([0, 1, 2, 4, 0, 1])
    track = np.array([0, 0, 0, 0, 1, 1])
    residuals = np.arange(12.0).reshape(6, 2)
    rho, pairs = along_track_correlation(residuals, frame, track, min_pairs=1)
    assert pairs[0] == 3  # (0,1), (1,2) of track 0 and (0,1) of track 1; not 2 -> 4
    assert pairs[1] == 1  # 0 -> 2 of track 0; 2 -> 4 has a frame missing between
    empty, none = along_track_correlation(residuals, frame, track, min_pairs=100)
    assert empty.size == 0 and none.size == 0
    rows = StereoRows(frame, track, np.zeros((6, 4)))
    c = track_correlation(np.zeros((6, 3)), rows)
    assert c.time is None and c.to_dict()["lag1"] is None


def test_the_model_carries_the_correlation_time_and_the_estimators_use_the_long_run_sigma(tmp_path):
    base = dict(velocity_sigma=(0.5, 0.5, 0.5), gyro_sigma=(0.05, 0.05, 0.05), pixel_sigma=0.6,
                velocity_pairing="next", cam_T_imu=np.eye(4))
    white = Model(**base)
    assert model_config(FilterConfig(), white).pixel_sigma == pytest.approx(0.6)
    drifting = Model(**base, pixel_correlation_time=4.0)
    assert model_config(FilterConfig(), drifting).pixel_sigma == pytest.approx(1.2)
    assert long_run_pixel_sigma(0.6, 4.0) == pytest.approx(1.2)
    assert long_run_pixel_sigma(0.6, None) == 0.6
    back = Model.from_toml(drifting.write_toml(tmp_path / "m.toml"))
    assert back == drifting and back.pixel_correlation_time == 4.0
    assert "pixel_correlation_time = 4.0" in drifting.to_toml()
    assert "pixel_correlation_time" not in white.to_toml()
    for bad in (0.5, float("inf"), float("nan"), True, "3", 2000.0):
        with pytest.raises(InputError, match="pixel_correlation_time"):
            Model(**base, pixel_correlation_time=bad)


def test_the_simulator_drifts_pixel_errors_along_tracks_and_states_the_true_time():
    config = dataclasses.replace(DEFAULT_SIM, n_frames=150)
    white = simulate(config)
    same = simulate(dataclasses.replace(config, pixel_correlation=0.0))
    np.testing.assert_array_equal(white.sequence.obs.z, same.sequence.obs.z)
    assert white.model.pixel_correlation_time is None
    truth = simulate(dataclasses.replace(config, noise_free=True))
    drift = simulate(dataclasses.replace(config, pixel_correlation=0.8))
    assert drift.model.pixel_correlation_time == pytest.approx(9.0)
    obs, ref = drift.sequence.obs, truth.sequence.obs
    assert np.array_equal(obs.frame_index, ref.frame_index) and np.array_equal(obs.track, ref.track)
    error = (obs.z - ref.z) / config.pixel_sigma
    rho, _ = along_track_correlation(error, obs.frame_index, obs.track)
    assert rho[0] == pytest.approx(0.8, abs=0.03)
    assert error.std() == pytest.approx(1.0, abs=0.05)  # each error still N(0, sigma^2)
    for bad in (-0.1, 0.99, 1.0, float("nan"), True):
        with pytest.raises(InputError, match="pixel_correlation"):
            SimConfig(pixel_correlation=bad)


def test_monte_carlo_redraws_drift_like_the_simulator():
    rng = np.random.default_rng(3)
    residuals, frame, track = ar1_tracks(0.0, 400, 30, seed=1)
    white = rng.standard_normal((frame.size, 4))
    drifted = _drift_along_tracks(white, frame, track, 0.7)
    rho, _ = along_track_correlation(drifted, frame, track)
    assert rho[0] == pytest.approx(0.7, abs=0.03)
    np.testing.assert_array_equal(_drift_along_tracks(white, frame, track, 0.0), white)
    # one step by hand: a continuing track mixes, a new one is the white draw
    out = drifting_noise(np.ones((2, 4)), np.full((2, 4), 2.0), np.array([True, False]), 0.6)
    np.testing.assert_allclose(out[0], 0.6 * 2.0 + 0.8)
    np.testing.assert_allclose(out[1], 1.0)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 2])
def test_identified_on_a_drifting_tracker_and_none_on_white_noise(seed):
    """A tracker drifting with a = 0.7 (true correlation time 5.7 frames) is detected, and its
    time measured low (the landmark fit absorbs part of each track's slow error: 2.8-2.9 on
    these seeds, conservative); white pixel noise gets none."""
    from tests.test_calibrate import fit

    drifting = fit(seed, 0.5, 0.05, pixel_correlation=0.7)
    c = drifting.pixel_correlation_test
    assert c["decision"] == "correlated", c
    assert 2.0 < drifting.pixel_correlation_time < (1 + 0.7) / (1 - 0.7), c
    assert drifting.to_model("test").pixel_correlation_time == drifting.pixel_correlation_time
    white = fit(seed, 0.5, 0.05)
    assert white.pixel_correlation_time is None, white.pixel_correlation_test
    assert white.to_model("test").pixel_correlation_time is None
