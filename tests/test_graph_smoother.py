"""The GTSAM smoothers on simulated drives: recovery, accuracy against the EKF, marginals,
cheirality and outlier handling, and clear errors."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
import scipy.sparse.linalg

from vislam.ekf.config import FilterConfig
from vislam.ekf.errors import EstimationError, InputError
from vislam.ekf.sequence import Observations, Sequence
from vislam.eval.metrics import ate_rmse
from vislam.eval.simulate import SimConfig, simulate
from vislam.graph.factors import (NoiseModels, build_graph, keep_multi_observed, relative_motions,
                           triangulate_landmarks, usable_rows)
from vislam.graph.isam2 import final_relinearizations, isam2_solve, run_fixed_lag, run_isam2
from vislam.graph.marginals import gtsam_marginals, information_solver, schur_marginals, whitened_system
from vislam.graph.pose_conversions import L, X, estimation_error
from vislam.graph.settings import SmootherSettings
from vislam.graph.smoother import run_smoother, solve_smoother

CONFIG = FilterConfig(clean_tracks=False)  # simulated tracks need no repair


@pytest.fixture(scope="module")
def noise_free():
    return simulate(SimConfig(seed=3, n_frames=120, noise_free=True))


@pytest.fixture(scope="module")
def noisy():
    return simulate(SimConfig(seed=4, n_frames=150))


def test_noise_free_batch_recovers_ground_truth(noise_free):
    est = run_smoother(noise_free.sequence, CONFIG, init="dead-reckoning")
    assert ate_rmse(est.poses, noise_free.poses) < 0.01
    has = est.has_landmark
    assert has.sum() > 100
    np.testing.assert_allclose(est.landmarks[has], noise_free.landmarks[has], atol=0.01)
    assert set(est.info["timing"]) == {"build_s", "initialise_s", "optimise_s", "marginals_s"}
    assert np.all(np.isfinite(est.pose_cov)) and np.all(np.isfinite(est.landmark_cov[has]))
    assert est.info["track_origin"] == list(range(noise_free.sequence.n_tracks))


def test_noise_free_isam2_recovers_ground_truth(noise_free):
    est = run_isam2(noise_free.sequence, CONFIG)
    assert ate_rmse(est.poses, noise_free.poses) < 0.01
    assert np.all(np.isfinite(est.pose_cov))


@pytest.mark.regression
def test_fixed_lag_recovers_ground_truth_and_marginalises(noise_free):
    """A 1 s window on a 12 s noise-free drive: every pose and landmark left the window (and
    was recorded as it left) with a finite, positive definite marginal covariance."""
    seq = noise_free.sequence
    est = run_fixed_lag(seq, CONFIG, settings=SmootherSettings(fixed_lag_s=1.0))
    assert est.estimator == "smoother-fixed-lag" and est.info["fixed_lag_s"] == 1.0
    assert ate_rmse(est.poses, noise_free.poses) < 0.01
    has = est.has_landmark
    assert has.sum() > 100
    np.testing.assert_allclose(est.landmarks[has], noise_free.landmarks[has], atol=0.05)
    assert np.all(np.linalg.eigvalsh(est.pose_cov) > 0)
    assert np.all(np.linalg.eigvalsh(est.landmark_cov[has]) > 0)


@pytest.mark.regression
def test_fixed_lag_longer_than_the_drive_is_isam2(noisy):
    """With a window longer than the drive nothing is marginalised: the fixed-lag smoother
    gives iSAM2's estimate (the same updates, with iSAM2 set to relinearise as the fixed-lag
    smoother does: every 10 updates, no final rounds). Its marginals are iSAM2's Bayes tree's, at the
    linearisation points, where smoother-isam2 re-linearises at the final estimate, so only the
    prior-anchored first pose agrees exactly. A 1.5 s window is a different estimate, not much
    worse on this drive."""
    seq = noisy.sequence
    full = run_isam2(seq, CONFIG, settings=SmootherSettings(isam2_relinearize_skip=10,
                                                            isam2_final_relinearizations=0,
                                                            isam2_wildfire_threshold=0.001))
    long = run_fixed_lag(seq, CONFIG, settings=SmootherSettings(fixed_lag_s=1e4, fixed_lag_relinearize_skip=10))
    np.testing.assert_allclose(long.poses, full.poses, rtol=0, atol=1e-9)
    np.testing.assert_allclose(long.pose_cov[0], full.pose_cov[0], rtol=1e-6, atol=1e-12)
    short = run_fixed_lag(seq, CONFIG, settings=SmootherSettings(fixed_lag_s=1.5))
    assert np.abs(short.poses - full.poses).max() > 1e-4
    assert ate_rmse(short.poses, noisy.poses) < 2 * ate_rmse(full.poses, noisy.poses)
    assert np.all(np.linalg.eigvalsh(short.pose_cov) > 0)


@pytest.mark.parametrize("factorization", ["cholesky", "qr"])
def test_final_relinearizations_are_isam2s_forced_full_updates(noisy, factorization):
    """smoother-isam2's final rounds, solved in batch, are what iSAM2 itself computes with
    ``force_relinearize`` and ``forceFullSolve`` updates and ``calculateBestEstimate``: the
    same factors given to a fresh ISAM2 at a linearisation point away from the solution, whose
    first solution is therefore exact (no stale back-substitution)."""
    from vislam.ekf.runner import prepare_sequence

    settings = SmootherSettings(isam2_factorization=factorization)
    cleaned, _ = prepare_sequence(noisy.sequence, CONFIG)
    result = isam2_solve(cleaned, CONFIG, settings)
    poses = [X(k) for k in range(cleaned.n_frames)]
    points = [L(int(j)) for j in result.tracks]
    theta = gtsam.Values()
    rng = np.random.default_rng(0)
    for key in poses:  # a point the Gauss-Newton steps have work to do from
        theta.insert(key, result.values.atPose3(key).retract(rng.normal(0, 0.01, 6)))
    for key in points:
        theta.insert(key, result.values.atPoint3(key) + rng.normal(0, 0.05, 3))
    params = gtsam.ISAM2Params()
    params.enableRelinearization = False
    params.setFactorization(factorization.upper())
    isam = gtsam.ISAM2(params)
    isam.update(result.factors, theta)
    forced = gtsam.ISAM2UpdateParams()
    forced.force_relinearize = True
    forced.forceFullSolve = True
    for rounds in range(3):
        best = isam.calculateBestEstimate()
        ours = final_relinearizations(result.factors, theta, rounds, factorization)
        for key in poses:
            d = best.atPose3(key).localCoordinates(ours.atPose3(key))
            assert np.abs(d).max() < 1e-7, (rounds, gtsam.Symbol(key).string())
        for key in points:
            assert np.abs(best.atPoint3(key) - ours.atPoint3(key)).max() < 1e-7, \
                (rounds, gtsam.Symbol(key).string())
        isam.update(gtsam.NonlinearFactorGraph(), gtsam.Values(), forced)


def test_rejection_rounds_stop_early_and_the_last_converges(noisy):
    """The rounds before the last stop at ``rejection_relative_error_tol`` (they only find the
    outliers): fewer first-round iterations, nearly the same outliers (a residual within a
    hair of the 4 px test can fall either side: 3 against 6 of 11064 rows here) and, after the
    last round (to ``relative_error_tol``), the solution of every round to that tolerance."""
    seq = noisy.sequence
    tight = solve_smoother(seq, CONFIG, SmootherSettings(rejection_relative_error_tol=1e-5),
                           init="dead-reckoning")
    loose = solve_smoother(seq, CONFIG, SmootherSettings(), init="dead-reckoning")
    assert len(loose.iterations) == len(tight.iterations) == 2
    assert loose.iterations[0] < tight.iterations[0], (loose.iterations, tight.iterations)
    assert abs(loose.n_outliers - tight.n_outliers) <= 1e-3 * len(tight.problem.rows)
    assert abs(loose.errors[-1][1] - tight.errors[-1][1]) <= 2e-3 * tight.errors[-1][1]
    np.testing.assert_allclose(loose.poses, tight.poses, rtol=0, atol=5e-3)
    assert ate_rmse(loose.poses, noisy.poses) < 1.05 * ate_rmse(tight.poses, noisy.poses)


def test_nothing_to_reject_still_ends_at_the_final_tolerance(noisy):
    """No bias to re-estimate and no outlier (threshold 1e6 px): the graph is not rebuilt, but
    the loosely solved first round is continued to ``relative_error_tol``, which a single round
    reaches directly; with one tolerance for every round that first round is the answer."""
    config = CONFIG.replace(gyro_bias=False)
    settings = SmootherSettings(outlier_threshold_px=1e6)
    two = solve_smoother(noisy.sequence, config, settings, init="dead-reckoning")
    one = solve_smoother(noisy.sequence, config, settings.replace(rejection_rounds=0),
                         init="dead-reckoning")
    assert len(two.iterations) == 2 and len(one.iterations) == 1 and two.n_outliers == 0
    assert two.iterations[0] < one.iterations[0]
    assert abs(two.errors[-1][1] - one.errors[-1][1]) <= 1e-4 * one.errors[-1][1]
    np.testing.assert_allclose(two.poses, one.poses, rtol=0, atol=2e-3)
    # with the same tolerance in every round the first solve is already final (as before)
    same = solve_smoother(noisy.sequence, config, settings.replace(rejection_relative_error_tol=1e-5),
                          init="dead-reckoning")
    assert same.iterations == one.iterations and np.array_equal(same.poses, one.poses)

def _row_keys(rows, n_tracks):
    return set((rows.frame.astype(np.int64) * n_tracks + rows.track).tolist())


def test_a_warm_start_is_one_round_tested_at_the_warm_start(noisy):
    """EM's E-steps start from the last solution (``warm_start``): one round, its rows every
    row that passes the outlier test at the warm start (rows rejected before come back where
    the solution explains them; without the test, rows the solution no longer explains would
    stay), and with ``rejection_rounds`` 0 exactly the warm start's rows."""
    from vislam.graph.factors import stereo_residuals, usable_rows

    seq, settings = noisy.sequence, SmootherSettings()
    cold = solve_smoother(seq, CONFIG, settings, init="dead-reckoning")
    assert len(cold.iterations) == 2 and cold.n_outliers > 0
    warm = solve_smoother(seq, CONFIG, settings, warm_start=cold)
    assert len(warm.iterations) == 1
    M = cold.cleaned.n_tracks
    candidates, _ = usable_rows(cold.cleaned, CONFIG.min_disparity)
    residual, depth = stereo_residuals(cold.poses, cold.landmarks, cold.cleaned.calibration, candidates)
    passes = ((np.linalg.norm(residual, axis=1) <= settings.outlier_threshold_px)
              & (depth >= settings.min_depth))
    expected = candidates.subset(passes)
    expected = expected.subset(keep_multi_observed(expected, M))
    assert _row_keys(warm.problem.rows, M) == _row_keys(expected, M)
    assert _row_keys(warm.problem.rows, M) != _row_keys(cold.problem.rows, M)  # the test did something
    # the warm start is next to the minimum: a few iterations, the same solution
    assert warm.iterations[0] <= 3 and warm.errors[0][0] < 1.05 * cold.errors[-1][1]
    assert ate_rmse(warm.poses, cold.poses) < 1e-2
    same_rows = solve_smoother(seq, CONFIG, settings.replace(rejection_rounds=0), warm_start=cold)
    assert _row_keys(same_rows.problem.rows, M) == _row_keys(cold.problem.rows, M)


