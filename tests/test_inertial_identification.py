"""Issue 39 item 2: the raw-IMU noise identified by EM around the raw-IMU smoother
(graph.inertial_identification): the linear decomposition of GTSAM's preintegrated covariance,
the M-step's fixed point, the E-step's moments, recovery on simulated drives whose true noise
differs from their sheet, and `vislam calibrate` on a raw-IMU drive."""

from __future__ import annotations

import dataclasses
import functools


import numpy as np
import pytest

from vislam.ekf.inertial import ImuNoise
from vislam.eval.cli import main
from vislam.eval.imu_sim import simulate_imu
from vislam.eval.imu_sim_config import EUROC_IMU_NOISE, ImuSimConfig
from vislam.eval.inertial_files import load_inertial_drive, save_inertial_drive
from vislam.graph.inertial_factors import preintegrate, preintegration_params
from vislam.graph.inertial_identification import (FIGURES, factor_covariance, identify_imu_noise, m_step, noise_bases,
                                                  score, scoring_step, whitened_bases, with_noise)
from vislam.graph.inertial_smoother import build_problem, smooth

#: A short room flight whose vision resolves the IMU's noise per interval: 0.1 px tracks (at
#: 1 px, a 5 s drive leaves the gyro noise to its posterior: share 0.99, undetermined).
SIM = dict(n_frames=101, rest_s=1.0, pixel_sigma=0.1, scenario="room")


@functools.cache
def drive(seed: int, scale: float, frames: int = SIM["n_frames"]):
    return simulate_imu(ImuSimConfig(seed=seed, imu_noise_scale=scale, **dict(SIM, n_frames=frames)))[0]


@functools.cache
def fit(seed: int, scale: float):
    return identify_imu_noise(drive(seed, scale), max_iterations=12)


def test_preintegrated_covariance_is_linear_in_the_four_squared_figures():
    """GTSAM's covariance at other figures equals Sigma0 + sum theta_i B_i of the bases."""
    d = drive(0, 1.0, 21)
    problem = build_problem(d)
    S0, B = noise_bases(problem, EUROC_IMU_NOISE)
    theta = np.array([4.0, 0.3, 9.0, 2.5])
    other = ImuNoise.from_array(EUROC_IMU_NOISE.as_array() * np.sqrt(theta))
    params = preintegration_params(other, d.calibration.gravity)
    for k in (1, 10, 20):
        want = factor_covariance(preintegrate(d.imu, d.timestamps[k - 1], d.timestamps[k], params,
                                              problem.bias0))
        got = S0[k - 1] + np.einsum("i,iab->ab", theta, B[:, k - 1])
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12 * np.abs(want).max())
    # the blocks are coupled: the gyro noise enters the velocity block too
    assert np.abs(B[0, 10, 6:9, 6:9]).max() > 0
    # and the factor's covariance is not the preintegration's (the sign of a cross block)
    pim = preintegrate(d.imu, d.timestamps[0], d.timestamps[1], params, problem.bias0)
    assert np.abs(factor_covariance(pim) - pim.preintMeasCov()).max() > 1e-3 * np.abs(want).max()


def test_whitened_bases_make_the_factors_covariance_the_identity():
    problem = build_problem(drive(0, 1.0, 21))
    S0, B = noise_bases(problem, EUROC_IMU_NOISE)
    S0w, Bw = whitened_bases(problem, S0, B)
    S = S0w + Bw.sum(axis=0)
    np.testing.assert_allclose(S, np.broadcast_to(np.eye(15), S.shape), atol=1e-6)


def _synthetic(seed: int, n: int = 400):
    """Random positive semi-definite bases of rank 3 on different blocks, and the exact
    expected outer products of a known theta."""
    rng = np.random.default_rng(seed)
    Bw = np.zeros((4, n, 15, 15))
    for i, rows in enumerate((slice(0, 9), slice(12, 15), slice(3, 9), slice(6, 12))):
        G = np.zeros((n, 15, 4))
        G[:, rows] = rng.normal(size=(n, rows.stop - rows.start, 4))
        Bw[i] = G @ G.transpose(0, 2, 1)
    S0w = np.broadcast_to(1e-3 * np.eye(15), (n, 15, 15)).copy()
    truth = np.array([2.0, 0.5, 3.0, 1.5])
    E = S0w + np.einsum("i,ifab->fab", truth, Bw)
    return E, S0w, Bw, truth


