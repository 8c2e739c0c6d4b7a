"""The incremental smoothers: iSAM2 (``smoother-isam2``) and its fixed-lag form
(``smoother-fixed-lag``), frame by frame.

Each frame adds its pose (predicted from the previous estimate and the interval's twist), the
motion factor, and the stereo factors of its observations. A track enters the graph at its
second usable observation (the spec's "at least two observations"): its landmark is
triangulated from the larger-disparity one of the two, and it is dropped for good if it lies
behind either camera (GTSAM's stereo factor has a zero Jacobian there and iSAM2 would then
throw an indeterminate-system error). Later observations whose residual against the current
estimate exceeds ``4 * settings.outlier_threshold_px`` are not added.

Returning tracks (a loop's, a room's): each iSAM2 update re-eliminates the Bayes tree from the
cliques its new factors touch to the root, and a landmark last seen long ago sits deep in the
tree, so an update that re-observes it re-eliminates everything since (docs/findings.md). So
``smoother-isam2`` holds such observations back (a landmark unseen for more than
``settings.isam2_return_batch`` frames, and every later observation of it while it waits) and
adds them together, gated against the estimates of then, with the frame that ends the batch;
that update orders only the frame's new variables last, not the returning landmarks. Held
observations enter at linearisation points up to a batch old; the final relinearisations
relinearise every variable, so that costs nothing at the end. A drive whose tracks never
return is not affected (a gap that track cleaning made, by taking out an observation, is not
a return).

After each update iSAM2 back-substitutes only where the solution moved by more than
``settings.isam2_wildfire_threshold`` (GTSAM's wildfire; 0.01, GTSAM's default is 0.001): the
frame's new pose and the landmarks it sees are exact, older variables may be that stale, and the
back-substitution of the whole drive after every frame is what made a long drive's cost grow
with its length. The final relinearisations (``settings.isam2_final_relinearizations``
Gauss-Newton steps from the full solution, every variable relinearised: what iSAM2's forced
relinearisations with a full solve compute, solved in batch, :func:`final_relinearizations`)
decide on the full solution, so the result does not depend on that threshold (with
``calculateEstimate`` it did, and with iSAM2's own final updates a little: their first step
was the stale solution; docs/findings.md). The fixed-lag smoother keeps GTSAM's threshold, as
it reports each variable when it leaves the window, and reads the variables still in the
window at the end from the full back-substitution too.

The fixed-lag smoother (GTSAM's ``IncrementalFixedLagSmoother``, iSAM2 underneath) runs the same
loop but keeps only the last ``settings.fixed_lag_s`` seconds: a pose leaves the window that
long after its frame, a landmark that long after its last observation, marginalised into a prior
on what stays. Each is reported as it was when it left (its estimate and marginal covariance
then): a smoother with a bounded delay and bounded cost per frame, between the EKFs (no delay)
and the full smoothers (the whole drive).

Neither estimates the gyro bias or the speed scale (``config.gyro_bias``, ``config.speed_scale``):
their motion factors are the plain between-factors of the measured twists, whatever the
configuration says (the batch smoother, :mod:`graph.smoother`, carries both).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Callable

import gtsam
import numpy as np

from vislam.ekf.config import FilterConfig
from vislam.ekf.errors import EstimationError
from vislam.ekf.driver import track_returns
from vislam.ekf.estimate import Estimate
from vislam.ekf.sequence import Sequence
from vislam.graph.factors import (
    NoiseModels,
    StereoRows,
    camera_points,
    landmarks_from_values,
    poses_from_values,
    relative_motions,
    stereo_residuals,
    triangulate_landmarks,
    unconstrained_intervals,
    usable_rows,
)
from vislam.ekf.numerics import NumericalGuard
from vislam.ekf.runner import finish_estimate, prepare_sequence
from vislam.graph.marginals import schur_marginals
from vislam.graph.memory import release_freed_memory
from vislam.ekf.conventions import gtsam_cov_to_estimate
from vislam.graph.pose_conversions import L, X, estimation_error, named_error, to_pose3
from vislam.graph.settings import SmootherSettings
from vislam.graph.twist_smoothness import gap_prior, smoothness_sigma

log = logging.getLogger(__name__)

#: The twist-smoothness sigma at a gap is measured on the estimates of this many frames before it.
_SIGMA_WINDOW = 200

#: Observations of a track already in the graph are skipped when their residual against the
#: current estimate exceeds this many times ``outlier_threshold_px`` (the pose is only
#: predicted at that point, so the gate is loose).
_GATE_FACTOR = 4.0


@dataclass
class Isam2Result:
    """What :func:`isam2_solve` leaves: its estimate and the factors it holds."""

    #: smoother-isam2 only (None for the fixed lag): the nonlinear factors and the final estimate.
    factors: gtsam.NonlinearFactorGraph | None
    values: gtsam.Values | None
    poses: np.ndarray
    landmarks: np.ndarray
    tracks: np.ndarray
    rows: StereoRows
    rejected: np.ndarray
    initialised: np.ndarray
    timing: dict
    #: Gap intervals that got a twist-smoothness prior.
    n_gap_priors: int = 0
    #: Fixed lag only: marginal covariances as each variable left the window (GTSAM convention
    #: for poses).
    pose_cov: np.ndarray | None = None
    landmark_cov: np.ndarray | None = None


def _add_gap_prior(graph: gtsam.NonlinearFactorGraph, isam, poses: np.ndarray, k: int,
                   tau: np.ndarray, gaps: np.ndarray, settings: SmootherSettings,
                   first_in_window: int = 0) -> int:
    """At frame ``k``, the twist-smoothness prior for the gap interval ``[k-2, k-1]`` on
    ``X(k-3) .. X(k)`` (graph.twist_smoothness), its sigma measured on the estimates of the
    last frames; linearised at the current estimates and the prediction of ``X(k)`` unless
    ``settings.gap_twist_prior == "exact"``. Returns 1 if added, 0 if too early to measure."""
    if k - 3 < first_in_window:  # a pose it would touch has left a fixed-lag window
        return 0
    lo = max(k - _SIGMA_WINDOW, 0)
    for j in range(k - 3, k):  # the latest estimates of the poses the factor touches
        poses[j] = isam.calculateEstimatePose3(X(j)).matrix()
    sigma = smoothness_sigma(poses[lo:k + 1], tau[lo:k], gaps[lo:k])
    if sigma is None:
        return 0
    point = None
    if settings.gap_twist_prior != "exact":
        point = gtsam.Values()
        for j in range(k - 3, k + 1):
            point.insert(X(j), to_pose3(poses[j]))
    graph.add(gap_prior(k - 2, tau, sigma, point))
    return 1


def tracks_return(seq: Sequence, gap: int) -> bool:
    """Whether a track of ``seq`` is seen again more than ``gap`` frames after it was last
    seen (module docstring: returning tracks)."""
    _, last_seen, returns = track_returns(seq)
    return bool(np.any(returns - last_seen > gap))


def _estimator_name(lag: float | None) -> str:
    """``smoother-isam2``, or ``smoother-fixed-lag`` with a window ``lag``."""
    return "smoother-isam2" if lag is None else "smoother-fixed-lag"


def isam2_solve(seq: Sequence, config: FilterConfig, settings: SmootherSettings,
                progress: Callable | None = None, lag: float | None = None,
                source: Sequence | None = None) -> Isam2Result:
    """Run iSAM2 over an already cleaned sequence; with ``lag`` (seconds) the fixed-lag
    smoother instead (see the module docstring). ``source`` is the drive before cleaning: its
    returning tracks are the ones held back (a gap that cleaning made is not a return)."""
    T, M, calib = seq.n_frames, seq.n_tracks, seq.calibration
    tick = time.perf_counter()
    deltas, motion_covs = relative_motions(seq, config)
    noise = NoiseModels.create(seq, config, settings, motion_covs)
    rows, rejected = usable_rows(seq, config.min_disparity)
    rejected = rejected.astype(np.int64)
    frame_ptr = np.searchsorted(rows.frame, np.arange(T + 1))  # rows are sorted by frame
    # interval [k, k+1] without vision: known once frame k+1's observations are in
    gaps = unconstrained_intervals(rows, T) if settings.gap_twist_prior != "off" else np.zeros(max(T - 1, 0), bool)
    n_prior = 0
    build_s = time.perf_counter() - tick

    # Returning tracks (module docstring): their observations wait, and enter together every
    # ``batch`` frames; 0 where none waits.
    batch = int(settings.isam2_return_batch)
    if lag is not None or batch < 2 or not tracks_return(seq if source is None else source, batch):
        batch = 0
    params = gtsam.ISAM2Params()
    params.setRelinearizeThreshold(settings.isam2_return_relinearize_threshold if batch
                                   else settings.isam2_relinearize_threshold)
    skip = settings.isam2_relinearize_skip if lag is None else settings.fixed_lag_relinearize_skip
    params.relinearizeSkip = max(int(skip), 1)
    params.enableRelinearization = skip > 0
    params.setFactorization(settings.isam2_factorization.upper())
    if lag is None:  # the final estimate is solved in full (module docstring)
        params.setOptimizationParams(gtsam.ISAM2GaussNewtonParams(settings.isam2_wildfire_threshold))
    isam = gtsam.ISAM2(params) if lag is None else gtsam.IncrementalFixedLagSmoother(lag, params)
    times = seq.timestamps - seq.timestamps[0]
    window = _Window(T, M) if lag is not None else None
    name = _estimator_name(lag)

    pending: dict[int, int] = {}  # track -> row index of its first usable observation
    dropped = np.zeros(M, dtype=bool)
    in_graph = np.zeros(M, dtype=bool)
    landmark_est = np.full((M, 3), np.nan)
    poses = np.empty((T, 4, 4))
    used = np.zeros(len(rows), dtype=bool)
    initialised = np.zeros(T, dtype=np.int64)
    optimise_s = 0.0
    last_added = np.full(M, -1, dtype=np.int64)  # frame of each landmark's latest factor
    waiting = np.zeros(M, dtype=bool)  # the landmark has observations waiting
    held: list[np.ndarray] = []  # rows waiting
    held_since = -1  # frame of the oldest waiting row
    n_held = 0

    def gate(obs_rows: np.ndarray) -> np.ndarray:
        """The loose gate: residual against the current estimates, depth."""
        residual, depth = stereo_residuals(poses, landmark_est, calib, rows.subset(obs_rows))
        return ((np.linalg.norm(residual, axis=1) <= _GATE_FACTOR * settings.outlier_threshold_px)
                & (depth >= settings.min_depth))

    for k in range(T):
        tick = time.perf_counter()
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        if k == 0:
            predicted = np.eye(4)
            graph.add(gtsam.PriorFactorPose3(X(0), gtsam.Pose3(), noise.pose_prior))
        else:
            predicted = poses[k - 1] @ deltas[k - 1]
            graph.add(gtsam.BetweenFactorPose3(X(k - 1), X(k), to_pose3(deltas[k - 1]), noise.motion[k - 1]))
        values.insert(X(k), to_pose3(predicted))
        poses[k] = predicted
        if k >= 3 and gaps[k - 2]:
            n_prior += _add_gap_prior(graph, isam, poses, k, seq.dt, gaps, settings,
                                      0 if window is None else window.first_pose)

        a, b = frame_ptr[k], frame_ptr[k + 1]
        idx = np.arange(a, b)
        tracks = rows.track[idx]
        # observations of landmarks already in the graph: loose gate, then add
        if window is not None:  # landmarks marginalised already: their observations are late
            late = idx[window.gone[tracks]]
            rejected[k] += late.size
            idx = idx[~window.gone[tracks]]
            tracks = rows.track[idx]
        old = idx[in_graph[tracks]]
        if batch and old.size:  # returning landmarks' observations wait (module docstring)
            back = waiting[rows.track[old]] | (k - last_added[rows.track[old]] > batch)
            if back.any():
                held.append(old[back])
                waiting[rows.track[old[back]]] = True
                held_since = k if held_since < 0 else held_since
                n_held += int(back.sum())
                old = old[~back]
        if old.size:
            ok = gate(old)
            noise.add_stereo_factors(graph, rows.subset(old[ok]))  # rows of frame k
            used[old[ok]] = True
            last_added[rows.track[old[ok]]] = k
            rejected[k] += int(np.sum(~ok))
        # second observations: triangulate, check cheirality in both cameras, add
        new = [i for i in idx if not in_graph[rows.track[i]] and not dropped[rows.track[i]]]
        for i in new:
            j = int(rows.track[i])
            if j not in pending:
                pending[j] = i
                continue
            first = pending.pop(j)
            if window is not None and rows.frame[first] < window.first_pose:
                rejected[rows.frame[first]] += 1  # its pose left the window: start again
                pending[j] = i
                continue
            pair = rows.subset(np.array([first, i]))
            alone = StereoRows(pair.frame, np.zeros(2, dtype=np.int64), pair.z)  # as track 0:
            point = triangulate_landmarks(poses, calib, alone, 1)  # not an (M, 3) array each
            depths = camera_points(poses, point, calib, alone)[:, 2]
            if not np.all(depths >= settings.min_depth):
                dropped[j] = True
                rejected[rows.frame[first]] += 1
                rejected[k] += 1
                continue
            landmark_est[j] = point[0]
            in_graph[j] = True
            initialised[k] += 1
            values.insert(L(j), point[0])
            graph.add(gtsam.PriorFactorPoint3(L(j), point[0], noise.landmark_prior))
            noise.add_stereo_factors(graph, pair)
            used[[first, i]] = True
            last_added[j] = k
        if held and (k - held_since + 1 >= batch or k + 1 == T):  # the waiting observations
            back = np.concatenate(held)
            for j in np.unique(rows.frame[back]):
                if j < k:
                    poses[j] = isam.calculateEstimatePose3(X(int(j))).matrix()
            for j in np.unique(rows.track[back]):
                landmark_est[j] = isam.calculateEstimatePoint3(L(int(j)))
            ok = gate(back)
            np.add.at(rejected, rows.frame[back[~ok]], 1)
            back = back[ok]
            noise.add_stereo_factors(graph, rows.subset(back))
            used[back] = True
            np.maximum.at(last_added, rows.track[back], rows.frame[back])
            waiting[:] = False
            held, held_since = [], -1
            flushed = np.unique(rows.track[back])
        else:
            flushed = None
        build_s += time.perf_counter() - tick

        tick = time.perf_counter()
        try:
            if flushed is not None:  # only the frame's new variables ordered last
                update = gtsam.ISAM2UpdateParams()
                last = gtsam.KeyGroupMap()
                for key in values.keys():
                    last.insert2(key, 1)
                update.constrainedKeys = last
                isam.update(graph, values, update)
            elif window is None:
                isam.update(graph, values)
            else:
                stamps = {X(k): times[k]}
                stamps.update({L(int(j)): times[k] for j in tracks[in_graph[tracks]]})
                window.last_seen[tracks[in_graph[tracks]]] = times[k]
                isam.update(graph, values, stamps)
            poses[k] = isam.calculateEstimatePose3(X(k)).matrix()
            if window is not None:  # what leaves at the next update: as it is now
                t_next = times[k + 1] - lag if k + 1 < T else np.inf
                window.leave(isam, poses, times, in_graph, t_next, k)
        except RuntimeError as exc:
            raise estimation_error(exc, f"adding frame {k} to the incremental smoother",
                                   estimator=name) from None
        optimise_s += time.perf_counter() - tick
        # refresh the landmarks seen now (cheap: only this frame's, and the waiting ones')
        for j in tracks[in_graph[tracks]] if flushed is None else np.union1d(tracks[in_graph[tracks]], flushed):
            landmark_est[j] = isam.calculateEstimatePoint3(L(int(j)))
        if progress is not None and ((k + 1) % 10 == 0 or k + 1 == T):
            progress(k + 1, T)

    # single observations never entered the graph
    for first in pending.values():
        rejected[rows.frame[first]] += 1
    tracks = np.flatnonzero(in_graph)
    timing = {"build_s": build_s, "initialise_s": 0.0, "optimise_s": optimise_s, "marginals_s": 0.0,
              "held_observations": n_held}
    if window is not None:
        return Isam2Result(
            factors=None, values=None, poses=window.poses, landmarks=window.landmarks,
            tracks=tracks, rows=rows.subset(used), rejected=rejected, initialised=initialised, timing=timing,
            n_gap_priors=n_prior, pose_cov=window.pose_cov, landmark_cov=window.landmark_cov,
        )
    tick = time.perf_counter()
    # copies: the references GTSAM returns would keep the solver, and its Bayes tree, alive
    factors = gtsam.NonlinearFactorGraph(isam.getFactorsUnsafe())
    theta = gtsam.Values(isam.getLinearizationPoint())
    del isam  # the final rounds are solved in batch: the Bayes tree is not needed any more
    release_freed_memory()  # its blocks, else kept by the C heap (graph.memory)
    try:
        estimate = final_relinearizations(factors, theta, settings.isam2_final_relinearizations,
                                          settings.isam2_factorization)
    except RuntimeError as exc:
        raise estimation_error(exc, "computing the iSAM2 estimate",
                               estimator="smoother-isam2") from None
    optimise_s += time.perf_counter() - tick
    return Isam2Result(
        factors=factors,
        values=estimate,
        poses=poses_from_values(estimate, T),
        landmarks=landmarks_from_values(estimate, tracks, M),
        tracks=tracks,
        rows=rows.subset(used),
        rejected=rejected,
        initialised=initialised,
        timing={**timing, "optimise_s": optimise_s},
        n_gap_priors=n_prior,
    )


def final_relinearizations(factors: gtsam.NonlinearFactorGraph, theta: gtsam.Values,
                           rounds: int, factorization: str) -> gtsam.Values:
    """iSAM2's final rounds, solved in batch: ``rounds`` Gauss-Newton steps from the full
    solution at the solver's linearisation point ``theta``. That is what ``rounds`` iSAM2
    updates with no new factors, ``force_relinearize`` and ``forceFullSolve`` compute, then
    ``calculateBestEstimate``: GTSAM relinearises every variable in an update that forces a
    full solve, and every factor is linearised at ``theta`` (a factor's cached linearisation is
    redone whenever one of its variables is relinearised). Solved in iSAM2 itself, each round
    removes the whole Bayes tree first, and GTSAM's ``removeTop`` keeps the orphaned subtrees
    in a list it searches for every clique it removes: quadratic in the drive's length (30 s a
    round on a 4,541-frame road against 0.6 s at 1,200 frames; docs/findings.md)."""
    eliminate = {"function": gtsam.EliminateQR} if factorization.lower() == "qr" else {}
    for _ in range(rounds + 1):
        delta = factors.linearize(theta).optimize(**eliminate)
        theta = theta.retract(delta)
    return theta


class _Window:
    """What has left a fixed-lag smoother's window: each pose and landmark as it was then."""

    def __init__(self, n_frames: int, n_tracks: int):
        self.first_pose = 0  # the oldest pose still in the window
        self.poses = np.full((n_frames, 4, 4), np.nan)
        self.pose_cov = np.full((n_frames, 6, 6), np.nan)
        self.landmarks = np.full((n_tracks, 3), np.nan)
        self.landmark_cov = np.full((n_tracks, 3, 3), np.nan)
        self.last_seen = np.full(n_tracks, np.inf)  # time of the last observation in the graph
        self.gone = np.zeros(n_tracks, dtype=bool)

    def leave(self, smoother, poses, times, in_graph, before: float, k: int) -> None:
        """Record the poses (up to frame ``k``) and landmarks whose time is before ``before``:
        GTSAM marginalises them at the next update. At the end of the drive (``before``
        infinite) every variable left is read from the full back-substitution."""
        if np.isinf(before):
            best = smoother.getISAM2().calculateBestEstimate()
            pose, point = best.atPose3, best.atPoint3
        else:
            pose, point = smoother.calculateEstimatePose3, smoother.calculateEstimatePoint3
        first = self.first_pose
        while self.first_pose <= k and times[self.first_pose] < before:
            self.first_pose += 1
        frames = np.arange(first, self.first_pose)
        tracks = np.flatnonzero(in_graph & ~self.gone & (self.last_seen < before))
        keys = [X(int(j)) for j in frames] + [L(int(j)) for j in tracks]
        cov = _marginal_covariances(smoother, keys)
        for j in frames:
            self.poses[j] = pose(X(int(j))).matrix()
            self.pose_cov[j] = cov(X(int(j)))
            poses[j] = self.poses[j]
        for j in tracks:
            self.landmarks[j] = point(L(int(j)))
            self.landmark_cov[j] = cov(L(int(j)))
            self.gone[j] = True


