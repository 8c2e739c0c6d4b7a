"""Propagation of the right-invariant raw-IMU EKF (ekf.imu_invariant_propagation): the transition
and noise of one sample and of a frame interval against finite differences of the strapdown
step, the conversions both ways, a Monte Carlo of a noise-only drive, and gtsam's own IMU
integration as an independent check of the mean."""

import numpy as np
import pytest
from scipy.stats import chi2
from vislam.ekf.filter import ImuSamples
from vislam.ekf.geometry import se3_exp, se3_inv, se3_log, so3_exp
from vislam.ekf.imu_invariant_propagation import (
    BA,
    BG,
    N_CORE,
    POS,
    ROT,
    VEL,
    error_between,
    estimate_pose_jacobian,
    frame_covariance,
    landmark_errors,
    propagate,
    retract,
    retract_landmarks,
    sample_noise,
    sample_transition,
    strapdown_to_invariant,
)
from vislam.ekf.inertial import ImuNoise
from vislam.ekf.strapdown import NavState, exp_and_right_jacobian, step

from tests.numdiff import numeric_jacobian

G_WORLD = np.array([0.0, 0.0, -9.81])


def _state(rng) -> NavState:
    return NavState(so3_exp(rng.normal(size=3)), rng.normal(size=3), rng.normal(size=3),
                    0.1 * rng.normal(size=3), 0.3 * rng.normal(size=3))


def _imu(rng, n, rate=200.0):
    t = np.arange(n) / rate
    return ImuSamples(t, rng.normal(size=(n, 3)) + [0, 0, 9.81], rng.normal(size=(n, 3)))


def _full_error(true_s, true_lm, est_s, est_lm):
    return np.concatenate([error_between(true_s, est_s),
                           landmark_errors(true_lm, est_lm, true_s.R, est_s.R).ravel()])


def _full_retract(s, lm, xi):
    return retract(s, xi[:N_CORE]), retract_landmarks(lm, xi[ROT], xi[N_CORE:].reshape(-1, 3))


def test_retract_and_error_are_inverse():
    rng = np.random.default_rng(1)
    s, lm = _state(rng), rng.normal(size=(3, 3))
    xi = 0.3 * rng.normal(size=N_CORE + 9)
    s2, lm2 = _full_retract(s, lm, xi)
    np.testing.assert_allclose(_full_error(s2, lm2, s, lm), xi, atol=1e-12)


@pytest.mark.parametrize("dt", [0.005, 0.05, 0.4])
def test_sample_transition_against_finite_differences(dt):
    """RI-3: F of one sample, core and two landmarks (their rows from the frame formula RI-5
    with one sample), against the step of ekf.strapdown on a retracted state."""
    rng = np.random.default_rng(3)
    for _ in range(4):
        s, lm = _state(rng), 3 * rng.normal(size=(2, 3))
        gyro, accel = rng.normal(size=3), rng.normal(size=3) + [0, 0, 9.81]
        ref = step(s, gyro, accel, dt, G_WORLD)
        Jr = exp_and_right_jacobian((gyro - s.bg) * dt)[1]
        F = sample_transition(ref, s.R, Jr, dt, G_WORLD)

        def moved(xi, s=s, lm=lm, gyro=gyro, accel=accel, ref=ref):
            s1, lm1 = _full_retract(s, lm, xi)
            return _full_error(step(s1, gyro, accel, dt, G_WORLD), lm1, ref, lm)

        num = numeric_jacobian(moved, np.zeros(N_CORE + 6))
        np.testing.assert_allclose(F, num[:N_CORE, :N_CORE], atol=1e-7)
        # the landmark rows: xi_l' = xi_l + l^ (xi_R' - xi_R), as frame_covariance applies them
        P = np.eye(N_CORE + 6)
        Pf = frame_covariance(P, F, np.zeros((N_CORE, N_CORE)), lm, np.array([True, True]))
        np.testing.assert_allclose(Pf, num @ num.T, atol=1e-6)


