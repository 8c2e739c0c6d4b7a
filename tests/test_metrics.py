"""Trajectory metrics against evo (an independent implementation) and hand-made cases."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from vislam.ekf.errors import InputError
from vislam.ekf.estimate import Estimate
from vislam.ekf.geometry import se3_exp, se3_log, so3_exp
from vislam.eval.metrics import (
    align_trajectory,
    ate_rmse,
    drive_rpe,
    interval_errors,
    kitti_drift,
    nees,
    pose_errors,
    rotation_angle,
    rpe,
    trajectory_metrics,
    turn_scale_error,
    umeyama,
)

from vislam.eval.rpe_segments import (
    drive_segment_lengths,
    length_segments,
    path_distances,
    readable_length,
)

import evo.core.metrics as evo_metrics  # noqa: E402  (evo: the test extra)
import evo.core.trajectory as evo_traj  # noqa: E402


def _random_drive(rng, n=300, dt=0.1, vertical=0.0):
    """A smooth random drive (T, 4, 4) integrated from random body twists; with ``vertical``
    (m/s) a random vertical speed too, so that it climbs and its positions are not planar."""
    u = np.zeros((n - 1, 6))
    u[:, 0] = 8.0 + rng.normal(0, 0.5, n - 1)
    if vertical:
        u[:, 2] = rng.normal(0, vertical, n - 1)
    u[:, 3:] = rng.normal(0, 0.05, (n - 1, 3))
    steps = se3_exp(dt * u)
    poses = np.empty((n, 4, 4))
    poses[0] = np.eye(4)
    for k in range(n - 1):
        poses[k + 1] = poses[k] @ steps[k]
    return poses


def _perturbed(rng, gt, sigma_t=0.3, sigma_r=0.01, drift=True):
    """An estimate: ground truth with a random walk of errors (right perturbations)."""
    noise = np.concatenate(
        [rng.normal(0, sigma_t, (gt.shape[0], 3)), rng.normal(0, sigma_r, (gt.shape[0], 3))], axis=1
    )
    if drift:
        noise = np.cumsum(noise, axis=0) / np.sqrt(gt.shape[0])
    return gt @ se3_exp(noise)


def _evo(poses):
    return evo_traj.PosePath3D(poses_se3=list(poses))


@pytest.fixture(params=[0, 1, 2])
def pair(request):
    rng = np.random.default_rng(request.param)
    gt = _random_drive(rng)
    # Put the estimate in a different frame and scale so alignment has work to do.
    est = _perturbed(rng, gt)
    offset = se3_exp(np.array([3.0, -2.0, 1.0, 0.05, -0.1, 0.3]))
    return est, gt, offset


@pytest.mark.parametrize("align", [None, "se3", "sim3"])
def test_ate_matches_evo(pair, align):
    est, gt, offset = pair
    est = offset @ est
    if align == "sim3":
        est = est.copy()
        est[:, :3, 3] *= 0.8
    ref, traj = _evo(gt), _evo(est)
    if align is not None:
        traj.align(ref, correct_scale=align == "sim3")
    ape = evo_metrics.APE(evo_metrics.PoseRelation.translation_part)
    ape.process_data((ref, traj))
    expected = ape.get_statistic(evo_metrics.StatisticsType.rmse)
    assert ate_rmse(est, gt, align=align) == pytest.approx(expected, abs=1e-6)


@pytest.mark.parametrize("delta", [1, 10, 37])
@pytest.mark.parametrize("all_pairs", [False, True])
def test_rpe_matches_evo(pair, delta, all_pairs):
    est, gt, _ = pair
    ours = rpe(est, gt, delta=delta, all_pairs=all_pairs)
    for relation, key in [
        (evo_metrics.PoseRelation.translation_part, "trans_rmse_m"),
        (evo_metrics.PoseRelation.rotation_angle_deg, "rot_rmse_deg"),
    ]:
        m = evo_metrics.RPE(relation, delta=delta, delta_unit=evo_metrics.Unit.frames,
                            all_pairs=all_pairs)
        m.process_data((_evo(gt), _evo(est)))
        assert ours[key] == pytest.approx(m.get_statistic(evo_metrics.StatisticsType.rmse), abs=1e-6)
        assert ours["n_pairs"] == len(m.error)


def test_rpe_is_invariant_to_a_global_transform(pair):
    est, gt, offset = pair
    a, b = rpe(est, gt, delta=5), rpe(offset @ est, gt, delta=5)
    assert a["trans_rmse_m"] == pytest.approx(b["trans_rmse_m"], rel=1e-9)


def test_interval_errors_recover_a_known_error_per_interval():
    """Each estimated step is the true one times exp(e_k): the interval errors are e_k (the
    inverse of the true step cancels), whatever the drive and the global frame."""
    rng = np.random.default_rng(11)
    gt = _random_drive(rng, n=60)
    e = rng.normal(0, 1e-3, (59, 6)) + np.array([0.0, 0.0, 0.0, 0.0, 0.0, 5e-4])
    est = np.empty_like(gt)
    est[0] = se3_exp(np.array([1.0, 2.0, 3.0, 0.1, -0.2, 0.3]))
    for k in range(59):
        est[k + 1] = est[k] @ (np.linalg.inv(gt[k]) @ gt[k + 1]) @ se3_exp(e[k])
    np.testing.assert_allclose(interval_errors(est, gt), e, atol=1e-12)
    assert interval_errors(est[:1], gt[:1]).shape == (0, 6)


def _scaled_turns(gt, k, noise, rng):
    """An estimate of ``gt`` whose every step turns by (1 + k) times the true turn, with white
    rotation noise ``noise`` (rad) on top; the true interval motions beside it."""
    true = se3_log(np.linalg.inv(gt[:-1]) @ gt[1:])
    step = true.copy()
    step[:, 3:] *= 1.0 + k
    step[:, 3:] += rng.normal(0, noise, step[:, 3:].shape)
    est = np.empty_like(gt)
    est[0] = gt[0]
    for i, xi in enumerate(step):
        est[i + 1] = est[i] @ se3_exp(xi)
    return est, true


def test_turn_scale_error_recovers_a_known_scale_and_its_standard_error():
    rng = np.random.default_rng(12)
    gt = _random_drive(rng, n=400)
    est, true = _scaled_turns(gt, 0.01, 0.0, rng)
    k, sd = turn_scale_error(interval_errors(est, gt), true)
    assert k == pytest.approx(0.01, rel=2e-3)  # exact up to the BCH terms of a 1 % change
    assert sd < 1e-4
    ks, sds = [], []
    for _ in range(200):  # white rotation noise: the standard error is the spread of k
        est, true = _scaled_turns(gt[:80], -0.02, 2e-3, rng)
        k, sd = turn_scale_error(interval_errors(est, gt[:80]), true)
        ks.append(k)
        sds.append(sd)
    assert np.mean(ks) == pytest.approx(-0.02, abs=4 * np.std(ks) / np.sqrt(len(ks)))
    assert np.mean(sds) == pytest.approx(np.std(ks), rel=0.15)


def test_turn_scale_error_is_nan_without_turns():
    gt = np.repeat(np.eye(4)[None], 5, axis=0)
    gt[:, 0, 3] = np.arange(5.0)
    k, sd = turn_scale_error(interval_errors(gt, gt), se3_log(np.linalg.inv(gt[:-1]) @ gt[1:]))
    assert np.isnan(k) and np.isnan(sd)


def test_umeyama_recovers_a_known_transform_exactly():
    rng = np.random.default_rng(5)
    src = rng.normal(0, 10, (50, 3))
    R = so3_exp(np.array([0.3, -1.2, 2.0]))
    t = np.array([4.0, -7.0, 0.5])
    R_hat, t_hat, s_hat = umeyama(src, src @ R.T + t)
    np.testing.assert_allclose(R_hat, R, atol=1e-12)
    np.testing.assert_allclose(t_hat, t, atol=1e-10)
    assert s_hat == 1.0
    R_hat, t_hat, s_hat = umeyama(src, 2.5 * src @ R.T + t, with_scale=True)
    np.testing.assert_allclose(R_hat, R, atol=1e-12)
    np.testing.assert_allclose(t_hat, t, atol=1e-10)
    assert s_hat == pytest.approx(2.5, rel=1e-12)


def test_umeyama_handles_a_reflection_and_rejects_degenerate_points():
    rng = np.random.default_rng(6)
    src = rng.normal(0, 1, (20, 3))
    R, _, _ = umeyama(src, src * np.array([1.0, 1.0, -1.0]))
    assert np.linalg.det(R) == pytest.approx(1.0)
    line = np.outer(np.arange(10.0), [1.0, 2.0, 3.0])
    with pytest.raises(InputError, match="degenerate"):
        umeyama(line, line)
    with pytest.raises(InputError, match="at least 3"):
        umeyama(src[:2], src[:2])


def test_alignment_undoes_a_global_similarity(pair):
    _, gt, offset = pair
    est = offset @ gt
    assert ate_rmse(est, gt) > 1.0
    assert ate_rmse(est, gt, align="se3") < 1e-9
    np.testing.assert_allclose(align_trajectory(est, gt, "se3"), gt, atol=1e-9)
    scaled = est.copy()
    scaled[:, :3, 3] *= 1.7
    assert ate_rmse(scaled, gt, align="se3") > 1.0
    assert ate_rmse(scaled, gt, align="sim3") < 1e-9


def test_rotation_angle_is_accurate_small_and_large():
    for angle in (1e-10, 1e-5, 0.3, np.pi - 1e-6):
        R = so3_exp(angle * np.array([0.6, 0.0, 0.8]))
        assert rotation_angle(R) == pytest.approx(angle, rel=1e-9)


def test_kitti_drift_of_a_one_percent_scale_error():
    # A straight 1 km drive; the estimate travels 1 % further: 1 % drift, no rotation error.
    n = 1001
    gt = np.tile(np.eye(4), (n, 1, 1))
    gt[:, 0, 3] = np.arange(n) * 1.0
    est = gt.copy()
    est[:, 0, 3] *= 1.01
    d = kitti_drift(est, gt)
    assert d["t_rel_pct"] == pytest.approx(1.0, rel=0.02)
    assert d["r_rel_deg_per_100m"] == pytest.approx(0.0, abs=1e-9)
    # Segments start every 10 frames; 100 m needs frames 0..899 as starts (last > first + 100).
    assert d["n_segments"] == sum(len(range(0, n - length - 1, 10)) + 0 for length in range(100, 900, 100))


def _devkit_reference(est, gt, lengths=range(100, 900, 100), step=10):
    """A literal loop port of the KITTI devkit's calcSequenceErrors, for comparison."""
    dist = [0.0]
    for i in range(1, len(gt)):
        dist.append(dist[-1] + float(np.linalg.norm(gt[i, :3, 3] - gt[i - 1, :3, 3])))
    t_errs, r_errs = [], []
    for first in range(0, len(gt), step):
        for length in lengths:
            last = next((i for i in range(first, len(dist)) if dist[i] > dist[first] + length), -1)
            if last == -1:
                continue
            d_gt = np.linalg.inv(gt[first]) @ gt[last]
            d_est = np.linalg.inv(est[first]) @ est[last]
            err = np.linalg.inv(d_est) @ d_gt
            a, b, c = err[0, 0], err[1, 1], err[2, 2]
            r_errs.append(np.arccos(max(min(0.5 * (a + b + c - 1.0), 1.0), -1.0)) / length)
            t_errs.append(np.linalg.norm(err[:3, 3]) / length)
    return 100 * np.mean(t_errs), np.degrees(np.mean(r_errs)) * 100, len(t_errs)