def _marginal_covariances(smoother, keys: list, chunk: int = 64):
    """``cov(key)``: each of ``keys``' marginal covariance in ``smoother``'s Bayes tree. Several
    keys come from one joint marginal (``ISAM2.jointMarginalCovariance``, its diagonal blocks):
    the same figures as a ``marginalCovariance`` per key (to about 1e-11 relative), in a tenth of
    the time, because the cliques' separator marginals are shared instead of taken again from
    the root for every key. At most ``chunk`` keys share one joint marginal: it is dense, and at
    the end of the drive every variable still in the window leaves at once (the whole drive
    when the window is longer than it)."""
    if len(keys) < 2:
        return smoother.marginalCovariance
    isam = smoother.getISAM2()
    blocks = {}
    for start in range(0, len(keys), chunk):
        part = keys[start:start + chunk]
        joint = isam.jointMarginalCovariance(part)
        blocks.update({key: joint.at(key, key) for key in part})
    return blocks.__getitem__


def run_isam2(
    seq: Sequence,
    config: FilterConfig = FilterConfig(),
    *,
    settings: SmootherSettings = SmootherSettings(),
    progress: Callable | None = None,
) -> Estimate:
    """Incremental smoother (iSAM2), frame by frame; returns the final (smoothed) estimate.

    ``progress(done, total)`` is called every 10 frames. Landmarks are indexed by the tracks of
    the cleaned sequence (``info["track_origin"]``).
    """
    try:
        return _run_isam2(seq, config, settings=settings, progress=progress)
    except EstimationError as exc:  # shared parts name only what failed: add the estimator
        raise named_error(exc, "smoother-isam2") from None


