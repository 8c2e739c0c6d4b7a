"""Stretches of a drive: consecutive windows of a few seconds, the unit the drive's checks and
its out-of-sample folds work in (graph.data_check, graph.drift_check, graph.out_of_sample)."""

from __future__ import annotations

import numpy as np


def stretch_labels(times: np.ndarray, stretch_s: float) -> np.ndarray:
    """Stretch index (0, 1, ...) of each interval from its start time ``times`` (n,) (s from
    the first frame): consecutive ``stretch_s`` windows, empty ones skipped, a last stretch
    shorter than ``stretch_s / 2`` joined to the one before."""
    if times.size == 0:
        return np.zeros(0, dtype=np.int64)
    raw = np.floor((times - times[0]) / stretch_s).astype(np.int64)
    labels = np.r_[0, np.cumsum(np.diff(raw) != 0)].astype(np.int64)
    last = labels == labels[-1]
    if labels[-1] > 0 and times[-1] - times[last][0] < 0.5 * stretch_s:
        labels[last] = labels[-1] - 1
    return labels


def row_folds(A, offsets: dict, solution, stretch_s: float) -> np.ndarray:
    """The fold (stretch index) of each row of a linearisation ``A`` (its ``offsets``: key ->
    first column) of ``solution``'s graph: the stretch of the earliest pose the row touches, -1
    for rows touching none (:func:`graph.out_of_sample.row_frames`)."""
    from vislam.graph.out_of_sample import row_frames
    from vislam.graph.pose_conversions import X

    T = solution.poses.shape[0]
    frames = row_frames(A, np.array([offsets[X(k)] for k in range(T)]))
    times = np.asarray(solution.cleaned.timestamps, dtype=float)
    labels = stretch_labels(times - times[0], stretch_s)
    return np.where(frames >= 0, labels[np.clip(frames, 0, T - 1)], -1)


__all__ = ["row_folds", "stretch_labels"]