def test_kitti_drift_matches_a_port_of_the_devkit():
    rng = np.random.default_rng(3)
    gt = _random_drive(rng, n=1500)
    est = _perturbed(rng, gt, sigma_t=2.0, sigma_r=0.05)
    t_ref, r_ref, n_ref = _devkit_reference(est, gt)
    d = kitti_drift(est, gt)
    assert d["n_segments"] == n_ref
    assert d["t_rel_pct"] == pytest.approx(t_ref, rel=1e-9)
    assert d["r_rel_deg_per_100m"] == pytest.approx(r_ref, rel=1e-6)
    assert set(d["per_length"]) == set(range(100, 900, 100))
    # A pure scale error of 1 % on a curved drive: 1 % of the chord over the path length.
    scaled = gt.copy()
    scaled[:, :3, 3] *= 1.01
    d = kitti_drift(scaled, gt)
    assert 0.99 < d["t_rel_pct"] <= 1.0
    assert d["t_rel_pct"] == pytest.approx(_devkit_reference(scaled, gt)[0], rel=1e-9)


def test_kitti_drift_of_a_constant_yaw_rate_error():
    # A heading error growing 1 deg per 100 m gives a rotation drift of 1 deg / 100 m.
    n = 1001
    gt = np.tile(np.eye(4), (n, 1, 1))
    gt[:, 0, 3] = np.arange(n) * 1.0
    est = gt.copy()
    est[:, :3, :3] = so3_exp(np.outer(np.radians(np.arange(n) / 100.0), [0, 0, 1.0]))
    d = kitti_drift(est, gt)
    # Segment length L + 1 m (the first frame strictly beyond L): (L + 1) / L deg per 100 m.
    expected = np.mean([(L + 1) / L for L in range(100, 900, 100)
                        for _ in range(0, n - L - 1, 10)])
    assert d["r_rel_deg_per_100m"] == pytest.approx(expected, rel=1e-9)