def test_a_warm_start_under_a_moved_extrinsic_keeps_its_cameras(noisy):
    """An EM step moves the extrinsic (here by 20 mrad and 5 cm): the warm start keeps the
    cameras where vision put them (world_T_cam), so its landmarks project as before,
    the outlier test keeps the rows it keeps under the old extrinsic (started from the old
    body poses instead, the cameras would move and the pixels of every far landmark with them,
    past the test), and LM reaches the minimum a cold start reaches."""
    from vislam.ekf.geometry import se3_exp, se3_inv
    from vislam.ekf.model import with_extrinsic
    from vislam.graph.smoother import warm_start_poses

    seq, settings = noisy.sequence, SmootherSettings()
    cold = solve_smoother(seq, CONFIG, settings, init="dead-reckoning")
    C0 = np.asarray(cold.cleaned.calibration.cam_T_imu)
    C1 = se3_exp(np.array([0.02, -0.01, 0.01, 0.05, 0.0, -0.02])) @ C0
    poses = warm_start_poses(cold, C1)
    # (to 1e-6: the simulator's KITTI rotation is orthonormal to about 1e-7, se3_inv transposes)
    np.testing.assert_allclose(poses @ se3_inv(C1), cold.poses @ se3_inv(C0), rtol=0, atol=1e-6)
    assert warm_start_poses(cold, C0) is cold.poses
    moved = solve_smoother(with_extrinsic(seq, C1), CONFIG, settings, warm_start=cold)
    M = cold.cleaned.n_tracks
    same = solve_smoother(seq, CONFIG, settings, warm_start=cold)  # the extrinsic unmoved
    assert _row_keys(moved.problem.rows, M) == _row_keys(same.problem.rows, M)
    # and it reaches the minimum a cold start under the moved extrinsic reaches
    fresh = solve_smoother(with_extrinsic(seq, C1), CONFIG, settings, initial_poses=cold.poses)
    assert abs(moved.errors[-1][1] - fresh.errors[-1][1]) < 2e-3 * fresh.errors[-1][1]
    assert ate_rmse(moved.poses, fresh.poses) < 1e-2


