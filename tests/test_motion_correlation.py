"""The velocity errors' long-run sigma (graph.motion_correlation): the block residual and its
Jacobians against finite differences, the fixed-point search, and identification on simulated
drives with white and with correlated velocity errors."""

import numpy as np
import pytest

from vislam.ekf.geometry import se3_exp
from vislam.eval.simulate import SimConfig, simulate, true_model
from vislam.graph.motion_correlation import (
    MIN_BLOCKS, block_bounds, block_residual, fixed_point, transport_jacobians)
from vislam.graph.pose_conversions import expmap_right_jacobian, twist_to_gtsam, to_pose3

import gtsam


def _drive(rng, n=12):
    twist = np.c_[rng.uniform(5, 10, n), rng.normal(0, 0.3, (n, 2)), rng.normal(0, 0.1, (n, 3))]
    tau = np.full(n, 0.1)
    deltas = se3_exp(tau[:, None] * twist)
    return twist, tau, deltas


def _compose(deltas):
    poses = [np.eye(4)]
    for d in deltas:
        poses.append(poses[-1] @ d)
    return np.array(poses)


def test_block_residual_is_the_transported_sum_of_interval_noises():
    """eps_B of poses made with twist noises w_k equals sum_k A_k w_k to first order."""
    rng = np.random.default_rng(0)
    twist, tau, deltas = _drive(rng)
    w = 1e-5 * rng.standard_normal((len(tau), 6))  # GTSAM order [rot; trans]
    noisy = np.array([
        (to_pose3(d).compose(gtsam.Pose3.Expmap(
            tau[k] * expmap_right_jacobian(twist_to_gtsam(tau[k] * twist[k])) @ w[k]))).matrix()
        for k, d in enumerate(deltas)])
    poses = _compose(noisy)
    s, e = 2, 11
    eps, _ = block_residual(poses, deltas, s, e)
    A = transport_jacobians(deltas, twist, tau, s, e)
    predicted = np.einsum("kij,kj->i", A, w[s:e])
    assert np.allclose(eps, predicted, atol=1e-3 * np.abs(predicted).max())


def test_block_residual_jacobians_match_finite_differences():
    rng = np.random.default_rng(1)
    twist, tau, deltas = _drive(rng)
    poses = _compose(se3_exp(tau[:, None] * (twist + 0.05 * rng.standard_normal(twist.shape))))
    s, e = 1, 9
    eps0, Cs = block_residual(poses, deltas, s, e)
    h = 1e-6
    num_s, num_e = np.zeros((6, 6)), np.zeros((6, 6))
    for i in range(6):
        d = np.zeros(6)
        d[i] = h
        for which, out in ((s, num_s), (e, num_e)):
            moved = poses.copy()
            moved[which] = (to_pose3(poses[which]).compose(gtsam.Pose3.Expmap(d))).matrix()
            out[:, i] = (block_residual(moved, deltas, s, e)[0] - eps0) / h
    # The factor's Jacobians up to J_r^-1(eps), which is the identity at eps = 0 and near it
    # for a small residual (eps here is a few 1e-3).
    J_inv = gtsam.Pose3.LogmapDerivative(eps0)
    assert np.allclose(num_s, J_inv @ Cs, atol=1e-4)
    assert np.allclose(num_e, J_inv, atol=1e-4)


def test_block_bounds_cover_whole_intervals_of_five_seconds():
    blocks = block_bounds(np.full(120, 0.1))
    assert blocks == [(0, 50), (50, 100)]
    assert block_bounds(np.zeros(0)) == []


def test_fixed_point_finds_a_slow_map_s_root_and_respects_the_floor():
    target = np.array([np.log(0.2), np.log(0.05), np.log(0.01)])

    def slow(theta):  # EM-like: moves 5 % of the way per step
        return theta + 0.05 * (target - theta)

    theta, converged = fixed_point(slow, np.log([0.01, 0.05, 0.1]), np.log([0.001, 0.001, 0.02]),
                                   rtol=1e-4, max_solves=20)
    assert converged
    assert np.allclose(theta[:2], target[:2], atol=1e-2)
    assert theta[2] == pytest.approx(np.log(0.02))  # the floor, where the root lies below it


def _identified(config):
    from vislam.graph.identification import identify_model

    result = simulate(config)
    return identify_model(result.sequence, extrinsic=False, radial=False), true_model(result)


@pytest.mark.regression
def test_white_velocity_errors_get_no_long_run_sigma():
    """Every long-run level the drive determines stays white; one it cannot determine (issue
    34) takes its conservative value and is named as undetermined, never silently white."""
    config = SimConfig(seed=3, n_frames=401, velocity_sigma=0.1,
                       gyro_sigma=0.01, velocity_pairing="next")
    fit, _ = _identified(config)
    test = fit.motion_correlation_test
    assert test["tested"] and test["n_blocks"] >= max(MIN_BLOCKS, 8)
    times = (fit.gyro_correlation_time or (1.0,) * 3) + (fit.velocity_correlation_time or (1.0,) * 3)
    for level, time in zip(test["levels"], times):
        if level["determined"]:
            assert time == 1.0, level
        elif time > 1.0:
            axis = level["name"].split()[0] + "_correlation_time_" + level["name"].split()[1]
            assert axis in fit.noise_undetermined, (level, fit.noise_undetermined)