def test_sample_noise_is_the_sample_noise_through_the_step():
    """RI-4: Q equals G diag(sg^2/dt, sa^2/dt) G^T with G the finite-difference Jacobian of the
    invariant error after one step in the samples' noise; the bias block is the walk."""
    rng = np.random.default_rng(4)
    noise = ImuNoise(0.02, 0.003, 0.2, 0.04)
    dt = 0.01
    s = _state(rng)
    gyro, accel = rng.normal(size=3), rng.normal(size=3)
    ref = step(s, gyro, accel, dt, G_WORLD)
    # truth = measurement - noise: the estimate integrates the noisy sample
    G = numeric_jacobian(
        lambda n: error_between(step(s, gyro - n[:3], accel - n[3:], dt, G_WORLD), ref),
        np.zeros(6))
    S = np.diag([noise.gyro_noise_density ** 2 / dt] * 3 + [noise.accel_noise_density ** 2 / dt] * 3)
    expected = G @ S @ G.T
    expected[BG, BG] = noise.gyro_random_walk ** 2 * dt * np.eye(3)
    expected[BA, BA] = noise.accel_random_walk ** 2 * dt * np.eye(3)
    Jr = exp_and_right_jacobian((gyro - s.bg) * dt)[1]
    np.testing.assert_allclose(sample_noise(ref, Jr, dt, noise), expected, atol=1e-10, rtol=1e-6)


def test_frame_transition_against_finite_differences_and_dense_form():
    """RI-5 over a frame interval of ten samples split at both ends: Phi against finite
    differences of the whole interval; frame_covariance against the dense
    [[Phi, 0], [U D, I]] P [..]^T + Q with the correlated landmark noise; a landmark outside
    the group keeps its rows."""
    rng = np.random.default_rng(5)
    imu = _imu(rng, 12)
    t0, t1 = 0.002, 0.052
    s, lm = _state(rng), 4 * rng.normal(size=(3, 3))
    noise = ImuNoise(0.02, 0.003, 0.2, 0.04)
    out, Phi, Qc = propagate(s, imu, t0, t1, G_WORLD, noise)

    def moved(xi):
        s1 = retract(s, xi)
        return error_between(propagate(s1, imu, t0, t1, G_WORLD, noise)[0], out)

    np.testing.assert_allclose(Phi, numeric_jacobian(moved, np.zeros(N_CORE)), atol=1e-7)
    in_group = np.array([True, False, True])
    n = N_CORE + 9
    A = rng.normal(size=(n, n))
    P = A @ A.T
    U = np.zeros((9, 3))
    for j in range(3):
        if in_group[j]:
            U[3 * j:3 * j + 3] = np.array([[0, -lm[j, 2], lm[j, 1]], [lm[j, 2], 0, -lm[j, 0]],
                                          [-lm[j, 1], lm[j, 0], 0]])
    D = Phi[ROT].copy()
    D[:, ROT] -= np.eye(3)
    F = np.eye(n)
    F[:N_CORE, :N_CORE] = Phi
    F[N_CORE:, :N_CORE] = U @ D
    B = np.zeros((n, N_CORE))
    B[:N_CORE] = np.eye(N_CORE)
    B[N_CORE:, ROT] = U
    expected = F @ P @ F.T + B @ Qc @ B.T
    np.testing.assert_allclose(frame_covariance(P, Phi, Qc, lm, in_group), expected,
                               rtol=1e-10, atol=1e-9)


def test_strapdown_conversion_both_ways():
    """RI-6: S maps the strapdown error (body rotation, world v and p) to the invariant one, and
    its inverse maps back, both against finite differences of the exact errors."""
    rng = np.random.default_rng(6)
    s = _state(rng)
    S = strapdown_to_invariant(s)
    num = numeric_jacobian(lambda dx: error_between(s.retract(dx), s), np.zeros(N_CORE))
    np.testing.assert_allclose(S, num, atol=1e-8)

    def back(xi):
        t = retract(s, xi)
        return np.concatenate([so3_log_rel(s.R, t.R), t.v - s.v, t.p - s.p, t.bg - s.bg,
                               t.ba - s.ba])

    np.testing.assert_allclose(np.linalg.inv(S), numeric_jacobian(back, np.zeros(N_CORE)),
                               atol=1e-8)


def so3_log_rel(R0, R1):
    from vislam.ekf.geometry import so3_log
    return so3_log(R0.T @ R1)


def test_estimate_convention_both_ways():
    """RI-6: [rho; phi] = E xi (the right perturbation of world_T_imu, translation first) and
    back, against finite differences of se3_log(T^-1 T_true)."""
    rng = np.random.default_rng(7)
    s = _state(rng)
    E = estimate_pose_jacobian(s)
    num = numeric_jacobian(lambda xi: se3_log(se3_inv(s.pose) @ retract(s, xi).pose),
                           np.zeros(N_CORE))
    np.testing.assert_allclose(E, num, atol=1e-8)
    pose_cols = np.r_[POS.start:POS.stop, ROT.start:ROT.stop]

    def back(x):
        T = s.pose @ se3_exp(x)
        t = NavState(T[:3, :3], s.v, T[:3, 3], s.bg, s.ba)
        return error_between(t, s)[pose_cols]

    inv = np.linalg.inv(E[:, pose_cols])
    np.testing.assert_allclose(inv, numeric_jacobian(back, np.zeros(6)), atol=1e-8)
    assert np.all(E[:, VEL] == 0) and np.all(E[:, BG] == 0) and np.all(E[:, BA] == 0)


