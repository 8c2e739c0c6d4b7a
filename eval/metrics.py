"""Trajectory and map accuracy, and consistency (NEES), against ground truth.

Poses are ``world_T_imu`` (T, 4, 4) in float64; every figure is vectorised over the trajectory.

* ATE (absolute trajectory error): RMSE of position differences (m), raw or after a
  least-squares alignment of the estimated positions onto the true ones. Same definition as
  evo's APE with ``PoseRelation.translation_part``. The alignments (:data:`ALIGN_MODES`,
  :func:`align_trajectory`, every command's ``--align``):

  - ``se3``: rotation and translation (Umeyama 1991), 6 dof; the default.
  - ``sim3``: rotation, translation and scale (Umeyama 1991), 7 dof.
  - ``yaw``: rotation about the world z axis (gravity) and translation, 4 dof: what a
    gravity-aligned visual-inertial estimate leaves unobservable (Zhang and Scaramuzza 2018, "A
    Tutorial on Quantitative Trajectory Evaluation for Visual(-Inertial) Odometry";
    rpg_trajectory_evaluation's ``align_posyaw``). Closed form, :func:`yaw_fit`. Roll and pitch
    errors stay in the figure, as they should when gravity is observed.
  - ``none``: the identity (the raw ATE).
* RPE (relative pose error, evo's definition): for index pairs (i, j = i + delta), non-overlapping
  by default as in evo, ``E = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j)`` with Q the truth and P the estimate;
  RMSE of the translation norm of E (m) and of its rotation angle (deg).
* KITTI drift (the KITTI odometry devkit, ``evaluate_odometry.cpp``): segments of 100..800 m of
  travelled true path, starting every ``step`` frames; the error of a segment is
  ``inv(est_i^-1 est_j) @ (gt_i^-1 gt_j)`` (the devkit's order; the inverse has the same
  translation norm and rotation angle), its translation norm and rotation angle divided by the
  segment length, averaged over all segments of all lengths: percent and degrees per 100 m.
* Drive-fitted RPE (:func:`drive_rpe`), so that every drive with ground truth has a relative
  error, however short: KITTI's 100..800 m segments fit only drives longer than 100 m. The
  segment lengths come from the drive's own true path (1 to 5 steps of a tenth of it, rounded
  to one significant figure) and each frame starts a segment whose end is the frame closest to
  the length along the true path, within 10 % (evo's all-pairs segments): the rule in full is
  :mod:`eval.rpe_segments`. The error of a segment is evo's ``E = (Q_i^-1 Q_j)^-1 (P_i^-1
  P_j)``: translation ``|t(E)|`` (m, and in percent of the segment's own true path length) and
  rotation angle (deg, and deg per metre of that length). Per length and over the segments of
  every length together: mean, median and RMSE; the drive's headline figures (the bench
  table's "RPE (%)" and "RPE (°/m)") are the means over all segments of all lengths, as
  KITTI's t_rel / r_rel are over its segments.
* NEES of poses in the :class:`ekf.estimate.Estimate` convention: right perturbation,
  translation first, ``xi = se3_log(inv(est) @ gt)``, ``NEES = xi^T cov^-1 xi`` (6 dof);
  of points ``e = gt - est`` (3 dof).
"""

from __future__ import annotations

import math

import numpy as np

from vislam.ekf.errors import InputError
from vislam.ekf.geometry import se3_inv, se3_log, vee
from vislam.eval.rpe_segments import (
    RPE_END_TOLERANCE,
    drive_segment_lengths,
    length_segments,
    lengths_text,
    path_distances,
)

#: Segment lengths (m) of the KITTI odometry benchmark.
KITTI_LENGTHS = (100, 200, 300, 400, 500, 600, 700, 800)


#: The trajectory alignments before an aligned ATE (see the module docstring); "se3" is the
#: default everywhere.
ALIGN_MODES = ("se3", "sim3", "yaw", "none")
#: Each alignment mode in words, for the outputs that record which one was used.
ALIGN_DESCRIPTIONS = {
    "se3": "SE(3) alignment (rotation and translation)",
    "sim3": "Sim(3) alignment (rotation, translation and scale)",
    "yaw": "yaw-only 4-dof alignment (rotation about gravity, the world z axis, and translation)",
    "none": "no alignment (equal to the raw ATE)",
}


