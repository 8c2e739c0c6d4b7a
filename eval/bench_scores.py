"""The figures of ``results.json``: each estimator on a drive scored against ground truth and
against the smoother's estimate on the same data.

``results.json`` (schema 2)::

    {"schema": 2, "rpe_definition": ..., "rpe_drive_definition": ..., "reference": ...,
     "alignment": "se3", "alignment_definition": ..., "sequences": [
        {"name", "path", "frames", "has_ground_truth", "has_landmark_truth", "model",
         "truth_check", "estimators": [
            {"name", "error", "runtime_s", "frames_per_s", "landmarks",
             "ate_m", "ate_aligned_m", "rpe_trans_pct", "rpe_rot_deg_per_100m",
             "rpe_drive_trans_pct", "rpe_drive_rot_deg_per_m", "rpe_drive",
             "nees_pose_mean", "map_rmse_m", "nees_landmark_mean",
             "vs_smoother": {"ate_m", "ate_aligned_m", "map_rmse_m", "nees_pose_mean",
                             "inside_95_fraction"}}, ...]}, ...]}

Every key is always present; a figure that cannot be computed is null. ``rpe_trans_pct`` /
``rpe_rot_deg_per_100m`` are KITTI's drift over 100-800 m (null on a drive shorter than 100 m);
``rpe_drive_trans_pct`` / ``rpe_drive_rot_deg_per_m`` the drive-fitted RPE over segment lengths
chosen from the drive's own true path (:func:`eval.metrics.drive_rpe`: mean over all segments),
and ``rpe_drive`` its detail: the lengths used, the true path length, per length the number of
segments and mean / median / RMSE of the translation error (m, %) and rotation error (deg,
deg/m), and ``note``, in words why there is no figure (null when there is one). ``rpe_drive`` is
null only without ground truth or for a failed estimator. Schema 1 (before ``rpe_drive``) is
read too (:mod:`eval.results`). ``alignment`` is the
alignment before every ``ate_aligned_m`` (against ground truth and against the smoother): one
of :data:`eval.metrics.ALIGN_MODES` (``--align``; "se3" by default, and in files written before
the key existed), ``alignment_definition`` says it in words. ``map_rmse_m`` and
``nees_landmark_mean`` compare with true landmarks (simulations only); ``vs_smoother`` compares
with the smoother's estimate on the same sequence (null for the smoothers themselves).
``truth_check`` is, on a raw-IMU drive with ground truth, how the truth's turn over 1 s compares
with the gyro's (:func:`eval.inertial_truth.gyro_agreement`: ``interval_s``, ``pairs``,
``rms_mrad`` per body axis, ``sheet_mrad`` what the IMU's data sheet allows, ``truth_bias``,
``ratio``), null elsewhere.
"""

from __future__ import annotations

import numpy as np

from vislam.ekf.estimate import Estimate
from vislam.ekf.geometry import se3_inv
from vislam.eval.consistency import (
    ate_or_none,
    landmark_nees,
    landmark_rmse,
    pose_nees,
    versus_smoother,
)
from vislam.eval.drives import BenchSequence
from vislam.eval.inertial_truth import frame0_gauge
from vislam.eval.metrics import check_align_mode, drive_rpe, kitti_drift
from vislam.eval.registry import INERTIAL_SMOOTHERS, SMOOTHERS, drive_kind
from vislam.eval.study import JobFailure, JobResult

#: The results.json schema written here; 2 added the drive-fitted RPE (``rpe_drive*``).
SCHEMA = 2
ESTIMATOR_KEYS = (
    "name", "error", "runtime_s", "frames_per_s", "landmarks", "ate_m", "ate_aligned_m",
    "rpe_trans_pct", "rpe_rot_deg_per_100m", "rpe_drive_trans_pct", "rpe_drive_rot_deg_per_m",
    "rpe_drive", "nees_pose_mean", "map_rmse_m", "nees_landmark_mean", "vs_smoother",
)
#: The trajectory figures of a row (:func:`trajectory_scores`), in the row's order.
TRAJECTORY_KEYS = ("ate_m", "ate_aligned_m", "rpe_trans_pct", "rpe_rot_deg_per_100m",
                   "rpe_drive_trans_pct", "rpe_drive_rot_deg_per_m", "rpe_drive",
                   "nees_pose_mean")
