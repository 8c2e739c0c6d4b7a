"""The one per-frame loop: :func:`run_filter` drives any :class:`~ekf.filter.Filter` over a sequence.

Every per-frame estimator (dead reckoning, mapping, ekf-decoupled, ekf-joint, ekf-invariant and a
user's filter) runs through this loop and gets the same Estimate: validation and track cleaning
first (:func:`ekf.runner.prepare_sequence`), BLAS pinned (:func:`ekf.runner.blas_limits`), per-frame
wall time and counters, numerical rejections counted in ``info`` and the estimator contract's
finiteness checks (:func:`ekf.runner.finish_estimate`).

**Tracks that come back.** A track is *ended* (``marginalise``) only after its last observation
in the drive, so a track seen again after a gap (a room, a loop, a tracker that recognises a
landmark) keeps its landmark in the filter's state through the gap and is updated with it when
it returns: the same landmark, with every correlation the filter holds. To bound the state, at
most ``max_carried`` landmarks are carried through gaps at once (MAX_CARRIED by default): when
more are, those unseen the longest are ended at their last observation before the gap, and the
track's observations after it become a new track index (:func:`carry_tracks`), a new landmark
(re-initialising it from its old estimate without that estimate's correlations to the state
would be inconsistent). The new indices follow the sequence's, ``track_origin`` names the
source column of each (as track cleaning's splits do), and ``info["n_carry_splits"]`` counts
them. The KITTI drives' tracks never come back, except across a rejected observation or two.

**Raw-IMU drives** (:class:`ekf.inertial.InertialDrive`). The same loop drives a filter over a
raw-IMU drive (:func:`run_filter` takes either kind): ``initialise`` is given the InertialDrive
(its calibration, IMU stream and tracks), each interval's :class:`~ekf.filter.MotionInput`
carries the IMU samples of ``(t_k-1, t_k]`` (``imu``; ``start``, ``end`` the two frame times; no
twist: ``twist`` is NaN), and each :class:`~ekf.filter.FrameObservations` the frame's pixels,
``(n, 2)`` for a monocular drive and ``(n, 4)`` for a stereo one (:func:`inertial_motion_inputs`
says how an interval's samples are cut). Its tracks are not cleaned (the velocity drives' cleaning
is a stereo rule); they are carried through gaps as above, a split track's ``track_id`` that of
its source track.
"""

from __future__ import annotations

import dataclasses
import heapq

import numpy as np

from vislam.ekf.config import FilterConfig
from vislam.ekf.estimate import Estimate
from vislam.ekf.filter import Filter, FrameObservations, MotionInput
from vislam.ekf.inertial import InertialDrive
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
from vislam.ekf.sequence import Observations, Sequence

#: The most landmarks a per-frame filter carries through their tracks' gaps at once (module
#: docstring): a room's few dozen landmarks are all carried; a long loop's are not.
MAX_CARRIED = 100