def test_damping_rules_and_linear_solvers_reach_the_same_solution(noisy):
    """How LM damps and which linear solver it uses change the path, not the answer: each
    ``lm_damping`` and ``linear_solver`` ends within a hair of the defaults (Nielsen's rule,
    sequential Cholesky). Each setting is used: the other damping rule and QR do not
    reproduce the defaults' floating-point result."""
    from vislam.graph.settings import LINEAR_SOLVERS, LM_DAMPING_MODES

    seq = noisy.sequence
    base = solve_smoother(seq, CONFIG, SmootherSettings(), init="dead-reckoning")
    variants = [{"lm_damping": d} for d in LM_DAMPING_MODES if d != "nielsen"]
    variants += [{"linear_solver": s} for s in LINEAR_SOLVERS if s != "sequential-cholesky"]
    for changes in variants:
        other = solve_smoother(seq, CONFIG, SmootherSettings(**changes), init="dead-reckoning")
        np.testing.assert_allclose(other.poses, base.poses, rtol=0, atol=1e-5, err_msg=str(changes))
        assert abs(other.errors[-1][1] - base.errors[-1][1]) <= 1e-6 * base.errors[-1][1], changes
        if changes.get("linear_solver") != "multifrontal-cholesky":  # the same sums, regrouped
            assert other.errors[-1][1] != base.errors[-1][1], f"{changes} has no effect"


