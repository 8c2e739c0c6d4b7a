"""The batch smoother's speed-scale variables (graph/speed_scale.py, ``config.speed_scale``)."""

from __future__ import annotations

import dataclasses

import gtsam
import numpy as np
import pytest

from vislam.ekf.config import FilterConfig
from vislam.eval.metrics import ate_rmse, nees, pose_errors
from vislam.eval.simulate import SimConfig, simulate
from vislam.graph.factors import (NoiseModels, build_graph, gaussian_stereo, relative_motions,
                                  usable_rows)
from vislam.graph.marginals import gtsam_marginals, schur_marginals
from vislam.graph.pose_conversions import X, to_pose3
from vislam.graph.settings import SmootherSettings
from vislam.graph.smoother import run_smoother, solve_smoother
from vislam.graph.speed_scale import (S, SpeedScaleModel, scaled_deltas, scaled_motion_error,
                                      scaled_motion_factor)
from tests.numdiff import numeric_jacobian


def _random_case(seed: int):
    rng = np.random.default_rng(seed)
    xi0 = rng.normal(size=6) * 0.3
    dxi = np.r_[np.zeros(3), xi0[3:]]
    x0 = gtsam.Pose3.Expmap(rng.normal(size=6))
    x1 = x0.compose(gtsam.Pose3.Expmap(xi0 + rng.normal(size=6) * 0.05))
    C = gtsam.Pose3.Expmap(rng.normal(size=6) * 0.02)
    D = rng.normal(size=(6, 3)) * 0.1
    b = rng.normal(size=3) * 0.01
    return xi0, dxi, x0, x1, C, D, b, float(rng.normal() * 0.02)


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("kind", ["plain", "fixed correction", "bias variable"])
def test_jacobians_match_finite_differences(seed, kind):
    xi0, dxi, x0, x1, C, D, b, s = _random_case(seed)
    kw = {"plain": {}, "fixed correction": {"correction": C},
          "bias variable": {"D": D, "bias": b}}[kind]
    H: list = []
    scaled_motion_error(xi0, dxi, x0, x1, s, H=H, **kw)
    assert len(H) == (4 if kind == "bias variable" else 3)
    n0 = numeric_jacobian(lambda d: scaled_motion_error(xi0, dxi, x0.retract(d), x1, s, **kw), np.zeros(6))
    n1 = numeric_jacobian(lambda d: scaled_motion_error(xi0, dxi, x0, x1.retract(d), s, **kw), np.zeros(6))
    ns = numeric_jacobian(lambda d: scaled_motion_error(xi0, dxi, x0, x1, s + d[0], **kw), np.zeros(1))
    np.testing.assert_allclose(H[0], n0, atol=1e-7)
    np.testing.assert_allclose(H[1], n1, atol=1e-7)
    np.testing.assert_allclose(H[2], ns, atol=1e-7)
    if kind == "bias variable":
        nb = numeric_jacobian(lambda d: scaled_motion_error(xi0, dxi, x0, x1, s, D=D, bias=b + d), np.zeros(3))
        np.testing.assert_allclose(H[3], nb, atol=1e-7)


def test_factor_is_the_exactly_scaled_between_factor():
    """The CustomFactor's error is the plain between-factor's on ``exp(tau [(1 + s) v; w])``
    (translation-first twist, as the other factors build it), and its linearisation is the
    analytic Jacobians'."""
    xi0, dxi, x0, x1, C, D, b, s = _random_case(4)
    noise = gtsam.noiseModel.Isotropic.Sigma(6, 0.1)
    factor = scaled_motion_factor(X(0), X(1), S(0), xi0, dxi, noise, correction=C.matrix())
    values = gtsam.Values()
    values.insert(X(0), x0)
    values.insert(X(1), x1)
    values.insert(S(0), s)
    twist = np.r_[(1 + s) * xi0[3:], xi0[:3]]  # translation first, times tau
    from vislam.ekf.geometry import se3_exp
    delta = se3_exp(twist[None])[0] @ C.matrix()
    plain = gtsam.BetweenFactorPose3(X(0), X(1), to_pose3(delta), noise)
    np.testing.assert_allclose(factor.unwhitenedError(values), plain.unwhitenedError(values), atol=1e-10)
    H: list = []
    scaled_motion_error(xi0, dxi, x0, x1, s, correction=C, H=H)
    A = factor.linearize(values).jacobian()[0]
    np.testing.assert_allclose(A, np.hstack(H) / 0.1, atol=1e-9)
    np.testing.assert_allclose(scaled_deltas(np.array([np.r_[xi0[3:], xi0[:3]]]), np.ones(1),
                                             np.array([s]), C.matrix()[None])[0], delta, atol=1e-12)