def track_returns(seq: Sequence) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every return of a track after a gap (by track, then frame): the observation row where it
    returns, the frame it was last seen in before, and the frame it returns in."""
    frame = seq.obs.frame_index
    order = np.lexsort((frame, seq.obs.track))
    t, f = seq.obs.track[order], frame[order]
    back = np.flatnonzero((t[1:] == t[:-1]) & (f[1:] - f[:-1] > 1)) + 1
    return order[back], f[back - 1], f[back]


def carried_gaps(seq: Sequence, max_carried: int = MAX_CARRIED) -> tuple[np.ndarray, np.ndarray]:
    """The gaps of ``seq``'s tracks and whether each is carried (module docstring).

    Returns the observation rows where a track returns after a gap (N_gaps,; by track, then
    frame),
    and a bool per gap: True when the landmark is carried through the gap, False when more than
    ``max_carried`` landmarks were in gaps at some frame of it and it was among those unseen the
    longest (ties: the lower track index first)."""
    rows, last_seen, returns = track_returns(seq)
    carried = np.ones(rows.size, dtype=bool)
    if rows.size <= max_carried:
        return rows, carried
    track = seq.obs.track[rows]
    starts = np.argsort(last_seen, kind="stable")  # a gap opens the frame after last_seen
    heap: list[tuple[int, int, int]] = []
    open_now = np.zeros(rows.size, dtype=bool)
    ends = np.argsort(returns, kind="stable")
    n_open = i_start = i_end = 0
    for k in np.unique(last_seen + 1):
        while i_end < ends.size and returns[ends[i_end]] <= k:  # returned by frame k
            g = ends[i_end]
            if open_now[g]:
                open_now[g] = False
                n_open -= 1
            i_end += 1
        while i_start < starts.size and last_seen[starts[i_start]] + 1 == k:
            g = starts[i_start]
            if returns[g] > k:
                open_now[g] = True
                n_open += 1
                heapq.heappush(heap, (int(last_seen[g]), int(track[g]), int(g)))
            i_start += 1
        while n_open > max_carried:
            _, _, g = heapq.heappop(heap)
            if open_now[g]:
                open_now[g] = False
                carried[g] = False
                n_open -= 1
    return rows, carried


def carry_tracks(seq: Sequence, max_carried: int = MAX_CARRIED) -> tuple[Sequence, int]:
    """``seq`` with each gap that is not carried (:func:`carried_gaps`) splitting its track: the
    observations after it take a new track index (``n_tracks``, ``n_tracks + 1``, ... in order of
    their first frame, then of the track split), ``track_origin`` extended to them. Returns
    ``(seq, number of splits)``; ``seq`` itself when every gap is carried."""
    rows, carried = carried_gaps(seq, max_carried)
    cut = rows[~carried]
    if cut.size == 0:
        return seq, 0
    obs = seq.obs
    frame = obs.frame_index
    order = np.lexsort((frame, obs.track))
    starts_piece = np.zeros(len(obs), dtype=np.int64)
    starts_piece[cut] = 1
    s = starts_piece[order]
    t = obs.track[order]
    first = np.flatnonzero(np.r_[True, t[1:] != t[:-1]])
    count = np.cumsum(s)
    piece_sorted = count - np.repeat(count[first] - s[first], np.diff(np.r_[first, t.size]))
    piece = np.empty_like(piece_sorted)
    piece[order] = piece_sorted
    track = obs.track.copy()
    later = piece > 0
    base = int(piece.max()) + 1
    uniq, inv = np.unique(obs.track[later] * base + piece[later], return_inverse=True)
    first_frame = np.full(uniq.size, np.iinfo(np.int64).max, dtype=np.int64)
    np.minimum.at(first_frame, inv, frame[later])
    parent = uniq // base
    rank = np.empty(uniq.size, dtype=np.int64)
    rank[np.lexsort((parent, first_frame))] = np.arange(uniq.size)
    track[later] = seq.n_tracks + rank[inv]
    origin = np.asarray(seq.track_origin, dtype=np.int64)
    origin = np.concatenate([origin, origin[parent[np.argsort(rank)]]])
    split = dataclasses.replace(
        seq, obs=Observations.from_rows(frame, track, obs.z, seq.n_frames),
        n_tracks=seq.n_tracks + int(uniq.size), track_origin=origin,
    )
    return split, int(cut.size)


def filter_name(filt) -> str:
    """The name an Estimate of ``filt`` carries: its ``name``, else its class's name."""
    return str(getattr(filt, "name", None) or type(filt).__name__)


def motion_inputs(seq: Sequence, config: FilterConfig) -> list[MotionInput]:
    """The ``T - 1`` motion inputs of ``seq``: ``out[k]`` the interval ``[k, k+1]``."""
    tau, u = interval_twists(seq, config)
    return [MotionInput(k + 1, tau[k], u[k]) for k in range(seq.n_frames - 1)]


#: The twist of a raw-IMU drive's MotionInput: there is none (a velocity filter fed one fails
#: on it instead of integrating zeros).
NO_TWIST = np.full(6, np.nan)


