"""The raw-IMU filters' propagation (ekf/imu_propagation.py): the same mean and covariance as
strapdown integration, the interval's transition against finite differences, the once-per-frame
cross-covariance against per-sample propagation, a Monte Carlo of a noise-only drive, and
GTSAM's preintegration as an independent check of the mean."""

import numpy as np
import pytest
from scipy.stats import chi2

from tests.numdiff import numeric_jacobian
from vislam.ekf.filter import ImuSamples
from vislam.ekf.geometry import so3_exp, so3_log
from vislam.ekf.imu_propagation import propagate
from vislam.ekf.inertial import ImuNoise
from vislam.ekf.strapdown import N_ERROR, NavState, integrate, step_jacobian

G_WORLD = np.array([0.0, 0.0, -9.81])
NOISE = ImuNoise(2e-3, 2e-4, 2e-2, 3e-3)  # ten times EuRoC's: errors well above rounding


def _samples(seed: int, n: int = 12, rate: float = 200.0, t0: float = 0.0) -> ImuSamples:
    rng = np.random.default_rng(seed)
    t = t0 + np.arange(n) / rate + 1e-4 * rng.uniform(size=n)
    t.sort()
    return ImuSamples(t, np.array([0.3, -0.2, 9.7]) + rng.normal(size=(n, 3)),
                      0.5 * rng.normal(size=(n, 3)))


def _state(seed: int) -> NavState:
    rng = np.random.default_rng(seed)
    return NavState(so3_exp(rng.normal(size=3)), rng.normal(size=3), rng.normal(size=3),
                    0.01 * rng.normal(size=3), 0.1 * rng.normal(size=3))


def _local(ref: NavState, s: NavState) -> np.ndarray:
    return np.concatenate([so3_log(ref.R.T @ s.R), s.v - ref.v, s.p - ref.p, s.bg - ref.bg,
                           s.ba - ref.ba])


def _spd(seed: int, n: int) -> np.ndarray:
    A = np.random.default_rng(seed).normal(size=(n, n))
    return 1e-3 * (A @ A.T + n * np.eye(n))


def test_propagate_is_strapdown_integration_with_its_transition():
    imu, s0, P0 = _samples(1), _state(2), _spd(3, N_ERROR)
    t0, t1 = imu.time[0] + 0.001, imu.time[-1] + 0.002  # both ends split a sample
    s, P, Phi = propagate(s0, P0, imu, t0, t1, G_WORLD, NOISE)
    s_ref, P_ref = integrate(s0, P0, imu, t0, t1, G_WORLD, NOISE)
    for a in ("R", "v", "p", "bg", "ba"):
        np.testing.assert_allclose(getattr(s, a), getattr(s_ref, a), rtol=0, atol=1e-12)
    np.testing.assert_allclose(P, P_ref, rtol=1e-12, atol=1e-15)
    # the transition is the derivative of the whole interval's map
    num = numeric_jacobian(
        lambda dx: _local(s, integrate(s0.retract(dx), None, imu, t0, t1, G_WORLD)[0]),
        np.zeros(N_ERROR))
    np.testing.assert_allclose(Phi, num, atol=1e-6)


