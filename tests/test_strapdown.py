"""Strapdown integration (ekf.strapdown), rest initialisation (ekf.imu_init) and raw-IMU dead
reckoning (ekf.inertial_dead_reckoning): Jacobians, noise, Monte Carlo consistency."""

import numpy as np
import pytest
from scipy.stats import chi2

from tests.numdiff import numeric_jacobian
from vislam.ekf.errors import EstimationError, InputError
from vislam.ekf.filter import ImuSamples
from vislam.ekf.geometry import se3_inv, se3_log, so3_exp, so3_log
from vislam.ekf.imu_init import InitialState, Rest, RestConfig, detect_rest, rest_initial_state
from vislam.ekf.inertial import ImuNoise
from vislam.ekf.inertial_dead_reckoning import run_inertial_dead_reckoning, strapdown_frames
from vislam.ekf.strapdown import (BA, BG, N_ERROR, ROT, NavState,
                                  exp_and_right_jacobian, integrate, step, step_jacobian,
                                  step_noise)
from vislam.eval.imu_sim import simulate_imu
from vislam.eval.imu_sim_config import ImuSimConfig

G_WORLD = np.array([0.0, 0.0, -9.81])


def _state(rng) -> NavState:
    return NavState(so3_exp(rng.normal(size=3)), rng.normal(size=3), rng.normal(size=3),
                    0.1 * rng.normal(size=3), 0.3 * rng.normal(size=3))


def _local(ref: NavState, s: NavState) -> np.ndarray:
    """Error-state coordinates of ``s`` around ``ref`` (inverse of NavState.retract)."""
    return np.concatenate([so3_log(ref.R.T @ s.R), s.v - ref.v, s.p - ref.p, s.bg - ref.bg,
                           s.ba - ref.ba])


def test_retract_and_local_are_inverse():
    rng = np.random.default_rng(1)
    s, dx = _state(rng), 0.1 * rng.normal(size=N_ERROR)
    np.testing.assert_allclose(_local(s, s.retract(dx)), dx, atol=1e-12)


def test_right_jacobian():
    rng = np.random.default_rng(2)
    for scale in (1e-9, 1e-3, 0.5, 2.0):
        phi = scale * rng.normal(size=3)
        R, Jr = exp_and_right_jacobian(phi)
        np.testing.assert_allclose(R, so3_exp(phi), atol=1e-14)
        num = numeric_jacobian(lambda d: so3_log(R.T @ so3_exp(phi + d)), np.zeros(3))
        np.testing.assert_allclose(Jr, num, atol=1e-8)


@pytest.mark.parametrize("dt", [0.005, 0.05, 0.4])
def test_step_jacobian_against_finite_differences(dt):
    rng = np.random.default_rng(3)
    for _ in range(5):
        s = _state(rng)
        gyro, accel = rng.normal(size=3), rng.normal(size=3) + [0, 0, 9.81]
        ref = step(s, gyro, accel, dt, G_WORLD)
        F = step_jacobian(s, gyro, accel, dt)
        def moved(dx, s=s, gyro=gyro, accel=accel, ref=ref):
            return _local(ref, step(s.retract(dx), gyro, accel, dt, G_WORLD))

        num = numeric_jacobian(moved, np.zeros(N_ERROR))
        np.testing.assert_allclose(F, num, atol=1e-8)


def test_step_noise_is_the_sample_noise_through_the_step():
    """Q's white part equals G diag(sg^2/dt, sa^2/dt) G^T with G the finite-difference
    Jacobian of one step in the gyro and accelerometer samples; the bias block is the walk."""
    rng = np.random.default_rng(4)
    noise = ImuNoise(0.02, 0.003, 0.2, 0.04)
    dt = 0.01
    s = _state(rng)
    gyro, accel = rng.normal(size=3), rng.normal(size=3)
    ref = step(s, gyro, accel, dt, G_WORLD)
    G = numeric_jacobian(lambda m: _local(ref, step(s, m[:3], m[3:], dt, G_WORLD)),
                         np.concatenate([gyro, accel]))
    S = np.diag([noise.gyro_noise_density ** 2 / dt] * 3
                + [noise.accel_noise_density ** 2 / dt] * 3)
    Jr = exp_and_right_jacobian((gyro - s.bg) * dt)[1]
    Q = step_noise(Jr, dt, noise)
    expected = G @ S @ G.T
    expected[BG, BG] = noise.gyro_random_walk ** 2 * dt * np.eye(3)
    expected[BA, BA] = noise.accel_random_walk ** 2 * dt * np.eye(3)
    np.testing.assert_allclose(Q, expected, atol=1e-10, rtol=1e-6)