def test_short_trajectory_gives_none_not_missing():
    rng = np.random.default_rng(4)
    gt = _random_drive(rng, n=50)  # about 40 m
    est = _perturbed(rng, gt)
    d = kitti_drift(est, gt)
    assert d["t_rel_pct"] is None and d["r_rel_deg_per_100m"] is None and d["n_segments"] == 0
    m = trajectory_metrics(est, gt)
    assert m["kitti_t_rel_pct"] is None and m["kitti_n_segments"] == 0
    assert m["rpe10_trans_rmse_m"] is not None
    m2 = trajectory_metrics(est[:5], gt[:5])
    assert m2["rpe10_trans_rmse_m"] is None and m2["rpe10_rot_rmse_deg"] is None
    m3 = trajectory_metrics(est[:2], gt[:2])
    assert m3["ate_se3_rmse_m"] is None and m3["ate_sim3_rmse_m"] is None and m3["sim3_scale"] is None
    assert m3["ate_rmse_m"] is not None
    assert set(m3) == set(m)


def test_trajectory_metrics_with_an_estimate_and_frames(pair):
    est, gt, _ = pair
    e = Estimate.empty("test", np.arange(est.shape[0] + 5) * 0.1, n_tracks=0)
    e.poses[: est.shape[0]] = est
    frames = np.arange(est.shape[0])
    m = trajectory_metrics(e, gt, frames)
    assert m["n_frames"] == gt.shape[0]
    assert m["ate_rmse_m"] == pytest.approx(ate_rmse(est, gt))
    assert m["ate_se3_rmse_m"] <= m["ate_rmse_m"]
    assert m["ate_sim3_rmse_m"] <= m["ate_se3_rmse_m"] + 1e-12
    assert m["rpe1_trans_rmse_m"] == pytest.approx(rpe(est, gt, 1)["trans_rmse_m"])
    assert m["kitti_n_segments"] > 0
    with pytest.raises(InputError, match="poses"):
        trajectory_metrics(e, gt)  # 305 estimated poses against 300 true ones


