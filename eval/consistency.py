"""Consistency scores: NEES against ground truth, chi-square bounds and verdicts, and the
cross-validation of an EKF against the smoother where ground truth is missing.

Definitions (DESIGN.md, "Scoring"):

- Pose NEES at step k: ``xi^T P^-1 xi`` with ``world_T_imu_true = world_T_imu_est @ exp(xi)``
  (the Estimate's right perturbation, 6 dof): :func:`pose_nees`, the quadratic form
  :func:`eval.metrics.nees`.
  Landmark NEES: ``e^T P^-1 e`` with ``e = m_true - m_est`` (3 dof).
- Step 0 is left out of every pose-NEES average: the world frame is the IMU frame at step 0, so
  the error there is zero by construction and its NEES says nothing about consistency.
- ANEES over N Monte Carlo runs: the mean of N NEES values of d dof; for a consistent estimator
  N * ANEES ~ chi2(N d), so its two-sided 95 % bounds are ``chi2.ppf([0.025, 0.975], N d) / N``.
  The single-run case is N = 1.
- Verdict: "inside" the bounds; "above" the upper bound = the estimator is overconfident (its
  covariance is too small for its errors); "below" = underconfident.
- Without ground truth the smoother stands in: the EKF's pose error relative to the smoother,
  normalised by the EKF's covariance (the smoother's own uncertainty is ignored, so these NEES
  values are a lower bound on what full ground truth would give).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from vislam.ekf import chi_square as chi2

from vislam.ekf.estimate import Estimate
from vislam.ekf.errors import InputError
from vislam.eval.metrics import ate_rmse, check_align_mode, nees, pose_errors

POSE_DOF = 6
LANDMARK_DOF = 3

VERDICT_INSIDE = "inside"
VERDICT_ABOVE = "above"  # overconfident
VERDICT_BELOW = "below"  # underconfident
#: Each verdict in words, as the checks and reports say it.
VERDICT_WORDS = {VERDICT_INSIDE: "inside", VERDICT_ABOVE: "above (overconfident)",
                 VERDICT_BELOW: "below (underconfident)"}


def chi2_bounds(n_runs: int, dof: int, probability: float = 0.95) -> tuple[float, float]:
    """Two-sided bounds on the mean of ``n_runs`` NEES values of ``dof`` degrees of freedom."""
    if n_runs < 1 or dof < 1:
        raise ValueError(f"n_runs and dof must be >= 1, got {n_runs}, {dof}")
    tail = (1.0 - probability) / 2.0
    lo, hi = chi2.ppf([tail, 1.0 - tail], n_runs * dof) / n_runs
    return float(lo), float(hi)


#: Two-sided 95 % band of a single 6-dof pose NEES (chi-square): where a consistent estimator's
#: mean pose NEES against ground truth belongs when it is read frame by frame over one drive.
POSE_NEES_BAND = (1.237, 14.449)


def reference_honesty(name: str, nees: float | None) -> str | None:
    """The sentence that says a reference's covariance is not a fair yardstick on a drive: its
    mean pose NEES against ground truth ``nees`` outside :data:`POSE_NEES_BAND`; None inside it
    (or without a figure)."""
    if nees is None or not np.isfinite(nees):
        return None
    lo, hi = POSE_NEES_BAND
    if lo <= nees <= hi:
        return None
    word = "overconfident" if nees > hi else "underconfident"
    return (f"The {name} is {word} on this drive: pose NEES {nees:.3g}, band [{lo:.2f}, {hi:.2f}]; "
            "its covariance is not a fair yardstick here")


def verdict(value: float, bounds: tuple[float, float]) -> str | None:
    """"inside", "above" (overconfident) or "below" (underconfident); None for a NaN value."""
    if value is None or not np.isfinite(value):
        return None
    if value > bounds[1]:
        return VERDICT_ABOVE
    if value < bounds[0]:
        return VERDICT_BELOW
    return VERDICT_INSIDE


@dataclass
class AneesResult:
    """ANEES of items (time steps or landmarks) averaged over N runs.

    ``per_item`` (K,) the N-run average of each item (NaN where any run lacks it); ``mean`` the
    mean of ``per_item`` over items; ``bounds`` the N-run chi-square bounds; ``verdict`` of
    ``mean`` against ``bounds``; ``inside_fraction`` the share of items inside the bounds.
    """

    dof: int
    n_runs: int
    per_item: np.ndarray
    mean: float
    bounds: tuple[float, float]
    verdict: str | None
    inside_fraction: float

    def to_dict(self, prefix: str = "") -> dict:
        return {
            f"{prefix}anees": _finite_or_none(self.mean),
            f"{prefix}bounds": list(self.bounds),
            f"{prefix}verdict": self.verdict,
            f"{prefix}inside_fraction": _finite_or_none(self.inside_fraction),
        }


def anees(nees: np.ndarray, dof: int, probability: float = 0.95) -> AneesResult:
    """ANEES of an (N runs, K items) NEES array (a 1-D array is one run)."""
    nees = np.atleast_2d(np.asarray(nees, dtype=float))
    n_runs = nees.shape[0]
    bounds = chi2_bounds(n_runs, dof, probability)
    complete = np.all(np.isfinite(nees), axis=0)
    per_item = np.full(nees.shape[1], np.nan)
    per_item[complete] = nees[:, complete].mean(axis=0)
    if np.any(complete):
        mean = float(per_item[complete].mean())
        inside = (per_item[complete] >= bounds[0]) & (per_item[complete] <= bounds[1])
        inside_fraction = float(inside.mean())
    else:
        mean, inside_fraction = float("nan"), float("nan")
    return AneesResult(dof, n_runs, per_item, mean, bounds, verdict(mean, bounds), inside_fraction)


# --- NEES against ground truth -------------------------------------------------------------


def pose_nees(est: Estimate, gt_frames: np.ndarray, gt_poses: np.ndarray) -> np.ndarray:
    """Pose NEES (T,) of ``est`` against ground truth; NaN at step 0, at steps without ground
    truth, and where the covariance is missing."""
    out = np.full(est.n_frames, np.nan)
    frames = np.asarray(gt_frames, dtype=np.int64)
    keep = (frames >= 0) & (frames < est.n_frames)
    frames = frames[keep]
    if frames.size == 0:
        return out
    values = nees(pose_errors(est.poses[frames], np.asarray(gt_poses)[keep]), est.pose_cov[frames])
    out[frames] = values
    out[0] = np.nan
    return out


def landmark_truth_for(est: Estimate, truth: np.ndarray) -> np.ndarray:
    """True landmark positions (M_est, 3) per track of ``est``: ``truth`` is indexed by the
    source file's track columns and a cleaned estimate maps its tracks to them through
    ``info["track_origin"]``."""
    truth = np.asarray(truth, dtype=float)
    n = est.landmarks.shape[0]
    origin = est.info.get("track_origin")
    if origin is None:
        if n != truth.shape[0]:
            return np.full((n, 3), np.nan)
        return truth
    origin = np.asarray(origin, dtype=np.int64)
    out = np.full((n, 3), np.nan)
    ok = (origin >= 0) & (origin < truth.shape[0])
    out[ok] = truth[origin[ok]]
    return out


def landmark_nees(est: Estimate, truth: np.ndarray) -> np.ndarray:
    """Landmark NEES (M_est,) against true positions (source-track indexed); NaN where the
    estimate has no landmark or no covariance."""
    gt = landmark_truth_for(est, truth)
    out = np.full(est.landmarks.shape[0], np.nan)
    ok = (
        est.has_landmark
        & np.all(np.isfinite(gt), axis=1)
        & np.all(np.isfinite(est.landmark_cov.reshape(-1, 9)), axis=1)
    )
    if np.any(ok):
        out[ok] = nees(gt[ok] - est.landmarks[ok], est.landmark_cov[ok])
    return out


def landmark_rmse(est: Estimate, truth: np.ndarray) -> float | None:
    """RMSE (m) of the estimated landmarks against true positions; None with no landmark."""
    gt = landmark_truth_for(est, truth)
    ok = est.has_landmark & np.all(np.isfinite(gt), axis=1)
    if not np.any(ok):
        return None
    return float(np.sqrt(np.mean(np.sum((est.landmarks[ok] - gt[ok]) ** 2, axis=1))))


# --- cross-validation against the smoother ---------------------------------------------------


def match_landmarks(a: Estimate, b: Estimate) -> tuple[np.ndarray, np.ndarray]:
    """Indices (ia, ib) of tracks both estimates gave a landmark.

    Same track count (same cleaning): per track index. Otherwise through
    ``info["track_origin"]``, keeping only source tracks that map to one track in each.
    """
    if a.landmarks.shape[0] == b.landmarks.shape[0]:
        idx = np.nonzero(a.has_landmark & b.has_landmark)[0]
        return idx, idx
    oa, ob = a.info.get("track_origin"), b.info.get("track_origin")
    if oa is None or ob is None:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    oa, ob = np.asarray(oa, dtype=np.int64), np.asarray(ob, dtype=np.int64)
    ua, ca = np.unique(oa, return_counts=True)
    ub, cb = np.unique(ob, return_counts=True)
    common = np.intersect1d(ua[ca == 1], ub[cb == 1])
    pos_a = {o: i for i, o in enumerate(oa)}
    pos_b = {o: i for i, o in enumerate(ob)}
    ia = np.array([pos_a[o] for o in common], dtype=np.int64)
    ib = np.array([pos_b[o] for o in common], dtype=np.int64)
    if ia.size == 0:
        return ia, ib
    ok = a.has_landmark[ia] & b.has_landmark[ib]
    return ia[ok], ib[ok]


def position_deviation(est: Estimate, ref: Estimate) -> tuple[np.ndarray, np.ndarray]:
    """World-frame position deviation ``est - ref`` (T, 3) and the 1-sigma (T, 3) of ``est``.

    In the Estimate convention the position covariance in the world frame is
    ``R Sigma_rhorho R^T`` (the translation block of a right perturbation, rotated to world).
    """
    dev = est.positions - ref.positions
    R = est.poses[:, :3, :3]
    cov = np.einsum("tij,tjk,tlk->til", R, est.pose_cov[:, :3, :3], R)
    sigma = np.sqrt(np.clip(np.einsum("tii->ti", cov), 0.0, None))
    return dev, sigma


def versus_smoother(est: Estimate, smoother: Estimate, probability: float = 0.95,
                    align: str = "se3") -> dict:
    """Cross-validation of ``est`` against the smoother: ``ate_m`` and ``ate_aligned_m`` (est
    trajectory error w.r.t. the smoother's, raw and after the alignment ``align``, one of
    :data:`eval.metrics.ALIGN_MODES`), ``map_rmse_m`` (landmark RMSE over tracks both
    estimated), ``nees_pose_mean`` (est error w.r.t. the smoother normalised by est's covariance,
    steps 1..T-1) and ``inside_95_fraction`` (share of steps with NEES <= chi2.ppf(0.95, 6)).
    Anything that cannot be computed is None; an unknown ``align`` is an InputError."""
    check_align_mode(align)
    out = {
        "ate_m": None,
        "ate_aligned_m": None,
        "map_rmse_m": None,
        "nees_pose_mean": None,
        "inside_95_fraction": None,
    }
    if est.n_frames != smoother.n_frames:
        return out
    out["ate_m"] = ate_or_none(est.poses, smoother.poses, align=None)
    out["ate_aligned_m"] = ate_or_none(est.poses, smoother.poses, align=align)
    ia, ib = match_landmarks(est, smoother)
    if ia.size:
        d = est.landmarks[ia] - smoother.landmarks[ib]
        out["map_rmse_m"] = float(np.sqrt(np.mean(np.sum(d**2, axis=1))))
    nees = pose_nees(est, np.arange(smoother.n_frames), smoother.poses)
    finite = np.isfinite(nees)
    if np.any(finite):
        out["nees_pose_mean"] = float(nees[finite].mean())
        out["inside_95_fraction"] = float(
            np.mean(nees[finite] <= chi2.ppf(probability, POSE_DOF))
        )
    return out


def ate_or_none(est_poses: np.ndarray, ref_poses: np.ndarray, align: str | None) -> float | None:
    """ATE RMSE (m) of ``est_poses`` against ``ref_poses`` after the alignment ``align`` (one of
    :data:`eval.metrics.ALIGN_MODES`, or None for none); None where it cannot be computed
    (degenerate alignment, non-finite poses). An unknown ``align`` is an InputError, not None."""
    if align is not None:
        check_align_mode(align)

    try:
        return _finite_or_none(ate_rmse(est_poses, ref_poses, align=align))
    except (InputError, np.linalg.LinAlgError):
        return None


def _finite_or_none(x) -> float | None:
    if x is None:
        return None
    x = float(x)
    return x if np.isfinite(x) else None