def _monte_carlo(P0, filter_noise=None, runs=200, seed=8):
    """ANEES (and its two-sided 95 % bounds) of ``runs`` seeded noise-only drives: one second at
    200 Hz, ten times EuRoC's densities (so the errors stand above rounding), two world
    landmarks in the group; the estimate integrates the noisy samples from a state drawn from
    ``P0`` and propagates ``P0`` with ``filter_noise`` (default: the true noise)."""
    rng = np.random.default_rng(seed)
    noise = ImuNoise(2e-3, 2e-4, 2e-2, 3e-3)
    filter_noise = filter_noise or noise
    rate, n = 200.0, 200
    t = np.arange(n) / rate
    gyro = 0.5 * np.sin(np.outer(t, [1.0, 2.0, 3.0]))
    accel = np.array([0.0, 0.0, 9.81]) + np.sin(np.outer(t, [2.0, 1.5, 1.0]))
    truth0 = NavState(so3_exp([0.1, -0.2, 0.3]), np.array([0.5, 0.0, 0.2]), np.zeros(3),
                      np.array([0.003, -0.002, 0.001]), np.array([0.02, -0.01, 0.03]))
    lm0 = np.array([[3.0, 1.0, 1.0], [-2.0, 4.0, 0.5]])
    L0 = np.linalg.cholesky(P0)
    dim = N_CORE + 6
    nees = np.empty(runs)
    for r in range(runs):
        # the truth: samples of the true motion (with its bias walk); the estimate integrates
        # them with white noise added, from a state drawn from its prior
        xi0 = L0 @ rng.normal(size=dim)
        est, est_lm = _full_retract(truth0, lm0, -xi0)  # exp(-xi) = exp(xi)^-1: truth = exp(xi0) est
        walk = np.sqrt(1 / rate) * rng.normal(size=(2, n, 3))
        bg_walk = np.cumsum(noise.gyro_random_walk * walk[0], axis=0)
        ba_walk = np.cumsum(noise.accel_random_walk * walk[1], axis=0)
        true_imu = ImuSamples(t, accel + truth0.ba + ba_walk, gyro + truth0.bg + bg_walk)
        meas = ImuSamples(t, true_imu.accel + noise.accel_noise_density * np.sqrt(rate)
                          * rng.normal(size=(n, 3)),
                          true_imu.gyro + noise.gyro_noise_density * np.sqrt(rate)
                          * rng.normal(size=(n, 3)))
        # truth integrated noise-free with the known (walking) bias subtracted
        tr = truth0
        for j in range(n):
            bias = NavState(tr.R, tr.v, tr.p, truth0.bg + bg_walk[j], truth0.ba + ba_walk[j])
            tr = step(bias, true_imu.gyro[j], true_imu.accel[j], 1 / rate, G_WORLD)
        tr = NavState(tr.R, tr.v, tr.p, truth0.bg + bg_walk[-1], truth0.ba + ba_walk[-1])
        out, Phi, Qc = propagate(est, meas, 0.0, n / rate, G_WORLD, filter_noise)
        P1 = frame_covariance(P0, Phi, Qc, est_lm, np.array([True, True]))
        e = _full_error(tr, lm0, out, est_lm)
        nees[r] = e @ np.linalg.solve(P1, e)
    lo, hi = chi2.ppf([0.025, 0.975], dim * runs) / runs
    return nees.mean(), lo, hi


def test_noise_only_drive_against_monte_carlo():
    """The propagated covariance of a noise-only drive (initial error, white noise and bias
    walk) against 200 seeded runs: the 21-dimensional NEES at the end (core and two group
    landmarks) inside the two-sided 95 % chi-square bounds of the ANEES."""
    P0 = np.diag([1e-4] * 3 + [1e-3] * 3 + [1e-3] * 3 + [1e-5] * 3 + [1e-3] * 3 + [1e-2] * 6)
    value, lo, hi = _monte_carlo(P0)
    assert lo < value < hi, (value, lo, hi)