@pytest.mark.slow
def test_noisy_smoother_beats_the_ekf(noisy):
    from vislam.ekf.estimators import ESTIMATORS

    ekf = ESTIMATORS["ekf-joint"](noisy.sequence, CONFIG, None)
    est = run_smoother(noisy.sequence, CONFIG, initial=ekf)
    ate_ekf = ate_rmse(ekf.poses, noisy.poses)
    ate_smoother = ate_rmse(est.poses, noisy.poses)
    assert ate_smoother < ate_ekf, (ate_smoother, ate_ekf)
    # the covariance is roughly consistent: mean pose NEES within a loose band of 6
    from vislam.eval.metrics import nees, pose_errors

    values = nees(pose_errors(est.poses, noisy.poses), est.pose_cov)
    assert 1.0 < np.mean(values) < 20.0


def _small_graph(sim):
    seq = sim.sequence
    settings = SmootherSettings()
    deltas, covs = relative_motions(seq, CONFIG)
    rows, _ = usable_rows(seq, 1.0)
    rows = rows.subset(keep_multi_observed(rows, seq.n_tracks))
    landmarks = triangulate_landmarks(sim.poses, seq.calibration, rows, seq.n_tracks)
    noise = NoiseModels.create(seq, CONFIG, settings, covs)
    return build_graph(sim.poses, landmarks, rows, deltas, noise)