def run_fixed_lag(
    seq: Sequence,
    config: FilterConfig = FilterConfig(),
    *,
    settings: SmootherSettings = SmootherSettings(),
    progress: Callable | None = None,
) -> Estimate:
    """Fixed-lag smoother (GTSAM's ``IncrementalFixedLagSmoother``, window
    ``settings.fixed_lag_s`` seconds): each pose and landmark as estimated when it left the
    window, with its marginal covariance then (see the module docstring)."""
    try:
        return _run_isam2(seq, config, settings=settings, progress=progress, lag=settings.fixed_lag_s)
    except EstimationError as exc:
        raise named_error(exc, "smoother-fixed-lag") from None


def _run_isam2(
    seq: Sequence,
    config: FilterConfig = FilterConfig(),
    *,
    settings: SmootherSettings = SmootherSettings(),
    progress: Callable | None = None,
    lag: float | None = None,
) -> Estimate:
    start = time.perf_counter()
    name = _estimator_name(lag)
    with_cov = bool(settings.compute_marginals) or lag is not None  # fixed lag: always
    cleaned, cleaning = prepare_sequence(seq, config)
    T, M = cleaned.n_frames, cleaned.n_tracks
    factorization = settings.isam2_factorization
    try:
        result = isam2_solve(cleaned, config, settings, progress, lag, source=seq)
    except EstimationError as exc:
        if factorization != "cholesky" or "indeterminate" not in str(exc):
            raise
        log.warning("%s; running again with QR factorisation", exc)
        factorization = f"qr (cholesky failed: {exc})"
        result = isam2_solve(cleaned, config, settings.replace(isam2_factorization="qr"), progress,
                             lag, source=seq)
    timing = result.timing
    est = Estimate.empty(name, cleaned.timestamps, M)
    est.poses = result.poses
    est.landmarks = result.landmarks
    if not np.all(np.isfinite(est.poses)):
        raise EstimationError(f"{name} produced non-finite poses")
    if lag is not None:  # its marginals were taken as each variable left the window
        est.pose_cov = gtsam_cov_to_estimate(result.pose_cov)
        est.landmark_cov = result.landmark_cov
    elif settings.compute_marginals:
        tick = time.perf_counter()
        est.pose_cov, est.landmark_cov = schur_marginals(result.factors, result.values, T,
                                                         result.tracks, M)
        timing["marginals_s"] = time.perf_counter() - tick
    total = time.perf_counter() - start
    est.step_time_s = np.full(T, total / T)
    est.n_updates = np.bincount(result.rows.frame, minlength=T).astype(np.int64)
    est.n_rejected = result.rejected
    est.n_initialised = result.initialised
    est.info = {
        "estimator": name,
        "timing": timing,
        "total_s": total,
        "n_landmarks": int(result.tracks.size),
        "n_stereo_factors": int(len(result.rows)),
        "n_gap_priors": result.n_gap_priors,
        "track_origin": cleaning.pop("track_origin"),
        "cleaning": cleaning,
        "settings": settings.to_dict(),
        "config": config.to_dict(),
        "marginals_computed": with_cov,
        "factorization": factorization,
    }
    if lag is not None:
        est.info["fixed_lag_s"] = float(lag)
    return finish_estimate(est, NumericalGuard(name, cleaned.timestamps),
                           check_cov=with_cov,
                           drop_unusable_cov=False)
