"""The figures of one drive of `vislam bench` (and of `vislam run`'s one estimator): PNG files of
the trajectories, the map, the error over distance, the EKFs against the smoother and the pose
NEES over time (:mod:`eval.plots` draws them).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from vislam.ekf.estimate import Estimate
from vislam.eval import plots, plots_top_view
from vislam.eval.bench_scores import landmark_truth_in_gauge, reference_smoother, truth_in_gauge
from vislam.eval.consistency import pose_nees
from vislam.eval.drives import BenchSequence, is_raw_imu
from vislam.eval.registry import (
    ESTIMATOR_NAMES,
    INERTIAL_ESTIMATOR_NAMES,
    INERTIAL_SMOOTHERS,
    SMOOTHER_INITIAL_FROM,
    SMOOTHERS,
)


def sequence_figures(folder: Path, bs: BenchSequence, ests: dict[str, Estimate]) -> list[Path]:
    """The PNG figures of one sequence into ``folder``; returns the paths written."""
    written = []
    if not ests:
        return written
    ref = reference_smoother(ests)
    # A raw-IMU drive's truth in each estimate's own gauge (bench_scores.truth_in_gauge), as the
    # scores take it; the top view and the map show it in the reference's (else the first's).
    gt = bs.gt
    truth = {n: truth_in_gauge(gt, bs.sequence, e) for n, e in ests.items()} if gt is not None else {}
    shown = truth.get(ref, next(iter(truth.values()), None))
    gt_pos = np.asarray(shown.poses)[:, :3, 3] if shown is not None else None
    title = bs.name
    written.append(plots_top_view.plot_trajectories(folder / "trajectories.png", ests, gt_pos,
                                           f"{title}: trajectories, top view",
                                           world="raw-imu" if is_raw_imu(bs) else "velocity"))
    map_from = next(
        (n for n in (*SMOOTHERS, *INERTIAL_SMOOTHERS, *SMOOTHER_INITIAL_FROM, "ekf-decoupled", "mapping")
         if n in ests and np.any(ests[n].has_landmark)),
        None,
    )
    if map_from is not None:
        true_map = landmark_truth_in_gauge(gt, bs.sequence, ests[map_from], bs.landmark_truth)
        map_gt = truth.get(map_from)
        written.append(plots_top_view.plot_map(folder / "map.png", ests[map_from],
                                      None if map_gt is None else np.asarray(map_gt.poses)[:, :3, 3],
                                      true_map,
                                      f"{title}: landmark map ({map_from})"))
    if gt is not None:
        written.append(plots.plot_error_over_distance(
            folder / "error_over_distance.png", ests, gt.frames,
            {n: np.asarray(t.poses) for n, t in truth.items()},
            f"{title}: translation error over distance (no alignment)"))
    # vislam's EKFs and a user's estimators (MODULE:FUNCTION, plug-ins): everything but the
    # smoothers, dead reckoning and mapping, which the smoother would only dwarf
    ours = ESTIMATOR_NAMES + INERTIAL_ESTIMATOR_NAMES
    ekfs = {n: e for n, e in ests.items() if n.startswith("ekf-") or n not in ours}
    if ref is not None and ekfs:
        written.append(plots.plot_vs_smoother(
            folder / "vs_smoother.png", ekfs, ests[ref],
            f"{title}: EKF position minus {ref}, with the EKF's ±3σ"))
    # Pose NEES over time: against ground truth where known, else against the smoother.
    if gt is not None:
        against, frames, poses, who = "ground truth", gt.frames, np.asarray(gt.poses), ests
    elif ref is not None:
        against, frames, poses = ref, np.arange(ests[ref].n_frames), ests[ref].poses
        who = {n: e for n, e in ests.items() if n not in SMOOTHERS + INERTIAL_SMOOTHERS}
    else:
        who = {}
    series = {n: pose_nees(e, frames, np.asarray(truth[n].poses) if against == "ground truth"
                           else poses) for n, e in who.items()}
    series = {n: v for n, v in series.items() if np.any(np.isfinite(v))}
    if series:
        t = next(iter(ests.values())).timestamps
        written.append(plots.plot_nees(
            folder / "nees.png", series, dof=6, times=t - t[0],
            title=f"{title}: pose NEES against {against}",
            ylabel=f"pose NEES vs {against} (6 dof)"))
    return written
