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


#: (seed, true noise over the sheet): a sheet 3x too low, and a sheet that is right.
CASES = [(1, 3.0), (3, 1.0)]


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
    written = load_inertial_drive(out)
    assert written.calibration.noise != EUROC_IMU_NOISE
    assert written.calibration.noise.gyro_noise_density > EUROC_IMU_NOISE.gyro_noise_density
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