def test_cross_covariance_by_the_interval_transition_is_the_per_sample_one():
    """Once per frame ``Phi P_IL`` equals propagating the whole joint covariance sample by
    sample (landmarks static, no noise on them)."""
    imu, s0 = _samples(4, n=20), _state(5)
    n_lm = 6
    P0 = _spd(6, N_ERROR + n_lm)
    t0, t1 = imu.time[0], imu.time[-1] + 0.005
    _, Pii, Phi = propagate(s0, P0[:N_ERROR, :N_ERROR], imu, t0, t1, G_WORLD, NOISE)
    cross = Phi @ P0[:N_ERROR, N_ERROR:]
    # reference: every sample's step on the joint covariance
    P, s = P0.copy(), s0
    ends = np.append(imu.time[1:], t1)
    for j in range(imu.time.size):
        dt = min(ends[j], t1) - max(imu.time[j], t0)
        F = np.eye(N_ERROR + n_lm)
        F[:N_ERROR, :N_ERROR] = step_jacobian(s, imu.gyro[j], imu.accel[j], dt)
        sub = ImuSamples(imu.time[j:j + 1], imu.accel[j:j + 1], imu.gyro[j:j + 1])
        _, Pj = integrate(s, P[:N_ERROR, :N_ERROR], sub, imu.time[j], imu.time[j] + dt, G_WORLD,
                          NOISE)
        s = integrate(s, None, sub, imu.time[j], imu.time[j] + dt, G_WORLD)[0]
        P = F @ P @ F.T
        P[:N_ERROR, :N_ERROR] = Pj
    np.testing.assert_allclose(cross, P[:N_ERROR, N_ERROR:], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(Pii, P[:N_ERROR, :N_ERROR], rtol=1e-9, atol=1e-12)


def test_noise_only_drive_monte_carlo_matches_the_propagated_covariance():
    """300 runs (seed 7) of a constant true motion with white noise, bias walks and an initial
    error drawn from P0: the 15-state NEES after 0.5 s inside the two-sided 95 % bounds."""
    rate, n, runs = 200.0, 100, 300
    t = np.arange(n) / rate
    t1 = n / rate
    w_true, f_true = np.array([0.2, -0.4, 0.3]), np.array([0.5, 0.2, 9.9])
    truth0 = NavState(so3_exp(np.array([0.1, -0.2, 0.3])), np.array([1.0, 0.0, 0.5]),
                      np.zeros(3), np.array([0.01, -0.02, 0.005]), np.array([0.05, 0.0, -0.1]))
    P0 = np.diag([1e-4] * 3 + [1e-3] * 3 + [1e-3] * 3 + [1e-5] * 3 + [1e-3] * 3)
    L0 = np.linalg.cholesky(P0)
    dt = 1.0 / rate
    sg, sa = NOISE.gyro_noise_density / np.sqrt(dt), NOISE.accel_noise_density / np.sqrt(dt)
    wg, wa = NOISE.gyro_random_walk * np.sqrt(dt), NOISE.accel_random_walk * np.sqrt(dt)
    rng = np.random.default_rng(7)
    # the filter starts at truth0 and integrates noisy samples; truth starts at truth0 + e0
    # and integrates the noise-free ones with its walking biases
    nees = np.empty(runs)
    P_end = None
    for r in range(runs):
        e0 = L0 @ rng.normal(size=N_ERROR)
        true_start = truth0.retract(e0)
        bg = true_start.bg + np.cumsum(np.vstack([np.zeros(3), wg * rng.normal(size=(n - 1, 3))]), 0)
        ba = true_start.ba + np.cumsum(np.vstack([np.zeros(3), wa * rng.normal(size=(n - 1, 3))]), 0)
        gyro = w_true + bg + sg * rng.normal(size=(n, 3))
        accel = f_true + ba + sa * rng.normal(size=(n, 3))
        measured = ImuSamples(t, accel, gyro)
        s, P, _ = propagate(truth0, P0, measured, 0.0, t1, G_WORLD, NOISE)
        P_end = P
        # truth: noise-free samples with its own biases (the truth's bias state walks too)
        x = true_start
        for j in range(n):
            x = NavState(x.R, x.v, x.p, bg[j], ba[j])
            x = integrate(x, None, ImuSamples(t[j:j + 1], (f_true + ba[j])[None],
                                              (w_true + bg[j])[None]), t[j], t[j] + dt, G_WORLD)[0]
        e = _local(s, x)
        nees[r] = e @ np.linalg.solve(P, e)
    lo, hi = chi2.ppf([0.025, 0.975], N_ERROR * runs) / runs
    assert lo < nees.mean() < hi, (nees.mean(), lo, hi)
    assert np.all(np.isfinite(P_end))


def test_mean_matches_gtsam_preintegration():
    """GTSAM's PreintegratedImuMeasurements over the same held samples predicts the same
    NavState (an independent implementation of the mean). GTSAM's default build preintegrates
    in the tangent space, exact to second order in the rotation per step: with these samples
    (0.5 rad/s, 0.2 s) it is within 1e-5 of the exact per-sample exponential."""
    gtsam = pytest.importorskip("gtsam")
    imu, s0 = _samples(8, n=40), _state(9)
    t = imu.time
    t0, t1 = t[0], t[-1] + 0.005
    s, _, _ = propagate(s0, np.zeros((N_ERROR, N_ERROR)), imu, t0, t1, G_WORLD, NOISE)
    params = gtsam.PreintegrationParams.MakeSharedU(9.81)
    params.setAccelerometerCovariance(np.eye(3) * 1e-4)
    params.setGyroscopeCovariance(np.eye(3) * 1e-6)
    params.setIntegrationCovariance(np.eye(3) * 1e-8)
    bias = gtsam.imuBias.ConstantBias(s0.ba, s0.bg)
    pim = gtsam.PreintegratedImuMeasurements(params, bias)
    ends = np.append(t[1:], t1)
    for j in range(t.size):
        pim.integrateMeasurement(imu.accel[j], imu.gyro[j], float(ends[j] - t[j]))
    start = gtsam.NavState(gtsam.Rot3(s0.R), gtsam.Point3(*s0.p), s0.v)
    pred = pim.predict(start, bias)
    np.testing.assert_allclose(so3_log(pred.attitude().matrix().T @ s.R), 0.0, atol=1e-5)
    np.testing.assert_allclose(pred.position(), s.p, atol=1e-5)
    np.testing.assert_allclose(pred.velocity(), s.v, atol=1e-5)
    # and the motion is far larger than the tolerance
    assert np.linalg.norm(so3_log(s0.R.T @ s.R)) > 0.01 and np.linalg.norm(s.p - s0.p) > 0.1


def _held_pieces_by_definition(time, t0, t1):
    """Every sample held from max(t_j, t0) to min(t_j+1, t1), the last until t1: the rule
    written out over the whole stream, without the binary searches."""
    ends = np.append(time[1:], t1)
    return [(j, float(min(ends[j], t1) - max(time[j], t0))) for j in range(time.size)
            if min(ends[j], t1) - max(time[j], t0) > 0]


def test_held_pieces_reads_only_the_interval_and_gives_the_rules_pieces():
    from vislam.ekf.errors import EstimationError
    from vislam.ekf.strapdown import held_pieces

    rng = np.random.default_rng(3)
    time = np.cumsum(rng.uniform(0.004, 0.006, 400))
    for t0, t1 in [(time[10], time[20]), (time[10] + 1e-4, time[20] - 1e-4), (time[0], time[1]),
                   (time[-3] + 1e-4, time[-1] + 0.02), (time[5] + 1e-5, time[5] + 2e-5),
                   (time[-1], time[-1] + 0.01)] + [tuple(np.sort(rng.uniform(time[0], time[-1] + 0.01, 2)))
                                                    for _ in range(50)]:
        assert held_pieces(time, t0, t1) == _held_pieces_by_definition(time, t0, t1)
    with pytest.raises(EstimationError, match="no IMU sample at or before"):
        held_pieces(time, time[0] - 1e-3, time[3])
