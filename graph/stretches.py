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


__all__ = ["stretch_labels"]