def check_align_mode(mode) -> str:
    """``mode`` if it is one of :data:`ALIGN_MODES`; an InputError naming it and them otherwise."""
    if not isinstance(mode, str) or mode not in ALIGN_MODES:
        raise InputError(f"alignment mode must be one of {', '.join(ALIGN_MODES)}, got {mode!r}")
    return mode


def _poses(x, what: str) -> np.ndarray:
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 3 or x.shape[1:] != (4, 4):
        raise InputError(f"{what}: poses must have shape (T, 4, 4), got {x.shape}")
    return x


def _pair(est, gt) -> tuple[np.ndarray, np.ndarray]:
    est, gt = _poses(est, "estimated trajectory"), _poses(gt, "ground truth")
    if est.shape[0] != gt.shape[0]:
        raise InputError(
            f"estimated trajectory has {est.shape[0]} poses, ground truth {gt.shape[0]}; "
            "select the common frames first"
        )
    return est, gt


def rotation_angle(R: np.ndarray) -> np.ndarray:
    """Angle (rad, in [0, pi]) of rotation matrices (..., 3, 3), accurate near 0 and pi."""
    R = np.asarray(R, dtype=np.float64)
    sin_t = np.linalg.norm(vee(R - np.swapaxes(R, -1, -2)), axis=-1) / 2.0
    cos_t = (np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.arctan2(sin_t, cos_t)


def _rmse(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


# --------------------------------------------------------------------------- alignment


def umeyama(
    src: np.ndarray, dst: np.ndarray, with_scale: bool = False
) -> tuple[np.ndarray, np.ndarray, float]:
    """Least-squares ``(R, t, s)`` minimising ``sum ||dst_i - (s R src_i + t)||^2``.

    ``src``, ``dst`` (N, 3). ``s`` is 1 unless ``with_scale``. Raises :class:`InputError` when
    the points are too few or degenerate (collinear) for a unique rotation.
    """
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3:
        raise InputError(f"umeyama: need two (N, 3) point sets, got {src.shape} and {dst.shape}")
    n = src.shape[0]
    if n < 3:
        raise InputError(f"umeyama: need at least 3 points, got {n}")
    if not (np.all(np.isfinite(src)) and np.all(np.isfinite(dst))):
        raise InputError("umeyama: points contain non-finite values")
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    xs, xd = src - mu_s, dst - mu_d
    var_s = np.sum(xs * xs) / n
    cov = xd.T @ xs / n  # Umeyama eq. 38
    U, d, Vt = np.linalg.svd(cov)
    if not np.all(np.isfinite(d)) or np.count_nonzero(d > 1e-12 * max(d[0], 1e-300)) < 2:
        raise InputError(f"umeyama: the {n} points are degenerate (collinear or identical)")
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1.0
    R = U @ S @ Vt
    s = float(np.sum(d * np.diag(S)) / var_s) if with_scale else 1.0
    t = mu_d - s * R @ mu_s
    return R, t, s


def yaw_fit(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray]:
    """Least-squares ``(theta, t)`` minimising ``sum ||dst_i - (Rz(theta) src_i + t)||^2``, with
    ``Rz(theta)`` the rotation by ``theta`` (rad) about the z axis: the 4-dof (position and yaw)
    alignment of Zhang and Scaramuzza 2018 (rpg_trajectory_evaluation's ``align_posyaw``).

    ``src``, ``dst`` (N, 3). Derivation: for any rotation the best translation is
    ``t = mean(dst) - Rz mean(src)``, which leaves the centred points ``x_i = src_i - mean(src)``,
    ``y_i = dst_i - mean(dst)``. ``Rz`` does not change z, so minimising ``sum ||y_i - Rz x_i||^2``
    is maximising ``sum y_i . Rz x_i = cos(theta) B + sin(theta) A`` over the horizontal parts,
    with::

        A = sum_i (x_i,x y_i,y - x_i,y y_i,x)     (the cross terms)
        B = sum_i (x_i,x y_i,x + x_i,y y_i,y)     (the dot terms)

    whose maximum is at ``theta = atan2(A, B)`` (unique unless ``A = B = 0``). Degenerate input
    (one pose, or no horizontal spread in either set, so that ``A = B = 0`` and every yaw fits
    equally well): ``theta = 0``, a least-squares solution like any other, never NaN. Raises
    :class:`InputError` for no points or non-finite ones.
    """
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3:
        raise InputError(f"yaw alignment: need two (N, 3) point sets, got {src.shape} and {dst.shape}")
    if src.shape[0] < 1:
        raise InputError("yaw alignment: need at least 1 pose, got none")
    if not (np.all(np.isfinite(src)) and np.all(np.isfinite(dst))):
        raise InputError("yaw alignment: points contain non-finite values")
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    x, y = src[:, :2] - mu_s[:2], dst[:, :2] - mu_d[:2]
    A = float(np.sum(x[:, 0] * y[:, 1] - x[:, 1] * y[:, 0]))
    B = float(np.sum(x[:, 0] * y[:, 0] + x[:, 1] * y[:, 1]))
    # |A + iB| <= |x| |y| (Cauchy-Schwarz); below rounding of that bound the yaw is arbitrary.
    scale = float(np.sqrt(np.sum(x * x) * np.sum(y * y)))
    theta = float(np.arctan2(A, B)) if np.hypot(A, B) > 1e-13 * scale else 0.0
    t = mu_d - _rot_z(theta) @ mu_s
    return theta, t


def _rot_z(theta: float) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def alignment_transform(est_poses, gt_poses, mode: str = "se3") -> tuple[np.ndarray, np.ndarray, float]:
    """The ``(R, t, s)`` of :func:`align_trajectory`: ``gt ~ s R est + t`` for the positions
    (``mode`` one of :data:`ALIGN_MODES`; identity for "none"). Raises :class:`InputError` for an
    unknown mode or input the mode cannot align (see :func:`umeyama`, :func:`yaw_fit`)."""
    est, gt = _pair(est_poses, gt_poses)
    check_align_mode(mode)
    if mode == "none":
        return np.eye(3), np.zeros(3), 1.0
    if mode == "yaw":
        theta, t = yaw_fit(est[:, :3, 3], gt[:, :3, 3])
        return _rot_z(theta), t, 1.0
    return umeyama(est[:, :3, 3], gt[:, :3, 3], with_scale=mode == "sim3")


def align_trajectory(est_poses, gt_poses, mode: str = "se3") -> np.ndarray:
    """Estimated poses moved onto the ground truth by the least-squares fit of their positions.

    ``mode`` (:data:`ALIGN_MODES`): "se3" (rotation and translation, Umeyama), "sim3" (also
    scale: positions are scaled, then the rigid transform is applied to the whole pose, as evo
    does), "yaw" (rotation about the world z axis and translation, :func:`yaw_fit`) or "none"
    (an unchanged copy). An unknown mode is an :class:`InputError` naming the valid ones.
    """
    est, gt = _pair(est_poses, gt_poses)
    check_align_mode(mode)
    if mode == "none":
        return est.copy()
    R, t, s = alignment_transform(est, gt, mode)
    out = est.copy()
    out[:, :3, :3] = R @ est[:, :3, :3]
    out[:, :3, 3] = s * est[:, :3, 3] @ R.T + t
    return out


# --------------------------------------------------------------------------- ATE, RPE


def ate_rmse(est_poses, gt_poses, align: str | None = None) -> float:
    """Translation RMSE (m) of the absolute trajectory error, after the alignment ``align`` (one
    of :data:`ALIGN_MODES`; None is "none")."""
    est, gt = _pair(est_poses, gt_poses)
    if align is not None:
        est = align_trajectory(est, gt, align)
    return _rmse(np.linalg.norm(est[:, :3, 3] - gt[:, :3, 3], axis=1))


def rpe_pairs(n: int, delta: int, all_pairs: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (i, i + delta): consecutive non-overlapping ones (evo's default) or all."""
    if delta < 1:
        raise InputError(f"RPE delta must be at least 1 frame, got {delta}")
    if all_pairs:
        i = np.arange(max(n - delta, 0))
        return i, i + delta
    ids = np.arange(0, n, delta)
    return ids[:-1], ids[1:]


def relative_errors(est: np.ndarray, gt: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """``E = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j)`` (n, 4, 4) for index pairs (i, j): the error of the
    estimated motion from i to j, Q the truth and P the estimate (module docstring, RPE)."""
    return se3_inv(se3_inv(gt[i]) @ gt[j]) @ (se3_inv(est[i]) @ est[j])


def interval_errors(est_poses, gt_poses) -> np.ndarray:
    """The error of each estimated interval motion ``[k, k+1]`` as a twist (T-1, 6),
    translation first: ``se3_log`` of :func:`relative_errors` of consecutive poses. Its mean
    over many intervals is the systematic part of the drift (it adds up coherently), its
    spread the random part."""
    est, gt = _pair(est_poses, gt_poses)
    i = np.arange(max(est.shape[0] - 1, 0))
    return se3_log(relative_errors(est, gt, i, i + 1))


def turn_scale_error(errors: np.ndarray, true_motions: np.ndarray) -> tuple[float, float]:
    """How much too large the estimated turns are, as a fraction of the true turn, and its
    standard error: the least-squares ``k`` in ``e_k = k theta_k + r_k`` over intervals, with
    ``e_k`` the rotation part of :func:`interval_errors` and ``theta_k`` that of the true
    interval motions (``se3_log`` of consecutive true poses), both (n, 6). An estimator whose
    every step turns by ``(1 + k) theta`` has interval errors ``k theta``; a constant ``k``
    adds up to ``k`` times the drive's net turn (a focal length off by 1 % makes vision's
    turns 1 % too large), where white rotation errors average out. The standard error
    treats the residuals ``r_k`` as white; NaN for a drive that does not turn."""
    e = np.asarray(errors, dtype=float)[:, 3:]
    theta = np.asarray(true_motions, dtype=float)[:, 3:]
    ok = np.all(np.isfinite(e), axis=1) & np.all(np.isfinite(theta), axis=1)
    e, theta = e[ok], theta[ok]
    turned = float(np.sum(theta * theta))
    if e.shape[0] < 2 or turned <= 0.0:
        return float("nan"), float("nan")
    k = float(np.sum(e * theta)) / turned
    resid = e - k * theta
    dof = max(3 * e.shape[0] - 1, 1)
    return k, float(np.sqrt(np.sum(resid * resid) / dof / turned))


def rpe(est_poses, gt_poses, delta: int = 1, all_pairs: bool = False) -> dict:
    """Relative pose error over ``delta`` frames (evo's definition; see the module docstring).

    Returns ``trans_rmse_m``, ``trans_mean_m``, ``rot_rmse_deg``, ``rot_mean_deg`` and
    ``n_pairs``; the figures are None when the trajectory is shorter than ``delta + 1`` poses.
    """
    est, gt = _pair(est_poses, gt_poses)
    i, j = rpe_pairs(est.shape[0], int(delta), all_pairs)
    if i.size == 0:
        return dict(trans_rmse_m=None, trans_mean_m=None, rot_rmse_deg=None, rot_mean_deg=None,
                    n_pairs=0)
    E = relative_errors(est, gt, i, j)
    t_err = np.linalg.norm(E[:, :3, 3], axis=1)
    r_err = np.degrees(rotation_angle(E[:, :3, :3]))
    return dict(
        trans_rmse_m=_rmse(t_err),
        trans_mean_m=float(t_err.mean()),
        rot_rmse_deg=_rmse(r_err),
        rot_mean_deg=float(r_err.mean()),
        n_pairs=int(i.size),
    )


# --------------------------------------------------------------------------- KITTI drift


def kitti_drift(est_poses, gt_poses, lengths=KITTI_LENGTHS, step: int = 10) -> dict:
    """KITTI odometry drift (devkit ``calcSequenceErrors``).

    Returns ``t_rel_pct`` (mean translation error per metre, in percent), ``r_rel_deg_per_100m``
    (mean rotation error per metre, in degrees per 100 m), ``n_segments``, and ``per_length``
    {length: (t_rel_pct, r_rel_deg_per_100m, n)} for the lengths that had segments. The two
    figures are None when the path is shorter than every segment length.
    """
    est, gt = _pair(est_poses, gt_poses)
    n = gt.shape[0]
    # Distance travelled along the true path up to each frame (devkit trajectoryDistances).
    dist = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(gt[:, :3, 3], axis=0), axis=1))])
    first = np.arange(0, n, int(step))
    t_all, r_all, per_length = [], [], {}
    for length in lengths:
        # devkit lastFrameFromSegmentLength: first frame whose distance exceeds dist[i] + len.
        last = np.searchsorted(dist, dist[first] + length, side="right")
        ok = last < n
        i, j = first[ok], last[ok]
        if i.size == 0:
            continue
        err = se3_inv(se3_inv(est[i]) @ est[j]) @ (se3_inv(gt[i]) @ gt[j])
        t_err = np.linalg.norm(err[:, :3, 3], axis=1) / length
        r_err = rotation_angle(err[:, :3, :3]) / length
        t_all.append(t_err)
        r_all.append(r_err)
        per_length[int(length)] = (
            float(100.0 * t_err.mean()),
            float(np.degrees(r_err.mean()) * 100.0),
            int(i.size),
        )
    if not t_all:
        return dict(t_rel_pct=None, r_rel_deg_per_100m=None, n_segments=0, per_length={})
    t_cat, r_cat = np.concatenate(t_all), np.concatenate(r_all)
    return dict(
        t_rel_pct=float(100.0 * t_cat.mean()),
        r_rel_deg_per_100m=float(np.degrees(r_cat.mean()) * 100.0),
        n_segments=int(t_cat.size),
        per_length=per_length,
    )


# --------------------------------------------------------------------------- drive-fitted RPE


def _stats(x: np.ndarray) -> dict | None:
    """mean, median and RMSE of ``x``; None for no values."""
    if x.size == 0:
        return None
    return {"mean": float(np.mean(x)), "median": float(np.median(x)), "rmse": _rmse(x)}


def drive_rpe(est_poses, gt_poses, lengths=None) -> dict:
    """The drive-fitted relative pose error (module docstring) of ``est_poses`` against
    ``gt_poses`` (same frames, (n, 4, 4) each). ``lengths`` (m): None for the drive's own
    (:func:`eval.rpe_segments.drive_segment_lengths`).

    Returns a JSON-ready dict: ``lengths_m`` (list), ``path_length_m`` (the true path),
    ``frames``, ``n_segments``, ``trans_pct`` and ``rot_deg_per_m`` over the segments of every
    length ({mean, median, rmse}, None without segments), ``per_length`` (per length in order:
    ``length_m``, ``n_segments``, and {mean, median, rmse} of ``trans_m``, ``trans_pct``,
    ``rot_deg``, ``rot_deg_per_m``, each None where the length has no segment), and ``note``:
    None, or in words why there is no figure (too short, too few frames, no segment found), a
    clause that reads after "No RPE: ".
    """
    est, gt = _pair(est_poses, gt_poses)
    dist = path_distances(gt)
    note = None
    if lengths is None:
        lengths, note = drive_segment_lengths(gt)
    lengths = tuple(float(L) for L in lengths)
    if any(not (math.isfinite(L) and L > 0) for L in lengths):
        raise InputError(f"segment lengths must be positive metres, got {list(lengths)}")
    out = {"lengths_m": list(lengths), "path_length_m": float(dist[-1]) if dist.size else 0.0,
           "frames": int(gt.shape[0]), "n_segments": 0, "trans_pct": None,
           "rot_deg_per_m": None, "per_length": [], "note": note}
    t_all, r_all = [], []
    for length in lengths:
        i, j = length_segments(dist, length)
        entry = {"length_m": length, "n_segments": int(i.size), "trans_m": None,
                 "trans_pct": None, "rot_deg": None, "rot_deg_per_m": None}
        if i.size:
            E = relative_errors(est, gt, i, j)
            along = dist[j] - dist[i]
            t_m = np.linalg.norm(E[:, :3, 3], axis=1)
            r_deg = np.degrees(rotation_angle(E[:, :3, :3]))
            t_pct, r_per_m = 100.0 * t_m / along, r_deg / along
            entry.update(trans_m=_stats(t_m), trans_pct=_stats(t_pct), rot_deg=_stats(r_deg),
                         rot_deg_per_m=_stats(r_per_m))
            t_all.append(t_pct)
            r_all.append(r_per_m)
        out["per_length"].append(entry)
    if t_all:
        t_cat, r_cat = np.concatenate(t_all), np.concatenate(r_all)
        out.update(n_segments=int(t_cat.size), trans_pct=_stats(t_cat),
                   rot_deg_per_m=_stats(r_cat))
    elif lengths and note is None:
        out["note"] = (f"no segment of {lengths_text(lengths)} has an end within "
                       f"{100 * RPE_END_TOLERANCE:g} % of its length on this drive's ground truth")
    return out


# --------------------------------------------------------------------------- NEES


def pose_errors(est_poses, gt_poses) -> np.ndarray:
    """Right-perturbation errors ``xi = se3_log(inv(est) @ gt)`` (T, 6), translation first."""
    est, gt = _pair(est_poses, gt_poses)
    return se3_log(se3_inv(est) @ gt)


def nees(errors, cov) -> np.ndarray:
    """NEES ``e^T cov^-1 e`` (N,) of each row of ``errors`` (N, d) under its covariance ``cov``
    (N, d, d); NaN where the covariance is missing or singular. The pose NEES of an estimate is
    :func:`eval.consistency.pose_nees` (errors :func:`pose_errors`, 6 dof), its landmarks'
    :func:`eval.consistency.landmark_nees` (``m_true - m_est``, 3 dof)."""
    e = np.asarray(errors, dtype=np.float64)
    cov = np.asarray(cov, dtype=np.float64)
    if e.ndim != 2:
        raise InputError(f"errors must be an (N, d) array, got shape {e.shape}")
    if cov.shape != (e.shape[0], e.shape[1], e.shape[1]):
        raise InputError(f"covariances must have shape ({e.shape[0]}, {e.shape[1]}, "
                         f"{e.shape[1]}), got {cov.shape}")
    out = np.full(e.shape[0], np.nan)
    good = np.all(np.isfinite(cov.reshape(cov.shape[0], -1)), axis=1) & np.all(np.isfinite(e), axis=1)
    if np.any(good):
        c, x = cov[good], e[good]
        try:
            sol = np.linalg.solve(c, x[..., None])[..., 0]
            out[good] = np.sum(x * sol, axis=1)
        except np.linalg.LinAlgError:
            for k, (ck, xk) in zip(np.flatnonzero(good), zip(c, x)):
                try:
                    out[k] = float(xk @ np.linalg.solve(ck, xk))
                except np.linalg.LinAlgError:
                    pass
    return out


# --------------------------------------------------------------------------- summary


def trajectory_metrics(est, gt_poses, frames=None) -> dict:
    """Every trajectory figure of one estimate against ground truth.

    ``est`` an :class:`ekf.estimate.Estimate` (or a (T, 4, 4) pose array); ``gt_poses`` the
    true ``world_T_imu`` of ``frames`` (indices into the estimate; all frames when None, e.g.
    the 1101 of 1106 frames of 0027 that have ground truth). Keys are always present; a figure
    that cannot be computed (too short, degenerate alignment) is None.
    """
    poses = np.asarray(getattr(est, "poses", est), dtype=np.float64)
    poses = _poses(poses, "estimate")
    if frames is not None:
        frames = np.asarray(frames, dtype=np.int64)
        if frames.ndim != 1 or (frames.size and (frames.min() < 0 or frames.max() >= poses.shape[0])):
            raise InputError(f"frames must index the estimate's {poses.shape[0]} poses")
        poses = poses[frames]
    est_p, gt = _pair(poses, gt_poses)
    out: dict = {"n_frames": int(gt.shape[0])}
    out["ate_rmse_m"] = ate_rmse(est_p, gt) if gt.shape[0] else None
    for mode in ("se3", "sim3"):
        try:
            R, t, s = umeyama(est_p[:, :3, 3], gt[:, :3, 3], with_scale=mode == "sim3")
        except InputError:
            out[f"ate_{mode}_rmse_m"] = None
            if mode == "sim3":
                out["sim3_scale"] = None
            continue
        out[f"ate_{mode}_rmse_m"] = ate_rmse(est_p, gt, align=mode)
        if mode == "sim3":
            out["sim3_scale"] = s
    try:
        out["ate_yaw_rmse_m"] = ate_rmse(est_p, gt, align="yaw")
    except InputError:
        out["ate_yaw_rmse_m"] = None
    for delta in (1, 10):
        r = rpe(est_p, gt, delta=delta)
        out[f"rpe{delta}_trans_rmse_m"] = r["trans_rmse_m"]
        out[f"rpe{delta}_rot_rmse_deg"] = r["rot_rmse_deg"]
    drift = kitti_drift(est_p, gt)
    out["kitti_t_rel_pct"] = drift["t_rel_pct"]
    out["kitti_r_rel_deg_per_100m"] = drift["r_rel_deg_per_100m"]
    out["kitti_n_segments"] = drift["n_segments"]
    fitted = drive_rpe(est_p, gt)
    out["rpe_drive_trans_pct"] = (fitted["trans_pct"] or {}).get("mean")
    out["rpe_drive_rot_deg_per_m"] = (fitted["rot_deg_per_m"] or {}).get("mean")
    out["rpe_drive_n_segments"] = fitted["n_segments"]
    return out
