"""The top views of a drive's figures: every estimate's trajectory, and one estimate's landmark
map over it (:mod:`eval.plots` holds the styles they share and the other figures)."""

from __future__ import annotations

import textwrap
from collections.abc import Mapping
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from vislam.ekf.estimate import Estimate
from vislam.eval import plots
from vislam.eval.plots import GT_STYLE, coincident, curve_label, legend_outside, line_style


def _equal_xy(ax, xy: np.ndarray, margin: float = 0.05) -> None:
    """Equal-aspect limits around points (n, 2), ignoring non-finite rows."""
    xy = xy[np.all(np.isfinite(xy), axis=1)]
    if xy.size == 0:
        return
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    span = max(float(np.max(hi - lo)), 1.0) * (1 + 2 * margin)
    mid = (lo + hi) / 2
    ax.set_xlim(mid[0] - span / 2, mid[0] + span / 2)
    ax.set_ylim(mid[1] - span / 2, mid[1] + span / 2)
    ax.set_aspect("equal", adjustable="box")


#: Axis labels of the top view for each kind of drive's world frame (DESIGN.md; docs/raw_imu.md).
WORLD_AXES = {
    "velocity": ("x (m, forward at start)", "y (m, left at start)"),
    "raw-imu": ("x (m, level; yaw of the IMU at start)", "y (m, level)"),
}
#: An estimate whose path leaves the others' extent by more than this many times that extent
#: (dead reckoning on a raw IMU drifts by metres in seconds) is drawn, but the view keeps to the
#: rest; its legend entry says how far it goes.
VIEW_OUTLIER_FACTOR = 3.0


def _view_points(pts: dict[str, np.ndarray], anchor: np.ndarray | None) -> tuple[np.ndarray, dict]:
    """The points the top view is fitted to, and the estimates left out of it with how far
    beyond it each goes (m): the view fits the ground truth (without one, the estimate of the
    median extent) and every estimate that stays within :data:`VIEW_OUTLIER_FACTOR` times that
    extent of it."""
    finite = {n: p[np.all(np.isfinite(p), axis=1)] for n, p in pts.items()}
    finite = {n: p for n, p in finite.items() if len(p)}
    if anchor is not None:
        anchor = anchor[np.all(np.isfinite(anchor), axis=1)]
    if anchor is None or not len(anchor):
        if not finite:
            return np.zeros((0, 2)), {}
        # no truth: the estimate of the median extent (the lower one of an even count)
        by_span = sorted(finite.values(), key=lambda p: float(np.max(p.max(axis=0) - p.min(axis=0))))
        anchor = by_span[(len(by_span) - 1) // 2]
    lo, hi = anchor.min(axis=0), anchor.max(axis=0)
    span = max(float(np.max(hi - lo)), 1.0)
    mid = (lo + hi) / 2
    beyond = {}
    keep = [anchor]
    for n, p in finite.items():
        far = float(np.max(np.abs(p - mid))) - span / 2
        if far > VIEW_OUTLIER_FACTOR * span:
            beyond[n] = far
        else:
            keep.append(p)
    return np.concatenate(keep), beyond


def plot_trajectories(
    path, estimates: Mapping[str, Estimate], gt_positions: np.ndarray | None = None, title: str = "",
    world: str = "velocity",
) -> Path:
    """Top view (x-y) of every estimated trajectory, with ground truth when known. ``world``
    the kind of drive (:data:`WORLD_AXES`) whose world frame the axes are in. An estimate far
    outside the others (:data:`VIEW_OUTLIER_FACTOR`) runs off the view, and its legend says
    how far it goes."""
    fig = Figure(figsize=(9, 7), layout="constrained")
    ax = fig.add_subplot()
    if gt_positions is not None:
        ax.plot(gt_positions[:, 0], gt_positions[:, 1], zorder=10, **GT_STYLE)
    xy = {n: e.positions[:, :2] for n, e in estimates.items()}
    view, beyond = _view_points(xy, None if gt_positions is None else gt_positions[:, :2])
    same = coincident(xy)
    for i, (name, est) in enumerate(estimates.items()):
        p = est.positions
        label = curve_label(name, same)
        if name in beyond:
            label += f" (off the view, up to {beyond[name]:.3g} m beyond)"
        ax.plot(p[:, 0], p[:, 1], label=label, **line_style(name, i))
    first = next(iter(estimates.values()), None)
    if first is not None:
        ax.plot(*first.positions[0, :2], "k^", markersize=9, label="start", zorder=11)
    _equal_xy(ax, view)
    xlabel, ylabel = WORLD_AXES[world]
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title or "Trajectories, top view")
    ax.grid(True, alpha=0.3)
    legend_outside(fig, ax)
    return plots.save_figure(fig, path)


#: The map shows landmarks within this many metres of the trajectory's bounding box.
MAP_MARGIN_M = 60.0


def plot_map(
    path,
    est: Estimate,
    gt_positions: np.ndarray | None = None,
    truth_landmarks: np.ndarray | None = None,
    title: str = "",
) -> Path:
    """Top view of ``est``'s landmark map over its trajectory (and ground truth when known).
    Landmarks more than :data:`MAP_MARGIN_M` outside the trajectory's bounding box are left out
    (the title says how many, and how many tracks have no finite landmark); the true landmarks
    are drawn on top as hollow black circles, the estimates as small filled dots."""
    fig = Figure(figsize=(9, 7.5), layout="constrained")
    ax = fig.add_subplot()
    traj = est.positions
    has = est.has_landmark
    lm = est.landmarks[has]
    lo = traj[:, :2].min(axis=0) - MAP_MARGIN_M
    hi = traj[:, :2].max(axis=0) + MAP_MARGIN_M
    near = np.all((lm[:, :2] >= lo) & (lm[:, :2] <= hi), axis=1) if lm.size else np.zeros(0, bool)
    n_far, n_missing = int((~near).sum()), int((~has).sum())
    left_out = []
    if n_far:
        left_out.append(f"{n_far} more than {MAP_MARGIN_M:g} m outside the trajectory's extent")
    if n_missing:
        left_out.append(f"{n_missing} tracks without a finite landmark")
    note = (f"{int(near.sum())} of {len(lm)} estimated landmarks shown"
            + ("; not shown: " + ", ".join(left_out) if left_out else "; none left out"))
    ax.scatter(lm[near, 0], lm[near, 1], s=5, c="tab:blue", alpha=0.8, linewidths=0, zorder=2,
               label=f"{est.estimator} landmarks ({int(near.sum())} shown)")
    if truth_landmarks is not None:
        tl = truth_landmarks[np.all(np.isfinite(truth_landmarks), axis=1)]
        ax.scatter(tl[:, 0], tl[:, 1], s=22, facecolors="none", edgecolors="black",
                   linewidths=0.7, zorder=3, label=f"true landmarks ({len(tl)})")
    ax.plot(traj[:, 0], traj[:, 1], color="tab:red", linewidth=2.0,
            label=f"{est.estimator} trajectory", zorder=5)
    if gt_positions is not None:
        ax.plot(gt_positions[:, 0], gt_positions[:, 1], zorder=6, **GT_STYLE)
    _equal_xy(ax, np.concatenate([traj[:, :2], lm[near, :2]]))
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title("\n".join([title or f"Landmark map ({est.estimator})", *textwrap.wrap(note, 64)]),
                 fontsize=10)
    ax.grid(True, alpha=0.3)
    legend_outside(fig, ax, markerscale=2)
    return plots.save_figure(fig, path)
