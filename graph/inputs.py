"""What both smoothers do to a :class:`Sequence` before building a graph: track cleaning."""

from __future__ import annotations

import dataclasses
import logging

import numpy as np

from ekf.config import FilterConfig
from ekf.errors import InputError
from ekf.sequence import Sequence

log = logging.getLogger(__name__)


def prepare_sequence(seq: Sequence, config: FilterConfig) -> tuple[Sequence, dict]:
    """The cleaned sequence (tracks split at exact repeats, tiny disparities dropped) when
    ``config.clean_tracks``, else ``seq`` itself; and a JSON-able summary of the cleaning.

    Without the track repair the smoother is worse than dead reckoning on the shared data
    (DESIGN.md, foundation issue).
    """
    for key, arr in (("timestamps", seq.timestamps), ("linear_velocity", seq.linear_velocity),
                     ("angular_velocity", seq.angular_velocity)):
        bad = np.flatnonzero(~np.all(np.isfinite(np.reshape(arr, (len(arr), -1))), axis=1))
        if bad.size:
            raise InputError(f"sequence {seq.name!r}: {key} is not finite at step {int(bad[0])}")
    if seq.n_frames > 1 and not np.all(np.diff(seq.timestamps) > 0):
        k = int(np.flatnonzero(~(np.diff(seq.timestamps) > 0))[0])
        raise InputError(f"sequence {seq.name!r}: timestamps do not increase at step {k + 1}")
    if not config.clean_tracks:
        return seq, {"cleaned": False}
    try:
        from ekf.cleaning import clean_sequence
    except ImportError:
        log.warning("ekf.cleaning is not available: estimating on the uncleaned tracks")
        return seq, {"cleaned": False, "reason": "ekf.cleaning not available"}
    cleaned, report = clean_sequence(seq, split_repeats=True, min_disparity=config.min_disparity,
                                     max_depth=None)
    summary: dict = {"cleaned": True}
    if dataclasses.is_dataclass(report):
        summary["report"] = {k: v for k, v in dataclasses.asdict(report).items()
                             if isinstance(v, (int, float, str, bool))}
    return cleaned, summary