def test_pose_nees_is_chi_square_6_when_errors_follow_the_covariance():
    rng = np.random.default_rng(8)
    n = 4000
    gt = _random_drive(rng, n=n)
    A = rng.normal(0, 0.1, (6, 6))
    cov = A @ A.T + 1e-3 * np.eye(6)
    xi = rng.multivariate_normal(np.zeros(6), cov, n)
    est = gt @ se3_exp(-xi)  # gt = est @ exp(xi) to first order... exactly: est = gt exp(-xi)
    nees_ = nees(pose_errors(est, gt), np.broadcast_to(cov, (n, 6, 6)))
    lo, hi = chi2.ppf([0.0005, 0.9995], 6 * n) / n
    assert lo < nees_.mean() < hi
    # Exact convention check: est @ exp(xi) == gt gives xi back.
    e = nees(pose_errors(gt[:1] @ se3_exp(-np.array([[0.1, 0, 0, 0, 0, 0]])), gt[:1]),
             np.eye(6)[None] * 0.01)
    assert e[0] == pytest.approx(1.0, rel=1e-12)


def test_nees_nan_where_no_covariance_and_points():
    rng = np.random.default_rng(9)
    gt = rng.normal(0, 10, (100, 3))
    cov = np.broadcast_to(np.diag([0.1, 0.2, 0.3]), (100, 3, 3)).copy()
    est = gt + rng.normal(0, 1, (100, 3)) * np.sqrt([0.1, 0.2, 0.3])
    cov[3] = np.nan
    points = nees(gt - est, cov)
    assert np.isnan(points[3]) and np.isfinite(np.delete(points, 3)).all()
    e = gt[0] - est[0]
    assert points[0] == pytest.approx(e @ np.linalg.solve(cov[0], e))
    with pytest.raises(InputError, match="covariances"):
        nees(gt - est, cov[:5])