@pytest.mark.regression
def test_correlated_velocity_errors_get_their_long_run_sigma():
    """AR(1) velocity errors, a = 0.9 (correlation time 19 frames): every velocity axis is kept
    and the long-run sigma is within a factor of 1.6 of the truth (23 blocks of 5 s; with 12 the forward axis, which vision pins least, is not kept)."""
    config = SimConfig(seed=4, n_frames=1151, velocity_sigma=0.1, gyro_sigma=0.01,
                       velocity_pairing="next", velocity_correlation=0.9)
    fit, truth = _identified(config)
    test = fit.motion_correlation_test
    assert set(test["kept"]) >= {"velocity x", "velocity y", "velocity z"}, test
    long_run = np.asarray(test["long_run_interval_sigma"])[3:]
    true_long_run = 0.1 * np.sqrt(np.asarray(truth.velocity_correlation_time))
    assert np.all(long_run / true_long_run < 1.6) and np.all(long_run / true_long_run > 1 / 1.6), \
        (long_run, true_long_run)
    model = fit.to_model("test")
    assert model.velocity_correlation_time == fit.velocity_correlation_time


def test_simulator_velocity_correlation_is_checked_and_changes_nothing_when_zero():
    from vislam.ekf.errors import InputError

    with pytest.raises(InputError, match="velocity_correlation"):
        SimConfig(velocity_correlation=1.0)
    a = simulate(SimConfig(seed=5, n_frames=30)).sequence
    b = simulate(SimConfig(seed=5, n_frames=30, velocity_correlation=0.0)).sequence
    c = simulate(SimConfig(seed=5, n_frames=30, velocity_correlation=0.8)).sequence
    assert np.array_equal(a.linear_velocity, b.linear_velocity)
    assert not np.array_equal(a.linear_velocity, c.linear_velocity)
    assert np.array_equal(a.angular_velocity, c.angular_velocity)


def test_simulate_command_writes_the_velocity_correlation_and_refuses_a_bad_one(tmp_path, capsys):
    """``vislam simulate --velocity-correlation A``: the drive's velocities drift and its true
    model (NAME_model.toml) carries their long-run variance; a value outside [0, 0.99) is a
    one-line error (exit 2) naming the setting, and nothing is written."""
    from vislam.ekf.model import Model
    from vislam.eval.cli import main

    out = tmp_path / "sim"
    assert main(["simulate", "--out", str(out), "--frames", "30", "--seed", "5",
                 "--velocity-correlation", "0.8"]) == 0
    model = Model.from_toml(out / "sim-seed5_model.toml")
    expected = true_model(simulate(SimConfig(seed=5, n_frames=30, velocity_correlation=0.8)))
    assert model.velocity_correlation_time is not None
    assert np.allclose(model.velocity_correlation_time, expected.velocity_correlation_time)
    drifting = np.load(out / "sim-seed5.npz")["linear_velocity"]
    white = simulate(SimConfig(seed=5, n_frames=30)).sequence.linear_velocity
    assert not np.allclose(drifting, np.asarray(white).reshape(drifting.shape))

    capsys.readouterr()
    bad = tmp_path / "bad"
    assert main(["simulate", "--out", str(bad), "--frames", "30",
                 "--velocity-correlation", "1.5"]) == 2
    assert "velocity_correlation" in capsys.readouterr().err
    assert not bad.exists() or not any(bad.iterdir())


def test_calibrate_report_line_names_the_gyro_axes_with_the_velocity_ones():
    """The calibrate report's line covers all six axes the blocks test: its label says velocity
    and gyro, and a kept gyro axis is named with its long-run sigma."""
    from vislam.eval.commands.calibrate import _motion_correlation_line
    from vislam.graph.motion_correlation import AXES, MotionCorrelation

    m = MotionCorrelation(np.array([1.0, 1.0, 4.0, 1.0, 1.0, 1.0]),
                          long_run_sigma=np.array([0.01, 0.01, 0.04, 0.1, 0.1, 0.1]),
                          ratio=np.array([1.0, 1.1, 9.0, 1.2, 1.0, 0.9]), threshold=2.16,
                          n_blocks=23, block_frames=48, solves=3, converged=True, tested=True,
                          kept=(AXES[2],)).to_dict()
    line = _motion_correlation_line(m)
    assert line.startswith("velocity and gyro errors in time: long-run / white variance over 23")
    assert "gyro z: the estimators use the long-run interval sigma gyro z 0.04" in line
    assert _motion_correlation_line({}).startswith("velocity and gyro errors in time: not measured")