def test_schur_marginals_equal_gtsam_marginals():
    sim = simulate(SimConfig(seed=5, n_frames=40))
    problem = _small_graph(sim)
    T, M = sim.sequence.n_frames, sim.sequence.n_tracks
    fast = schur_marginals(problem.graph, problem.values, T, problem.landmark_tracks, M)
    ref = gtsam_marginals(problem.graph, problem.values, T, problem.landmark_tracks, M)
    for a, b in zip(fast, ref):
        assert np.array_equal(np.isfinite(a), np.isfinite(b))
        ok = np.isfinite(b)
        np.testing.assert_allclose(a[ok], b[ok], rtol=1e-6, atol=1e-12 * np.abs(b[ok]).max())


def test_information_solver_solves_the_whole_information_matrix():
    """``information_solver(A, keys, T).solve(B)`` (landmarks eliminated, banded Cholesky) is
    ``(A^T A)^-1 B`` from a sparse LU of the whole matrix, landmark and pose rows alike; a graph
    with another variable is refused."""
    sim = simulate(SimConfig(seed=5, n_frames=40))
    problem = _small_graph(sim)
    T = sim.sequence.n_frames
    system = whitened_system(problem.graph, problem.values, "test")
    H = (system.A.T @ system.A).tocsc()
    B = np.random.default_rng(0).standard_normal((H.shape[0], 7))
    expected = scipy.sparse.linalg.splu(H).solve(B)
    got = information_solver(system.A, system.keys, T).solve(B)
    np.testing.assert_allclose(got, expected, rtol=1e-7, atol=1e-9 * np.abs(expected).max())
    np.testing.assert_allclose(information_solver(system.A, system.keys, T).solve(B[:, 0]),
                               expected[:, 0], rtol=1e-7, atol=1e-9 * np.abs(expected).max())
    n_p = 6 * T  # a right-hand side on the poses only: the pose block of H^-1 is S^-1
    B_p = np.vstack([np.zeros((H.shape[0] - n_p, 7)), B[-n_p:]])
    np.testing.assert_allclose(information_solver(system.A, system.keys, T).pose_solve(B[-n_p:]),
                               scipy.sparse.linalg.splu(H).solve(B_p)[-n_p:], rtol=1e-7,
                               atol=1e-9 * np.abs(expected).max())
    with pytest.raises(EstimationError, match="expected poses and landmarks"):
        information_solver(system.A, system.keys, T - 1)