# --------------------------------------------------------------------------- drive-fitted RPE


def _straight(path_m: float, n: int) -> np.ndarray:
    """A straight drive along x of ``path_m`` metres over ``n`` evenly spaced poses."""
    gt = np.tile(np.eye(4), (n, 1, 1))
    gt[:, 0, 3] = np.linspace(0.0, path_m, n)
    return gt


@pytest.mark.parametrize("x, rounded", [(4.4, 4.0), (13.7, 10.0), (250.0, 300.0), (0.072, 0.07),
                                        (9.6, 10.0), (1.5, 2.0), (1.49, 1.0), (70.3, 70.0)])
def test_readable_length_keeps_one_significant_figure(x, rounded):
    assert readable_length(x) == rounded


@pytest.mark.parametrize("path_m, n, lengths", [
    (44.0, 441, (4.0, 8.0, 12.0, 16.0, 20.0)),            # the 44 m drive of the issue
    (163.1, 200, (20.0, 40.0, 60.0, 80.0, 100.0)),        # `vislam simulate --frames 200`
    (700.0, 1101, (70.0, 140.0, 210.0, 280.0, 350.0)),    # a KITTI-like drive
    (4541.0, 4541, (500.0, 1000.0, 1500.0, 2000.0, 2500.0)),
    (7.2, 120, (0.7, 1.4, 2.1, 2.8, 3.5)),                # a drone in a room
    (0.72, 100, (0.07, 0.14, 0.21, 0.28, 0.35)),
    (11.6, 14, (5.0,)),                                   # 1..4 m span fewer than 5 frame steps
])
def test_segment_lengths_follow_the_drives_own_path(path_m, n, lengths):
    got, note = drive_segment_lengths(_straight(path_m, n))
    assert got == lengths and note is None
    # The rule in words: a tenth of the path to one significant figure, 1..5 times, each
    # spanning at least 5 frame steps on average; every kept length fits the drive.
    step = readable_length(path_m / 10)
    assert all(L == pytest.approx(k * step) for L, k in zip(reversed(got), range(5, 0, -1)))
    assert all(5 * path_m / (n - 1) <= L < path_m for L in got)


def test_too_short_or_still_drives_have_no_lengths_and_say_why():
    lengths, note = drive_segment_lengths(_straight(4.5, 5))
    assert lengths == () and note.startswith("the drive is too short: 5 frames")
    assert "0.5, 1, 1.5, 2 and 2.5 m" in note and "16 frames" in note
    assert drive_segment_lengths(_straight(3.0, 1))[1] == "only 1 frame with ground truth"
    assert "does not move" in drive_segment_lengths(np.tile(np.eye(4), (50, 1, 1)))[1]
    # From 16 frames on a drive always keeps a length, whatever its path rounds to.
    for n in (16, 17, 30):
        for path_m in np.linspace(0.5, 200.0, 400):
            assert drive_segment_lengths(_straight(path_m, n))[0], (n, path_m)
    d = drive_rpe(_straight(4.5, 5), _straight(4.5, 5))
    assert d["lengths_m"] == [] and d["trans_pct"] is None and d["n_segments"] == 0
    assert d["note"].startswith("the drive is too short")


