"""graph.drift_check: dead reckoning against the smoother over stretches (issue 34 item 4).

Its two covariances against GTSAM's own marginals, the statistic's size under the true model of
simulated drives (chi2/dof about 1), its power where the model claims more than the data hold,
and its errors."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from vislam.ekf.config import FilterConfig
from vislam.ekf.errors import InputError
from vislam.ekf.model import model_config
from vislam.eval.simulate import SimConfig, simulate, true_model
from vislam.graph.drift_check import (dead_reckoning_relative, drift_check, hausman_statistic,
                                      joint_pose_marginals)
from vislam.graph.pose_conversions import X
from vislam.graph.settings import SmootherSettings
from vislam.graph.smoother import solve_smoother


def _model(result, changes: dict | None = None):
    """The drive's true model as the estimators need it: under the "mean" pairing two
    intervals sharing a sample are correlated by a half, so the long-run variance is twice the
    interval's (eval.campaign.drive_true_model; the simulator's own true model leaves it out)."""
    model = true_model(result)
    if model.velocity_pairing == "mean":
        model = model.replace(velocity_correlation_time=(2.0,) * 3, gyro_correlation_time=(2.0,) * 3)
    return model.replace(**(changes or {}))


def _solved(config: SimConfig, model_changes: dict | None = None):
    result = simulate(config)
    model = _model(result, model_changes)
    cfg = model_config(FilterConfig(), model)
    return solve_smoother(result.sequence, cfg, SmootherSettings()), cfg


def test_dead_reckoning_covariance_is_gtsams_marginal_of_a_motion_chain():
    """The propagated P_D is the marginal of the chain's last pose, given the first exactly."""
    rng = np.random.default_rng(3)
    n = 7
    twist = rng.normal(0.0, [0.2, 0.1, 0.05, 5.0, 0.5, 0.2], size=(n, 6))  # GTSAM order
    tau = np.full(n, 0.1)
    from vislam.graph.pose_conversions import expmap_right_jacobian

    deltas = np.stack([gtsam.Pose3.Expmap(t * u).matrix() for t, u in zip(tau, twist)])
    scale = np.stack([t * expmap_right_jacobian(t * u) for t, u in zip(tau, twist)])
    W = np.diag([0.01, 0.02, 0.015, 0.3, 0.2, 0.1]) ** 2
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    graph.add(gtsam.PriorFactorPose3(X(0), gtsam.Pose3(), gtsam.noiseModel.Isotropic.Sigma(6, 1e-9)))
    pose = gtsam.Pose3()
    values.insert(X(0), pose)
    for k in range(n):
        step = gtsam.Pose3(deltas[k])
        cov = scale[k] @ W @ scale[k].T
        graph.add(gtsam.BetweenFactorPose3(X(k), X(k + 1), step, gtsam.noiseModel.Gaussian.Covariance(cov)))
        pose = pose.compose(step)
        values.insert(X(k + 1), pose)
    rel, P = dead_reckoning_relative(deltas, scale, W, 0, n)
    ref = gtsam.Marginals(graph, values).marginalCovariance(X(n))
    np.testing.assert_allclose(rel.matrix(), pose.matrix(), atol=1e-12)
    np.testing.assert_allclose(P, ref, rtol=1e-6, atol=1e-14)


@pytest.fixture(scope="module")
def short_solution():
    return _solved(SimConfig(seed=4, n_frames=60))


def test_joint_pose_marginals_are_gtsams(short_solution):
    solution, _ = short_solution
    from vislam.graph.drift_check import posterior_system

    _, reduced = posterior_system(solution)
    pairs = [(0, 20), (20, 59), (5, 6)]
    blocks = joint_pose_marginals(reduced, solution.poses.shape[0], pairs)
    marginals = gtsam.Marginals(solution.problem.graph, solution.values)
    for (a, b), block in zip(pairs, blocks):
        ref = marginals.jointMarginalCovariance(gtsam.KeyVector([X(a), X(b)])).fullMatrix()
        np.testing.assert_allclose(block, ref, rtol=1e-6, atol=1e-12)


