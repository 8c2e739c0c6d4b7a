"""The batch smoother: Levenberg-Marquardt over the whole drive (the reference for the EKF).

Steps, each timed (``est.info["timing"]``):

1. *initialise*: a trajectory (the EKF's estimate by default, dead reckoning or iSAM2 on
   request; LM from dead reckoning converges badly on long real drives), landmarks triangulated
   from each track's largest-disparity observation, and tracks behind any of their cameras
   dropped (GTSAM's stereo factor fails silently there: constant residual, zero Jacobian).
2. *build* the graph (:mod:`graph.factors`). On intervals no track spans (a tracker's
   repeat events) a twist-smoothness prior (:mod:`graph.twist_smoothness`) predicts the
   motion from the two neighbouring intervals, with a sigma measured on the drive itself. A
   constant gyro bias (:mod:`graph.gyro_bias`) is estimated from the initial trajectory and
   removed from every motion factor (``settings.gyro_bias="alternate"``; not when
   ``config.gyro_bias`` is False, as for the EKFs), or estimated jointly
   as a graph variable (``"joint"``, slower). With ``config.speed_scale`` the motion factors
   carry a slowly varying speed scale of the linear velocities (:mod:`graph.speed_scale`: one
   variable per interval, a random walk), estimated jointly with the poses; the alternating
   bias step then reads the motions at the current scale.
3. *optimise* with LM; then re-estimate the bias (and the smoothness sigma, relinearising the
   prior) from the solution, remove stereo factors whose residual exceeds
   ``settings.outlier_threshold_px`` (or whose point went behind the camera), and solve again.
4. *marginals*: pose and landmark covariances (conditional on the estimated bias; the speed
   scales' uncertainty included: they stay in the graph), converted to the Estimate convention.
   The scale estimate and its sigma are in ``est.info["speed_scale"]`` (only with
   ``config.speed_scale``).

Accuracy and timing on real drives: docs/findings.md and benchmarks/smoother_timing.py.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass
from typing import Callable

import gtsam
import numpy as np

from vislam.ekf.config import FilterConfig
from vislam.ekf.conventions import estimate_cov_to_gtsam
from vislam.ekf.errors import EstimationError, InputError
from vislam.ekf.estimate import Estimate
from vislam.ekf.geometry import se3_inv
from vislam.ekf.sequence import Sequence
from vislam.ekf.estimators import SMOOTHER_INITIALISERS
from vislam.graph.factors import (
    GraphProblem,
    NoiseModels,
    StereoRows,
    TwistSmoothness,
    build_graph,
    cheirality_ok,
    dead_reckoning,
    fix_bias,
    gaussian_stereo,
    interval_twists,
    keep_multi_observed,
    landmarks_from_values,
    poses_from_values,
    relative_motions,
    stereo_residuals,
    triangulate_landmarks,
    unconstrained_intervals,
    usable_rows,
)
from vislam.graph.gyro_bias import (BIAS_KEY, GyroBiasModel, bias_corrections, corrected_deltas,
                                    estimate_bias)
from vislam.graph.speed_scale import S, SpeedScaleModel, scale_values
from vislam.ekf.numerics import NumericalGuard
from vislam.ekf.runner import finish_estimate, prepare_sequence
from vislam.graph.memory import release_freed_memory
from vislam.graph.marginals import batch_marginals, linearise
from vislam.graph.pose_conversions import estimation_error, named_error
from vislam.graph.settings import INITIALISERS, LINEAR_SOLVERS, SmootherSettings
from vislam.graph.twist_smoothness import smoothness_sigma

log = logging.getLogger(__name__)

#: The EKF variants tried, in order, for the default initialisation (named in ekf.estimators).
EKF_INITIALISERS = SMOOTHER_INITIALISERS

Progress = Callable[[int, int], None]


def ekf_trajectory(seq: Sequence, config: FilterConfig) -> tuple[np.ndarray | None, str]:
    """Poses from the best EKF available (``ekf.estimators.ESTIMATORS``), or None.

    An EKF that fails (EstimationError) is logged and the next one tried."""
    from vislam.ekf.estimators import ESTIMATORS

    failed = []
    for name in EKF_INITIALISERS:
        if name in ESTIMATORS:
            try:
                est = ESTIMATORS[name](seq, config, None)
            except EstimationError as exc:
                log.warning("smoother: cannot initialise from %s: %s", name, exc)
                failed.append(name)
                continue
            return np.asarray(est.poses, dtype=float), name
    if failed:
        return None, f"{', '.join(failed)} failed"
    return None, f"none of {EKF_INITIALISERS} registered"


def initial_trajectory(seq: Sequence, cleaned: Sequence, config: FilterConfig, init: str,
                       initial: Estimate | None, settings: SmootherSettings) -> tuple[np.ndarray, str]:
    """The trajectory LM starts from and a word on where it came from; ``initial`` (an EKF
    estimate already computed) is used only when ``init`` is ``"ekf"``."""
    if init not in INITIALISERS:
        raise InputError(f"smoother init must be one of {INITIALISERS}, got {init!r}")
    if initial is not None and init == "ekf":
        poses = np.asarray(initial.poses, dtype=float)
        if poses.shape != (seq.n_frames, 4, 4) or not np.all(np.isfinite(poses)):
            raise InputError(
                f"initial estimate: poses must be finite with shape ({seq.n_frames}, 4, 4), "
                f"got {poses.shape}")
        return poses, f"given ({initial.estimator})"
    if init == "ekf":
        poses, source = ekf_trajectory(seq, config)
        if poses is not None:
            return poses, source
        log.warning("smoother: no EKF to initialise from (%s); using dead reckoning", source)
        return _finite_dead_reckoning(cleaned, config), "dead-reckoning (EKF unavailable)"
    if init == "isam2":
        from vislam.graph.isam2 import isam2_solve

        return isam2_solve(cleaned, config, settings, source=seq).poses, "isam2"
    return _finite_dead_reckoning(cleaned, config), "dead-reckoning"


def _finite_dead_reckoning(seq: Sequence, config: FilterConfig) -> np.ndarray:
    """:func:`graph.factors.dead_reckoning`, or EstimationError at the first non-finite pose."""
    with np.errstate(all="ignore"):
        poses = dead_reckoning(seq, config)
    bad = np.flatnonzero(~np.isfinite(poses.reshape(len(poses), -1)).all(axis=1))
    if bad.size:
        t = int(bad[0])
        raise EstimationError(f"smoother: frame {t} (t={seq.timestamps[t]:.2f} s): "
                              "dead-reckoned initial pose not finite")
    return poses


def _levenberg_marquardt(problem: GraphProblem, settings: SmootherSettings,
                         relative_tol: float | None = None) -> tuple[gtsam.Values, int, float, float]:
    """LM on ``problem`` to ``relative_tol`` (default ``settings.relative_error_tol``): the
    solution, iterations, initial and final error."""
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(int(settings.max_iterations))
    params.setRelativeErrorTol(settings.relative_error_tol if relative_tol is None else relative_tol)
    params.setAbsoluteErrorTol(settings.absolute_error_tol)
    params.setUseFixedLambdaFactor(settings.lm_damping == "fixed")
    params.setLinearSolverType(LINEAR_SOLVERS[settings.linear_solver])
    try:
        # COLAMD once: without an ordering GTSAM's LM orders the damped linear system again at
        # every trial step (14 % of an iteration on a 1,224-frame drive), and the structure
        # never changes during a solve; the ordering is the same, so are the iterates.
        ordering = gtsam.Ordering.ColamdNonlinearFactorGraph(problem.graph)
    except RuntimeError as exc:
        raise estimation_error(exc, "optimising") from None
    if problem.scale is not None or problem.values.exists(BIAS_KEY):
        # Python factors (speed scale, joint gyro bias): the loop that hands them Python-owned values
        return _python_values_lm(problem, settings, params, ordering)
    try:
        params.setOrdering(ordering)
        optimizer = gtsam.LevenbergMarquardtOptimizer(problem.graph, problem.values, params)
        initial_error = optimizer.error()  # the graph's error at the values, as LM keeps it
        result = _optimize(optimizer, params)
        final_error = optimizer.error()
    except RuntimeError as exc:
        raise estimation_error(exc, "optimising") from None
    if not np.isfinite(final_error):
        raise EstimationError("smoother failed while optimising: the error is not finite "
                              "(a non-finite measurement or initial value)")
    return result, int(optimizer.iterations()), float(initial_error), final_error


def _python_values_lm(problem: GraphProblem, settings: SmootherSettings,
                      params: gtsam.LevenbergMarquardtParams,
                      ordering: gtsam.Ordering) -> tuple[gtsam.Values, int, float, float]:
    """:func:`_levenberg_marquardt` for a graph with one Python ``CustomFactor`` per interval
    (the speed scale, :mod:`graph.speed_scale`; the joint gyro bias, :mod:`graph.gyro_bias`): GTSAM's LM hands each Python factor a copy of
    its whole ``Values`` at every evaluation (pybind11 copies a C++-owned argument), so an
    iteration costs (intervals x variables): 4-5 s on a 1,224-frame KITTI drive against 0.3 s
    here, where the graph is linearised and evaluated at Python-owned values (passed by
    reference). The steps are GTSAM's LM's (``LevenbergMarquardtOptimizer::tryLambda``): the
    linearisation damped by ``lambda I`` on every variable (Nielsen's rule or a fixed factor,
    ``settings.lm_damping``; GTSAM's default lambda bounds and model-fidelity threshold), the
    same stopping rule (``gtsam.checkConvergence``), eliminating in ``ordering`` (COLAMD's, as
    for GTSAM's LM)."""
    graph = problem.graph
    solver = settings.linear_solver
    lam, lam_max, factor = params.getlambdaInitial(), params.getlambdaUpperBound(), params.getlambdaFactor()
    fixed = settings.lm_damping == "fixed"
    try:
        values = gtsam.Values(problem.values)
        error = graph.error(values)
        initial_error = error
        zero = values.zeroVectors()  # each variable's dimension
        dims = {int(k): zero.at(k).size for k in values.keys()}
        iterations = 0
        while iterations < params.getMaxIterations() and np.isfinite(error) and error > params.getErrorTol():
            linear = graph.linearize(values)
            new_values, new_error = None, error
            while lam < lam_max:
                damped = linear.clone()
                root = float(np.sqrt(lam))
                for key, d in dims.items():
                    damped.add(gtsam.JacobianFactor(key, root * np.eye(d), np.zeros(d),
                                                    gtsam.noiseModel.Unit.Create(d)))
                try:
                    delta = (damped.optimize(ordering) if solver.startswith("multifrontal")
                             else damped.eliminateSequential(ordering).optimize())
                except RuntimeError:  # indeterminate: more damping
                    delta = None
                if delta is not None:
                    old_linear = linear.error(gtsam.VectorValues.Zero(delta))  # not `error`: robust kernels
                    model_change = old_linear - linear.error(delta)
                    if model_change >= 0.0:
                        trial = values.retract(delta)
                        trial_error = graph.error(trial)
                        change = error - trial_error
                        measured = model_change > np.finfo(float).eps * old_linear
                        fidelity = change / model_change if measured else 0.0
                        if (fidelity > 1e-3 or not measured) and np.isfinite(trial_error):
                            new_values, new_error = trial, trial_error
                            if fixed:
                                lam /= factor
                            else:
                                lam *= max(1.0 / 3.0, 1.0 - (2.0 * fidelity - 1.0) ** 3)
                                factor = 2.0
                            lam = max(lam, params.getlambdaLowerBound())
                            break
                        if abs(change) < params.getRelativeErrorTol() * error:
                            break  # too small a change to try more damping (GTSAM's rule)
                lam *= factor
                if not fixed:
                    factor *= 2.0
            iterations += 1
            if new_values is None:  # no step decreased the error: converged or stuck
                break
            converged = gtsam.checkConvergence(params, error, new_error)
            values, error = new_values, new_error
            if converged:
                break
    except RuntimeError as exc:
        raise estimation_error(exc, "optimising") from None
    if not np.isfinite(error):
        raise EstimationError("smoother failed while optimising: the error is not finite "
                              "(a non-finite measurement or initial value)")
    return values, iterations, float(initial_error), float(error)


def _optimize(optimizer: gtsam.LevenbergMarquardtOptimizer,
              params: gtsam.LevenbergMarquardtParams) -> gtsam.Values:
    """GTSAM's ``NonlinearOptimizer::defaultOptimize`` loop, one ``iterate()`` per Python step:
    the same iterates and stopping rule as ``optimize()``, but Ctrl-C and SIGTERM are acted on
    after the current iteration instead of after the whole solve (seconds on a real drive)."""
    if optimizer.error() <= params.getErrorTol():
        return optimizer.values()
    while True:
        current = optimizer.error()
        optimizer.iterate()
        new = optimizer.error()
        if (optimizer.iterations() >= params.getMaxIterations()
                or gtsam.checkConvergence(params, current, new) or not np.isfinite(current)):
            return optimizer.values()


def _inliers(poses: np.ndarray, landmarks: np.ndarray, calib, rows: StereoRows,
             settings: SmootherSettings, n_tracks: int) -> np.ndarray:
    """Boolean (N,): the row's stereo residual is within ``outlier_threshold_px``, its depth at
    least ``min_depth``, and its track keeps at least two such rows (the outlier test)."""
    residual, depth = stereo_residuals(poses, landmarks, calib, rows)
    good = (np.linalg.norm(residual, axis=1) <= settings.outlier_threshold_px) & (depth >= settings.min_depth)
    keep = np.zeros(len(rows), dtype=bool)
    keep[np.flatnonzero(good)[keep_multi_observed(rows.subset(good), n_tracks)]] = True
    return keep


def _twist_smoothness(poses: np.ndarray, tau: np.ndarray, gaps: np.ndarray,
                      exact: bool = False) -> TwistSmoothness | None:
    """The twist-smoothness prior for the gap intervals, its sigma measured on ``poses``
    (None when there is no gap or too little to measure it on)."""
    if not np.any(gaps):
        return None
    sigma = smoothness_sigma(poses, tau, gaps)
    if sigma is None:
        return None
    log.info("smoother: twist-smoothness prior on %d gap intervals, sigma %s (rad/s, m/s)",
             int(gaps.sum()), np.array2string(sigma, precision=4))
    return TwistSmoothness(gaps, tau, sigma, exact)


def run_smoother(
    seq: Sequence,
    config: FilterConfig = FilterConfig(),
    *,
    init: str | None = None,
    initial: Estimate | None = None,
    settings: SmootherSettings = SmootherSettings(),
    progress: Progress | None = None,
) -> Estimate:
    """Batch Levenberg-Marquardt smoother over the whole sequence (estimator ``smoother``).

    ``init``: ``"ekf"`` (falls back to dead reckoning with a warning when no EKF is registered
    or every EKF fails with an EstimationError),
    ``"dead-reckoning"`` or ``"isam2"``; None takes ``settings.init`` (default ``"ekf"``).
    ``initial`` an EKF estimate to start from instead of running the EKF again (used only when
    the initialisation is ``"ekf"``). ``progress(done, total)`` is called after each stage (4 in all).
    Landmarks are indexed by the tracks of the cleaned sequence (``info["track_origin"]`` maps
    them to the source file's columns). Every EstimationError it raises names ``smoother``.
    """
    try:
        return _run_smoother(seq, config, init=init, initial=initial, settings=settings,
                             progress=progress)
    except EstimationError as exc:  # shared parts name only what failed: add the estimator
        raise named_error(exc, "smoother") from None


@dataclass
class SmootherSolution:
    """A solved batch graph and what its factors stand for (the smoother's Estimate is built
    from it; :mod:`graph.identification` reads its residuals and posterior)."""

    cleaned: Sequence
    cleaning: dict
    problem: GraphProblem
    values: gtsam.Values
    poses: np.ndarray  # (T, 4, 4)
    landmarks: np.ndarray  # (n_tracks, 3), NaN where no landmark
    deltas: np.ndarray  # (T-1, 4, 4) the measured motions the factors use (bias removed)
    twist: np.ndarray  # (T-1, 6) the interval twists (pairing applied, bias not removed)
    tau: np.ndarray  # (T-1,)
    noise: NoiseModels
    pose_prior_cov: np.ndarray  # (6, 6) GTSAM order
    n_smoothness: int  # twist-smoothness factors in the graph
    gyro_bias: np.ndarray | None  # (3,) the bias removed or estimated
    bias_model: GyroBiasModel | None  # the joint bias variable's model ("joint"), else None
    rejected: np.ndarray
    source: str
    timing: dict
    iterations: list
    errors: list
    n_outliers: int
    n_cheirality: int
    #: The speed-scale variables' model (``config.speed_scale``), else None, and their
    #: estimates per interval (T-1,); ``deltas`` are then the motions at these scales.
    scale_model: SpeedScaleModel | None = None
    speed_scale: np.ndarray | None = None
    #: (WhitenedSystem, LandmarksEliminated) at ``values``, once computed (:meth:`linearised`)
    _linearised: tuple | None = dataclasses.field(default=None, repr=False, compare=False)

    @property
    def calibration(self):
        return self.cleaned.calibration

    def linearised(self):
        """GTSAM's linearisation of the graph at the solution and its information matrix with
        the landmarks eliminated (:func:`graph.marginals.linearise`), computed once: EM's
        E-step, the extrinsic step and the motion-correlation blocks read the same one."""
        if self._linearised is None:
            self._linearised = linearise(self.problem.graph, self.values, self.poses.shape[0],
                                         "linearising the smoother's solution")
        return self._linearised


def solve_smoother(seq: Sequence, config: FilterConfig = FilterConfig(),
                   settings: SmootherSettings = SmootherSettings(), *,
                   initial_poses: np.ndarray | None = None, init: str | None = None,
                   initial: Estimate | None = None,
                   warm_start: "SmootherSolution | None" = None,
                   progress: Progress | None = None) -> SmootherSolution:
    """Build and solve the batch graph (steps 1-3 of the module docstring) without the
    marginals. ``initial_poses`` (T, 4, 4), when given, is the starting trajectory.
    ``warm_start``, a solution of the same drive under a nearby model (the previous EM
    iteration's), gives the starting poses and landmarks: LM starts next to its minimum
    instead of re-fighting the outliers. The outlier test looks at every row at the warm
    start (so a row rejected before can come back) and one round is solved: the warm start
    is the solution a first round would reach, so its test is the one that round would make
    (the alternating bias step is taken there too). With ``rejection_rounds`` 0 the rows are
    the warm start's, untested."""
    if warm_start is not None:
        initial_poses = warm_start_poses(warm_start, seq.calibration.cam_T_imu)
    try:
        return _solve(seq, config, init=init, initial=initial, settings=settings,
                      progress=progress, initial_poses=initial_poses, warm_start=warm_start)
    except EstimationError as exc:
        raise named_error(exc, "smoother") from None


def warm_start_poses(warm_start: "SmootherSolution", cam_T_imu: np.ndarray) -> np.ndarray:
    """The starting poses ``world_T_imu`` (T, 4, 4) that a warm start gives a drive whose
    extrinsic is ``cam_T_imu``: its cameras ``world_T_cam`` kept where vision put them
    (``world_T_imu = world_T_cam cam_T_imu``), so that its landmarks project as they did; under
    the warm start's own extrinsic, its poses. An EM step that moves the extrinsic by several
    sigmas would otherwise start LM at thousands of times the minimum's error and the outlier
    test at pixels shifted by the move."""
    before = np.asarray(warm_start.cleaned.calibration.cam_T_imu, dtype=float)
    now = np.asarray(cam_T_imu, dtype=float)
    if np.array_equal(before, now):
        return warm_start.poses
    return warm_start.poses @ (se3_inv(before) @ now)


def _solve(
    seq: Sequence,
    config: FilterConfig,
    *,
    init: str | None,
    initial: Estimate | None,
    settings: SmootherSettings,
    progress: Progress | None,
    initial_poses: np.ndarray | None = None,
    warm_start: SmootherSolution | None = None,
) -> SmootherSolution:
    timing = {"build_s": 0.0, "initialise_s": 0.0, "optimise_s": 0.0, "marginals_s": 0.0}
    report = progress or (lambda done, total: None)
    start = time.perf_counter()

    init = settings.init if init is None else init
    cleaned, cleaning = prepare_sequence(seq, config)
    T, M, calib = cleaned.n_frames, cleaned.n_tracks, cleaned.calibration
    deltas, motion_covs = relative_motions(cleaned, config)
    rows, rejected_disparity = usable_rows(cleaned, config.min_disparity)
    rejected = rejected_disparity.astype(np.int64)
    tick = time.perf_counter()
    timing["build_s"] += tick - start

    if initial_poses is not None:
        poses0, source = np.asarray(initial_poses, dtype=float), "given poses"
        if poses0.shape != (T, 4, 4) or not np.all(np.isfinite(poses0)):
            raise InputError(f"initial poses must be finite with shape ({T}, 4, 4), "
                             f"got {poses0.shape}")
    else:
        poses0, source = initial_trajectory(seq, cleaned, config, init, initial, settings)
    multi = keep_multi_observed(rows, M)
    rejected += np.bincount(rows.frame[~multi], minlength=T)
    rows = rows.subset(multi)
    landmarks0 = triangulate_landmarks(poses0, calib, rows, M)
    if warm_start is not None:
        if warm_start.landmarks.shape != (M, 3):
            raise InputError(f"warm start: landmarks must have shape ({M}, 3), got "
                             f"{warm_start.landmarks.shape}")
        known = np.all(np.isfinite(warm_start.landmarks), axis=1)
        landmarks0[known] = warm_start.landmarks[known]
    in_front = cheirality_ok(poses0, landmarks0, calib, rows, M, settings.min_depth)
    n_cheirality = int(np.sum(~in_front & (np.bincount(rows.track, minlength=M) > 0)))
    keep = in_front[rows.track]
    rejected += np.bincount(rows.frame[~keep], minlength=T)
    rows = rows.subset(keep)
    n_outliers = 0
    one_round = warm_start is not None and settings.rejection_rounds > 0
    if one_round:  # the outlier test a first round would make, made at the warm start
        inlier = _inliers(poses0, landmarks0, calib, rows, settings, M)
        n_outliers += int(np.sum(~inlier))
        rejected += np.bincount(rows.frame[~inlier], minlength=T)
        rows = rows.subset(inlier)
    elif warm_start is not None:  # no outlier round: the warm start's rows, as they were
        before = warm_start.problem.rows
        kept = np.isin(rows.frame.astype(np.int64) * M + rows.track,
                       before.frame.astype(np.int64) * M + before.track)
        rows = rows.subset(kept)
        rows = rows.subset(keep_multi_observed(rows, M))
    timing["initialise_s"] += time.perf_counter() - tick
    report(1, 4)

    tick = time.perf_counter()
    noise = NoiseModels.create(cleaned, config, settings, motion_covs)
    smoothness = None
    if settings.gap_twist_prior != "off":
        smoothness = _twist_smoothness(poses0, cleaned.dt, unconstrained_intervals(rows, T),
                                       settings.gap_twist_prior == "exact")
    bias = None  # the joint bias variable ("joint")
    b_hat = None  # the bias the motion factors are corrected for ("alternate")
    motion = deltas
    # config.gyro_bias=False (a model saying the data has none, --no-gyro-bias): none here
    # either, as in the EKFs.
    twist, tau = interval_twists(cleaned, config.velocity_pairing)
    scale = None  # the speed-scale variables (config.speed_scale)
    if config.speed_scale:
        scale = SpeedScaleModel.create(twist, tau, config.speed_scale_sigma, config.speed_scale_walk)
    if settings.gyro_bias != "off" and config.gyro_bias:
        model = GyroBiasModel.create(twist, tau, config.gyro_bias_sigma)
        if settings.gyro_bias == "joint":
            bias = model
        else:
            b_hat = estimate_bias(poses0, deltas, model.D, motion_covs, config.gyro_bias_sigma)
            motion = corrected_deltas(deltas, model.D, b_hat)
            if scale is not None:
                scale.corrections = bias_corrections(model.D, b_hat)
    problem = build_graph(poses0, landmarks0, rows, motion, noise, bias, smoothness, scale)
    timing["build_s"] += time.perf_counter() - tick

    iterations: list[int] = []
    errors: list[tuple[float, float]] = []
    # The rounds before the last only find the outliers: a looser stopping rule there.
    rejection_tol = max(settings.relative_error_tol, settings.rejection_relative_error_tol)
    last_round = 0 if one_round else int(settings.rejection_rounds)
    for round_ in range(last_round + 1):
        tick = time.perf_counter()
        values, n_iter, e0, e1 = _levenberg_marquardt(
            problem, settings, settings.relative_error_tol if round_ == last_round else rejection_tol)
        iterations.append(n_iter)
        errors.append((e0, e1))
        timing["optimise_s"] += time.perf_counter() - tick
        log.info("smoother round %d: %d iterations, error %.4g -> %.4g", round_, n_iter, e0, e1)
        if round_ == last_round:
            break
        tick = time.perf_counter()
        poses = poses_from_values(values, T)
        landmarks = landmarks_from_values(values, problem.landmark_tracks, M)
        final_keep = _inliers(poses, landmarks, calib, rows, settings, M)
        if b_hat is not None:  # the bias step of the alternating scheme
            if scale is None:
                b_hat = estimate_bias(poses, deltas, model.D, motion_covs, config.gyro_bias_sigma, b_hat)
            else:  # the motions at the current speed scales
                scaled = dataclasses.replace(scale, corrections=None).deltas(
                    scale_values(values, scale.n_variables))
                b_hat = estimate_bias(poses, scaled, model.D, motion_covs, config.gyro_bias_sigma, b_hat)
                scale.corrections = bias_corrections(model.D, b_hat)
            motion = corrected_deltas(deltas, model.D, b_hat)
        elif final_keep.all() and len(rows) == len(problem.rows):
            # nothing to reject: done, or the same graph continued to the final stopping rule
            timing["build_s"] += time.perf_counter() - tick
            if rejection_tol <= settings.relative_error_tol:
                break
            last_round = round_ + 1
            problem = dataclasses.replace(problem, values=values)
            continue
        n_outliers += int(np.sum(~final_keep))
        rejected += np.bincount(rows.frame[~final_keep], minlength=T)
        rows = rows.subset(final_keep)
        if bias is not None:
            bias.initial = np.asarray(values.atPoint3(BIAS_KEY), dtype=float)
        if scale is not None:
            scale.initial = scale_values(values, scale.n_variables)
        if smoothness is not None:  # re-measured on the better trajectory
            smoothness = _twist_smoothness(poses, cleaned.dt, unconstrained_intervals(rows, T),
                                           smoothness.exact)
        problem = build_graph(poses, landmarks, rows, motion, noise, bias, smoothness, scale)
        timing["build_s"] += time.perf_counter() - tick
    report(3, 4)

    gyro_bias = b_hat if bias is None else np.asarray(values.atPoint3(BIAS_KEY), dtype=float)
    speed_scale = None
    if scale is not None:  # the motions the factors use at the solution: at the estimated scales
        s_hat = scale_values(values, scale.n_variables)
        speed_scale = scale.per_interval(s_hat)
        motion = scale.deltas(s_hat)
        deltas = motion
    return SmootherSolution(
        cleaned=cleaned, cleaning=cleaning, problem=problem, values=values,
        poses=poses_from_values(values, T),
        landmarks=landmarks_from_values(values, problem.landmark_tracks, M),
        deltas=motion if bias is None else deltas, twist=twist, tau=tau, noise=noise,
        pose_prior_cov=estimate_cov_to_gtsam(config.initial_pose_cov),
        n_smoothness=0 if smoothness is None else int(np.count_nonzero(smoothness.gaps)),
        gyro_bias=gyro_bias, bias_model=bias, rejected=rejected, source=source,
        timing=timing, iterations=iterations, errors=errors, n_outliers=n_outliers,
        n_cheirality=n_cheirality, scale_model=scale, speed_scale=speed_scale,
    )


def _speed_scale_info(s: np.ndarray, cov: np.ndarray | None) -> dict:
    """``info["speed_scale"]``: the speed-scale estimates (relative: 0.01 is 1 %) of the first
    and last interval, their mean over the variables, extremes, and 1-sd where the marginals
    were computed (None otherwise)."""
    n = s.size
    if n == 0:  # a drive of one frame: no interval
        return {"n_variables": 0}
    sd = None if cov is None else np.sqrt(np.maximum(np.diag(cov), 0.0))
    return {
        "n_variables": int(n),
        "first": float(s[0]), "final": float(s[-1]), "mean": float(np.mean(s)),
        "min": float(np.min(s)), "max": float(np.max(s)),
        "sigma_first": None if sd is None else float(sd[0]),
        "sigma_final": None if sd is None else float(sd[-1]),
        "sigma_mean": None if cov is None else float(np.sqrt(max(np.sum(cov), 0.0)) / n),
    }


def _run_smoother(seq: Sequence, config: FilterConfig, *, init: str | None,
                  initial: Estimate | None, settings: SmootherSettings,
                  progress: Progress | None) -> Estimate:
    """:func:`run_smoother`'s body (its errors not yet named): solve, marginals, Estimate."""
    start = time.perf_counter()
    report = progress or (lambda done, total: None)
    sol = _solve(seq, config, init=init, initial=initial, settings=settings, progress=progress)
    cleaned, problem, rows, timing = sol.cleaned, sol.problem, sol.problem.rows, sol.timing
    T, M = cleaned.n_frames, cleaned.n_tracks
    est = Estimate.empty("smoother", cleaned.timestamps, M)
    est.poses = sol.poses
    est.landmarks = sol.landmarks
    if settings.compute_marginals:
        tick = time.perf_counter()
        release_freed_memory()  # the solves' Bayes nets, else kept by the C heap (graph.memory)
        graph, solution = (problem.graph, sol.values) if sol.bias_model is None else fix_bias(
            problem, sol.values, sol.deltas, sol.noise, sol.bias_model)
        graph = gaussian_stereo(graph, rows, 1 + len(sol.deltas), sol.noise)
        if sol.scale_model is None:
            est.pose_cov, est.landmark_cov = batch_marginals(graph, solution, T, problem.landmark_tracks, M)
        else:
            est.pose_cov, est.landmark_cov, scale_cov = batch_marginals(
                graph, solution, T, problem.landmark_tracks, M,
                others=[S(i) for i in range(sol.scale_model.n_variables)])
        timing["marginals_s"] = time.perf_counter() - tick
    report(4, 4)

    total = time.perf_counter() - start
    est.step_time_s = np.full(T, total / T)
    est.n_updates = np.bincount(rows.frame, minlength=T).astype(np.int64)
    est.n_rejected = sol.rejected
    first = cleaned.track_first_frame()[problem.landmark_tracks]
    est.n_initialised = np.bincount(first, minlength=T).astype(np.int64)
    cleaning = dict(sol.cleaning)
    speed_scale = None if sol.scale_model is None else _speed_scale_info(
        scale_values(sol.values, sol.scale_model.n_variables),
        scale_cov if settings.compute_marginals else None)
    est.info = {
        "estimator": "smoother",
        "init": sol.source,
        "timing": timing,
        "total_s": total,
        "iterations": int(sum(sol.iterations)),
        "iterations_per_round": sol.iterations,
        "initial_error": sol.errors[0][0],
        "final_error": sol.errors[-1][1],
        "gyro_bias": None if sol.gyro_bias is None else sol.gyro_bias.tolist(),
        "n_landmarks": int(problem.landmark_tracks.size),
        "n_stereo_factors": int(len(rows)),
        "n_outliers_removed": sol.n_outliers,
        "n_cheirality_dropped": sol.n_cheirality,
        "track_origin": cleaning.pop("track_origin"),
        "cleaning": cleaning,
        "settings": settings.to_dict(),
        "config": config.to_dict(),
        "marginals_computed": bool(settings.compute_marginals),
    }
    if speed_scale is not None:  # only with config.speed_scale: the info is otherwise as before
        est.info["speed_scale"] = speed_scale
    return finish_estimate(est, NumericalGuard("smoother", cleaned.timestamps),
                           check_cov=bool(settings.compute_marginals),
                           drop_unusable_cov=False)
