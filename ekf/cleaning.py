"""Repair the shared drives' track quirk and reject unusable stereo observations.

The quirk (foundation issue, DESIGN.md): at each frame where many new tracks start, every
continuing track repeats its previous observation exactly, and its later observations no longer
fit its earlier ones (they lag). The repair drops the repeated observation and continues the
rest of the track as a **new** track index, so that no landmark is fitted to both parts (with
known poses, the split tracks' reprojection residuals fall: ``tests/test_cleaning.py``).

Stereo observations with non-positive or tiny disparity ``uL - uR`` (down to about -190 px in
the shared data) cannot be triangulated and are rejected here too, as are points beyond
``max_depth`` if given. Both estimators call :func:`clean_sequence` before estimating.

Track numbering after a split: the first part of a track keeps its index; later parts get new
indices ``n_tracks, n_tracks + 1, ...`` in order of their first frame, and ``track_origin``
keeps the column of the source file each one came from.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass

import numpy as np

from vislam.ekf.sequence import Observations, Sequence

log = logging.getLogger(__name__)

#: A frame is a repeat event when at least this many tracks repeat there ...
EVENT_MIN_REPEATS = 3
#: ... and at least this fraction of the tracks continuing into it do.
EVENT_MIN_FRACTION = 0.5


@dataclass(frozen=True)
class RepeatEvent:
    """One frame at which many continuing tracks repeat their previous observation exactly.

    ``n_repeats`` tracks repeat, out of ``n_continuing`` observed at both ``frame - 1`` and
    ``frame``; ``n_new`` tracks start at ``frame``.
    """

    frame: int
    n_repeats: int
    n_continuing: int
    n_new: int


@dataclass(frozen=True)
class CleaningReport:
    """What :func:`clean_sequence` found and changed (counts of observations and tracks)."""

    n_observations_in: int
    n_observations_out: int
    n_tracks_in: int
    n_tracks_out: int
    #: Observations equal to the previous observation of their track.
    n_repeats_found: int
    n_repeats_dropped: int
    #: Source tracks cut into two or more parts, and the new track indices created.
    n_tracks_split: int
    n_new_tracks: int
    #: Observations rejected for disparity <= 0, for 0 < disparity < min_disparity, and for
    #: depth beyond max_depth.
    n_nonpositive_disparity: int
    n_tiny_disparity: int
    n_far: int
    #: Frames where many tracks repeat at once (see :func:`find_repeat_events`).
    repeat_event_frames: tuple[int, ...]
    #: Repeats outside those frames.
    n_isolated_repeats: int

    @property
    def n_repeat_events(self) -> int:
        return len(self.repeat_event_frames)

    @property
    def n_rejected(self) -> int:
        return self.n_nonpositive_disparity + self.n_tiny_disparity + self.n_far

    def summary(self) -> str:
        return (
            f"{self.n_repeat_events} repeat events, {self.n_repeats_found} repeats "
            f"({self.n_repeats_dropped} dropped, {self.n_tracks_split} tracks split into "
            f"{self.n_new_tracks} new), rejected {self.n_nonpositive_disparity} non-positive, "
            f"{self.n_tiny_disparity} tiny-disparity, {self.n_far} far observations; "
            f"{self.n_observations_in} -> {self.n_observations_out} observations"
        )


def _track_order(obs: Observations) -> tuple[np.ndarray, np.ndarray]:
    """Row order sorting observations by (track, frame), and the frame of each row."""
    frame = obs.frame_index
    return np.lexsort((frame, obs.track)), frame


def repeat_mask(obs: Observations) -> np.ndarray:
    """(N,) True where an observation equals the previous observation of its track exactly."""
    order, _ = _track_order(obs)
    t = obs.track[order]
    z = obs.z[order]
    rep_sorted = np.zeros(len(obs), dtype=bool)
    rep_sorted[1:] = (t[1:] == t[:-1]) & np.all(z[1:] == z[:-1], axis=1)
    rep = np.empty_like(rep_sorted)
    rep[order] = rep_sorted
    return rep


def find_repeat_events(
    seq: Sequence,
    min_repeats: int = EVENT_MIN_REPEATS,
    min_fraction: float = EVENT_MIN_FRACTION,
) -> list[RepeatEvent]:
    """Frames where at least ``min_repeats`` tracks, and at least ``min_fraction`` of the tracks
    continuing from the previous frame, repeat their previous observation exactly."""
    obs = seq.obs
    T = seq.n_frames
    frame = obs.frame_index
    rep = repeat_mask(obs)
    n_rep = np.bincount(frame[rep], minlength=T)
    first = seq.track_first_frame()
    starts = first[first >= 0]
    n_new = np.bincount(starts, minlength=T)
    n_cont = obs.per_frame - np.bincount(frame[first[obs.track] == frame], minlength=T)
    events = np.nonzero((n_rep >= min_repeats) & (n_rep >= min_fraction * np.maximum(n_cont, 1)))
    return [
        RepeatEvent(int(f), int(n_rep[f]), int(n_cont[f]), int(n_new[f])) for f in events[0]
    ]


def clean_sequence(
    seq: Sequence,
    split_repeats: bool = True,
    min_disparity: float = 1.0,
    max_depth: float | None = None,
) -> tuple[Sequence, CleaningReport]:
    """Split tracks at exact repeats and reject unusable disparities (see the module notes).

    ``split_repeats=False`` keeps tracks as given (repeats are still counted, not dropped).
    Observations with disparity ``uL - uR <= 0`` or ``< min_disparity`` (px) are rejected, and,
    if ``max_depth`` (m) is given, those whose stereo depth ``fsu b / d`` exceeds it.
    Returns the cleaned sequence and a :class:`CleaningReport`.
    """
    obs = seq.obs
    n_in = len(obs)
    frame = obs.frame_index
    track = obs.track.copy()
    z = obs.z
    rep = repeat_mask(obs)
    events = find_repeat_events(seq)
    event_frames = tuple(e.frame for e in events)
    n_isolated = int(np.sum(rep & ~np.isin(frame, event_frames)))

    keep = np.ones(n_in, dtype=bool)
    n_tracks = seq.n_tracks
    origin = np.asarray(seq.track_origin, dtype=np.int64)
    n_split = n_new = 0
    if split_repeats and rep.any():
        keep &= ~rep
        # Part index of each observation within its track: repeats seen so far in the track.
        order = np.lexsort((frame, track))
        rep_s = rep[order]
        t_s = track[order]
        count = np.cumsum(rep_s)
        start = np.flatnonzero(np.r_[True, t_s[1:] != t_s[:-1]])
        part_s = count - np.repeat(count[start] - rep_s[start], np.diff(np.r_[start, n_in]))
        part = np.empty_like(part_s)
        part[order] = part_s
        later = keep & (part > 0)
        if later.any():
            key = track[later] * (int(part.max()) + 1) + part[later]
            uniq, inv = np.unique(key, return_inverse=True)
            first_frame = np.full(uniq.size, np.iinfo(np.int64).max, dtype=np.int64)
            np.minimum.at(first_frame, inv, frame[later])
            parent = uniq // (int(part.max()) + 1)
            rank = np.empty(uniq.size, dtype=np.int64)
            rank[np.lexsort((parent, first_frame))] = np.arange(uniq.size)
            track[later] = n_tracks + rank[inv]
            origin = np.concatenate([origin, origin[parent[np.argsort(rank)]]])
            n_new = int(uniq.size)
            n_split = int(np.unique(parent).size)
            n_tracks += n_new

    d = z[:, 0] - z[:, 2]
    nonpos = d <= 0
    tiny = ~nonpos & (d < min_disparity)
    far = np.zeros(n_in, dtype=bool)
    if max_depth is not None:
        cal = seq.calibration
        with np.errstate(divide="ignore"):
            far = ~nonpos & ~tiny & (cal.fsu * cal.baseline / np.where(d > 0, d, 1.0) > max_depth)
    counted = keep.copy()  # a dropped repeat is not also counted as a bad disparity
    keep &= ~(nonpos | tiny | far)

    new_obs = Observations.from_rows(frame[keep], track[keep], z[keep], seq.n_frames)
    cleaned = dataclasses.replace(seq, obs=new_obs, n_tracks=n_tracks, track_origin=origin)
    report = CleaningReport(
        n_observations_in=n_in,
        n_observations_out=len(new_obs),
        n_tracks_in=seq.n_tracks,
        n_tracks_out=n_tracks,
        n_repeats_found=int(rep.sum()),
        n_repeats_dropped=int(rep.sum()) if split_repeats else 0,
        n_tracks_split=n_split,
        n_new_tracks=n_new,
        n_nonpositive_disparity=int(np.sum(nonpos & counted)),
        n_tiny_disparity=int(np.sum(tiny & counted)),
        n_far=int(np.sum(far & counted)),
        repeat_event_frames=event_frames,
        n_isolated_repeats=n_isolated,
    )
    log.info("cleaned %s: %s", seq.name, report.summary())
    return cleaned, report