def test_hausman_statistic_leaves_out_directions_vision_does_not_see():
    P_D = np.diag([4.0, 1.0, 1.0, 1.0, 1.0, 1.0])
    P_S = np.diag([1.0, 0.5, 0.999, 1.0, 1.0, 1.0])  # vision adds nothing on the last three
    d = np.array([np.sqrt(3.0), 0.5, 10.0, 10.0, 10.0, 10.0])
    c, k = hausman_statistic(d, P_D, P_S)
    assert k == 2
    assert c == pytest.approx(3.0 / 3.0 + 0.25 / 0.5)


def test_the_true_model_explains_simulated_drives():
    """chi2/dof over drives under their true model is about 1 (each 200 frames, 2 stretches of
    10 s; seeds 0-5: 0.56-1.85 a drive, 0.96 in all)."""
    chi2 = dof = 0.0
    for seed in range(6):
        solution, cfg = _solved(SimConfig(seed=seed, n_frames=200))
        check = drift_check(solution, cfg)
        assert check.dof > 0 and sum(s.dof for s in check.stretches) == check.dof
        assert all(s.last > s.first for s in check.stretches)
        chi2, dof = chi2 + check.chi2, dof + check.dof
        assert check.explains, check.lines()
    assert 0.6 < chi2 / dof < 1.6


@pytest.mark.parametrize("gyro, velocity", [(0.3, 1.0), (0.5, 0.5)])
def test_a_model_claiming_too_much_for_dead_reckoning_does_not_explain_the_drive(gyro, velocity):
    """Dead reckoning claims a heading (and speed) two to three times as good as it is."""
    config = SimConfig(seed=1, n_frames=250)
    true = _model(simulate(config))
    changes = {"gyro_sigma": tuple(gyro * s for s in true.gyro_sigma),
               "velocity_sigma": tuple(velocity * s for s in true.velocity_sigma)}
    solution, cfg = _solved(config, changes)
    check = drift_check(solution, cfg)
    assert not check.explains
    assert check.ratio > 1.6
    assert "does not explain the drive" in check.lines()[0]


def test_widening_every_level_makes_the_stretches_agree():
    """drift_widening's factor, applied to every noise level, leaves a model under which the
    stretches agree (chi2/dof about 1); a model that explains the drive is left as it is."""
    from vislam.graph.drift_check import drift_widening

    config = SimConfig(seed=2, n_frames=250)
    result = simulate(config)
    true = _model(result)
    check, factor = drift_widening(result.sequence, FilterConfig(), true, SmootherSettings())
    assert check.explains and factor == 1.0
    tight = true.replace(velocity_sigma=tuple(0.5 * s for s in true.velocity_sigma),
                         gyro_sigma=tuple(0.5 * s for s in true.gyro_sigma),
                         pixel_sigma=0.5 * true.pixel_sigma)
    check, factor = drift_widening(result.sequence, FilterConfig(), tight, SmootherSettings())
    assert not check.explains and 1.5 < factor < 3.0
    wide = tight.replace(velocity_sigma=tuple(factor * s for s in tight.velocity_sigma),
                         gyro_sigma=tuple(factor * s for s in tight.gyro_sigma),
                         pixel_sigma=factor * tight.pixel_sigma)
    again, factor_again = drift_widening(result.sequence, FilterConfig(), wide, SmootherSettings())
    assert again.explains and factor_again == 1.0
    assert again.ratio == pytest.approx(1.0, abs=0.25)


@pytest.mark.parametrize("kwargs, what", [({"stretch_s": 0.0}, "stretch length"),
                                          ({"stretch_s": float("nan")}, "stretch length"),
                                          ({"level": 1.0}, "level")])
def test_bad_arguments_are_named(short_solution, kwargs, what):
    solution, cfg = short_solution
    with pytest.raises(InputError, match=what):
        drift_check(solution, cfg, **kwargs)