def test_m_step_recovers_theta_from_exact_moments():
    """With E = Sigma(theta_true), Q's maximum is theta_true: the fixed point finds it from the
    sheet (all ones), and the score vanishes there."""
    E, S0w, Bw, truth = _synthetic(1)
    theta = m_step(E, S0w, Bw, np.ones(4))
    np.testing.assert_allclose(theta, truth, rtol=1e-4)
    assert np.abs(score(E, S0w, Bw, truth)).max() < 1e-6 * np.abs(score(E, S0w, Bw, np.ones(4))).max()


def test_scoring_step_converges_to_the_same_fixed_point():
    E, S0w, Bw, truth = _synthetic(2)
    L = np.zeros_like(E)  # no posterior: complete data
    theta = np.ones(4)
    for _ in range(30):
        theta = scoring_step(E, L, S0w, Bw, theta)
    np.testing.assert_allclose(theta, truth, rtol=1e-6)


def test_imu_moments_trace_is_chi2_plus_leverage():
    r = smooth(drive(0, 1.0, 41))
    tr = np.einsum("fii->f", r.imu_moments)
    mean = r.info["imu_chi2_mean"] + r.info["imu_leverage_mean"]
    assert tr.mean() == pytest.approx(mean, rel=1e-9)
    lev = np.einsum("fii->f", r.imu_leverage)
    assert lev.mean() == pytest.approx(r.info["imu_leverage_mean"], rel=1e-9)


def _within(fit_, truth_ratio, name, rtol=0.2, n_sigma=3.0):
    i = FIGURES.index(name)
    value, sd = fit_.noise.as_array()[i], fit_.noise_std[i]
    want = truth_ratio * fit_.sheet.as_array()[i]
    assert np.isfinite(sd) and sd < 0.5 * value, (name, value, sd)
    assert abs(value / want - 1.0) <= rtol or abs(value - want) <= n_sigma * sd, (name, value / want, sd / want)


#: (seed, true noise over the sheet): a sheet 3x too low, and a sheet that is right (model
#: identification: the second in the regression tier, the fast tier keeps the first).
CASES = [(1, 3.0), pytest.param(3, 1.0, marks=pytest.mark.regression)]


@pytest.mark.parametrize("seed, scale", CASES)
def test_gyro_noise_recovered_where_the_sheet_is_wrong_and_kept_where_right(seed, scale):
    """A true IMU 3x noisier than its sheet: the gyro noise density within 20 % of 3x the
    sheet's (3.14x measured); a sheet that is right stays within 20 % of it (0.91x). The gyro
    walk is not determined by 5 s of flight: kept at the sheet's and named."""
    f = fit(seed, scale)
    _within(f, scale, "gyro_noise_density")
    assert "gyro_random_walk" in f.undetermined
    assert f.noise.gyro_random_walk == f.sheet.gyro_random_walk
    assert f.pixel_sigma == pytest.approx(0.1, rel=0.15)
    # settled, and the smoother finds the model's solution from its own start (2e-6..6e-4
    # measured on seeds 0-4): the gyro noise is what is to be used
    assert f.usable.gyro_noise_density == f.noise.gyro_noise_density
    assert f.cold_start_nees < 0.01


@pytest.mark.xfail(strict=True, reason="the accelerometer's figures come out low: 1.87x and 0.53x "
                   "for true 3x and 1x (docs/findings.md, issue 39 item 2)")
@pytest.mark.parametrize("seed, scale", CASES)
def test_accelerometer_noise_recovered(seed, scale):
    f = fit(seed, scale)
    _within(f, scale, "accel_noise_density")


def test_the_sheets_ratio_is_the_identified_over_the_files():
    f = fit(1, 3.0)
    rows = f.rows()
    assert [r[0] for r in rows] == list(FIGURES) + ["pixel_sigma"]
    np.testing.assert_allclose([r[4] for r in rows[:4]], f.ratio)
    assert f.ratio[0] > 2.0  # the gyro noise: the sheet's 3x too low, not "about the sheet"


def _write(tmp_path, name="imu.npz", **changes):
    d = drive(0, 3.0, 41)
    if changes:
        d = dataclasses.replace(d, calibration=dataclasses.replace(d.calibration, **changes))
    return save_inertial_drive(tmp_path / name, d)


