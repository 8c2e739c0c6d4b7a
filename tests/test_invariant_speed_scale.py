"""ekf-invariant with a speed-scale state (``FilterConfig.speed_scale``, issue 34): the error
dynamics against finite differences of the exact model ``[(1 + s) v; w - b]``, the covariance
step of the filter, kept landmarks against their dense form, and on small simulated drives whose
measured speed is 1 % off: the scale found within its sigma, a better aligned ATE and pose NEES
than without the state, with Euclidean and inverse-depth landmarks."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from vislam.ekf import invariant as inv
from vislam.ekf.config import FilterConfig
from vislam.ekf.driver import run_filter
from vislam.ekf.geometry import se3_exp
from vislam.eval.consistency import pose_nees
from vislam.eval.metrics import ate_rmse
from vislam.eval.sim_config import SimConfig
from vislam.eval.simulate import simulate
from tests.numdiff import numeric_jacobian
from tests.test_ekf_estimators import assert_same_as_dense
from tests.test_ekf_invariant import error_dynamics_scene, random_pose

#: The measured linear velocities are (1 + SPEED_ERROR) times the true ones.
SPEED_ERROR = 0.01
#: The scale the filter should find: v_true = (1 + s) v_measured.
TRUE_SCALE = 1.0 / (1.0 + SPEED_ERROR) - 1.0
N_FRAMES = 150
SIGMAS = dict(velocity_sigma=0.05, gyro_sigma=0.005)
CONFIG = FilterConfig(clean_tracks=False, velocity_pairing="mean", speed_scale_sigma=0.02,
                      **SIGMAS)


# --------------------------------------------------------------------------------------
# Group math and Jacobians
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("use_bias", [False, True])
def test_retract_and_error_between_carry_the_scale(use_bias):
    rng = np.random.default_rng(1)
    T = random_pose(rng)
    lm = rng.normal(scale=10, size=(4, 3))
    b = rng.normal(size=3) if use_bias else None
    s = 0.003
    off = inv.landmark_offset(use_bias, True)
    assert off == (10 if use_bias else 7) and inv.scale_index(use_bias) == off - 1
    d = rng.normal(scale=0.3, size=off + 12)
    T2, lm2, b2, s2 = inv.retract(T, lm, d, b, s)
    assert np.allclose(T2, se3_exp(d[:6]) @ T)
    assert s2 == s + d[off - 1]
    # The landmarks move exactly as without the scale (its row only moves s).
    T3, lm3, _, s3 = inv.retract(T, lm, np.delete(d, off - 1), b)
    assert s3 is None and np.array_equal(T2, T3) and np.array_equal(lm2, lm3)
    np.testing.assert_allclose(inv.error_between(T2, lm2, T, lm, b2, b, s2, s), d, atol=1e-10)


def _exact_step(T, lm, b, s, u, tau):
    """The exact one-step error ``xi' (xi, n)`` of the right-invariant filter whose true twist
    is ``[(1 + s) v; w - b] + n`` (``u = [v; w]`` the measurement)."""
    def ue(bt, st):
        out = u.copy()
        out[:3] *= 1.0 + st
        if bt is not None:
            out[3:] -= bt
        return out

    def step(xi, noise):
        Tt, lt, bt, st = inv.retract(T, lm, xi, b, s)
        return inv.error_between(Tt @ se3_exp(tau * (ue(bt, st) + noise)), lt,
                                 T @ se3_exp(tau * ue(b, s)), lm, bt, b, st, s)

    return step, tau * ue(b, s)


@pytest.mark.parametrize("use_bias", [False, True])
def test_error_dynamics_of_the_scale_against_the_exact_model(use_bias):
    """``xi' = (I + F S_e) xi + tau B n`` with ``F = twist_error_coupling``: the scale's column
    ``tau B_p v`` (and the bias's ``-tau B_R``) against finite differences."""
    T, lm, tau, u, b = error_dynamics_scene(use_bias)
    s = 0.004
    off = inv.landmark_offset(use_bias, True)
    n_x = off + 9
    step, twist = _exact_step(T, lm, b, s, u, tau)
    B = inv.noise_jacobian(T, lm, twist, use_bias, True)
    assert B.shape == (n_x, 6) and not B[6:off].any()
    F = inv.twist_error_coupling(B, tau, u[:3], use_bias, True)
    assert F.shape == (n_x, off - 6)
    expected = np.eye(n_x)
    expected[:, 6:off] += F
    Fx = numeric_jacobian(lambda xi: step(xi, np.zeros(6)), np.zeros(n_x))
    np.testing.assert_allclose(Fx, expected, atol=1e-6)
    np.testing.assert_allclose(F[:, -1], tau * B[:, :3] @ u[:3])  # the scale's column
    Fn = numeric_jacobian(lambda n: step(np.zeros(n_x), n), np.zeros(6))
    np.testing.assert_allclose(Fn, tau * B, atol=1e-6)


@pytest.mark.parametrize("use_bias", [False, True])
def test_propagation_covariance_is_phi_p_phi_t_plus_noise(use_bias):
    """The filter's covariance step (structured, in place) equals the dense
    ``Phi P Phi^T + tau^2 B W B^T + walks`` with ``Phi`` from finite differences of the exact
    model; the mean moves with the corrected twist."""
    rng = np.random.default_rng(7)
    T = random_pose(rng)
    lm = rng.normal(scale=10, size=(3, 3))
    tau, u = 0.1, np.array([8.0, 0.3, -0.1, 0.05, -0.02, 0.2])
    b = rng.normal(scale=0.01, size=3) if use_bias else None
    s = -0.006
    off = inv.landmark_offset(use_bias, True)
    n_x = off + 9
    A = rng.normal(size=(n_x, n_x))
    P = A @ A.T * 1e-3 + 1e-4 * np.eye(n_x)
    cfg = CONFIG.replace(gyro_bias=use_bias, speed_scale=True, speed_scale_walk=0.003,
                         gyro_bias_walk=1e-3)
    W_chol = np.linalg.cholesky(cfg.velocity_cov)
    st = inv.InvariantState(T=T.copy(), landmarks=lm.copy(), tracks=np.arange(3), P=P.copy(),
                            bias=None if b is None else b.copy(), scale=s)
    assert inv._propagate(st, u, tau, W_chol, cfg, off)
    step, twist = _exact_step(T, lm, b, s, u, tau)
    Phi = numeric_jacobian(lambda xi: step(xi, np.zeros(6)), np.zeros(n_x))
    Bn = tau * inv.noise_jacobian(T, lm, twist, use_bias, True) @ W_chol
    Q = Bn @ Bn.T
    walk = np.zeros(n_x)
    if use_bias:
        walk[inv.B_IDX] = cfg.gyro_bias_walk**2 * tau
    walk[inv.scale_index(use_bias)] = cfg.speed_scale_walk**2 * tau
    np.testing.assert_allclose(st.P, Phi @ P @ Phi.T + Q + np.diag(walk), atol=1e-8)
    np.testing.assert_allclose(st.T, T @ se3_exp(twist), atol=1e-12)
    assert st.scale == s


# --------------------------------------------------------------------------------------
# Simulated drives whose measured speed is 1 % too high
# --------------------------------------------------------------------------------------
def scaled_drive(seed: int, n_frames: int = N_FRAMES, landmark_density: float = 2.7):
    """A simulated drive (true noise model :data:`SIGMAS`) with its measured linear velocities
    times ``1 + SPEED_ERROR``; the truth unchanged."""
    r = simulate(SimConfig(seed=seed, n_frames=n_frames, landmark_density=landmark_density,
                           **SIGMAS))
    seq = r.sequence
    return replace(r, sequence=replace(seq, linear_velocity=seq.linear_velocity * (1.0 + SPEED_ERROR)))


def _scores(est, result):
    n = np.nanmean(pose_nees(est, np.arange(est.n_frames), result.poses))
    return ate_rmse(est.poses, result.poses, align="se3"), float(n)


@pytest.fixture(scope="module")
def drives():
    return [scaled_drive(seed) for seed in range(4)]


def test_scale_state_finds_the_speed_error_and_beats_no_state(drives):
    """On each drive: the scale within 3 sigma of the truth, the sigma below the prior's;
    aligned ATE and pose NEES better than without the state (there the 1 % error, 0.1 m/s,
    is twice the velocity sigma: NEES in the hundreds). Over the drives the normalised scale
    error's mean square is near 1 (measured: aligned ATE 0.25-0.35 -> 0.05-0.09 m, NEES
    110-210 -> 3-7, normalised scale errors -1.3 to 0.1)."""
    z = []
    for r in drives:
        off = run_filter(inv.InvariantEKF(), r.sequence, CONFIG)
        on = run_filter(inv.InvariantEKF(), r.sequence, CONFIG.replace(speed_scale=True))
        assert "speed_scale" not in off.info
        s, sd = on.info["speed_scale"], on.info["speed_scale_sigma_final"]
        assert 0 < sd < 0.5 * CONFIG.speed_scale_sigma
        z.append((s - TRUE_SCALE) / sd)
        (ate_off, nees_off), (ate_on, nees_on) = _scores(off, r), _scores(on, r)
        assert ate_on < 0.6 * ate_off
        assert nees_on < 0.2 * nees_off and nees_on < 12.0
    z = np.array(z)
    assert np.abs(z).max() < 3.0, z
    assert np.mean(z**2) < 4.0, z


def test_sparse_vision_drives_gain_too():
    """7-10 observations a frame, where vision cannot carry the motion: still the scale within
    3 sigma and a better ATE and NEES than without it (measured: aligned ATE 0.31-0.37 ->
    0.16-0.24 m, NEES 135-265 -> 3-6, normalised scale errors -1.4 to 0.4)."""
    for seed in range(3):
        r = scaled_drive(seed, landmark_density=0.3)
        off = run_filter(inv.InvariantEKF(), r.sequence, CONFIG)
        on = run_filter(inv.InvariantEKF(), r.sequence, CONFIG.replace(speed_scale=True))
        s, sd = on.info["speed_scale"], on.info["speed_scale_sigma_final"]
        assert abs(s - TRUE_SCALE) < 3 * sd
        (ate_off, nees_off), (ate_on, nees_on) = _scores(off, r), _scores(on, r)
        assert ate_on < 0.9 * ate_off and nees_on < 12.0 < nees_off


def test_speed_scale_off_reports_and_estimates_as_before(drives):
    """``speed_scale=False`` leaves the state at 6 (+3 with a bias) and the info without a
    scale; on, the error state says so."""
    r = drives[0]
    flt = inv.InvariantEKF()
    run_filter(flt, r.sequence, CONFIG.replace(gyro_bias=True))
    assert flt.off == 9 and flt.state.scale is None and "speed_scale" not in flt.info()
    flt = inv.InvariantEKF()
    run_filter(flt, r.sequence, CONFIG.replace(gyro_bias=True, speed_scale=True))
    assert flt.off == 10 and isinstance(flt.info()["speed_scale"], float)
    assert "(xi_s)" in flt.info()["error_state"]


@pytest.mark.parametrize("gyro_bias", [False, True])
def test_inverse_depth_landmarks_with_a_scale_state(gyro_bias):
    """Inverse-depth landmarks (with a gyro bias too): the scale found, a better ATE."""
    r = scaled_drive(11, n_frames=100)
    cfg = CONFIG.replace(landmark_parameterisation="inverse-depth", gyro_bias=gyro_bias)
    off = run_filter(inv.InvariantEKF(), r.sequence, cfg)
    on = run_filter(inv.InvariantEKF(), r.sequence, cfg.replace(speed_scale=True))
    s, sd = on.info["speed_scale"], on.info["speed_scale_sigma_final"]
    assert abs(s - TRUE_SCALE) < 3 * sd and sd < 0.5 * cfg.speed_scale_sigma
    assert on.info["inverse_depth_converted"] > 0
    assert _scores(on, r)[0] < 0.6 * _scores(off, r)[0]


@pytest.mark.parametrize("param, gyro_bias", [("euclidean", False), ("inverse-depth", True)])
def test_keep_landmarks_with_a_scale_state_equals_the_dense_form(param, gyro_bias):
    """``keep_landmarks`` with a speed scale (the retired landmarks take its coupling, RI-1)
    gives the numbers of the dense covariance (``textbook``) to 1e-9, and the scale too."""
    r = scaled_drive(5, n_frames=60)
    cfg = CONFIG.replace(keep_landmarks=True, speed_scale=True, landmark_parameterisation=param,
                         gyro_bias=gyro_bias)
    fast = run_filter(inv.InvariantEKF(), r.sequence, cfg)
    dense = run_filter(inv.InvariantEKF(textbook=True), r.sequence, cfg)
    assert_same_as_dense(fast, dense, 100)
    for key in ("speed_scale", "speed_scale_sigma_final"):
        assert abs(fast.info[key] - dense.info[key]) < 1e-12
    assert abs(fast.info["speed_scale"] - TRUE_SCALE) < 3 * fast.info["speed_scale_sigma_final"]