def inertial_motion_inputs(drive: InertialDrive) -> list[MotionInput]:
    """The ``T - 1`` motion inputs of a raw-IMU drive: ``out[k]`` the interval
    ``(t_k, t_k+1]``, ``imu`` its samples as :meth:`ekf.inertial.InertialDrive.imu_between` cuts
    them: the last sample at or before ``t_k`` first, then every sample stamped in
    ``(t_k, t_k+1]``. A sample holds its value from its stamp to the next one; in an interval it
    counts from ``max(stamp, t_k)`` to ``min(next stamp, t_k+1)`` (``start``, ``end``). So the
    sample straddling a frame is split there, its two parts integrated in the two intervals,
    and a sample stamped exactly at ``t_k+1`` holds for zero time in this interval and comes
    first in the next: no stretch of time is lost or integrated twice (as
    :func:`ekf.strapdown.integrate` and dead-reckoning-imu integrate them)."""
    ts = np.asarray(drive.timestamps, dtype=float)
    return [MotionInput(k, float(ts[k] - ts[k - 1]), NO_TWIST, drive.imu_between(k),
                        float(ts[k - 1]), float(ts[k])) for k in range(1, ts.size)]


@dataclasses.dataclass(frozen=True)
class _Tracks:
    """The track bookkeeping of a raw-IMU drive, in the form :func:`carry_tracks` and
    :func:`ekf.runner.tracks_ending` read from a Sequence."""

    obs: Observations
    n_tracks: int
    n_frames: int
    track_origin: np.ndarray

    def track_last_frame(self) -> np.ndarray:
        last = -np.ones(self.n_tracks, dtype=np.int64)
        np.maximum.at(last, self.obs.track, self.obs.frame_index)
        return last


def _prepare_inertial(drive: InertialDrive, max_carried: int) -> tuple[InertialDrive, _Tracks, dict]:
    view = _Tracks(drive.obs, int(drive.n_tracks), drive.n_frames,
                   np.arange(drive.n_tracks, dtype=np.int64))
    info: dict = {"clean_tracks": False, "cleaned": False}
    view, n_splits = carry_tracks(view, max_carried)
    if n_splits:
        info["n_carry_splits"] = n_splits
        ids = None if drive.track_id is None else np.asarray(drive.track_id)[view.track_origin]
        drive = dataclasses.replace(drive, obs=view.obs, n_tracks=view.n_tracks, track_id=ids)
    info["track_origin"] = np.asarray(view.track_origin, dtype=np.int64).tolist()
    return drive, view, info


def run_filter(
    filt: Filter,
    seq: Sequence,
    config: FilterConfig = FilterConfig(),
    progress: Progress = None,
    name: str | None = None,
    max_carried: int = MAX_CARRIED,
) -> Estimate:
    """Run ``filt`` over ``seq``, a velocity drive (:class:`ekf.sequence.Sequence`) or a raw-IMU
    drive (:class:`ekf.inertial.InertialDrive`, module docstring), (:mod:`ekf.filter` for the
    order of the calls) and return its Estimate, named ``name`` (default :func:`filter_name`).

    ``progress(frames done)`` is called every 10 frames and after the last. An EstimationError
    a filter raises (through its guard) ends the run. ``max_carried``: the most landmarks carried
    through their tracks' gaps at once (module docstring)."""
    if isinstance(seq, InertialDrive):
        seq, view, info = _prepare_inertial(seq, max_carried)
        ending = tracks_ending(view)
        motion = inertial_motion_inputs(seq)
    else:
        seq, info = prepare_sequence(seq, config)
        seq, n_splits = carry_tracks(seq, max_carried)
        if n_splits:
            info["n_carry_splits"] = n_splits
            info["track_origin"] = np.asarray(seq.track_origin, dtype=np.int64).tolist()
        ending = tracks_ending(seq)
        motion = motion_inputs(seq, config)
    name = name or filter_name(filt)
    guard = NumericalGuard(name, seq.timestamps)
    rec = StepRecorder(seq.n_frames)
    with blas_limits(config):
        filt.initialise(seq, config, guard)
        for t in range(seq.n_frames):
            tracks, z = seq.obs.frame(t)
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