VS_SMOOTHER_KEYS = ("ate_m", "ate_aligned_m", "map_rmse_m", "nees_pose_mean", "inside_95_fraction")
SEQUENCE_KEYS = ("name", "path", "frames", "has_ground_truth", "has_landmark_truth", "model",
                 "truth_check", "estimators")

#: What rpe_trans_pct / rpe_rot_deg_per_100m mean in every output.
RPE_DEFINITION = (
    "KITTI odometry drift: mean translation error (%) and rotation error (deg/100 m) over all "
    "path segments of 100, 200, ..., 800 m (eval.metrics.kitti_drift); null when the "
    "trajectory is shorter than the shortest segment"
)

#: What rpe_drive_trans_pct / rpe_drive_rot_deg_per_m (and rpe_drive) mean in every output.
RPE_DRIVE_DEFINITION = (
    "relative pose error over segment lengths fitted to the drive: 1, 2, 3, 4 and 5 steps, the "
    "step a tenth of the drive's true path length rounded to one significant figure (about "
    "10-50 % of the path; a length spanning fewer than 5 frame steps on average is dropped); "
    "every frame starts a "
    "segment, its end the frame whose true travelled distance is closest to the length, "
    "within 10 % of it (evo_rpe --delta_unit m --all_pairs --pairs_from_reference); "
    "translation error in % and rotation error in deg/m of each segment's true path length, "
    "the mean over all segments of all lengths (eval.metrics.drive_rpe); rpe_drive holds the "
    "lengths and, per length, mean / median / RMSE in m, %, deg and deg/m"
)


def trajectory_scores(est: Estimate, gt, align: str = "se3") -> dict:
    """ATE (raw and aligned by ``align``, one of eval.metrics.ALIGN_MODES, recorded as
    ``alignment``), KITTI drift, the drive-fitted RPE (``rpe_drive``: its detail, with the
    reason in words where it has no figure) and mean pose NEES of ``est`` against ground truth
    ``gt`` (frames, poses) on the frames both have; every figure None without ``gt``. An
    unknown ``align`` is an InputError."""
    check_align_mode(align)
    out = {
        "ate_m": None,
        "ate_aligned_m": None,
        "rpe_trans_pct": None,
        "rpe_rot_deg_per_100m": None,
        "rpe_drive_trans_pct": None,
        "rpe_drive_rot_deg_per_m": None,
        "rpe_drive": None,
        "nees_pose_mean": None,
        "gt_frames": 0,
        "alignment": align,
    }
    if gt is None:
        return out
    frames = np.asarray(gt.frames, dtype=np.int64)
    keep = (frames >= 0) & (frames < est.n_frames)
    frames, gt_poses = frames[keep], np.asarray(gt.poses)[keep]
    fitted = _finite(drive_rpe(est.poses[frames], gt_poses))
    out["rpe_drive"] = fitted
    out["rpe_drive_trans_pct"] = (fitted["trans_pct"] or {}).get("mean")
    out["rpe_drive_rot_deg_per_m"] = (fitted["rot_deg_per_m"] or {}).get("mean")
    if frames.size < 2:
        return out
    est_poses = est.poses[frames]
    out["gt_frames"] = int(frames.size)
    out["ate_m"] = ate_or_none(est_poses, gt_poses, align=None)
    out["ate_aligned_m"] = ate_or_none(est_poses, gt_poses, align=align)
    drift = kitti_drift(est_poses, gt_poses)
    if drift:
        out["rpe_trans_pct"] = _num(drift.get("t_rel_pct"))
        out["rpe_rot_deg_per_100m"] = _num(drift.get("r_rel_deg_per_100m"))
    nees = pose_nees(est, frames, gt_poses)
    finite = np.isfinite(nees)
    if np.any(finite):
        out["nees_pose_mean"] = float(nees[finite].mean())
    return out


def _num(x) -> float | None:
    if x is None:
        return None
    try:
        x = float(x)
    except (TypeError, ValueError):
        return None
    return x if np.isfinite(x) else None


