"""The smoother's twist-smoothness prior at intervals without vision: its Jacobians against
finite differences, its invariances, the linearised (C++) form against the exact one, the
sigma measured on a trajectory, and its effect on simulated drives with repeat events."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from vislam.ekf.cleaning import find_repeat_events
from vislam.ekf.config import FilterConfig
from vislam.ekf.errors import InputError
from vislam.ekf.geometry import se3_exp
from vislam.eval.metrics import ate_rmse, kitti_drift
from vislam.eval.simulate import SimConfig, simulate
from vislam.graph.pose_conversions import X, from_pose3, to_pose3
from vislam.graph.settings import SmootherSettings
from vislam.graph.smoother import run_smoother
from vislam.graph.twist_smoothness import (MIN_SIGMA, add_smoothness_factors, linearised, prior_intervals,
                                    smoothness_error, smoothness_factor, smoothness_sigma,
                                    twist_residuals)
from tests.numdiff import numeric_jacobian

TAU = np.array([0.1, 0.104, 0.097])


def _poses(seed: int, n: int = 4, jitter: float = 0.02) -> list[gtsam.Pose3]:
    """``n`` poses of a car-like motion (about 10 m/s, turning) from a random start."""
    rng = np.random.default_rng(seed)
    x = [to_pose3(se3_exp(rng.normal(0, 1, 6)))]
    for _ in range(n - 1):
        twist = np.array([10.0, 0.2, 0.1, 0.02, 0.01, 0.3]) + rng.normal(0, jitter, 6) * [50, 5, 5, 1, 1, 1]
        x.append(x[-1].compose(to_pose3(se3_exp(0.1 * twist))))
    return x


def _values(poses: list[gtsam.Pose3], first: int = 0) -> gtsam.Values:
    values = gtsam.Values()
    for i, p in enumerate(poses):
        values.insert(X(first + i), p)
    return values


@pytest.mark.parametrize("seed", range(4))
def test_jacobians_match_finite_differences(seed):
    poses = _poses(seed)
    H: list = []
    smoothness_error(poses, TAU, H)
    for i in range(4):
        def moved(d, i=i):
            x = list(poses)
            x[i] = x[i].compose(gtsam.Pose3.Expmap(d))
            return smoothness_error(x, TAU)
        np.testing.assert_allclose(H[i], numeric_jacobian(moved, np.zeros(6)), atol=1e-6)


def test_zero_for_a_constant_twist_and_invariant_to_the_world_frame():
    rng = np.random.default_rng(3)
    twist = np.array([8.0, 0.1, -0.05, 0.01, -0.02, 0.25])
    start = to_pose3(se3_exp(rng.normal(0, 1, 6)))
    poses = [start]
    for tau in TAU:
        poses.append(poses[-1].compose(to_pose3(se3_exp(tau * twist))))
    np.testing.assert_allclose(smoothness_error(poses, TAU), 0.0, atol=1e-12)
    bumpy = _poses(5)
    G = to_pose3(se3_exp(rng.normal(0, 2, 6)))
    moved = [G.compose(p) for p in bumpy]
    np.testing.assert_allclose(smoothness_error(moved, TAU), smoothness_error(bumpy, TAU), atol=1e-10)


def test_custom_factor_and_its_linearised_form():
    poses = _poses(7)
    noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.01, 0.01, 0.005, 0.05, 0.05, 0.05]))
    factor = smoothness_factor(5, TAU, noise)
    assert list(factor.keys()) == [X(i) for i in range(4, 8)]
    values = _values(poses, 4)
    np.testing.assert_allclose(factor.unwhitenedError(values), smoothness_error(poses, TAU), atol=1e-12)
    H: list = []
    smoothness_error(poses, TAU, H)
    jac = factor.linearize(values).jacobian()[0]
    whiten = np.diag(1.0 / noise.sigmas())
    np.testing.assert_allclose(jac, whiten @ np.hstack(H), atol=1e-9)

    lin = linearised(factor, values)
    assert lin.error(values) == pytest.approx(factor.error(values), rel=1e-12)
    # exact under a change of world frame, close for a small relative change
    G = to_pose3(se3_exp(np.array([5.0, -3.0, 1.0, 0.3, -0.2, 1.0])))
    shifted = _values([G.compose(p) for p in poses], 4)
    assert lin.error(shifted) == pytest.approx(factor.error(shifted), rel=1e-9)
    rng = np.random.default_rng(0)
    nudged = _values([p.compose(gtsam.Pose3.Expmap(rng.normal(0, 1e-4, 6))) for p in poses], 4)
    assert lin.error(nudged) == pytest.approx(factor.error(nudged), rel=1e-3)


def test_prior_intervals_need_a_neighbour_on_each_side():
    gaps = np.zeros(10, dtype=bool)
    gaps[[0, 3, 4, 9]] = True
    np.testing.assert_array_equal(prior_intervals(gaps), [3, 4])
    graph = gtsam.NonlinearFactorGraph()
    assert add_smoothness_factors(graph, gaps, np.full(10, 0.1), MIN_SIGMA) == 2
    assert graph.size() == 2


def test_sigma_is_measured_on_the_trajectory_away_from_gaps():
    rng = np.random.default_rng(1)
    n = 400
    tau = np.full(n - 1, 0.1)
    # twists with a known second difference: a random walk of slope, i.e. white "jerk"
    true_sigma = np.array([0.004, 0.006, 0.003, 0.05, 0.03, 0.02])
    twists = np.empty((n - 1, 6))  # rotation first
    twists[0] = [0.0, 0.0, 0.1, 10.0, 0.0, 0.0]
    twists[1] = twists[0]
    for k in range(2, n - 1):
        twists[k] = 2 * twists[k - 1] - twists[k - 2] + rng.normal(0, 2 * true_sigma)
        twists[k] -= 0.05 * (twists[k - 1] - twists[0])  # keep it bounded
    poses = [gtsam.Pose3()]
    for k in range(n - 1):
        poses.append(poses[-1].compose(gtsam.Pose3.Expmap(tau[k] * twists[k])))
    P = np.stack([from_pose3(p) for p in poses])
    r = twist_residuals(P, tau)
    np.testing.assert_allclose(r, twists[1:-1] - 0.5 * (twists[:-2] + twists[2:]), atol=1e-9)
    gaps = np.zeros(n - 1, dtype=bool)
    gaps[::7] = True
    r[gaps[1:-1]] = 100.0  # a gap's own residual must not enter the estimate
    sigma = smoothness_sigma(P, tau, gaps)
    expected = 1.4826 * np.median(np.abs(r[~(gaps[:-2] | gaps[1:-1] | gaps[2:])]), axis=0)
    np.testing.assert_allclose(sigma, np.maximum(expected, MIN_SIGMA), rtol=0.1)
    # a constant twist: the floor, not a rigid constraint; too short: nothing to measure
    straight = np.stack([se3_exp(np.array([1.0 * k, 0, 0, 0, 0, 0])) for k in range(50)])
    np.testing.assert_allclose(smoothness_sigma(straight, np.full(49, 0.1), np.zeros(49, bool)), MIN_SIGMA)
    assert smoothness_sigma(straight[:8], np.full(7, 0.1), np.zeros(7, bool)) is None


def test_setting_is_validated():
    with pytest.raises(InputError, match="gap_twist_prior"):
        SmootherSettings(gap_twist_prior="yes")


@pytest.fixture(scope="module")
def drive_with_events():
    sim = simulate(SimConfig(seed=1, n_frames=300, repeat_event_rate=0.08, gyro_bias=(0.005, -0.005, 0.007)))
    return sim


def test_simulated_repeat_events_are_found_and_cleaned(drive_with_events):
    sim = drive_with_events
    events = find_repeat_events(sim.sequence)
    assert 12 <= len(events) <= 40
    plain = simulate(SimConfig(seed=1, n_frames=300, gyro_bias=(0.005, -0.005, 0.007)))
    # the same drive and the same noise otherwise: only the repeated observations differ
    np.testing.assert_array_equal(plain.sequence.obs.track, sim.sequence.obs.track)
    differs = np.any(plain.sequence.obs.z != sim.sequence.obs.z, axis=1)
    assert np.all(np.isin(sim.sequence.obs.frame_index[differs], [e.frame for e in events]))


@pytest.mark.regression
def test_prior_improves_the_smoother_across_gaps(drive_with_events):
    sim = drive_with_events
    config = FilterConfig()
    base = SmootherSettings(compute_marginals=False)
    off = run_smoother(sim.sequence, config, settings=base.replace(gap_twist_prior="off"))
    on = run_smoother(sim.sequence, config, settings=base)
    exact = run_smoother(sim.sequence, config, settings=base.replace(gap_twist_prior="exact"))
    ate = {name: ate_rmse(e.poses, sim.poses, align="se3") for name, e in
           (("off", off), ("on", on), ("exact", exact))}
    drift = {name: kitti_drift(e.poses, sim.poses)["t_rel_pct"] for name, e in
             (("off", off), ("on", on))}
    assert ate["on"] < 0.9 * ate["off"], ate
    assert drift["on"] < drift["off"], drift
    # the linearised prior is as good as the exact one
    assert ate["on"] < 1.1 * ate["exact"], ate


@pytest.mark.regression
def test_prior_improves_isam2_across_gaps():
    from vislam.graph.isam2 import run_isam2

    sim = simulate(SimConfig(seed=2, n_frames=200, repeat_event_rate=0.08))
    base = SmootherSettings(compute_marginals=False)
    off = run_isam2(sim.sequence, FilterConfig(), settings=base.replace(gap_twist_prior="off"))
    on = run_isam2(sim.sequence, FilterConfig(), settings=base)
    assert off.info["n_gap_priors"] == 0 and on.info["n_gap_priors"] >= 5
    ate_off = ate_rmse(off.poses, sim.poses, align="se3")
    ate_on = ate_rmse(on.poses, sim.poses, align="se3")
    assert ate_on < 0.9 * ate_off, (ate_on, ate_off)
