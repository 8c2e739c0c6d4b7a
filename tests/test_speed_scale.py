"""The speed-scale state of dead reckoning and ekf-joint (``FilterConfig.speed_scale``): the
linear velocities are off by a slowly varying factor, ``v_true = (1 + s) v``, carried as a
random-walk state (ekf.prediction.error_state_transition; its Jacobian is checked against finite
differences in tests/test_ekf_jacobians.py)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from vislam.ekf.config import FilterConfig
from vislam.ekf.dead_reckoning import DeadReckoning
from vislam.ekf.decoupled import DecoupledEKF
from vislam.ekf.driver import run_filter
from vislam.ekf.joint import JointEKF
from vislam.ekf.model import Model, model_config, model_sequence
from vislam.eval.simulate import SimConfig, simulate, true_model

#: A 1.5 % speed error of every linear-velocity sample (constant: the walk is then a prior).
SCALE_ERROR = 0.015


def _drive(frames: int = 120, scale_error: float = 0.0, seed: int = 5):
    """A short simulated drive with clean velocities and sparse vision, its linear velocities
    multiplied by ``1 + scale_error``; (sequence, config under the true model, truth poses)."""
    result = simulate(SimConfig(seed=seed, n_frames=frames, velocity_sigma=0.01, gyro_sigma=0.002,
                                landmark_density=0.6, name="scale"))
    model = true_model(result)
    seq = model_sequence(result.sequence, model)
    seq = dataclasses.replace(seq, linear_velocity=seq.linear_velocity * (1.0 + scale_error))
    return seq, model_config(FilterConfig(), model), result.poses


def _pose_nees(est, truth) -> float:
    from vislam.eval.consistency import pose_nees

    return float(np.mean(pose_nees(est, np.arange(len(truth)), truth)[1:]))


def test_dead_reckoning_scale_state_widens_the_covariance_and_keeps_the_mean():
    """Nothing observes the scale: the mean is the plain prediction's to the last bit, and the
    along-track position variance grows by about (distance * sigma_s)^2 over a straight run."""
    seq, config, _ = _drive(frames=60)
    plain = run_filter(DeadReckoning(), seq, config)
    sigma_s = 0.01
    scaled = run_filter(DeadReckoning(), seq, config.replace(
        speed_scale=True, speed_scale_sigma=sigma_s, speed_scale_walk=0.0))
    np.testing.assert_array_equal(scaled.poses, plain.poses)
    distance = np.linalg.norm(plain.poses[-1][:3, 3] - plain.poses[0][:3, 3])
    grown = np.trace(scaled.pose_cov[-1][:3, :3]) - np.trace(plain.pose_cov[-1][:3, :3])
    assert grown == pytest.approx((distance * sigma_s) ** 2, rel=0.25)
    assert scaled.info["speed_scale"] == 0.0
    assert scaled.info["speed_scale_sigma_final"] == pytest.approx(sigma_s)


def test_dead_reckoning_with_a_speed_error_is_consistent_only_with_the_scale_state():
    seq, config, truth = _drive(scale_error=SCALE_ERROR)
    plain = run_filter(DeadReckoning(), seq, config)
    scaled = run_filter(DeadReckoning(), seq, config.replace(speed_scale=True, speed_scale_sigma=0.01))
    assert _pose_nees(plain, truth) > 50.0
    assert _pose_nees(scaled, truth) < 12.0


def test_joint_ekf_estimates_the_speed_scale():
    """A constant 1.5 % speed error: v_true = v / 1.015, so s = 1/1.015 - 1; ekf-joint with the
    state recovers it within 3 sigma and is consistent where without it it is not."""
    seq, config, truth = _drive(scale_error=SCALE_ERROR)
    plain = run_filter(JointEKF(), seq, config)
    scaled = run_filter(JointEKF(), seq, config.replace(speed_scale=True, speed_scale_sigma=0.01))
    s_true = 1.0 / (1.0 + SCALE_ERROR) - 1.0
    s, sd = scaled.info["speed_scale"], scaled.info["speed_scale_sigma_final"]
    assert sd < 0.01
    assert abs(s - s_true) < 3.0 * sd
    assert _pose_nees(scaled, truth) < _pose_nees(plain, truth) / 5.0


@pytest.mark.parametrize("changes", [{"keep_landmarks": True},
                                     {"landmark_parameterisation": "inverse-depth"},
                                     {"gyro_bias": False},
                                     {"joint_linearisation": "standard"}])
def test_joint_ekf_speed_scale_with_every_variant(changes):
    seq, config, truth = _drive(frames=60, scale_error=SCALE_ERROR)
    est = run_filter(JointEKF(), seq, config.replace(speed_scale=True, **changes))
    assert np.isfinite(est.poses).all() and np.isfinite(est.pose_cov).all()
    assert np.isfinite(est.info["speed_scale"])
    assert _pose_nees(est, truth) < 30.0


def test_decoupled_ignores_the_speed_scale():
    seq, config, _ = _drive(frames=40)
    a = run_filter(DecoupledEKF(), seq, config)
    b = run_filter(DecoupledEKF(), seq, config.replace(speed_scale=True))
    np.testing.assert_array_equal(a.poses, b.poses)
    np.testing.assert_array_equal(a.pose_cov, b.pose_cov)


def test_a_model_with_a_speed_scale_turns_the_state_on():
    seq, config, _ = _drive(frames=20)
    base = Model(velocity_sigma=(0.01,) * 3, gyro_sigma=(0.002,) * 3, pixel_sigma=1.0,
                 velocity_pairing="mean", cam_T_imu=seq.calibration.cam_T_imu)
    assert not model_config(FilterConfig(), base).speed_scale
    cfg = model_config(FilterConfig(), base.replace(speed_scale_sigma=0.004, speed_scale_walk=0.001))
    assert (cfg.speed_scale, cfg.speed_scale_sigma, cfg.speed_scale_walk) == (True, 0.004, 0.001)
    text = base.replace(speed_scale_sigma=0.004, speed_scale_walk=0.001).to_toml()
    assert "speed_scale_sigma = 0.004" in text
