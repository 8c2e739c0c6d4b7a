"""The one per-frame loop: :func:`run_filter` drives any :class:`~ekf.filter.Filter` over a sequence.

Every per-frame estimator (dead reckoning, mapping, ekf-decoupled, ekf-joint, ekf-invariant and a
user's filter) runs through this loop and gets the same Estimate: validation and track cleaning
first (:func:`ekf.runner.prepare_sequence`), BLAS pinned (:func:`ekf.runner.blas_limits`), per-frame
wall time and counters, numerical rejections counted in ``info`` and the estimator contract's
finiteness checks (:func:`ekf.runner.finish_estimate`).
"""

from __future__ import annotations

from vislam.ekf.config import FilterConfig
from vislam.ekf.estimate import Estimate
from vislam.ekf.filter import Filter, FrameObservations, MotionInput
from vislam.ekf.numerics import NumericalGuard
from vislam.ekf.runner import (
    Progress,
    StepRecorder,
    blas_limits,
    build_estimate,
    interval_twists,
    prepare_sequence,
    report_progress,
    tracks_ending,
)
from vislam.ekf.sequence import Sequence


def filter_name(filt) -> str:
    """The name an Estimate of ``filt`` carries: its ``name``, else its class's name."""
    return str(getattr(filt, "name", None) or type(filt).__name__)


def motion_inputs(seq: Sequence, config: FilterConfig) -> list[MotionInput]:
    """The ``T - 1`` motion inputs of ``seq``: ``out[k]`` the interval ``[k, k+1]``."""
    tau, u = interval_twists(seq, config)
    return [MotionInput(k + 1, tau[k], u[k]) for k in range(seq.n_frames - 1)]


def run_filter(
    filt: Filter,
    seq: Sequence,
    config: FilterConfig = FilterConfig(),
    progress: Progress = None,
    name: str | None = None,
) -> Estimate:
    """Run ``filt`` over ``seq`` (:mod:`ekf.filter` for the order of the calls) and return its
    Estimate, named ``name`` (default :func:`filter_name`).

    ``progress(frames done)`` is called every 10 frames and after the last. An EstimationError
    a filter raises (through its guard) ends the run."""
    seq, info = prepare_sequence(seq, config)
    name = name or filter_name(filt)
    guard = NumericalGuard(name, seq.timestamps)
    rec = StepRecorder(seq.n_frames)
    ending = tracks_ending(seq)
    motion = motion_inputs(seq, config)
    with blas_limits(config):
        filt.initialise(seq, config, guard)
        for t in range(seq.n_frames):
            tracks, z = seq.frame(t)
            with rec.step(t):
                if t > 0:
                    filt.predict(motion[t - 1])
                counts = filt.update(FrameObservations(t, seq.timestamps[t], tracks, z))
                filt.marginalise(ending[t])
                rec.n_updates[t] = counts.n_updates
                rec.n_rejected[t] = counts.n_rejected
                rec.n_initialised[t] = counts.n_initialised
                rec.poses[t] = filt.pose()
                rec.pose_cov[t] = filt.pose_cov()
            report_progress(progress, t, seq.n_frames)
        mean, cov = filt.landmark_map()
        active = filt.active_landmarks()
        if active.tracks.size:
            mean[active.tracks] = active.mean
            cov[active.tracks] = active.cov
    info.update(filt.info())
    return build_estimate(name, seq, rec, mean, cov, config, info, guard)
