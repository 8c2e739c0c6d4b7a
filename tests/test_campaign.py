"""The generalisation campaign's instrument (eval/campaign.py, issue 34 item 5): drives drawn
deterministically with every fault class, the speed-scale fault as documented, and the two
assertions on hand-made figures. The drives themselves run in the regression tier
(tests/regression/test_campaign_drives.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vislam.eval.campaign import (
    ATE_RATIO_MAX,
    EDITIONS,
    FAULT_CLASSES,
    MAX_OBS_PER_FRAME,
    MIN_OBS_PER_FRAME,
    CampaignDrive,
    DriveOutcome,
    EstimatorFigures,
    SpeedScaleFault,
    assess,
    ate_ratio,
    draw_drive,
    sparse_slow_speed_drive,
    summarise,
)
from vislam.eval.consistency import POSE_NEES_BAND
from vislam.eval.simulate import simulate, simulation_stats

SEEDS = range(30)


@pytest.fixture(scope="module")
def drives() -> list[CampaignDrive]:
    return [draw_drive(s, frames=120) for s in SEEDS]


def test_draw_drive_is_deterministic_and_seeds_differ(drives):
    again = [draw_drive(s, frames=120) for s in (0, 7, 29)]
    assert again == [drives[0], drives[7], drives[29]]
    assert len({d.sim for d in drives}) == len(drives)
    assert draw_drive(3, frames=120).sim.n_frames == 120
    assert draw_drive(3).sim.n_frames == 250


def test_every_fault_class_appears_and_is_absent_across_seeds(drives):
    for fault in FAULT_CLASSES:
        having = [d for d in drives if fault in d.faults]
        assert 0 < len(having) < len(drives), fault
    assert {d.edition for d in drives} == set(EDITIONS)
    targets = [d.target_obs_per_frame for d in drives]
    assert min(targets) >= MIN_OBS_PER_FRAME and max(targets) <= MAX_OBS_PER_FRAME
    assert min(targets) < 3.0 and max(targets) > 30.0  # sparse and dense drives both


def test_the_faults_drawn_are_in_the_settings(drives):
    for d in drives:
        s, f = d.sim, set(d.faults)
        assert (d.speed_scale is not None) == ("speed-scale" in f)
        assert (s.velocity_correlation > 0) == ("velocity-correlation" in f)
        assert (s.pixel_correlation > 0) == ("pixel-correlation" in f)
        wrong = s.file_extrinsic_fault != "none" or any(x != 0 for x in s.file_extrinsic_offset)
        assert wrong == ("file-extrinsic" in f)
        assert (s.radial_k1 != 0) == ("lens" in f)
        assert any(b != 0 for b in s.gyro_bias) == ("gyro-bias" in f)
        if d.edition == "noisy":
            assert s.velocity_sigma == (0.5, 0.5, 0.5) and s.gyro_sigma == (0.05, 0.05, 0.05)
        else:
            assert all(0.003 <= x <= 0.05 for x in s.velocity_sigma)
            assert all(0.001 <= x <= 0.02 for x in s.gyro_sigma)
        if d.speed_scale is not None:
            assert 0.002 <= d.speed_scale.amplitude <= 0.02
            assert 10.0 <= d.speed_scale.time_scale_s <= 40.0


def test_observations_per_frame_meet_the_target():
    ratios = []
    for seed in range(8):
        d = draw_drive(seed, frames=120)
        obs = simulation_stats(simulate(d.sim))["obs_per_frame_mean"]
        ratios.append(obs / d.target_obs_per_frame)
    assert 0.8 < np.median(ratios) < 1.25, ratios
    assert all(0.3 < r < 3.0 for r in ratios), ratios


def test_speed_scale_error_has_its_amplitude_and_time_scale():
    fault = SpeedScaleFault(amplitude=0.015, time_scale_s=20.0, seed=5)
    t = np.arange(0.0, 20000.0, 0.1)  # a thousand knots
    s = fault.error(t)
    assert np.max(np.abs(s)) <= 0.015 + 1e-15
    assert np.max(np.abs(s)) > 0.9 * 0.015
    assert 0.4 * 0.015 < s.std() < 0.6 * 0.015  # uniform knots: 0.58 a, less between them

    def rho(lag_s: float) -> float:
        k = int(round(lag_s / 0.1))
        return float(np.corrcoef(s[:-k], s[k:])[0, 1])

    assert rho(2.0) > 0.9  # smooth over a tenth of its time scale
    assert rho(10.0) > 0.3
    assert abs(rho(40.0)) < 0.1  # two knot spacings: independent
    assert abs(rho(100.0)) < 0.1
    assert np.array_equal(fault.error(t[:500]), SpeedScaleFault(0.015, 20.0, 5).error(t[:500]))


def test_speed_scale_fault_scales_the_measured_velocities_only():
    drive = sparse_slow_speed_drive(frames=80)
    clean = simulate(drive.sim)
    faulty = drive.simulate()
    factor = 1.0 + drive.speed_scale.error(clean.sequence.timestamps)
    np.testing.assert_array_equal(faulty.sequence.linear_velocity,
                                  clean.sequence.linear_velocity * factor[:, None])
    np.testing.assert_array_equal(faulty.sequence.angular_velocity, clean.sequence.angular_velocity)
    np.testing.assert_array_equal(faulty.poses, clean.poses)
    np.testing.assert_array_equal(faulty.true_velocities, clean.true_velocities)
    assert faulty.sequence.obs.z.tobytes() == clean.sequence.obs.z.tobytes()
    assert np.max(np.abs(factor - 1.0)) > 0.001


def test_sparse_slow_speed_drive_is_sparse():
    d = sparse_slow_speed_drive()
    obs = simulation_stats(d.simulate())["obs_per_frame_mean"]
    assert 1.5 < obs < 4.5
    assert d.speed_scale.amplitude == 0.016 and d.faults == ("speed-scale",)


# --- the assertions on hand-made figures -------------------------------------------------------


def _figures(dr=(1.0, 5.0), joint=(0.5, 6.0), inv=(0.5, 6.0), sm=(0.4, 5.0)):
    return {name: EstimatorFigures(ate, 1.0, nees) if not isinstance(ate, str)
            else EstimatorFigures(None, None, None, ate)
            for name, (ate, nees) in (("dead-reckoning", dr), ("ekf-joint", joint),
                                      ("ekf-invariant", inv), ("smoother", sm))}


def _verdicts(figures) -> tuple[bool, bool]:
    ate, nees = assess(figures)
    assert (ate.name, nees.name) == ("ate", "nees")
    return ate.ok, nees.ok


def test_assess_passes_a_good_drive():
    assert _verdicts(_figures()) == (True, True)


@pytest.mark.parametrize("who", ["ekf-joint", "ekf-invariant", "smoother"])
def test_a_slam_estimator_over_1_1x_dead_reckoning_fails_the_ate_assertion(who):
    keys = {"ekf-joint": "joint", "ekf-invariant": "inv", "smoother": "sm"}
    assert _verdicts(_figures(**{keys[who]: (1.11, 6.0)})) == (False, True)
    assert _verdicts(_figures(**{keys[who]: (ATE_RATIO_MAX * 1.0, 6.0)})) == (True, True)
    ate, _ = assess(_figures(**{keys[who]: (1.7, 6.0)}))
    assert any(who in line and "1.70x" in line and "fails" in line for line in ate.detail)


def test_nees_outside_the_band_fails_for_dead_reckoning_and_the_smoother_only():
    lo, hi = POSE_NEES_BAND
    assert _verdicts(_figures(dr=(1.0, hi * 1.01))) == (True, False)
    assert _verdicts(_figures(dr=(1.0, lo * 0.99))) == (True, False)
    assert _verdicts(_figures(sm=(0.4, 2000.0))) == (True, False)
    assert _verdicts(_figures(dr=(1.0, hi), sm=(0.4, lo))) == (True, True)
    assert _verdicts(_figures(joint=(0.5, 1000.0), inv=(0.5, 0.1))) == (True, True)
    _, nees = assess(_figures(sm=(0.4, 2063.0)))
    assert any("smoother" in line and "2.06e+03" in line and "overconfident" in line
               for line in nees.detail)


def test_a_failed_estimator_or_a_missing_figure_fails():
    assert _verdicts(_figures(sm=("diverged", None))) == (False, False)
    assert _verdicts(_figures(dr=("diverged", None))) == (False, False)
    assert _verdicts(_figures(joint=("diverged", None))) == (False, True)
    figs = _figures()
    del figs["ekf-invariant"]
    assert _verdicts(figs) == (False, True)
    figs = _figures()
    figs["smoother"] = EstimatorFigures(0.4, None, None)
    assert _verdicts(figs) == (True, False)
    assert _verdicts(_figures(dr=(1.0, float("nan")))) == (True, False)


def test_ate_ratio_and_summary():
    figs = _figures(joint=(1.5, 6.0))
    assert ate_ratio(figs) == pytest.approx(1.5)
    assert ate_ratio(_figures(sm=("diverged", None))) == math.inf
    drive = sparse_slow_speed_drive(frames=20)
    good = DriveOutcome(drive, 3.0, _figures(), assess(_figures()))
    bad = DriveOutcome(drive, 3.0, figs, assess(figs))
    worse = DriveOutcome(drive, 3.0, _figures(sm=(0.4, 144.49)), assess(_figures(sm=(0.4, 144.49))))
    assert good.ok and not bad.ok and not worse.ok
    assert good.worst_nees == 1.0 and worse.worst_nees == pytest.approx(10.0)
    summary = summarise([good, bad, worse])
    assert summary.passed == {"ate": 2, "nees": 2, "both": 1}
    assert summary.rate("both") == pytest.approx(1 / 3)