def test_cheirality_and_outliers_are_removed(noise_free):
    seq = noise_free.sequence
    z = seq.obs.z.copy()
    # one observation of a long track pushed 40 px sideways: an outlier
    lengths = seq.track_lengths()
    j = int(np.argmax(lengths))
    rows = np.flatnonzero(seq.obs.track == j)
    z[rows[len(rows) // 2], [0, 2]] += 40.0
    bad = Sequence(seq.name, seq.timestamps, seq.linear_velocity, seq.angular_velocity,
                   Observations(seq.obs.frame_ptr, seq.obs.track, z), seq.n_tracks, seq.calibration)
    est = run_smoother(bad, CONFIG, init="dead-reckoning")
    assert est.info["n_outliers_removed"] >= 1
    assert ate_rmse(est.poses, noise_free.poses) < 0.01


def test_estimation_error_names_the_landmark():
    """A landmark with only a behind-the-camera stereo factor (zero Jacobian), no prior."""
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorPose3(X(0), gtsam.Pose3(), gtsam.noiseModel.Isotropic.Sigma(6, 0.1)))
    K = gtsam.Cal3_S2Stereo(700, 700, 0, 600, 180, 0.5)
    graph.add(gtsam.GenericStereoFactor3D(gtsam.StereoPoint2(600, 590, 180),
                                          gtsam.noiseModel.Isotropic.Sigma(3, 1.0), X(0), L(12), K))
    values = gtsam.Values()
    values.insert(X(0), gtsam.Pose3())
    values.insert(L(12), np.array([0.0, 0.0, -5.0]))
    with pytest.raises(RuntimeError) as info:
        gtsam.Marginals(graph, values)
    err = estimation_error(info.value, "computing marginal covariances")
    assert isinstance(err, EstimationError)
    assert "landmark l12" in str(err) and "\n" not in str(err)
    with pytest.raises(EstimationError, match="landmark l12"):
        schur_marginals(graph, values, 1, np.array([12]), 13)


def test_bad_input_is_an_input_error(noise_free):
    seq = noise_free.sequence
    v = seq.linear_velocity.copy()
    v[7, 1] = np.nan
    bad = Sequence(seq.name, seq.timestamps, v, seq.angular_velocity, seq.obs, seq.n_tracks,
                   seq.calibration)
    with pytest.raises(InputError, match="linear_velocity.*step 7"):
        run_smoother(bad, CONFIG, init="dead-reckoning")
    with pytest.raises(InputError, match="init"):
        run_smoother(seq, CONFIG, init="magic")


def test_marginals_are_the_gaussian_models_at_the_robust_solution(noisy):
    """The covariances come from the stereo factors without the Huber kernel (graph.factors.
    gaussian_stereo): the same factors and keys, Gaussian noise, so at least the information
    of the robust weights (which are at most 1) and strictly more where a weight is below 1."""
    from vislam.graph.factors import gaussian_stereo
    from vislam.graph.marginals import batch_marginals
    from vislam.graph.smoother import _solve

    seq, cfg, settings = noisy.sequence, FilterConfig(gyro_bias=False), SmootherSettings(gyro_bias="off")
    sol = _solve(seq, cfg, init=None, initial=None, settings=settings, progress=None)
    problem, T, M = sol.problem, sol.cleaned.n_frames, sol.cleaned.n_tracks
    gauss = gaussian_stereo(problem.graph, problem.rows, 1 + len(sol.deltas), sol.noise)
    assert gauss.size() == problem.graph.size()
    robust_cov, _ = batch_marginals(problem.graph, sol.values, T, problem.landmark_tracks, M)
    gauss_cov, _ = batch_marginals(gauss, sol.values, T, problem.landmark_tracks, M)
    est = run_smoother(seq, cfg, settings=settings)
    np.testing.assert_allclose(est.pose_cov, gauss_cov, rtol=1e-6, atol=1e-14)
    tr_g, tr_r = np.trace(gauss_cov[1:], axis1=1, axis2=2), np.trace(robust_cov[1:], axis1=1, axis2=2)
    assert np.all(tr_g <= tr_r * (1 + 1e-9)) and np.mean(tr_g < tr_r * (1 - 1e-3)) > 0.9
    with pytest.raises(ValueError, match="not the stereo factor"):
        gaussian_stereo(problem.graph, problem.rows, 2 + len(sol.deltas), sol.noise)