def test_length_segments_pick_the_closest_end_within_tolerance():
    dist = np.array([0.0, 1.0, 2.0, 2.0, 3.5, 4.0, 5.2, 9.0])
    i, j = length_segments(dist, 2.0)
    # 0 -> 2 (exactly 2 m); 1 -> 3? 3.0 is wanted: 2.0 and 3.5 both miss by more than 0.2 m;
    # 2 and 3 -> 5 (4.0); 4 -> 6 (5.2, 0.3 m short: rejected); 5 -> 6 misses by 0.8.
    assert list(zip(i, j)) == [(0, 2), (2, 5), (3, 5)]
    i, j = length_segments(dist, 2.0, tolerance=0.5)
    assert list(zip(i, j)) == [(0, 2), (1, 4), (2, 5), (3, 5), (4, 6), (5, 6)]
    assert list(length_segments(dist, 100.0)[0]) == []


def test_drive_rpe_of_a_constant_scale_error_is_that_error_in_percent():
    # The estimate travels 2 % too far on a straight 44 m drive: 2 % on every segment of every
    # length (of each segment's own true path), and no rotation error.
    gt = _straight(44.0, 441)
    est = gt.copy()
    est[:, 0, 3] *= 1.02
    d = drive_rpe(est, gt)
    assert d["lengths_m"] == [4.0, 8.0, 12.0, 16.0, 20.0] and d["note"] is None
    assert d["path_length_m"] == pytest.approx(44.0) and d["frames"] == 441
    for stat in ("mean", "median", "rmse"):
        assert d["trans_pct"][stat] == pytest.approx(2.0, rel=1e-9)
        assert d["rot_deg_per_m"][stat] == pytest.approx(0.0, abs=1e-9)
    for e in d["per_length"]:
        L = e["length_m"]
        # Frames 0.1 m apart: every start with L m still ahead (ends exact), and the starts
        # with 0.9 L to L m ahead (the last frame, within the 10 % tolerance).
        assert 441 - 10 * L <= e["n_segments"] <= 441 - 9 * L + 1
        assert e["trans_m"]["median"] == pytest.approx(0.02 * L, rel=1e-9)  # most are L long
        assert e["trans_pct"]["rmse"] == pytest.approx(2.0, rel=1e-9)
    assert d["n_segments"] == sum(e["n_segments"] for e in d["per_length"])


def test_drive_rpe_of_a_pure_rotation_drift_is_that_rate_in_deg_per_m():
    # The heading drifts 0.5 deg per metre travelled, positions exact: 0.5 deg/m on every
    # segment, 0.5 L deg over a segment of L m; the translation error comes from reading the
    # true displacement in the turned frame (by hand below).
    n, rate = 441, 0.5
    gt = _straight(44.0, n)
    dist = path_distances(gt)
    est = gt.copy()
    est[:, :3, :3] = so3_exp(np.outer(np.radians(rate * dist), [0, 0, 1.0]))
    d = drive_rpe(est, gt)
    for e in d["per_length"]:
        L = e["length_m"]
        assert e["rot_deg"]["median"] == pytest.approx(rate * L, rel=1e-6)  # most are L long
        assert e["rot_deg_per_m"]["median"] == pytest.approx(rate, rel=1e-6)
    assert d["rot_deg_per_m"]["mean"] == pytest.approx(rate, rel=1e-6)
    # By hand: a segment of l m from a pose of heading a (the truth's: none) has the true
    # motion [l, 0, 0] and the estimated Rz(-a) [l, 0, 0], so E's translation is
    # Rz(-a) [l, 0, 0] - [l, 0, 0], of norm 2 l sin(a / 2): 200 sin(a / 2) % of l.
    e = d["per_length"][0]
    i, _ = length_segments(dist, e["length_m"])
    by_hand = 200.0 * np.sin(np.radians(rate * dist[i]) / 2)
    assert e["trans_pct"]["mean"] == pytest.approx(np.mean(by_hand), rel=1e-9)
    assert e["trans_pct"]["rmse"] == pytest.approx(np.sqrt(np.mean(by_hand**2)), rel=1e-9)


