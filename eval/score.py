"""Scoring a trajectory made by any system (``vislam score``) with the benchmark's definitions.

The trajectory (TUM, KITTI or EuRoC CSV: :func:`read_trajectory`) is associated with the
frames of the drive it was estimated on (:func:`associate`), turned into a vislam
:class:`~ekf.estimate.Estimate` on the associated frames (:func:`trajectory_estimate`), and
scored by the benchmark's own code (:func:`eval.bench_scores.score_sequence`, hence
:func:`eval.bench_scores.trajectory_scores` and :func:`eval.consistency.versus_smoother`): against
ground truth where the drive has one (ATE raw and aligned, KITTI drift t_rel / r_rel, mean pose
NEES) and against the reference smoother run on the same data exactly as ``vislam bench``
runs it (the batch smoother started from ekf-invariant's estimate, under the same model:
vs-smoother ATE, mean pose NEES of the difference, share of steps inside the 95 % bound).

Conventions. Poses are ``world_T_body`` of the body the drive's estimators estimate (the IMU),
with the world frame the IMU frame at frame 0, as vislam's estimates are; the aligned ATE and
the drift do not depend on the world frame, the raw ATE and the NEES do. Pose covariances
(``--cov``, :func:`eval.export.read_pose_covariances`) are vislam's: per pose the 6x6
covariance of ``xi = [rho; phi]`` (translation first, m and rad) in a right perturbation
``world_T_body_true = world_T_body_est @ se3_exp(xi)``. Without covariances every NEES figure
is null.

Association (:func:`associate`), evo's ``--t_max_diff`` / ``--t_offset`` rule: each pose's
time plus ``t_offset`` is matched to the nearest frame time of the drive, and kept when they
differ by at most ``t_max_diff`` seconds (ties go to the earlier frame); where several poses
fall to one frame only the nearest (then the first) is kept. A KITTI file has no times: its
poses are the drive's frames in order, one per frame (a different count is an error).
Covariances with times are associated to frames by the same rule; a ``.npy`` array has one
covariance per pose of the trajectory, in its order.

Frames the trajectory lacks: only the associated frames are scored, by the benchmark's
functions applied to the drive restricted to them (estimate, ground truth and reference alike);
fewer than :data:`MIN_ASSOCIATED` associated frames is an error. Where the trajectory covers
frame 0 (any complete or sub-sampled vislam trajectory) the figures are exactly the
benchmark's definitions on those frames; otherwise the first associated frame stands in for
frame 0, which every pose-NEES mean leaves out (eval.consistency).
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vislam.ekf.errors import InputError
from vislam.ekf.estimate import Estimate
from vislam.eval.bench_scores import RPE_DEFINITION, score_sequence
from vislam.eval.drives import KnownTruth, collect_sequences
from vislam.eval.metrics import ALIGN_DESCRIPTIONS, check_align_mode
from vislam.eval.registry import (INERTIAL_SMOOTHERS, SMOOTHER_INITIAL_FROM, SMOOTHERS, drive_kind,
                                  uses_initial)
from vislam.eval.study import JobFailure, JobResult, run_jobs

log = logging.getLogger(__name__)

SCHEMA = 1
#: Trajectory formats (``--format``).
FORMATS = ("tum", "kitti", "euroc")
#: ``--format`` when not given, by file extension.
EXTENSION_FORMATS = {".tum": "tum", ".txt": "tum", ".csv": "euroc", ".kitti": "kitti"}
#: Largest time difference of an associated pose and frame, s (evo's default --t_max_diff).
DEFAULT_T_MAX_DIFF = 0.01
#: Fewest associated frames scored (fewer is an error).
MIN_ASSOCIATED = 2
#: The reference the trajectory is compared with, and the EKF it starts from, as in bench.
REFERENCE = "smoother"
#: What ``vislam score --out DIR`` writes.
SCORE_FILES = ("score.json", "score.md")
#: The figures of the trajectory's row (the benchmark's keys).
SCORE_KEYS = ("ate_m", "ate_aligned_m", "rpe_trans_pct", "rpe_rot_deg_per_100m", "nees_pose_mean")
ASSOCIATION_RULE = (
    "each pose's time plus t_offset is matched to the nearest frame time of the drive and kept "
    "when they differ by at most t_max_diff s (ties: the earlier frame; several poses on one "
    "frame: the nearest, then the first, is kept); KITTI files (no times): pose k is frame k"
)


# --- reading ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class Trajectory:
    """A trajectory read from a file: ``poses`` (N, 4, 4) world_T_body, ``times`` (N,) in
    seconds (None for KITTI), ``lines`` (N,) the line of each pose in the file."""

    path: str
    format: str
    poses: np.ndarray
    times: np.ndarray | None
    lines: np.ndarray

    @property
    def n(self) -> int:
        return int(self.poses.shape[0])


def format_from_path(path: str | Path) -> str:
    """The trajectory format of ``path`` from its extension (:data:`EXTENSION_FORMATS`); an
    InputError asking for ``--format`` when the extension says nothing."""
    suffix = Path(path).suffix.lower()
    fmt = EXTENSION_FORMATS.get(suffix)
    if fmt is None:
        known = ", ".join(f"{k} -> {v}" for k, v in EXTENSION_FORMATS.items())
        raise InputError(f"{path}: cannot tell the trajectory format from the extension "
                         f"{suffix or '(none)'!r} ({known}); give --format "
                         f"{{{','.join(FORMATS)}}}")
    return fmt


def read_trajectory(path: str | Path, fmt: str | None = None) -> Trajectory:
    """The trajectory in ``path``: ``fmt`` one of :data:`FORMATS` (None: from the extension,
    :func:`format_from_path`); every line checked (eval.export's checked readers)."""
    from vislam.eval.export import read_euroc, read_kitti_checked, read_tum_checked

    fmt = format_from_path(path) if fmt is None else fmt
    if fmt == "tum":
        times, poses, lines = read_tum_checked(path)
    elif fmt == "euroc":
        times, poses, lines = read_euroc(path)
    elif fmt == "kitti":
        (poses, lines), times = read_kitti_checked(path), None
    else:
        raise InputError(f"unknown trajectory format {fmt!r}; one of {', '.join(FORMATS)}")
    log.info("%s: %d poses (%s)", path, poses.shape[0], fmt)
    return Trajectory(str(path), fmt, poses, times, lines)


# --- association -----------------------------------------------------------------------------


@dataclass(frozen=True)
class Association:
    """Poses matched to frames: ``frames`` (n,) increasing frame indices of the drive,
    ``rows`` (n,) the pose of the trajectory at each; ``by`` "time" or "index";
    ``unmatched`` poses with no frame within ``t_max_diff``; ``duplicates`` poses dropped
    because another was nearer the same frame; ``max_abs_diff_s`` the largest time difference
    of a kept pair (None by index)."""

    frames: np.ndarray
    rows: np.ndarray
    by: str
    t_max_diff: float
    t_offset: float
    unmatched: int = 0
    duplicates: int = 0
    max_abs_diff_s: float | None = None

    @property
    def n(self) -> int:
        return int(self.frames.size)

    def to_dict(self, n_poses: int, n_frames: int) -> dict:
        return {
            "by": self.by, "rule": ASSOCIATION_RULE, "t_max_diff_s": self.t_max_diff,
            "t_offset_s": self.t_offset, "trajectory_poses": int(n_poses),
            "data_frames": int(n_frames), "associated_frames": self.n,
            "unmatched_poses": self.unmatched, "duplicate_poses": self.duplicates,
            "max_abs_diff_s": self.max_abs_diff_s,
            "first_frame": int(self.frames[0]) if self.n else None,
            "last_frame": int(self.frames[-1]) if self.n else None,
        }


def match_times(times: np.ndarray, frame_times: np.ndarray, t_max_diff: float,
                t_offset: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """The association rule on bare times: (frames, rows, |dt|, duplicates) with ``frames``
    increasing, ``rows`` indices into ``times``; see the module docstring."""
    t = np.asarray(times, dtype=float) + float(t_offset)
    ft = np.asarray(frame_times, dtype=float)
    if t.size == 0 or ft.size == 0:
        empty = np.zeros(0, dtype=np.int64)
        return empty, empty, np.zeros(0), 0
    hi = np.clip(np.searchsorted(ft, t), 0, ft.size - 1)
    lo = np.clip(hi - 1, 0, ft.size - 1)
    d_lo, d_hi = np.abs(t - ft[lo]), np.abs(ft[hi] - t)
    frame = np.where(d_hi < d_lo, hi, lo)
    diff = np.minimum(d_lo, d_hi)
    ok = np.flatnonzero(diff <= t_max_diff)
    frame, diff = frame[ok], diff[ok]
    # One pose per frame: the nearest, then the first (a stable sort keeps row order on ties).
    order = np.lexsort((ok, diff, frame))
    first = np.ones(order.size, dtype=bool)
    first[1:] = frame[order][1:] != frame[order][:-1]
    keep = order[first]
    keep = keep[np.argsort(frame[keep], kind="stable")]
    return frame[keep].astype(np.int64), ok[keep].astype(np.int64), diff[keep], int(order.size - keep.size)


def associate(traj: Trajectory, frame_times: np.ndarray, t_max_diff: float = DEFAULT_T_MAX_DIFF,
              t_offset: float = 0.0, data: str = "the data", min_frames: int = MIN_ASSOCIATED
              ) -> Association:
    """Match the poses of ``traj`` to the frames (times ``frame_times``) of the drive ``data``
    (named in messages) by the rule of the module docstring; InputError when fewer than
    ``min_frames`` frames associate, or for a KITTI file whose pose count is not the frame
    count."""
    frame_times = np.asarray(frame_times, dtype=float)
    T = frame_times.size
    check_time_options(t_max_diff, t_offset)
    if traj.times is None:
        if traj.n != T:
            raise InputError(f"{traj.path}: {traj.n} poses for the {T} frames of {data}; a "
                             f"{traj.format.upper()} file has no times, so it must hold one pose "
                             "per frame, in order (give a TUM or EuRoC file to score part of a "
                             "drive)")
        idx = np.arange(T, dtype=np.int64)
        return Association(idx, idx.copy(), "index", float(t_max_diff), float(t_offset))
    frames, rows, diff, dup = match_times(traj.times, frame_times, t_max_diff, t_offset)
    if frames.size < min_frames:
        span = f"{traj.times[0] + t_offset:.6f}-{traj.times[-1] + t_offset:.6f} s"
        hint = ""
        if frames.size == 0:
            hint = (f"; --t-offset {frame_times[0] - traj.times[0]:.6f} would put the first "
                    "pose on the first frame" if T else "")
        raise InputError(f"{traj.path}: {frames.size} of its {traj.n} poses within --t-max-diff "
                         f"{t_max_diff:g} s of a frame of {data} (at least {min_frames} needed; "
                         f"pose times {span} after --t-offset {t_offset:g}, frame times "
                         f"{frame_times[0]:.6f}-{frame_times[-1]:.6f} s){hint}")
    unmatched = traj.n - int(frames.size) - dup
    if unmatched or dup:
        log.warning("%s: %d of %d poses associate with frames of %s (%d beyond --t-max-diff "
                    "%g s, %d on a frame taken by a nearer pose)", traj.path, frames.size,
                    traj.n, data, unmatched, t_max_diff, dup)
    return Association(frames, rows, "time", float(t_max_diff), float(t_offset), unmatched, dup,
                       float(diff.max()))


def check_time_options(t_max_diff: float, t_offset: float) -> None:
    """InputError unless ``t_max_diff`` is a finite number >= 0 and ``t_offset`` finite."""
    if not (np.isfinite(t_max_diff) and t_max_diff >= 0):
        raise InputError(f"--t-max-diff must be a finite number of seconds >= 0, got {t_max_diff}")
    if not np.isfinite(t_offset):
        raise InputError(f"--t-offset must be a finite number of seconds, got {t_offset}")


def positions_in(sorted_frames: np.ndarray, frames: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where each of ``frames`` stands in the increasing ``sorted_frames``: (positions, found),
    a position meaningful only where found."""
    pos = np.searchsorted(sorted_frames, frames)
    found = (pos < sorted_frames.size) & (
        sorted_frames[np.clip(pos, 0, max(sorted_frames.size - 1, 0))] == frames)
    return pos, found


def covariances_for(cov, traj: Trajectory, assoc: Association, frame_times: np.ndarray
                    ) -> tuple[np.ndarray, int]:
    """The covariance (n, 6, 6) of each associated frame from ``cov``
    (eval.covariance_files.PoseCovariances), NaN where it has none, and how many frames have one.
    Covariances with times are matched to frames by the association rule (same ``t_max_diff``
    and ``t_offset``); without times entry i belongs to pose i of ``traj``. InputError when a
    time-less file's count differs from the trajectory's, or when no frame gets a covariance."""
    out = np.full((assoc.n, 6, 6), np.nan)
    if cov.times is None:
        if cov.cov.shape[0] != traj.n:
            raise InputError(f"{cov.path}: {cov.cov.shape[0]} covariances for the {traj.n} poses "
                             f"of {traj.path}; a {cov.kind} file has no times, so it holds one "
                             "covariance per pose, in the trajectory's order")
        out[:] = cov.cov[assoc.rows]
        return out, assoc.n
    frames, rows, _, _ = match_times(cov.times, frame_times, assoc.t_max_diff, assoc.t_offset)
    pos, hit = positions_in(assoc.frames, frames)
    out[pos[hit]] = cov.cov[rows[hit]]
    n = int(np.count_nonzero(hit))
    if n == 0:
        raise InputError(f"{cov.path}: none of its {cov.cov.shape[0]} covariances is within "
                         f"--t-max-diff {assoc.t_max_diff:g} s (after --t-offset "
                         f"{assoc.t_offset:g}) of a scored frame")
    if n < assoc.n:
        log.warning("%s: covariances for %d of the %d scored frames; the NEES figures leave "
                    "the others out", cov.path, n, assoc.n)
    return out, n


# --- estimates on the associated frames ------------------------------------------------------


def trajectory_estimate(name: str, frame_times: np.ndarray, frames: np.ndarray,
                        poses: np.ndarray, cov: np.ndarray | None = None) -> Estimate:
    """An Estimate of the associated ``frames`` only: their data times, ``poses`` (n, 4, 4)
    and covariances ``cov`` (n, 6, 6; NaN when None), no landmarks."""
    frames = np.asarray(frames, dtype=np.int64)
    n = frames.size
    est = Estimate.empty(name, np.asarray(frame_times, dtype=float)[frames], 0)
    est.poses = np.array(poses, dtype=float).reshape(n, 4, 4)
    if cov is not None:
        est.pose_cov = np.array(cov, dtype=float).reshape(n, 6, 6)
    est.info = {"scored_frames": "the frames associated with the trajectory file"}
    return est


def restrict_estimate(est: Estimate, frames: np.ndarray) -> Estimate:
    """``est`` on ``frames`` only (per-frame arrays indexed; the map unchanged)."""
    frames = np.asarray(frames, dtype=np.int64)
    return dataclasses.replace(
        est, timestamps=est.timestamps[frames], poses=est.poses[frames],
        pose_cov=est.pose_cov[frames], step_time_s=est.step_time_s[frames],
        n_updates=est.n_updates[frames], n_rejected=est.n_rejected[frames],
        n_initialised=est.n_initialised[frames], info=dict(est.info))


def restrict_truth(gt, frames: np.ndarray):
    """Ground truth (``.frames``, ``.poses``) on ``frames`` only, its frames renumbered as
    positions in ``frames`` (an eval.drives.KnownTruth); None without ground truth."""
    if gt is None:
        return None
    frames = np.asarray(frames, dtype=np.int64)
    gt_frames = np.asarray(gt.frames, dtype=np.int64)
    pos, hit = positions_in(frames, gt_frames)
    return KnownTruth(pos[hit], np.asarray(gt.poses)[hit], getattr(gt, "source", None))


# --- the drive and its reference -------------------------------------------------------------


def load_drive(data: str | Path):
    """The drive ``data`` (one .npz file) as the benchmark reads it
    (eval.drives.BenchSequence, its ground truth found beside it), before any model."""
    if Path(data).is_dir():
        raise InputError(f"{data}: is a folder; --data takes the one .npz file the trajectory "
                         "was estimated on")
    (bs,) = collect_sequences([str(data)])
    return bs


def reference_name(bs=None) -> str:
    """The reference smoother of the drive ``bs``: :data:`REFERENCE`, or on a raw-IMU drive the
    raw-IMU smoother (``vislam bench``'s reference there)."""
    if bs is not None and drive_kind(bs.sequence) == "raw-imu":
        return INERTIAL_SMOOTHERS[0]
    return REFERENCE


def reference_estimators(smoother, bs=None) -> list[str]:
    """The estimators ``vislam bench`` runs for its reference: the EKF the batch smoother
    starts from (when it starts from one) and the smoother; on a raw-IMU drive its smoother."""
    if reference_name(bs) != REFERENCE:
        return [reference_name(bs)]
    return ([SMOOTHER_INITIAL_FROM[0], REFERENCE] if uses_initial(REFERENCE, smoother)
            else [REFERENCE])


def run_reference(bs, config, smoother, show_progress: bool = False):
    """The reference smoother on the drive ``bs``, run as ``vislam bench`` runs it
    (eval.study.run_jobs with :func:`reference_estimators`, the drive's own settings):
    an eval.study.JobResult, or an eval.study.JobFailure when it failed."""
    config = bs.config if bs.config is not None else config
    names = reference_estimators(smoother, bs)
    outcomes = run_jobs({bs.name: bs.sequence}, names, config, jobs=1,
                        show_progress=show_progress, smoother=smoother)
    return outcomes[(bs.name, reference_name(bs))]


# --- scoring ---------------------------------------------------------------------------------


def row_name(traj_path: str | Path) -> str:
    """The trajectory's row name in the table: its file name (never a smoother's name)."""
    name = Path(traj_path).name or str(traj_path)
    return f"{name} (scored)" if name in SMOOTHERS else name


def score_on_frames(bs, est: Estimate, frames: np.ndarray, reference=None,
                    align: str = "se3") -> dict:
    """The benchmark's entry of the drive restricted to ``frames`` (eval.bench_scores.
    score_sequence): ``est`` the trajectory's estimate on those frames (its ``estimator`` the
    row name), ``reference`` the smoother's run on the whole drive (JobResult or JobFailure;
    None: no reference), restricted to the same frames."""
    frames = np.asarray(frames, dtype=np.int64)
    sub = dataclasses.replace(bs, gt=restrict_truth(bs.gt, frames))
    outcomes = {est.estimator: JobResult(bs.name, est.estimator, est, 0.0)}
    names = [est.estimator]
    if reference is not None:
        ref_name = reference_name(bs)
        names.append(ref_name)
        if isinstance(reference, JobFailure):
            outcomes[ref_name] = reference
        else:
            outcomes[ref_name] = dataclasses.replace(
                reference, estimate=restrict_estimate(reference.estimate, frames))
    entry = score_sequence(sub, names, outcomes, align=align)
    for row in entry["estimators"]:  # times of runs are not what is scored here
        row["runtime_s"] = row["frames_per_s"] = None
    entry["frames_scored"] = int(frames.size)
    entry["gt_frames_scored"] = 0 if sub.gt is None else int(sub.gt.frames.size)
    return entry


def score(traj: Trajectory, bs, *, config, smoother, cov=None, t_max_diff: float = DEFAULT_T_MAX_DIFF,
          t_offset: float = 0.0, align: str = "se3", reference: bool = True,
          show_progress: bool = False, assoc: Association | None = None) -> dict:
    """Score ``traj`` on the drive ``bs`` (:func:`load_drive`); ``cov`` the pose covariances
    (eval.covariance_files.PoseCovariances) or None; ``reference`` False skips the smoother. Returns
    the score.json content: what was scored and how (trajectory, data, covariance,
    association, alignment, reference, model), ``scores`` (the trajectory's figures, the
    benchmark's keys and ``vs_smoother``) and ``sequence`` (the benchmark's results.json entry
    of the drive on the scored frames, the reference's row included)."""
    check_align_mode(align)
    frame_times = bs.sequence.timestamps
    data = bs.path or bs.name
    if assoc is None:
        assoc = associate(traj, frame_times, t_max_diff, t_offset, data=data)
    cov_frames = 0
    cov_matrix = None
    if cov is not None:
        cov_matrix, cov_frames = covariances_for(cov, traj, assoc, frame_times)
    name = row_name(traj.path)
    est = trajectory_estimate(name, frame_times, assoc.frames, traj.poses[assoc.rows], cov_matrix)
    ref = run_reference(bs, config, smoother, show_progress) if reference else None
    entry = score_on_frames(bs, est, assoc.frames, ref, align=align)
    row = next(r for r in entry["estimators"] if r["name"] == name)
    ref_row = next((r for r in entry["estimators"] if r["name"] == reference_name(bs)), None)
    nees_note = None
    if cov is None:
        nees_note = "no --cov given: the NEES figures are null (they need the pose covariances)"
    return {
        "schema": SCHEMA,
        "kind": "vislam score",
        "trajectory": {"path": str(Path(traj.path).resolve()), "format": traj.format,
                       "poses": traj.n, "name": name},
        "data": {"name": bs.name, "path": bs.path, "frames": bs.sequence.n_frames,
                 "has_ground_truth": bs.gt is not None},
        "covariance": None if cov is None else {
            "path": str(Path(cov.path).resolve()), "kind": cov.kind, "entries": int(cov.cov.shape[0]),
            "frames_with_covariance": cov_frames,
            "convention": "per pose the 6x6 covariance of xi = [rho; phi] (translation first, "
                          "m and rad), right perturbation world_T_body_true = world_T_body_est "
                          "@ se3_exp(xi)"},
        "nees": nees_note,
        "association": assoc.to_dict(traj.n, bs.sequence.n_frames),
        "alignment": align,
        "alignment_definition": f"ate_aligned_m (ATE al.): the ATE after {ALIGN_DESCRIPTIONS[align]}",
        "rpe_definition": RPE_DEFINITION,
        "reference": None if not reference else {
            "name": reference_name(bs), "estimators_run": reference_estimators(smoother, bs),
            "error": None if ref_row is None else ref_row["error"],
            "definition": "vs_smoother compares the trajectory with the batch smoother run on "
                          "the same data as vislam bench runs it (started from ekf-invariant's "
                          "estimate, under the same model), on the scored frames"},
        "model": bs.model,
        "scores": {k: row[k] for k in SCORE_KEYS} | {"vs_smoother": row["vs_smoother"],
                                                     "gt_frames": entry["gt_frames_scored"]},
        "sequence": entry,
    }