def test_half_the_accelerometer_noise_fails_the_monte_carlo():
    """The deliberate break of issue 38: a filter that assumes half the accelerometer's noise
    density is overconfident, and the same Monte Carlo (velocity and position known at the
    start, so the accelerometer noise is what they accumulate) says so, while the honest
    filter passes it."""
    P0 = np.diag([1e-6] * 3 + [1e-8] * 6 + [1e-8] * 6 + [1e-2] * 6)
    honest, lo, hi = _monte_carlo(P0, runs=100, seed=9)
    assert lo < honest < hi, (honest, lo, hi)
    half = ImuNoise(2e-3, 2e-4, 1e-2, 3e-3)
    broken, lo, hi = _monte_carlo(P0, half, runs=100, seed=9)
    assert broken > hi, (broken, lo, hi)


def _sine_imu(rate):
    n = int(rate)
    t = np.arange(n) / rate
    return ImuSamples(t, np.array([0.0, 0.0, 9.81]) + np.sin(np.outer(t, [2.0, 1.5, 1.0])),
                      0.5 * np.sin(np.outer(t, [1.0, 2.0, 3.0])))


_S0 = NavState(so3_exp([0.1, -0.2, 0.3]), np.array([0.5, 0.0, 0.2]), np.array([1.0, 2, 3]),
               np.array([0.003, -0.002, 0.001]), np.array([0.02, -0.01, 0.03]))


def test_mean_against_gtsam_preintegration():
    """The mean over a second of 200 Hz samples against gtsam's manifold preintegration
    (``PreintegratedImuMeasurementsManifold``, the same held-sample scheme): equal to rounding."""
    gtsam = pytest.importorskip("gtsam")
    imu = _sine_imu(200.0)
    out = propagate(_S0, imu, 0.0, 1.0, G_WORLD, ImuNoise(2e-3, 2e-4, 2e-2, 3e-3))[0]
    params = gtsam.PreintegrationParams(G_WORLD)
    params.setAccelerometerCovariance(np.eye(3) * 1e-4)
    params.setGyroscopeCovariance(np.eye(3) * 1e-6)
    params.setIntegrationCovariance(np.eye(3) * 1e-8)
    bias = gtsam.imuBias.ConstantBias(_S0.ba, _S0.bg)
    pim = gtsam.PreintegratedImuMeasurementsManifold(params, bias)
    for j in range(imu.time.size):
        pim.integrateMeasurement(imu.accel[j], imu.gyro[j], 1 / 200.0)
    pred = pim.predict(gtsam.NavState(gtsam.Rot3(_S0.R), gtsam.Point3(*_S0.p), _S0.v), bias)
    np.testing.assert_allclose(out.R, pred.attitude().matrix(), atol=1e-9)
    np.testing.assert_allclose(out.v, pred.velocity(), atol=1e-9)
    np.testing.assert_allclose(out.p, pred.position(), atol=1e-9)


def test_mean_against_gtsam_navstate_imu_ekf():
    """gtsam.NavStateImuEKF integrates each held sample in closed form with the specific force
    held in the body frame (ours holds it in the world frame over the sample, as preintegration
    does): the rotations agree to rounding, and velocity and position differ at first order in
    dt, so doubling the rate halves the difference (both converge to the same motion)."""
    gtsam = pytest.importorskip("gtsam")
    gaps = []
    for rate in (200.0, 400.0):
        imu = _sine_imu(rate)
        out = propagate(_S0, imu, 0.0, 1.0, G_WORLD, ImuNoise(2e-3, 2e-4, 2e-2, 3e-3))[0]
        nav0 = gtsam.NavState(gtsam.Rot3(_S0.R), gtsam.Point3(*_S0.p), _S0.v)
        ekf = gtsam.NavStateImuEKF(nav0, np.eye(9) * 1e-6, gtsam.PreintegrationParams(G_WORLD))
        for j in range(imu.time.size):
            ekf.predict(imu.gyro[j] - _S0.bg, imu.accel[j] - _S0.ba, 1 / rate)
        st = ekf.state()
        np.testing.assert_allclose(out.R, st.attitude().matrix(), atol=1e-12)
        gaps.append([np.linalg.norm(out.v - st.velocity()), np.linalg.norm(out.p - st.position())])
    gaps = np.array(gaps)
    assert np.all(gaps[0] < [0.02, 0.01])
    np.testing.assert_allclose(gaps[0] / gaps[1], 2.0, rtol=0.05)