def test_drive_rpe_matches_evo_all_pairs_in_metres():
    rng = np.random.default_rng(5)
    gt = _random_drive(rng, n=400)  # about 320 m
    est = _perturbed(rng, gt, sigma_t=0.5, sigma_r=0.02)
    d = drive_rpe(est, gt)
    for e in d["per_length"]:
        metric = evo_metrics.RPE(evo_metrics.PoseRelation.translation_part, delta=e["length_m"],
                                 delta_unit=evo_metrics.Unit.meters, rel_delta_tol=0.1,
                                 all_pairs=True, pairs_from_reference=True)
        metric.process_data((_evo(gt), _evo(est)))
        assert len(metric.error) == e["n_segments"]
        assert e["trans_m"]["rmse"] == pytest.approx(metric.get_statistic(
            evo_metrics.StatisticsType.rmse), rel=1e-9)
        assert e["trans_m"]["median"] == pytest.approx(metric.get_statistic(
            evo_metrics.StatisticsType.median), rel=1e-9)


def test_drive_rpe_is_in_trajectory_metrics_and_kitti_drift_is_unchanged(pair):
    est, gt, _ = pair
    m = trajectory_metrics(est, gt)
    d = drive_rpe(est, gt)
    assert m["rpe_drive_trans_pct"] == d["trans_pct"]["mean"]
    assert m["rpe_drive_rot_deg_per_m"] == d["rot_deg_per_m"]["mean"]
    assert m["rpe_drive_n_segments"] == d["n_segments"] > 0
    assert m["kitti_t_rel_pct"] == kitti_drift(est, gt)["t_rel_pct"]


def test_drive_rpe_on_a_room_drive_with_stops_and_loops():
    # A platform circling a 2 m radius in a room for 1,900 frames (16 Hz, 0.5 m/s), standing
    # still for 2 s every 10 s: the path length, not the displacement, picks the lengths;
    # starts inside a stop share their end, and every kept segment is within 10 % of length.
    n, dt, speed = 1900, 1 / 16, 0.5
    moving = (np.arange(n - 1) * dt) % 10.0 < 8.0
    s = np.concatenate([[0.0], np.cumsum(speed * dt * moving)])
    angle = s / 2.0
    gt = np.tile(np.eye(4), (n, 1, 1))
    gt[:, 0, 3], gt[:, 1, 3] = 2.0 * np.cos(angle), 2.0 * np.sin(angle)
    gt[:, :3, :3] = so3_exp(np.outer(angle, [0, 0, 1.0]))
    dist = path_distances(gt)
    lengths, note = drive_segment_lengths(gt)
    assert note is None and lengths == (5.0, 10.0, 15.0, 20.0, 25.0)  # 47.5 m of path
    for L in lengths:
        i, j = length_segments(dist, L)
        assert i.size > 0.8 * (n - L / (speed * dt))
        assert np.all(np.abs(dist[j] - dist[i] - L) <= 0.1 * L + 1e-12) and np.all(j > i)
    # A gyro scale error of 1 % (every turn 1 % too large): about 0.01 rad per rad turned,
    # i.e. 0.01 * (180 / pi) / 2 deg per metre on a 2 m radius (to the 1e-5 by which the
    # path between frames, chords of the circle, is shorter than its arc).
    est = gt.copy()
    est[:, :3, :3] = so3_exp(np.outer(1.01 * angle, [0, 0, 1.0]))
    d = drive_rpe(est, gt)
    assert d["rot_deg_per_m"]["median"] == pytest.approx(0.01 * np.degrees(1.0) / 2.0, rel=1e-4)