def test_random_walk_and_constant_scale():
    twists = np.tile([10.0, 0, 0, 0, 0, 0.1], (5, 1))
    tau = np.full(5, 0.1)
    walk = SpeedScaleModel.create(twists, tau, 0.005, 0.001)
    assert walk.n_variables == 5 and len(walk.walk) == 4
    np.testing.assert_allclose(walk.walk[0].sigmas(), [0.001 * np.sqrt(0.1)])
    np.testing.assert_allclose(walk.prior.sigmas(), [0.005])
    constant = SpeedScaleModel.create(twists, tau, 0.005, 0.0)
    assert constant.n_variables == 1 and not constant.walk
    np.testing.assert_array_equal(constant.index, np.zeros(5))
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    walk.add_variables(graph, values)
    assert graph.size() == 5 and values.size() == 5


def _scaled_drive(n_frames: int, scale: float, seed: int = 3):
    """A drive whose measured linear velocities are off by ``v_true = (1 + scale) v``."""
    sim = simulate(SimConfig(seed=seed, n_frames=n_frames, velocity_sigma=0.05, gyro_sigma=0.005,
                             landmark_density=0.5))
    seq = dataclasses.replace(sim.sequence, linear_velocity=sim.sequence.linear_velocity / (1 + scale))
    return sim, seq


_CONFIG = FilterConfig(clean_tracks=False, velocity_sigma=0.05, gyro_sigma=0.005)


def _nees(est, sim) -> float:
    return float(np.mean(nees(pose_errors(est.poses, sim.poses), est.pose_cov)))


def test_smoother_recovers_the_speed_scale():
    """A 2 % speed error the white velocity model cannot explain: with the scale a state the
    smoother recovers it within 3 sigma, and its ATE and pose NEES are far better."""
    sim, seq = _scaled_drive(120, 0.02)
    on = dataclasses.replace(_CONFIG, speed_scale=True, speed_scale_sigma=0.03)
    without = run_smoother(seq, _CONFIG, init="dead-reckoning")
    with_scale = run_smoother(seq, on, init="dead-reckoning")
    info = with_scale.info["speed_scale"]
    assert "speed_scale" not in without.info
    assert info["n_variables"] == 119
    assert abs(info["mean"] - 0.02) < 3 * info["sigma_mean"]
    assert info["sigma_mean"] < 0.005
    assert ate_rmse(with_scale.poses, sim.poses) < 0.5 * ate_rmse(without.poses, sim.poses)
    assert _nees(with_scale, sim) < 12.0 < _nees(without, sim)
    assert np.all(np.isfinite(with_scale.pose_cov))


def test_joint_gyro_bias_and_constant_scale():
    sim, seq = _scaled_drive(60, 0.02, seed=5)
    on = dataclasses.replace(_CONFIG, speed_scale=True, speed_scale_sigma=0.03)
    joint = run_smoother(seq, on, init="dead-reckoning", settings=SmootherSettings(gyro_bias="joint"))
    constant = run_smoother(seq, dataclasses.replace(on, speed_scale_walk=0.0), init="dead-reckoning")
    for est in (joint, constant):
        info = est.info["speed_scale"]
        assert abs(info["mean"] - 0.02) < 3 * info["sigma_mean"]
        assert np.all(np.isfinite(est.pose_cov))
    assert constant.info["speed_scale"]["n_variables"] == 1
    assert joint.info["gyro_bias"] is not None


