"""Repair the shared drives' track quirk and reject unusable stereo observations.

The quirk (foundation issue, DESIGN.md): at each frame where many new tracks start, every
continuing track repeats its previous observation exactly, and its later observations no longer
fit its earlier ones (they lag). The repair drops the repeated observation and continues the
rest of the track as a **new** track index, so that no landmark is fitted to both parts (with
known poses, the split tracks' reprojection residuals fall: ``tests/test_cleaning.py``).

Stereo observations with non-positive or tiny disparity ``uL - uR`` (down to about -190 px in
the shared data) cannot be triangulated and are rejected here too, as are points beyond
``max_depth`` if given. Both estimators call :func:`clean_sequence` before estimating.

A track that comes back after a gap (a room, a loop, a tracker that recognises a landmark it
saw before) is one landmark, and cleaning keeps it one track, unless its pixels say otherwise: an
observation equal to the track's previous one is a repeat (after a gap too: with pixel noise
the same four pixels are never seen twice), and a track's return is split off as a new track only when its stereo point does not fit the
point it left, in the rigid motion between the two frames that the other tracks seen in both
give (:func:`inconsistent_returns`). The KITTI drives' tracks have no gaps: none of this
changes them.

Track numbering after a split: the first part of a track keeps its index; later parts get new
indices ``n_tracks, n_tracks + 1, ...`` in order of their first frame, and ``track_origin``
keeps the column of the source file each one came from.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass

import numpy as np

from vislam.ekf.geometry import hat
from vislam.ekf.sequence import Observations, Sequence, track_runs

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


#: A return is judged only where at least this many other tracks are seen in both frames.
RETURN_MIN_COMMON = 4
#: A return is judged only where the fit of the others predicts its point to within this (m,
#: one sigma, first order): where they barely pin the motion down, the first order is no guide.
RETURN_MAX_FIT_M = 0.2
#: ... and split only when its point is also this far (m) from where the fit puts it.
RETURN_MIN_JUMP_M = 0.5
#: Returns after a gap shorter than this (s) are not judged: the tracker's own short losses
#: (most returns of a loop drive; judging them would cost more than the estimators).
RETURN_MIN_GAP_S = 1.0
#: Only points of at least this disparity (px) take part in judging a return: below it the
#: stereo depth is too far from Gaussian for a first-order covariance.
RETURN_MIN_DISPARITY = 20.0
#: Pixel sigma (px) the judgement of a return assumes: generous, as the model is not known yet.
RETURN_PIXEL_SIGMA = 2.0
#: A return is inconsistent when its squared Mahalanobis distance exceeds this (chi-square,
#: 3 dof, probability 1e-6 of a consistent one being split).
RETURN_CHI2 = 30.66


def inconsistent_returns(seq: Sequence) -> np.ndarray:
    """(N,) True at the observation where a track comes back after a gap with pixels that do not
    fit it: its stereo point at the return frame ``b``, moved into the frame ``a`` it was last
    seen in by the rigid motion that the other tracks seen in both frames give (least squares,
    scipy's Kabsch, refitted once without the others that do not fit), is further from its point
    at ``a`` than both points' stereo covariances (RETURN_PIXEL_SIGMA) and the fit's own error
    allow (RETURN_CHI2) and by at least RETURN_MIN_JUMP_M. A return is never split when its gap
    is shorter than RETURN_MIN_GAP_S, when the fit predicts its point only to RETURN_MAX_FIT_M,
    when fewer than RETURN_MIN_COMMON other tracks are seen in both frames, or when either point
    has a disparity below RETURN_MIN_DISPARITY (the others too take part only above it)."""
    from scipy.spatial.transform import Rotation

    from vislam.ekf.camera import triangulate

    obs = seq.obs
    out = np.zeros(len(obs), dtype=bool)
    order, frame = _track_order(obs)
    t, f = obs.track[order], frame[order]
    stamps = np.asarray(seq.timestamps, dtype=float)
    back = np.flatnonzero((t[1:] == t[:-1]) & (f[1:] - f[:-1] > 1)
                          & (stamps[f[1:]] - stamps[f[:-1]] >= RETURN_MIN_GAP_S)) + 1
    if back.size == 0:
        return out
    cal = seq.calibration
    z = obs.z
    ok_disp = z[:, 0] - z[:, 2] >= RETURN_MIN_DISPARITY
    pts = np.full((len(obs), 3), np.nan)
    covs = np.full((len(obs), 3, 3), np.nan)
    pts[ok_disp], covs[ok_disp] = triangulate(z[ok_disp], cal.K, cal.baseline,
                                              RETURN_PIXEL_SIGMA**2 * np.eye(4))
    ptr = obs.frame_ptr
    for i in back:
        r_b, r_a = order[i], order[i - 1]
        if not (ok_disp[r_a] and ok_disp[r_b]):
            continue
        a, b, j = int(f[i - 1]), int(f[i]), int(t[i])
        ta, tb = obs.track[ptr[a]:ptr[a + 1]], obs.track[ptr[b]:ptr[b + 1]]
        common, ia, ib = np.intersect1d(ta, tb, assume_unique=True, return_indices=True)
        keep = (common != j) & ok_disp[ptr[a] + ia] & ok_disp[ptr[b] + ib]
        if keep.sum() < RETURN_MIN_COMMON:
            continue
        rows_a, rows_b = ptr[a] + ia[keep], ptr[b] + ib[keep]
        pa, pb = pts[rows_a], pts[rows_b]
        use = np.ones(pa.shape[0], dtype=bool)
        for _ in range(2):  # fit, then refit without the others that do not fit
            ca, cb = pa[use].mean(axis=0), pb[use].mean(axis=0)
            R = Rotation.align_vectors(pa[use] - ca, pb[use] - cb)[0].as_matrix()
            res = (pb - cb) @ R.T + ca - pa
            cov = covs[rows_a] + R @ covs[rows_b] @ R.T
            fits = np.einsum("ni,ni->n", res, np.linalg.solve(cov, res[..., None])[..., 0])
            fitted, use = use, fits <= RETURN_CHI2
            if use.sum() < RETURN_MIN_COMMON:
                break
        if use.sum() < RETURN_MIN_COMMON:
            continue
        # The fit's own error (least squares' sandwich: (J^T J)^-1 J^T cov J (J^T J)^-1 with
        # J = [-(R q)^, I] per point, q about the centroid; large where the others are nearly
        # on a line) carried to the returning point.
        J = np.concatenate([-hat((pb[fitted] - cb) @ R.T), np.broadcast_to(np.eye(3), (int(fitted.sum()), 3, 3))], axis=2)
        bread = np.linalg.pinv(np.einsum("nji,njk->ik", J, J), hermitian=True)
        meat = np.einsum("nji,njk,nkl->il", J, cov[fitted], J)
        J_r = np.concatenate([-hat(R @ (pts[r_b] - cb)), np.eye(3)], axis=1)
        fit_cov = J_r @ bread @ meat @ bread @ J_r.T
        if np.trace(fit_cov) > RETURN_MAX_FIT_M**2:
            continue  # the others do not pin the motion down at this point
        d = R @ (pts[r_b] - cb) + ca - pts[r_a]
        S = R @ covs[r_b] @ R.T + covs[r_a] + fit_cov
        out[r_b] = (float(d @ np.linalg.solve(S, d)) > RETURN_CHI2
                    and float(np.linalg.norm(d)) > RETURN_MIN_JUMP_M)
    return out


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
    """Split tracks at exact repeats and at inconsistent returns after a gap, and reject unusable
    disparities (see the module notes).

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
    cut = inconsistent_returns(seq) if split_repeats else np.zeros(n_in, dtype=bool)
    if cut.any():
        log.info("cleaning %s: %d tracks come back with pixels that do not fit them: split",
                 seq.name, int(cut.sum()))
    if split_repeats and (rep.any() or cut.any()):
        keep &= ~rep
        # Part index of each observation within its track: repeats (dropped) and inconsistent
        # returns (kept, the first of their part) seen so far in the track.
        order, start, end = track_runs(frame, track)
        rep_s = (rep | cut)[order]
        count = np.cumsum(rep_s)
        part_s = count - np.repeat(count[start] - rep_s[start], end - start)
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
