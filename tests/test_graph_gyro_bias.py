"""The smoother's gyro-bias motion factor: Jacobians against finite differences, agreement with
the exact biased motion, and recovery of a constant gyro bias on simulated drives."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from vislam.ekf.config import FilterConfig
from vislam.ekf.geometry import se3_exp
from vislam.eval.metrics import ate_rmse
from vislam.eval.simulate import SimConfig, simulate
from vislam.graph.gyro_bias import (BIAS_KEY, biased_motion_error, biased_motion_factor, bias_jacobians,
                             corrected_delta)
from vislam.graph.pose_conversions import X, to_pose3
from vislam.graph.settings import SmootherSettings
from vislam.graph.smoother import run_smoother
from tests.numdiff import numeric_jacobian

CONFIG = FilterConfig(clean_tracks=False)


def _random_case(seed: int):
    rng = np.random.default_rng(seed)
    twist = np.concatenate([rng.normal(0, 5, 3), rng.normal(0, 0.5, 3)])
    tau = 0.1
    delta = se3_exp(tau * twist)
    D = bias_jacobians(twist[None], np.array([tau]))[0]
    x0 = to_pose3(se3_exp(rng.normal(0, 1, 6)))
    x1 = x0.compose(to_pose3(delta)).compose(gtsam.Pose3.Expmap(rng.normal(0, 0.05, 6)))
    bias = rng.normal(0, 0.02, 3)
    return twist, tau, delta, D, x0, x1, bias


@pytest.mark.parametrize("seed", range(4))
def test_jacobians_match_finite_differences(seed):
    _, _, delta, D, x0, x1, bias = _random_case(seed)
    measured = to_pose3(delta)
    H: list = []
    biased_motion_error(measured, D, x0, x1, bias, H)
    num0 = numeric_jacobian(lambda d: biased_motion_error(measured, D, x0.retract(d), x1, bias), np.zeros(6))
    num1 = numeric_jacobian(lambda d: biased_motion_error(measured, D, x0, x1.retract(d), bias), np.zeros(6))
    numb = numeric_jacobian(lambda b: biased_motion_error(measured, D, x0, x1, b), bias)
    np.testing.assert_allclose(H[0], num0, atol=1e-7)
    np.testing.assert_allclose(H[1], num1, atol=1e-7)
    np.testing.assert_allclose(H[2], numb, atol=1e-7)


def test_custom_factor_linearises_like_its_jacobians():
    _, _, delta, D, x0, x1, bias = _random_case(7)
    noise = gtsam.noiseModel.Isotropic.Sigma(6, 1.0)
    factor = biased_motion_factor(X(0), X(1), BIAS_KEY, delta, D, noise)
    values = gtsam.Values()
    values.insert(X(0), x0)
    values.insert(X(1), x1)
    values.insert(BIAS_KEY, bias)
    H: list = []
    e = biased_motion_error(to_pose3(delta), D, x0, x1, bias, H)
    np.testing.assert_allclose(factor.unwhitenedError(values), e, atol=1e-12)
    A, b = factor.linearize(values).jacobian()
    np.testing.assert_allclose(A, np.hstack(H), atol=1e-12)
    np.testing.assert_allclose(b, -e, atol=1e-12)


def test_bias_correction_matches_the_exact_biased_motion():
    """Delta Exp(-D b) ~= exp(tau (u - [0; b])) to second order in the bias."""
    twist, tau, delta, D, *_ = _random_case(3)
    bias = np.array([0.01, -0.008, 0.005])
    exact = se3_exp(tau * (twist - np.concatenate([np.zeros(3), bias])))
    approx = corrected_delta(to_pose3(delta), D, bias).matrix()
    err = np.abs(np.asarray(gtsam.Pose3.Logmap(to_pose3(exact).between(to_pose3(approx)))))
    assert err.max() < 1e-6


def test_zero_bias_is_the_plain_between_factor():
    _, _, delta, D, x0, x1, _ = _random_case(9)
    plain = gtsam.BetweenFactorPose3(X(0), X(1), to_pose3(delta), gtsam.noiseModel.Unit.Create(6))
    values = gtsam.Values()
    values.insert(X(0), x0)
    values.insert(X(1), x1)
    np.testing.assert_allclose(biased_motion_error(to_pose3(delta), D, x0, x1, np.zeros(3)),
                               plain.unwhitenedError(values), atol=1e-12)


@pytest.mark.slow
def test_smoother_recovers_a_constant_gyro_bias():
    """The bias is recovered to within the mean of the gyro noise (sigma/sqrt(T) = 0.0008
    rad/s here; with 0.05 rad/s noise the estimate is off by that mean, about 0.004 rad/s, and
    exact without gyro noise). The simulated drive has vision on every interval, so the
    trajectory hardly changes (it does on the shared drives' repeat events)."""
    bias = (0.008, -0.006, 0.01)
    sim = simulate(SimConfig(seed=11, n_frames=150, gyro_bias=bias, gyro_sigma=0.01))
    config = FilterConfig(clean_tracks=False, gyro_sigma=0.01)
    with_bias = run_smoother(sim.sequence, config, init="dead-reckoning")
    joint = run_smoother(sim.sequence, config, init="dead-reckoning",
                         settings=SmootherSettings(gyro_bias="joint", compute_marginals=False))
    np.testing.assert_allclose(joint.info["gyro_bias"], bias, atol=0.0025)
    without = run_smoother(sim.sequence, config, init="dead-reckoning",
                           settings=SmootherSettings(gyro_bias="off"))
    estimated = np.asarray(with_bias.info["gyro_bias"])
    np.testing.assert_allclose(estimated, bias, atol=0.0025)
    assert without.info["gyro_bias"] is None
    assert ate_rmse(with_bias.poses, sim.poses) < 1.05 * ate_rmse(without.poses, sim.poses)
    assert np.all(np.isfinite(with_bias.pose_cov)) and np.all(np.isfinite(with_bias.landmark_cov[with_bias.has_landmark]))


def test_gap_intervals():
    from vislam.graph.factors import StereoRows, unconstrained_intervals

    # track 0 on frames 0-2, track 1 on frames 3-5: the interval [2, 3] has no vision
    rows = StereoRows(np.array([0, 1, 2, 3, 4, 5]), np.array([0, 0, 0, 1, 1, 1]), np.zeros((6, 4)))
    gaps = unconstrained_intervals(rows, 6)
    np.testing.assert_array_equal(gaps, [False, False, True, False, False])


@pytest.mark.parametrize("damping", ["nielsen", "fixed"])
def test_joint_bias_lm_on_python_values_reaches_gtsams_minimum(damping):
    """A graph with the joint bias variable (one Python factor per interval) is solved by the
    LM loop on Python-owned values (graph.smoother._python_values_lm: GTSAM's LM copies the whole
    Values into every Python factor at every evaluation); it ends where GTSAM's own LM does."""
    import dataclasses

    from vislam.graph.factors import build_graph
    from vislam.graph.gyro_bias import GyroBiasModel
    from tests.lm_reference import assert_lm_reaches_gtsams_minimum
    from vislam.graph.smoother import solve_smoother

    sim = simulate(SimConfig(seed=11, n_frames=40, gyro_bias=(0.008, -0.006, 0.01), gyro_sigma=0.01))
    settings = SmootherSettings(gyro_bias="joint", lm_damping=damping, rejection_rounds=0,
                                relative_error_tol=1e-8)
    sol = solve_smoother(sim.sequence, CONFIG, settings, init="dead-reckoning")
    model = dataclasses.replace(sol.bias_model, initial=np.zeros(3))
    start = build_graph(sol.poses, sol.landmarks, sol.problem.rows, sol.deltas, sol.noise, bias=model)
    ours, theirs = assert_lm_reaches_gtsams_minimum(start, settings, 40)
    np.testing.assert_allclose(ours.atPoint3(BIAS_KEY), theirs.atPoint3(BIAS_KEY), atol=1e-7)


def test_motion_bias_jacobian_matches_finite_differences_of_the_whitened_motion_errors():
    """graph.gyro_bias.motion_bias_jacobian (the out-of-sample test's bias columns, issue 34)
    against central differences of the whitened between-factor errors with the bias moved."""
    from types import SimpleNamespace

    from vislam.graph.gyro_bias import bias_jacobians, corrected_deltas, motion_bias_jacobian
    from vislam.graph.marginals import linearise
    from vislam.graph.pose_conversions import X

    rng = np.random.default_rng(5)
    T = 6
    twist = rng.normal(0.0, [3.0, 0.3, 0.1, 0.05, 0.05, 0.3], size=(T - 1, 6))  # translation first
    tau = np.full(T - 1, 0.1)
    sigmas = np.array([0.002, 0.003, 0.002, 0.05, 0.02, 0.03])  # GTSAM order
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    graph.add(gtsam.PriorFactorPose3(X(0), gtsam.Pose3(), gtsam.noiseModel.Isotropic.Sigma(6, 0.01)))
    poses, deltas = [np.eye(4)], []
    for k in range(T - 1):
        xi = np.r_[twist[k, 3:], twist[k, :3]] * tau[k]
        delta = gtsam.Pose3.Expmap(xi)
        deltas.append(delta.matrix())
        graph.add(gtsam.BetweenFactorPose3(X(k), X(k + 1), delta, gtsam.noiseModel.Diagonal.Sigmas(sigmas)))
        noisy = gtsam.Pose3(poses[-1]).compose(delta).compose(gtsam.Pose3.Expmap(rng.normal(0, 0.01, 6)))
        poses.append(noisy.matrix())
    for k, P in enumerate(poses):
        values.insert(X(k), gtsam.Pose3(P))
    poses, deltas = np.stack(poses), np.stack(deltas)
    lin = linearise(graph, values, T, "test")
    solution = SimpleNamespace(poses=poses, deltas=deltas, twist=twist, tau=tau,
                               problem=SimpleNamespace(graph=graph), linearised=lambda: lin)
    rows, A_b = motion_bias_jacobian(solution)
    np.testing.assert_array_equal(rows, np.arange(6, 6 * T))
    D = bias_jacobians(twist, tau)

    def whitened(db):
        moved = corrected_deltas(deltas, D, db)
        return np.concatenate([gtsam.Pose3.Logmap(gtsam.Pose3(moved[k]).between(
            gtsam.Pose3(poses[k]).between(gtsam.Pose3(poses[k + 1])))) / sigmas for k in range(T - 1)])

    h = 1e-6
    numeric = np.column_stack([(whitened(h * e) - whitened(-h * e)) / (2 * h) for e in np.eye(3)])
    np.testing.assert_allclose(A_b, numeric, rtol=1e-5, atol=1e-6)