def test_integrate_is_steps_clipped_to_the_interval():
    rng = np.random.default_rng(5)
    t = np.array([0.0, 0.01, 0.02, 0.03])
    imu = ImuSamples(t, rng.normal(size=(4, 3)) + [0, 0, 9.81], rng.normal(size=(4, 3)))
    s = _state(rng)
    noise = ImuNoise(0.01, 0.001, 0.1, 0.01)
    out, P = integrate(s, np.zeros((15, 15)), imu, 0.005, 0.025, G_WORLD, noise)
    ref = s
    Pref = np.zeros((15, 15))
    for j, (a, b) in enumerate([(0.005, 0.01), (0.01, 0.02), (0.02, 0.025)]):
        F = step_jacobian(ref, imu.gyro[j], imu.accel[j], b - a)
        Jr = exp_and_right_jacobian((imu.gyro[j] - ref.bg) * (b - a))[1]
        Pref = F @ Pref @ F.T + step_noise(Jr, b - a, noise)
        ref = step(ref, imu.gyro[j], imu.accel[j], b - a, G_WORLD)
    np.testing.assert_allclose(out.R, ref.R, atol=1e-14)
    np.testing.assert_allclose(out.p, ref.p, atol=1e-14)
    np.testing.assert_allclose(P, Pref, atol=1e-16)
    with pytest.raises(EstimationError, match="no IMU sample at or before"):
        integrate(s, None, imu, -0.1, 0.01, G_WORLD)


@pytest.mark.slow
def test_monte_carlo_matches_the_propagated_covariance():
    """200 noisy runs of one scene from the true initial state against the covariance that
    dead reckoning propagates along the noise-free run: the pose NEES (Estimate convention) and
    the 15-state NEES at three frames inside the two-sided 95 % bounds."""
    runs = 200
    noise = ImuNoise(2e-3, 2e-4, 2e-2, 3e-3)  # ten times EuRoC's densities: errors above rounding
    base = dict(n_frames=41, rest_s=0.5, scene_seed=11, n_landmarks=1, noise=noise,
                gyro_bias_sigma=0.0, accel_bias_sigma=0.0)
    frames = (10, 25, 40)
    clean, ct = simulate_imu(ImuSimConfig(noise_free=True, **base))
    init = ct.initial_state(0.0)
    reference = strapdown_frames(clean, init)
    pose_cov = reference.pose_cov()
    g = np.array([0.0, 0.0, -clean.calibration.gravity])
    nees_pose = np.zeros((runs, len(frames)))
    nees_full = np.zeros((runs, len(frames)))
    for r in range(runs):
        drive, truth = simulate_imu(ImuSimConfig(seed=100 + r, **base))
        s, i = init.state, 0
        for k in range(1, frames[-1] + 1):
            s, _ = integrate(s, None, drive.imu_between(k), drive.timestamps[k - 1],
                             drive.timestamps[k], g)
            if k == frames[i]:
                xi = se3_log(se3_inv(s.pose) @ truth.frame_poses[k])
                nees_pose[r, i] = xi @ np.linalg.solve(pose_cov[k], xi)
                dx = _local(s, truth.frame_state(k))
                nees_full[r, i] = dx @ np.linalg.solve(reference.cov[k], dx)
                i += 1
    for nees, dof in ((nees_pose, 6), (nees_full, N_ERROR)):
        lo, hi = chi2.ppf([0.025, 0.975], dof * runs) / runs
        anees = nees.mean(axis=0)
        assert np.all((anees > lo) & (anees < hi)), (dof, anees, lo, hi)


def _rest_samples(rng, R, bg, ba, n, rate, noise, g=9.81):
    f = R.T @ np.array([0.0, 0.0, g]) + ba
    s_a = noise.accel_noise_density * np.sqrt(rate)
    s_g = noise.gyro_noise_density * np.sqrt(rate)
    t = np.arange(n) / rate
    return ImuSamples(t, f + s_a * rng.normal(size=(n, 3)), bg + s_g * rng.normal(size=(n, 3)))


def test_rest_initial_state_monte_carlo():
    """Tilt (two directions), gyro bias and accelerometer bias errors of the rest's initial
    state against its covariance: 300 rests with random tilt and biases."""
    rng = np.random.default_rng(6)
    noise = ImuNoise(2e-3, 0.0, 2e-2, 0.0)
    cfg = RestConfig(accel_bias_sigma=0.08)
    runs, nees = 300, []
    for _ in range(runs):
        R = so3_exp(np.r_[0.3 * rng.normal(size=2), rng.uniform(-3, 3)])
        bg, ba = 0.01 * rng.normal(size=3), cfg.accel_bias_sigma * rng.normal(size=3)
        imu = _rest_samples(rng, R, bg, ba, 400, 200.0, noise)
        init = rest_initial_state(imu, 0.0, 9.81, noise, cfg, Rest(0.0, imu.time[-1]))
        s, P = init.state, init.cov
        u0 = s.R.T @ np.array([0.0, 0.0, 1.0])
        ut = R.T @ np.array([0.0, 0.0, 1.0])
        dth = np.cross(ut - u0, u0)  # the tilt part of R_true = R_est Exp(dth)
        e1 = np.cross(u0, [1.0, 0.0, 0.0])
        e1 /= np.linalg.norm(e1)
        B = np.stack([e1, np.cross(u0, e1)])  # (2, 3) basis of the tilt
        J = np.zeros((8, N_ERROR))
        J[:2, ROT] = B
        J[2:5, BG] = np.eye(3)
        J[5:, BA] = np.eye(3)
        err = np.concatenate([B @ dth, bg - s.bg, ba - s.ba])
        nees.append(err @ np.linalg.solve(J @ P @ J.T, err))
    lo, hi = chi2.ppf([0.025, 0.975], 8 * runs) / runs
    assert lo < np.mean(nees) < hi


