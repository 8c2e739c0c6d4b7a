"""The segments of the drive-fitted RPE (:func:`eval.metrics.drive_rpe`): which lengths a
drive gets, and which frame pairs make the segments of each length.

KITTI's 100..800 m segments fit only drives longer than 100 m; these fit every drive. The
segment lengths come from the drive's own true path length ``D`` (the distance travelled along
the ground truth over the scored frames, :func:`path_distances`), by this rule
(:func:`drive_segment_lengths`):

- the step ``s`` is ``D / 10`` rounded to one significant figure (half up,
  :func:`readable_length`): 44 m of path gives 4 m, 137 m gives 10 m, 2.5 km gives 300 m;
- the lengths are ``s, 2 s, 3 s, 4 s, 5 s``: about 10 % to 50 % of the path, as
  rpg_trajectory_evaluation's default sub-trajectory lengths (10-50 % of the path), on one
  readable grid like ov_eval's 8, 16, ..., 40 m (a 44 m drive: 4, 8, 12, 16, 20 m);
- a length is kept only if it spans at least 5 frame steps on average (``L >= 5 D / (n - 1)``
  for n frames with ground truth); shorter ones would be the error of a frame or two, and the
  end of a segment could not be found within its tolerance. A drive of 16 frames or more always
  keeps a length; one of 9 to 15 frames may keep none (depending on how its path length
  rounds), one of 8 frames or fewer never does, nor does one whose truth does not move: it
  then says why in words.

The segments of a length ``L`` (:func:`length_segments`), as evo's ``evo_rpe --delta L
--delta_unit m --all_pairs --pairs_from_reference`` (evo's default relative tolerance 0.1;
without ``--pairs_from_reference`` evo measures the path along the estimate instead of the
truth): every frame ``i`` starts one; its end ``j > i`` is the frame whose travelled true
distance from ``i`` is closest to ``L`` (the earlier on a tie), kept only if it is within 10 %
of ``L``. Everything here depends on the truth alone, so every estimator of a drive gets the
same segments.
"""

from __future__ import annotations

import math

import numpy as np

from vislam.ekf.errors import InputError

#: The rule (module docstring): the step is this fraction of the true path length, rounded to
#: one significant figure ...
RPE_STEP_FRACTION = 0.1
#: ... the lengths are 1, 2, ..., this many steps ...
RPE_STEPS = 5
#: ... each spanning at least this many frame steps on average ...
RPE_MIN_FRAME_STEPS = 5
#: ... and a segment's end is within this fraction of its length (evo's default rel_tol).
RPE_END_TOLERANCE = 0.1


def _poses(x, what: str) -> np.ndarray:
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 3 or x.shape[1:] != (4, 4):
        raise InputError(f"{what}: poses must have shape (T, 4, 4), got {x.shape}")
    return x


def path_distances(poses) -> np.ndarray:
    """Distance travelled along ``poses`` (T, 4, 4) up to each pose (T,), from 0 (the KITTI
    devkit's ``trajectoryDistances``, evo's path length)."""
    p = _poses(poses, "trajectory")[:, :3, 3]
    if p.shape[0] == 0:
        return np.zeros(0)
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])


def readable_length(x: float) -> float:
    """``x`` > 0 rounded to one significant figure, half up (4.4 -> 4, 13.7 -> 10, 250 -> 300,
    0.072 -> 0.07), as the float nearest that decimal."""
    exponent = math.floor(math.log10(x))
    digit = math.floor(x / 10.0**exponent + 0.5)
    return float(f"{digit}e{exponent}")


def lengths_text(lengths) -> str:
    """Segment lengths (m) in words: "4, 8, 12, 16 and 20 m", "5 m", "none"."""
    shown = [f"{float(x):g}" for x in lengths]
    if not shown:
        return "none"
    return (shown[0] if len(shown) == 1 else ", ".join(shown[:-1]) + " and " + shown[-1]) + " m"


def drive_segment_lengths(gt_poses) -> tuple[tuple[float, ...], str | None]:
    """The segment lengths (m) of the drive-fitted RPE for the true poses ``gt_poses`` (n, 4, 4),
    by the rule of the module docstring (step ``D / 10`` to one significant figure, lengths 1..5
    steps, each at least 5 frame steps on average), and None; or no lengths and why, in words
    (a clause that reads after "No RPE: ").
    Depends on the truth alone, so every estimator of a drive gets the same lengths."""
    gt = _poses(gt_poses, "ground truth")
    n = gt.shape[0]
    if n < 2:
        return (), f"only {n} frame{'' if n == 1 else 's'} with ground truth"
    dist = path_distances(gt)
    total = float(dist[-1])
    if not (math.isfinite(total) and total > 0.0):
        return (), f"the true path of the {n} frames with ground truth does not move"
    step = readable_length(RPE_STEP_FRACTION * total)
    digit, exponent = f"{step:.0e}".split("e")
    candidates = [float(f"{k * int(digit)}e{int(exponent)}") for k in range(1, RPE_STEPS + 1)]
    shortest = RPE_MIN_FRAME_STEPS * total / (n - 1)
    lengths = tuple(L for L in candidates if L >= shortest)
    if lengths:
        return lengths, None
    # The step is at least 1/1.5 of a tenth of the path (1.49 rounds to 1), so the longest
    # length is at least a third of it, which spans 5 frame steps from 16 frames on.
    enough = math.ceil(RPE_MIN_FRAME_STEPS * 1.5 / (RPE_STEPS * RPE_STEP_FRACTION)) + 1
    return (), (f"the drive is too short: {n} frames with ground truth over {total:.3g} m of "
                f"true path, and its segment lengths ({lengths_text(candidates)}) would each "
                f"span fewer than {RPE_MIN_FRAME_STEPS} frame steps ({shortest:.3g} m here); "
                f"a drive of {enough} frames or more always has one")


def length_segments(distances: np.ndarray, length: float,
                    tolerance: float = RPE_END_TOLERANCE) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (i, j) of the segments of ``length`` (m) on a path with travelled distances
    ``distances`` (n,), non-decreasing: every i a start, j > i the frame whose distance from i
    is closest to ``length`` (the earlier on a tie), kept where that is within
    ``tolerance * length`` (evo's all-pairs path mode)."""
    dist = np.asarray(distances, dtype=np.float64)
    n = dist.size
    i = np.arange(n)
    target = dist + length
    hi = np.searchsorted(dist, target, side="left")  # the first frame at or beyond the target
    lo = hi - 1  # the last frame before it (at least i, since length > 0)
    hi_c = np.minimum(hi, n - 1)
    over = np.where(hi < n, dist[hi_c] - target, np.inf)
    under = np.where(lo > i, target - dist[np.maximum(lo, 0)], np.inf)
    j = np.where(over < under, hi_c, lo)
    ok = np.minimum(over, under) <= tolerance * length
    return i[ok], j[ok]
