"""The figures of one drive of `vislam bench` (and of `vislam run`'s one estimator): PNG files of
the trajectories, the map, the error over distance, the EKFs against the smoother and the pose
NEES over time (:mod:`eval.plots` draws them).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from vislam.ekf.estimate import Estimate
from vislam.eval import plots
from vislam.eval.bench_scores import reference_smoother
from vislam.eval.consistency import pose_nees
from vislam.eval.drives import BenchSequence
from vislam.eval.registry import ESTIMATOR_NAMES, SMOOTHER_INITIAL_FROM, SMOOTHERS


def sequence_figures(folder: Path, bs: BenchSequence, ests: dict[str, Estimate]) -> list[Path]:
    """The PNG figures of one sequence into ``folder``; returns the paths written."""
    written = []
    if not ests:
        return written
    gt = bs.gt
    gt_pos = np.asarray(gt.poses)[:, :3, 3] if gt is not None else None
    title = bs.name
    written.append(plots.plot_trajectories(folder / "trajectories.png", ests, gt_pos,
                                           f"{title}: trajectories, top view"))
    map_from = next(
        (n for n in (*SMOOTHERS, *SMOOTHER_INITIAL_FROM, "ekf-decoupled", "mapping")
         if n in ests and np.any(ests[n].has_landmark)),
        None,
    )
    if map_from is not None:
        written.append(plots.plot_map(folder / "map.png", ests[map_from], gt_pos, bs.landmark_truth,
                                      f"{title}: landmark map ({map_from})"))
    if gt is not None:
        written.append(plots.plot_error_over_distance(
            folder / "error_over_distance.png", ests, gt.frames, np.asarray(gt.poses),
            f"{title}: translation error over distance (no alignment)"))
    ref = reference_smoother(ests)
    # vislam's EKFs and a user's estimators (MODULE:FUNCTION, plug-ins): everything but the
    # smoothers, dead reckoning and mapping, which the smoother would only dwarf
    ekfs = {n: e for n, e in ests.items() if n.startswith("ekf-") or n not in ESTIMATOR_NAMES}
    if ref is not None and ekfs:
        written.append(plots.plot_vs_smoother(
            folder / "vs_smoother.png", ekfs, ests[ref],
            f"{title}: EKF position minus {ref}, with the EKF's ±3σ"))
    # Pose NEES over time: against ground truth where known, else against the smoother.
    if gt is not None:
        against, frames, poses, who = "ground truth", gt.frames, np.asarray(gt.poses), ests
    elif ref is not None:
        against, frames, poses = ref, np.arange(ests[ref].n_frames), ests[ref].poses
        who = {n: e for n, e in ests.items() if n not in SMOOTHERS}
    else:
        who = {}
    series = {n: pose_nees(e, frames, poses) for n, e in who.items()}
    series = {n: v for n, v in series.items() if np.any(np.isfinite(v))}
    if series:
        t = next(iter(ests.values())).timestamps
        written.append(plots.plot_nees(
            folder / "nees.png", series, dof=6, times=t - t[0],
            title=f"{title}: pose NEES against {against}",
            ylabel=f"pose NEES vs {against} (6 dof)"))
    return written