def test_marginals_with_scale_variables_match_gtsam():
    """The Schur marginals with the 1-dimensional scale variables in the border agree with
    gtsam.Marginals, and the scales widen the pose covariances."""
    sim, seq = _scaled_drive(30, 0.02, seed=7)
    on = dataclasses.replace(_CONFIG, speed_scale=True, speed_scale_sigma=0.03)
    sol = solve_smoother(seq, on, SmootherSettings(gyro_bias="off"), init="dead-reckoning")
    problem, T, M = sol.problem, sol.poses.shape[0], sol.cleaned.n_tracks
    graph = gaussian_stereo(problem.graph, problem.rows, 1 + len(sol.deltas), sol.noise)
    keys = [S(i) for i in range(sol.scale_model.n_variables)]
    pose_cov, lm_cov, scale_cov = schur_marginals(graph, sol.values, T, problem.landmark_tracks, M, keys)
    ref_pose, ref_lm = gtsam_marginals(graph, sol.values, T, problem.landmark_tracks, M)
    np.testing.assert_allclose(pose_cov, ref_pose, rtol=1e-6, atol=1e-12)
    tracks = problem.landmark_tracks
    np.testing.assert_allclose(lm_cov[tracks], ref_lm[tracks], rtol=1e-6, atol=1e-12)
    ref_scale = gtsam.Marginals(graph, sol.values).jointMarginalCovariance(keys).fullMatrix()
    np.testing.assert_allclose(scale_cov, ref_scale, rtol=1e-6, atol=1e-14)
    # given the scales (the motions at their estimates, no scale variables) the last pose is
    # more certain
    _, motion_covs = relative_motions(sol.cleaned, on)
    noise = NoiseModels.create(sol.cleaned, on, SmootherSettings(), motion_covs)
    plain = build_graph(sol.poses, sol.landmarks, problem.rows, sol.deltas, noise)
    plain_graph = gaussian_stereo(plain.graph, problem.rows, 1 + len(sol.deltas), noise)
    plain_pose, _ = schur_marginals(plain_graph, plain.values, T, plain.landmark_tracks, M)
    assert sol.scale_model.n_variables == T - 1
    assert np.trace(pose_cov[-1][:3, :3]) > 1.5 * np.trace(plain_pose[-1][:3, :3])


def test_speed_scale_off_builds_the_plain_graph():
    sim, seq = _scaled_drive(20, 0.0, seed=1)
    sol = solve_smoother(seq, _CONFIG, SmootherSettings(), init="dead-reckoning")
    assert sol.scale_model is None and sol.speed_scale is None and sol.problem.scale is None
    assert not any(chr(gtsam.Symbol(k).chr()) == "s" for k in sol.values.keys())
    assert isinstance(sol.problem.graph.at(1), gtsam.BetweenFactorPose3)
    rows, _ = usable_rows(sol.cleaned, _CONFIG.min_disparity)
    assert len(rows) >= len(sol.problem.rows)


@pytest.mark.parametrize("damping", ["nielsen", "fixed"])
def test_python_values_lm_reaches_gtsams_minimum(damping):
    """The speed-scale graph's LM loop (Python-owned values) ends where GTSAM's own LM does."""
    from tests.lm_reference import assert_lm_reaches_gtsams_minimum

    sim, seq = _scaled_drive(40, 0.02, seed=9)
    on = dataclasses.replace(_CONFIG, speed_scale=True, speed_scale_sigma=0.03)
    settings = SmootherSettings(lm_damping=damping, rejection_rounds=0, relative_error_tol=1e-8)
    sol = solve_smoother(seq, on, settings, init="dead-reckoning")
    problem = dataclasses.replace(sol.problem, values=gtsam.Values(sol.problem.values))
    start = build_graph(sol.poses, sol.landmarks, problem.rows, sol.deltas, sol.noise,
                        scale=dataclasses.replace(sol.scale_model, initial=np.zeros(sol.scale_model.n_variables)))
    start.values.update(X(0), start.values.atPose3(X(0)))
    ours, theirs = assert_lm_reaches_gtsams_minimum(start, settings, 40)
    np.testing.assert_allclose(ours.atDouble(S(5)), theirs.atDouble(S(5)), atol=1e-6)


def test_campaign_speed_fault_is_tracked():
    """The campaign's slowly varying speed fault (``eval.campaign.SpeedScaleFault``: up to 1 %,
    knots every 20 s): with the scale a state the smoother finds its mean within 3 sigma, and
    beats the white velocity model in ATE and pose NEES."""
    from vislam.eval.campaign import SpeedScaleFault

    fault = SpeedScaleFault(0.01, 20.0, 1)
    sim = fault.apply(simulate(SimConfig(seed=1, n_frames=150, velocity_sigma=0.05)))
    truth = 1.0 / (1.0 + fault.error(sim.sequence.timestamps)) - 1.0  # v_true = (1 + s) v_measured
    config = FilterConfig(velocity_sigma=0.05)
    without = run_smoother(sim.sequence, config, init="dead-reckoning")
    on = dataclasses.replace(config, speed_scale=True, speed_scale_sigma=0.01)
    with_scale = run_smoother(sim.sequence, on, init="dead-reckoning")
    info = with_scale.info["speed_scale"]
    assert abs(info["mean"] - np.mean(truth)) < 3 * info["sigma_mean"]
    ate = [ate_rmse(e.poses, sim.poses, align="se3") for e in (with_scale, without)]
    assert ate[0] < 0.5 * ate[1]
    assert _nees(with_scale, sim) < 12.0 < _nees(without, sim)