def _finite(x):
    """``x`` (nested dicts and lists of figures) with every non-finite number made None."""
    if isinstance(x, dict):
        return {k: _finite(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_finite(v) for v in x]
    if isinstance(x, float):
        return _num(x)
    return x


def default_alignment(align: str | None, seq) -> str:
    """The alignment of a drive's aligned ATE: ``align`` where given, else se3 for a velocity
    drive and yaw (4-DoF: rotation about gravity and translation) for a raw-IMU drive, whose
    roll and pitch gravity makes observable."""
    if align is not None:
        return align
    return "yaw" if drive_kind(seq) == "raw-imu" else "se3"


def truth_in_gauge(gt, seq, est: Estimate):
    """The ground truth ``est`` is scored against: a raw-IMU drive's moved onto the estimate's
    own yaw and origin at frame 0 (:func:`eval.inertial_truth.frame0_gauge`), any other as it
    is."""
    if gt is None or drive_kind(seq) != "raw-imu" or not est.n_frames:
        return gt
    return frame0_gauge(gt, est.poses[0])


def landmark_truth_in_gauge(gt, seq, est: Estimate, landmarks: np.ndarray | None) -> np.ndarray | None:
    """The true landmarks (n, 3) ``est``'s map is scored against: on a raw-IMU drive moved by the
    same rotation about gravity and translation as its ground truth (:func:`truth_in_gauge`),
    so that map and poses are scored in one world; any other as they are."""
    if landmarks is None:
        return None
    moved = truth_in_gauge(gt, seq, est)
    if moved is gt:
        return landmarks
    move = np.asarray(moved.poses)[0] @ se3_inv(np.asarray(gt.poses)[0])
    return np.asarray(landmarks) @ move[:3, :3].T + move[:3, 3]


def reference_smoother(ests: dict[str, Estimate]) -> str | None:
    """The smoother the EKFs are compared with: the batch one if it ran, else iSAM2; on a
    raw-IMU drive the raw-IMU smoother."""
    return next((n for n in SMOOTHERS + INERTIAL_SMOOTHERS if n in ests), None)


def score_sequence(bs: BenchSequence, estimators: list[str], outcomes: dict,
                   align: str = "se3") -> dict:
    """The results.json entry of one sequence (see the module docstring); ``align`` the
    alignment before every aligned ATE (eval.metrics.ALIGN_MODES); ``outcomes``
    {estimator: JobResult or JobFailure}."""
    ests = {n: o.estimate for n, o in outcomes.items() if isinstance(o, JobResult)}
    ref = reference_smoother(ests)
    rows = []
    for name in estimators:
        o = outcomes.get(name)
        row = {k: None for k in ESTIMATOR_KEYS}
        row["name"] = name
        row["vs_smoother"] = {k: None for k in VS_SMOOTHER_KEYS}
        if isinstance(o, JobFailure) or o is None:
            row["error"] = o.error if o is not None else "not run"
            rows.append(row)
            continue
        est = o.estimate
        row["runtime_s"] = o.wall_s
        row["frames_per_s"] = est.n_frames / o.wall_s if o.wall_s > 0 else None
        row["landmarks"] = int(np.count_nonzero(est.has_landmark))
        scores = trajectory_scores(est, truth_in_gauge(bs.gt, bs.sequence, est), align=align)
        for k in TRAJECTORY_KEYS:
            row[k] = scores[k]
        if bs.landmark_truth is not None and row["landmarks"]:
            true_map = landmark_truth_in_gauge(bs.gt, bs.sequence, est, bs.landmark_truth)
            row["map_rmse_m"] = landmark_rmse(est, true_map)
            nees = landmark_nees(est, true_map)
            if np.any(np.isfinite(nees)):
                row["nees_landmark_mean"] = float(np.nanmean(nees))
        if ref is not None and name not in SMOOTHERS + INERTIAL_SMOOTHERS:
            row["vs_smoother"] = versus_smoother(est, ests[ref], align=align)
        rows.append(row)
    return {
        "name": bs.name,
        "path": bs.path,
        "frames": bs.sequence.n_frames,
        "has_ground_truth": bs.gt is not None,
        "has_landmark_truth": bs.landmark_truth is not None,
        "model": bs.model,
        "truth_check": bs.truth_check,
        "reference_smoother": ref,
        "alignment": align,
        "estimators": rows,
    }

