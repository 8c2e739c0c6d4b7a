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
from vislam.eval.montecarlo import drift_along_tracks
from vislam.eval.simulate import DEFAULT_SIM, SimConfig, drifting_noise, simulate
from vislam.graph.factors import StereoRows
from vislam.graph.track_correlation import (
    SIMULATION_SEED,
    ar1_along_tracks,
    along_track_correlation,
    correlation_time,
    landmark_jacobians,
    track_correlation,
    without_landmark_fit,
)
from tests.numdiff import numeric_jacobian


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


def _simulated_rows(frames: int = 120):
    """A default simulated drive's true poses, landmarks, calibration and stereo rows."""
    from vislam.graph.factors import StereoRows as Rows

    drive = simulate(dataclasses.replace(DEFAULT_SIM, n_frames=frames))
    obs = drive.sequence.obs
    rows = Rows(obs.frame_index, obs.track, obs.z)
    return drive.poses, drive.landmarks, drive.sequence.calibration, rows


def test_landmark_jacobians_match_finite_differences():
    from vislam.graph.factors import stereo_residuals

    poses, landmarks, calib, rows = _simulated_rows(20)
    J = landmark_jacobians(poses, landmarks, calib, rows)
    for n in (0, len(rows) // 2, len(rows) - 1):
        one = rows.subset(np.array([n]))
        t = int(rows.track[n])

        def predicted(p):
            lm = landmarks.copy()
            lm[t] = p
            return -stereo_residuals(poses, lm, calib, one)[0][0] * np.array([1.0, 1.0, math.sqrt(2.0)])

        np.testing.assert_allclose(J[n], numeric_jacobian(predicted, landmarks[t], 1e-5),
                                   rtol=1e-6, atol=1e-6)


def test_ar1_errors_along_tracks_start_afresh_on_each_track_and_decay_over_gaps():
    residuals, frame, track = ar1_tracks(0.0, 2000, 25, seed=4)
    white = np.random.default_rng(5).standard_normal((frame.size, 3))
    e = ar1_along_tracks(frame, track, 0.8, white)
    rho, _ = along_track_correlation(e, frame, track)
    assert rho[0] == pytest.approx(0.8, abs=0.02) and rho[1] == pytest.approx(0.64, abs=0.03)
    assert e.std() == pytest.approx(1.0, abs=0.03)
    # by hand: a track's first error is its draw; across a gap of 2 frames the weight is a^2
    f, t = np.array([5, 6, 8, 0]), np.array([1, 1, 1, 0])
    w = np.arange(1.0, 5.0)[:, None]
    x = ar1_along_tracks(f, t, 0.5, w)[:, 0]
    assert x[3] == 4.0 and x[0] == 1.0
    assert x[1] == pytest.approx(0.5 * 1.0 + math.sqrt(0.75) * 2.0)
    assert x[2] == pytest.approx(0.25 * x[1] + math.sqrt(1 - 0.0625) * 3.0)


def test_the_landmark_fit_correction_recovers_the_errors_correlation_time_and_sigma():
    """AR(1) errors (a = 0.8, tau 9) through each track's landmark fit on a simulated drive's
    own geometry, drawn with another seed than the correction's: the residuals' estimate is
    far too low (the fit removes the slow part), the corrected one within 10 % of 9 and the
    residuals' variance ratio that of the draw."""
    poses, landmarks, calib, rows = _simulated_rows()
    J = landmark_jacobians(poses, landmarks, calib, rows)
    white = np.random.default_rng(SIMULATION_SEED + 11).standard_normal((len(rows), 3))
    r = without_landmark_fit(ar1_along_tracks(rows.frame, rows.track, 0.8, white), J, rows.track)
    residuals = r / np.array([1.0, 1.0, math.sqrt(2.0)])  # GTSAM's [uL, uR, v] units
    raw = track_correlation(residuals, rows)
    c = track_correlation(residuals, rows, J)
    assert raw.corrected is None and raw.time == raw.estimate < 6.0
    assert c.kept and c.estimate == raw.estimate
    assert c.time == pytest.approx(9.0, rel=0.10), c.lookup
    n_tracks = np.unique(rows.track).size
    assert c.variance_ratio == pytest.approx(np.sum(r * r) / (r.size - 3 * n_tracks), rel=0.05)
    assert c.sigma_factor == pytest.approx(1.0 / math.sqrt(c.variance_ratio))
    # a row without a finite Jacobian (a point at infinity) is left out of the simulation
    J_bad = J.copy()
    J_bad[::50] = np.nan
    c_bad = track_correlation(residuals, rows, J_bad)
    assert np.isfinite(c_bad.time) and c_bad.time == pytest.approx(c.time, rel=0.05)
    # white errors: nothing to correct, none kept
    w = without_landmark_fit(white, J, rows.track) / np.array([1.0, 1.0, math.sqrt(2.0)])
    none = track_correlation(w, rows, J)
    assert none.time is None and none.sigma_factor == 1.0


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
    drifted = drift_along_tracks(white, frame, track, 0.7)
    rho, _ = along_track_correlation(drifted, frame, track)
    assert rho[0] == pytest.approx(0.7, abs=0.03)
    np.testing.assert_array_equal(drift_along_tracks(white, frame, track, 0.0), white)
    # one step by hand: a continuing track mixes, a new one is the white draw
    out = drifting_noise(np.ones((2, 4)), np.full((2, 4), 2.0), np.array([True, False]), 0.6)
    np.testing.assert_allclose(out[0], 0.6 * 2.0 + 0.8)
    np.testing.assert_allclose(out[1], 1.0)


@pytest.mark.regression
@pytest.mark.slow
@pytest.mark.parametrize("velocity_sigma, a, seed", [  # both seeds, each correlation, in each
    (0.5, 0.7, 2), (0.5, 0.85, 1), (0.05, 0.7, 1), (0.05, 0.85, 2)])  # noise regime
def test_identified_on_a_drifting_tracker_and_none_on_white_noise(velocity_sigma, a, seed):
    """A tracker drifting with AR(1) correlation a (true correlation time (1 + a) / (1 - a):
    5.7 and 12.3 frames) is detected and its time and pixel sigma (1 px) recovered in both
    noise regimes: the residuals alone give about half the time and 0.86 / 0.77 px (the
    landmark fit absorbs part of each track's slow error); corrected for the fit, within 10 %
    and 5 % (measured: 5.44-5.47 and 11.6-11.7, 0.98-0.99 px, in both regimes). White pixel
    noise gets none."""
    from tests.test_calibrate import fit

    drifting = fit(seed, velocity_sigma, velocity_sigma / 10, pixel_correlation=a)
    c = drifting.pixel_correlation_test
    assert c["decision"] == "correlated", c
    true_tau = (1 + a) / (1 - a)
    assert c["estimate"] < 0.6 * true_tau, c  # what the residuals show
    assert drifting.pixel_correlation_time == pytest.approx(true_tau, rel=0.10), c
    assert drifting.pixel_sigma == pytest.approx(1.0, rel=0.05), c
    assert c["white_sigma"] < 0.9, c
    assert drifting.to_model("test").pixel_correlation_time == drifting.pixel_correlation_time
    if a == 0.7:
        white = fit(seed, velocity_sigma, velocity_sigma / 10)
        assert white.pixel_correlation_time is None, white.pixel_correlation_test
        assert white.to_model("test").pixel_correlation_time is None
