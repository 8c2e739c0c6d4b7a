"""The incremental smoother: iSAM2, frame by frame (estimator ``smoother-isam2``).

Each frame adds its pose (predicted from the previous estimate and the interval's twist), the
motion factor, and the stereo factors of its observations. A track enters the graph at its
second usable observation (the spec's "at least two observations"): its landmark is
triangulated from the larger-disparity one of the two, and it is dropped for good if it lies
behind either camera (GTSAM's stereo factor has a zero Jacobian there and iSAM2 would then
throw an indeterminate-system error). Later observations whose residual against the current
estimate exceeds ``4 * settings.outlier_threshold_px`` are not added.
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
from vislam.graph.marginals import isam2_marginals
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
    """What :func:`isam2_solve` leaves: the solver, its estimate and the factors it holds."""

    isam: gtsam.ISAM2
    poses: np.ndarray
    landmarks: np.ndarray
    tracks: np.ndarray
    rows: StereoRows
    rejected: np.ndarray
    initialised: np.ndarray
    timing: dict
    #: Gap intervals that got a twist-smoothness prior.
    n_gap_priors: int = 0


def _add_gap_prior(graph: gtsam.NonlinearFactorGraph, isam: gtsam.ISAM2, poses: np.ndarray, k: int,
                   tau: np.ndarray, gaps: np.ndarray, settings: SmootherSettings) -> int:
    """At frame ``k``, the twist-smoothness prior for the gap interval ``[k-2, k-1]`` on
    ``X(k-3) .. X(k)`` (graph.twist_smoothness), its sigma measured on the estimates of the
    last frames; linearised at the current estimates and the prediction of ``X(k)`` unless
    ``settings.gap_twist_prior == "exact"``. Returns 1 if added, 0 if too early to measure."""
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


def isam2_solve(seq: Sequence, config: FilterConfig, settings: SmootherSettings,
                progress: Callable | None = None) -> Isam2Result:
    """Run iSAM2 over an already cleaned sequence."""
    T, M, calib = seq.n_frames, seq.n_tracks, seq.calibration
    tick = time.perf_counter()
    deltas, motion_covs = relative_motions(seq, config)
    noise = NoiseModels.create(seq, config, settings, motion_covs)
    rows, rejected = usable_rows(seq, config.min_disparity)
    rejected = rejected.astype(np.int64)
    measured = rows.measured
    frame_ptr = np.searchsorted(rows.frame, np.arange(T + 1))  # rows are sorted by frame
    # interval [k, k+1] without vision: known once frame k+1's observations are in
    gaps = unconstrained_intervals(rows, T) if settings.gap_twist_prior != "off" else np.zeros(max(T - 1, 0), bool)
    n_prior = 0
    build_s = time.perf_counter() - tick

    params = gtsam.ISAM2Params()
    params.setRelinearizeThreshold(settings.isam2_relinearize_threshold)
    params.relinearizeSkip = int(settings.isam2_relinearize_skip)
    isam = gtsam.ISAM2(params)

    pending: dict[int, int] = {}  # track -> row index of its first usable observation
    dropped = np.zeros(M, dtype=bool)
    in_graph = np.zeros(M, dtype=bool)
    landmark_est = np.full((M, 3), np.nan)
    poses = np.empty((T, 4, 4))
    used = np.zeros(len(rows), dtype=bool)
    initialised = np.zeros(T, dtype=np.int64)
    optimise_s = 0.0

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
            n_prior += _add_gap_prior(graph, isam, poses, k, seq.dt, gaps, settings)

        a, b = frame_ptr[k], frame_ptr[k + 1]
        idx = np.arange(a, b)
        tracks = rows.track[idx]
        # observations of landmarks already in the graph: loose gate, then add
        old = idx[in_graph[tracks]]
        if old.size:
            residual, depth = stereo_residuals(poses, landmark_est, calib, rows.subset(old))
            ok = (np.linalg.norm(residual, axis=1) <= _GATE_FACTOR * settings.outlier_threshold_px) & (depth >= settings.min_depth)
            for i in old[ok]:
                graph.add(noise.stereo_factor(measured[i], k, rows.track[i]))
            used[old[ok]] = True
            rejected[k] += int(np.sum(~ok))
        # second observations: triangulate, check cheirality in both cameras, add
        new = [i for i in idx if not in_graph[rows.track[i]] and not dropped[rows.track[i]]]
        for i in new:
            j = int(rows.track[i])
            if j not in pending:
                pending[j] = i
                continue
            first = pending.pop(j)
            pair = rows.subset(np.array([first, i]))
            point = triangulate_landmarks(poses, calib, pair, M)
            depths = camera_points(poses, point, calib, pair)[:, 2]
            if not np.all(depths >= settings.min_depth):
                dropped[j] = True
                rejected[rows.frame[first]] += 1
                rejected[k] += 1
                continue
            landmark_est[j] = point[j]
            in_graph[j] = True
            initialised[k] += 1
            values.insert(L(j), point[j])
            graph.add(gtsam.PriorFactorPoint3(L(j), point[j], noise.landmark_prior))
            for r in (first, i):
                graph.add(noise.stereo_factor(measured[r], rows.frame[r], j))
            used[[first, i]] = True
        build_s += time.perf_counter() - tick

        tick = time.perf_counter()
        try:
            isam.update(graph, values)
            poses[k] = isam.calculateEstimatePose3(X(k)).matrix()
        except RuntimeError as exc:
            raise estimation_error(exc, f"adding frame {k} to iSAM2",
                                   estimator="smoother-isam2") from None
        optimise_s += time.perf_counter() - tick
        # refresh the landmarks seen now (cheap: only this frame's)
        for j in tracks[in_graph[tracks]]:
            landmark_est[j] = isam.calculateEstimatePoint3(L(int(j)))
        if progress is not None and ((k + 1) % 10 == 0 or k + 1 == T):
            progress(k + 1, T)

    # single observations never entered the graph
    for first in pending.values():
        rejected[rows.frame[first]] += 1
    tick = time.perf_counter()
    try:
        estimate = isam.calculateEstimate()
    except RuntimeError as exc:
        raise estimation_error(exc, "computing the iSAM2 estimate",
                               estimator="smoother-isam2") from None
    optimise_s += time.perf_counter() - tick
    tracks = np.flatnonzero(in_graph)
    return Isam2Result(
        isam=isam,
        poses=poses_from_values(estimate, T),
        landmarks=landmarks_from_values(estimate, tracks, M),
        tracks=tracks,
        rows=rows.subset(used),
        rejected=rejected,
        initialised=initialised,
        timing={"build_s": build_s, "initialise_s": 0.0, "optimise_s": optimise_s, "marginals_s": 0.0},
        n_gap_priors=n_prior,
    )


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


def _run_isam2(
    seq: Sequence,
    config: FilterConfig = FilterConfig(),
    *,
    settings: SmootherSettings = SmootherSettings(),
    progress: Callable | None = None,
) -> Estimate:
    start = time.perf_counter()
    cleaned, cleaning = prepare_sequence(seq, config)
    T, M = cleaned.n_frames, cleaned.n_tracks
    result = isam2_solve(cleaned, config, settings, progress)
    timing = result.timing
    timing["build_s"] += 0.0
    est = Estimate.empty("smoother-isam2", cleaned.timestamps, M)
    est.poses = result.poses
    est.landmarks = result.landmarks
    if not np.all(np.isfinite(est.poses)):
        raise EstimationError("smoother-isam2 produced non-finite poses")
    if settings.compute_marginals:
        tick = time.perf_counter()
        est.pose_cov, est.landmark_cov = isam2_marginals(result.isam, T, result.tracks, M)
        timing["marginals_s"] = time.perf_counter() - tick
    total = time.perf_counter() - start
    est.step_time_s = np.full(T, total / T)
    est.n_updates = np.bincount(result.rows.frame, minlength=T).astype(np.int64)
    est.n_rejected = result.rejected
    est.n_initialised = result.initialised
    est.info = {
        "estimator": "smoother-isam2",
        "timing": timing,
        "total_s": total,
        "n_landmarks": int(result.tracks.size),
        "n_stereo_factors": int(len(result.rows)),
        "n_gap_priors": result.n_gap_priors,
        "track_origin": cleaning.pop("track_origin"),
        "cleaning": cleaning,
        "settings": settings.to_dict(),
        "config": config.to_dict(),
        "marginals_computed": bool(settings.compute_marginals),
    }
    return finish_estimate(est, NumericalGuard("smoother-isam2", cleaned.timestamps),
                           check_cov=bool(settings.compute_marginals))