def test_calibrate_prints_the_sheet_beside_the_identified_and_writes_the_drive(tmp_path, capsys):
    path = _write(tmp_path)
    out = tmp_path / "identified.npz"
    assert main(["calibrate", str(path), "--max-iterations", "2", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "raw IMU" in text and "| gyro noise density (rad/s/sqrt(Hz)) | 0.0001697 |" in text
    assert "extrinsic: not checked" in text
    # two steps do not settle EM on a 3x sheet: the report says so and the file keeps the
    # sheet's figures for what was still moving (the gyro noise among them)
    assert "NOT to be trusted" in text and "had not settled" in text
    assert "| sheet's |" in text
    written = load_inertial_drive(out)
    assert written.calibration.noise.gyro_noise_density == EUROC_IMU_NOISE.gyro_noise_density
    np.testing.assert_array_equal(written.imu.gyro, load_inertial_drive(path).imu.gyro)


def test_calibrate_bad_input_names_the_file_and_key(tmp_path, capsys):
    path = _write(tmp_path, noise=ImuNoise(1.7e-4, 0.0, 2e-3, 3e-3))
    assert main(["calibrate", str(path), "--max-iterations", "2"]) == 2
    err = capsys.readouterr().err
    assert str(path) in err and "'imu_noise'" in err and "positive" in err
    good = _write(tmp_path, "good.npz")
    assert main(["calibrate", str(good), "--out", str(tmp_path / "model.toml")]) == 2
    assert "model.toml" in capsys.readouterr().err
    assert main(["calibrate", str(good), "--max-iterations", "0"]) == 2
    assert "--max-iterations" in capsys.readouterr().err


def test_unsettled_figures_keep_the_sheets_value_and_are_named():
    """EM stopped after 2 steps (a 3x sheet: still moving): every figure it had not settled keeps
    the sheet's value in what is to be used, is named, and the fit is not trusted."""
    f = identify_imu_noise(drive(0, 3.0, 41), max_iterations=2, check_cold_start=False)
    assert not f.converged and "gyro_noise_density" in f.unconverged
    assert not f.trusted
    for i, name in enumerate(FIGURES):
        if name in f.unconverged or name in f.undetermined:
            assert f.usable.as_array()[i] == f.sheet.as_array()[i], name
        else:
            assert f.usable.as_array()[i] == f.noise.as_array()[i], name
    assert set(f.withheld) == set(f.unconverged)
    assert np.isnan(f.cold_start_nees)


def test_cold_start_statistic_is_zero_for_the_same_solution_and_large_for_another():
    """Two solves of one model from one start agree (statistic 0); poses moved by 10 of their
    own sigmas along one axis give about 100 a frame."""
    from vislam.graph.inertial_identification import pose_mahalanobis

    r = smooth(drive(0, 1.0, 41))
    assert np.abs(pose_mahalanobis(r, r)).max() < 1e-12
    poses = r.estimate.poses.copy()
    sd = np.sqrt(r.estimate.pose_cov[:, 0, 0])  # translation along the body's x first
    poses[:, :3, 3] += poses[:, :3, 0] * (10 * sd)[:, None]
    moved = dataclasses.replace(r, estimate=dataclasses.replace(r.estimate, poses=poses))
    d = pose_mahalanobis(r, moved)[1:]
    assert np.median(d) > 50


def test_a_model_whose_cold_solve_lands_elsewhere_is_not_written(tmp_path, capsys, monkeypatch):
    """EuRoC V1_01 (docs/findings.md): the smoother under the identified figures, started from its
    own initial values, found another minimum (ATE 0.265 m against 0.027 m from EM's solution).
    When the cold-start check fails, every figure keeps the sheet's value in what is used and
    written, and calibrate says plainly that the identified figures are not to be trusted."""
    import vislam.graph.inertial_identification as ii

    identify = ii.identify_imu_noise
    # a loose rtol settles EM in a step or two, so that there is a model to check
    monkeypatch.setattr(ii, "identify_imu_noise", lambda d, **k: identify(d, **dict(k, rtol=0.99)))
    monkeypatch.setattr(ii, "cold_start_nees", lambda *a, **k: 1e5)
    f = ii.identify_imu_noise(drive(0, 3.0, 41), max_iterations=2)
    assert len(f.unconverged) < 4 - len(f.undetermined)  # something was settled, then withheld
    assert f.usable == f.sheet and not f.trusted and f.cold_start_nees == 1e5
    assert set(f.withheld) | set(f.undetermined) == set(FIGURES)
    path = _write(tmp_path)
    out = tmp_path / "identified.npz"
    assert main(["calibrate", str(path), "--max-iterations", "2", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "NOT to be trusted" in text and "different minimum" in text
    assert load_inertial_drive(out).calibration.noise == EUROC_IMU_NOISE
