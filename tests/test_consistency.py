"""Consistency math: chi-square bounds, verdicts, ANEES, NEES and the smoother cross-check."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from vislam.ekf.estimate import Estimate
from vislam.ekf.geometry import se3_exp, so3_exp
from vislam.eval import consistency as C


def test_chi2_bounds_single_and_many_runs():
    lo, hi = C.chi2_bounds(1, 6)
    assert lo == pytest.approx(1.2373, abs=1e-3) and hi == pytest.approx(14.449, abs=1e-3)
    lo, hi = C.chi2_bounds(50, 3)
    assert (lo, hi) == pytest.approx(tuple(chi2.ppf([0.025, 0.975], 150) / 50))
    assert lo < 3 < hi
    with pytest.raises(ValueError):
        C.chi2_bounds(0, 3)


def test_verdicts():
    b = (2.0, 4.0)
    assert C.verdict(3.0, b) == "inside"
    assert C.verdict(5.0, b) == "above"
    assert C.verdict(1.0, b) == "below"
    assert C.verdict(float("nan"), b) is None


@pytest.mark.parametrize("scale, expected", [(1.0, "inside"), (3.0, "above"), (0.3, "below")])
def test_anees_on_chi_square_draws(scale, expected):
    rng = np.random.default_rng(1)
    nees = scale * rng.chisquare(6, size=(50, 400))  # 50 runs, 400 steps
    res = C.anees(nees, 6)
    assert res.n_runs == 50 and res.per_item.shape == (400,)
    assert res.verdict == expected
    if expected == "inside":
        # 95 % of the per-step averages fall inside their bounds.
        assert 0.9 < res.inside_fraction <= 1.0
    else:
        assert res.inside_fraction < 0.1


def test_anees_skips_items_missing_in_any_run():
    nees = np.full((3, 4), 3.0)
    nees[1, 2] = np.nan
    res = C.anees(nees, 3)
    assert np.isnan(res.per_item[2]) and np.allclose(res.per_item[[0, 1, 3]], 3.0)
    assert res.mean == pytest.approx(3.0)
    assert C.anees(np.full((2, 3), np.nan), 3).verdict is None


def _estimate(T=200, M=20, seed=0):
    rng = np.random.default_rng(seed)
    est = Estimate.empty("ekf-joint", np.arange(T) * 0.1, M)
    xi = np.concatenate([np.cumsum(rng.normal(0, 0.5, (T, 3)), 0), rng.normal(0, 0.3, (T, 3))], 1)
    est.poses = se3_exp(xi)
    A = rng.normal(size=(T, 6, 6)) * 0.1
    est.pose_cov = A @ np.swapaxes(A, 1, 2) + 0.01 * np.eye(6)
    est.landmarks = rng.normal(0, 20, (M, 3))
    B = rng.normal(size=(M, 3, 3))
    est.landmark_cov = B @ np.swapaxes(B, 1, 2) + 0.1 * np.eye(3)
    return est


def test_pose_and_landmark_nees_are_chi_square_for_errors_drawn_from_the_covariance():
    rng = np.random.default_rng(2)
    est = _estimate(T=2000, M=2000)
    L = np.linalg.cholesky(est.pose_cov)
    xi = (L @ rng.standard_normal((est.n_frames, 6, 1)))[..., 0]
    truth = est.poses @ se3_exp(xi)  # right perturbation: true = est exp(xi)
    nees = C.pose_nees(est, np.arange(est.n_frames), truth)
    assert np.isnan(nees[0])  # step 0 is left out
    assert np.nanmean(nees) == pytest.approx(6.0, rel=0.05)
    Lm = np.linalg.cholesky(est.landmark_cov)
    gt = est.landmarks + (Lm @ rng.standard_normal((2000, 3, 1)))[..., 0]
    assert np.nanmean(C.landmark_nees(est, gt)) == pytest.approx(3.0, rel=0.05)


def test_landmark_truth_follows_track_origin():
    est = _estimate(M=3)
    est.info["track_origin"] = [2, 0, 0]
    truth = np.arange(12.0).reshape(4, 3)
    assert np.array_equal(C.landmark_truth_for(est, truth), truth[[2, 0, 0]])
    est.landmarks = truth[[2, 0, 0]] + 1.0
    assert C.landmark_rmse(est, truth) == pytest.approx(np.sqrt(3.0))


def test_versus_smoother_of_identical_estimates_is_zero():
    est = _estimate()
    res = C.versus_smoother(est, est)
    assert res["ate_m"] == pytest.approx(0, abs=1e-9)
    assert res["ate_aligned_m"] == pytest.approx(0, abs=1e-6)
    assert res["map_rmse_m"] == pytest.approx(0, abs=1e-12)
    assert res["nees_pose_mean"] == pytest.approx(0, abs=1e-9)
    assert res["inside_95_fraction"] == 1.0


def test_versus_smoother_matches_landmarks_through_track_origin_and_nulls_when_impossible():
    a, b = _estimate(M=4), _estimate(M=3)
    a.info["track_origin"] = [0, 1, 1, 2]  # track 1 was split: ambiguous, skipped
    b.info["track_origin"] = [0, 1, 2]
    b.landmarks = a.landmarks[[0, 1, 3]] + np.array([0.0, 0.0, 2.0])
    ia, ib = C.match_landmarks(a, b)
    assert ia.tolist() == [0, 3] and ib.tolist() == [0, 2]
    assert C.versus_smoother(a, b)["map_rmse_m"] == pytest.approx(2.0)
    short = _estimate(T=50)
    assert all(v is None for v in C.versus_smoother(short, a).values())
    b.landmarks[:] = np.nan
    assert C.versus_smoother(a, b)["map_rmse_m"] is None


def test_position_deviation_rotates_the_covariance_to_the_world():
    est = Estimate.empty("ekf-joint", np.arange(2.0), 0)
    ref = Estimate.empty("smoother", np.arange(2.0), 0)
    est.poses[1, :3, :3] = so3_exp(np.array([0, 0, np.pi / 2]))
    est.poses[1, :3, 3] = [1.0, 2.0, 3.0]
    est.pose_cov = np.tile(np.diag([1.0, 4.0, 9.0, 1, 1, 1]), (2, 1, 1))
    dev, sigma = C.position_deviation(est, ref)
    assert np.allclose(dev[1], [1, 2, 3])
    assert np.allclose(sigma[0], [1, 2, 3]) and np.allclose(sigma[1], [2, 1, 3])


def test_reference_honesty_sentence():
    from vislam.eval.consistency import POSE_NEES_BAND, reference_honesty

    np.testing.assert_allclose(POSE_NEES_BAND, chi2.ppf([0.025, 0.975], 6), atol=1e-3)
    assert reference_honesty("smoother", 6.0) is None and reference_honesty("smoother", None) is None
    assert reference_honesty("smoother", 97.0) == (
        "The smoother is overconfident on this drive: pose NEES 97, band [1.24, 14.45]; "
        "its covariance is not a fair yardstick here")
    assert "underconfident" in reference_honesty("smoother", 0.5)