def test_rest_detection_and_its_faults():
    drive, truth = simulate_imu(ImuSimConfig(n_frames=101, rest_s=2.0, n_landmarks=10))
    rest = detect_rest(drive.imu)
    assert rest.start == 0.0 and 1.4 <= rest.end <= 2.0
    moving, _ = simulate_imu(ImuSimConfig(n_frames=101, rest_s=0.0, n_landmarks=10))
    with pytest.raises(EstimationError, match="cannot be initialised from a rest"):
        run_inertial_dead_reckoning(moving)
    with pytest.raises(InputError, match="window_s"):
        RestConfig(window_s=-1.0)


@pytest.mark.parametrize("camera", ["mono", "stereo"])
def test_dead_reckoning_estimate(camera):
    drive, truth = simulate_imu(ImuSimConfig(n_frames=201, camera=camera))
    est = run_inertial_dead_reckoning(drive)
    assert est.poses.shape == (201, 4, 4) and est.pose_cov.shape == (201, 6, 6)
    assert est.landmarks.shape == (drive.n_tracks, 3)
    assert est.info["initialisation"] == "rest" and est.info["rest_s"][1] <= 2.0
    np.testing.assert_allclose(est.pose_cov, np.swapaxes(est.pose_cov, 1, 2), atol=1e-12)
    assert np.all(np.linalg.eigvalsh(est.pose_cov[1:]) > 0)
    # the world is gravity-aligned: the IMU's up at frame 0 agrees with the truth's within 3 sigma
    up_est = est.poses[0, :3, :3].T @ [0, 0, 1]
    up_true = truth.frame_poses[0, :3, :3].T @ [0, 0, 1]
    tilt = np.linalg.norm(np.cross(up_est, up_true))
    assert tilt < 3 * np.sqrt(np.trace(est.pose_cov[0, 3:, 3:]))
    np.testing.assert_array_equal(est.poses[0, :3, 3], 0.0)
    # given the true initial state, the noise-free drive's poses are the truth's
    clean, ct = simulate_imu(ImuSimConfig(n_frames=201, camera=camera, noise_free=True))
    T0 = ct.frame_poses[0]
    init = InitialState(0.0, NavState(T0[:3, :3], ct.frame_velocity[0], T0[:3, 3], np.zeros(3),
                                      np.zeros(3)), np.zeros((15, 15)))
    est2 = run_inertial_dead_reckoning(clean, init)
    np.testing.assert_allclose(est2.poses, ct.frame_poses, atol=1e-5)
    assert est2.info["initialisation"] == "given"


def test_given_state_before_frame_0_is_carried_to_it():
    """Frames between IMU samples, the first 3.0025 s after the given state: the state is
    carried to frame 0 and then from frame to frame, each sample held over its part."""
    from dataclasses import replace

    drive, truth = simulate_imu(ImuSimConfig(n_frames=161, noise_free=True, n_landmarks=10))
    times = drive.timestamps[60:-1] + 0.0025
    later = replace(drive, timestamps=times)
    T0 = truth.imu_poses[0]
    init = InitialState(0.0, NavState(T0[:3, :3], np.zeros(3), T0[:3, 3], np.zeros(3),
                                      np.zeros(3)), np.zeros((15, 15)))
    est = run_inertial_dead_reckoning(later, init)
    assert est.info["initial_time_s"] == 0.0 and est.n_frames == times.size
    g = np.array([0.0, 0.0, -drive.calibration.gravity])
    s, t_prev = init.state, 0.0
    for k, t in enumerate(times):
        s, _ = integrate(s, None, drive.imu, t_prev, t, g)
        t_prev = t
        np.testing.assert_allclose(est.poses[k], s.pose, atol=1e-12)
    # a sample's interval split by a frame is not exact for the held scheme (the second part
    # rotates the specific force by the rotation at the split): millimetres over 5 s here
    np.testing.assert_allclose(est.poses, truth.trajectory(times).poses, atol=5e-3)
    assert np.all(np.linalg.eigvalsh(est.pose_cov) > 0)
    with pytest.raises(EstimationError, match="after frame 0"):
        run_inertial_dead_reckoning(later, replace(init, time=5.0))
