"""Benchmark figures (PNG), drawn with matplotlib's object API on the Agg canvas (no pyplot, no
global backend switch, safe in worker processes and headless machines).

Every function takes the output path first and writes it atomically (rendered to memory, then
written through a temporary file and a rename). Axes: the world frame is the IMU frame at step
0 (x forward, y left, z up), so the top view plots x (m) against y (m).
"""

from __future__ import annotations

import io
import os
from pathlib import Path
from typing import Mapping

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from scipy.stats import chi2

from ekf.estimate import Estimate
from eval.atomic import write_bytes

#: One colour per estimator, stable across figures.
COLOURS = {
    "dead-reckoning": "tab:gray",
    "mapping": "tab:brown",
    "ekf-decoupled": "tab:orange",
    "ekf-joint": "tab:blue",
    "ekf-invariant": "tab:green",
    "smoother": "tab:red",
    "smoother-isam2": "tab:purple",
}
#: Mapping runs on the dead-reckoned trajectory: dashed, so dead reckoning shows beneath it.
LINESTYLES = {"mapping": (0, (5, 4))}
GT_STYLE = {"color": "black", "linestyle": "--", "linewidth": 1.5, "label": "ground truth"}
DPI = 110


def _colour(name: str, i: int) -> str:
    return COLOURS.get(name, f"C{i % 10}")


def _save(fig: Figure, path: str | os.PathLike) -> Path:
    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, bbox_inches="tight")
    write_bytes(path, buf.getvalue())
    return Path(path)


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


def plot_trajectories(
    path, estimates: Mapping[str, Estimate], gt_positions: np.ndarray | None = None, title: str = ""
) -> Path:
    """Top view (x-y) of every estimated trajectory, with ground truth when known."""
    fig = Figure(figsize=(7.5, 7))
    ax = fig.add_subplot()
    pts = []
    if gt_positions is not None:
        ax.plot(gt_positions[:, 0], gt_positions[:, 1], zorder=10, **GT_STYLE)
        pts.append(gt_positions[:, :2])
    for i, (name, est) in enumerate(estimates.items()):
        p = est.positions
        ax.plot(p[:, 0], p[:, 1], color=_colour(name, i), linewidth=1.2, label=name,
                linestyle=LINESTYLES.get(name, "-"))
        pts.append(p[:, :2])
    first = next(iter(estimates.values()), None)
    if first is not None:
        ax.plot(*first.positions[0, :2], "k^", markersize=8, label="start", zorder=6)
    _equal_xy(ax, np.concatenate(pts) if pts else np.zeros((0, 2)))
    ax.set_xlabel("x (m, forward at start)")
    ax.set_ylabel("y (m, left at start)")
    ax.set_title(title or "Trajectories, top view")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    return _save(fig, path)


def plot_map(
    path,
    est: Estimate,
    gt_positions: np.ndarray | None = None,
    truth_landmarks: np.ndarray | None = None,
    title: str = "",
) -> Path:
    """Top view of ``est``'s landmark map over its trajectory (and ground truth when known)."""
    fig = Figure(figsize=(7.5, 7))
    ax = fig.add_subplot()
    traj = est.positions
    lm = est.landmarks[est.has_landmark]
    # Keep the view on the drive: landmarks within 60 m of the trajectory's bounding box.
    lo, hi = traj[:, :2].min(axis=0) - 60, traj[:, :2].max(axis=0) + 60
    near = np.all((lm[:, :2] >= lo) & (lm[:, :2] <= hi), axis=1) if lm.size else np.zeros(0, bool)
    if truth_landmarks is not None:
        tl = truth_landmarks[np.all(np.isfinite(truth_landmarks), axis=1)]
        ax.scatter(tl[:, 0], tl[:, 1], s=3, c="0.7", marker="x", linewidths=0.5,
                   label=f"true landmarks ({len(tl)})")
    ax.scatter(lm[near, 0], lm[near, 1], s=2, c="tab:blue", alpha=0.6,
               label=f"{est.estimator} landmarks ({int(near.sum())} of {len(lm)} shown)")
    ax.plot(traj[:, 0], traj[:, 1], color="tab:red", linewidth=2.0, label=f"{est.estimator} trajectory",
            zorder=5)
    if gt_positions is not None:
        ax.plot(gt_positions[:, 0], gt_positions[:, 1], zorder=6, **GT_STYLE)
    _equal_xy(ax, np.concatenate([traj[:, :2], lm[near, :2]]))
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(title or f"Landmark map ({est.estimator})")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize=8, markerscale=3)
    return _save(fig, path)


def distance_travelled(positions: np.ndarray) -> np.ndarray:
    """Cumulative path length (T,) along positions (T, 3)."""
    steps = np.linalg.norm(np.diff(positions, axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(steps)])


def plot_error_over_distance(
    path, estimates: Mapping[str, Estimate], gt_frames: np.ndarray, gt_poses: np.ndarray,
    title: str = "",
) -> Path:
    """Translation error (m, not aligned) of each estimate against ground truth, over the
    distance travelled along the ground truth."""
    frames = np.asarray(gt_frames, dtype=np.int64)
    dist = distance_travelled(gt_poses[:, :3, 3])
    fig = Figure(figsize=(8, 4.5))
    ax = fig.add_subplot()
    for i, (name, est) in enumerate(estimates.items()):
        ok = frames < est.n_frames
        err = np.linalg.norm(est.positions[frames[ok]] - gt_poses[ok, :3, 3], axis=1)
        ax.plot(dist[ok], err, color=_colour(name, i), linewidth=1.2, label=name,
                linestyle=LINESTYLES.get(name, "-"))
    ax.set_xlabel("distance travelled (m)")
    ax.set_ylabel("translation error (m)")
    ax.set_title(title or "Translation error over distance (no alignment)")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    return _save(fig, path)


def plot_vs_smoother(path, ekfs: Mapping[str, Estimate], smoother: Estimate, title: str = "") -> Path:
    """Each EKF's world-frame position deviation from the smoother (x, y, z over time) with the
    EKF's own ±3σ band (R Σ_ρρ R^T, the Estimate's position covariance in the world frame)."""
    from eval.consistency import position_deviation

    names = list(ekfs)
    ncol = max(len(names), 1)
    fig = Figure(figsize=(4.2 * ncol, 7.5))
    axes = fig.subplots(3, ncol, sharex=True, squeeze=False)
    t = smoother.timestamps - smoother.timestamps[0]
    for c, name in enumerate(names):
        dev, sigma = position_deviation(ekfs[name], smoother)
        for r, axis in enumerate("xyz"):
            ax = axes[r, c]
            ax.fill_between(t, -3 * sigma[:, r], 3 * sigma[:, r], color=_colour(name, c),
                            alpha=0.2, label="±3σ (EKF)")
            ax.plot(t, dev[:, r], color=_colour(name, c), linewidth=1.0, label="EKF − smoother")
            ax.axhline(0, color="k", linewidth=0.5)
            ax.grid(True, alpha=0.3)
            if c == 0:
                ax.set_ylabel(f"{axis} deviation (m)")
            if r == 0:
                ax.set_title(name)
                ax.legend(loc="upper left", fontsize=7)
            if r == 2:
                ax.set_xlabel("time (s)")
            # Scale on the deviation and a moderate band, so neither hides the other.
            finite = np.isfinite(dev[:, r])
            if np.any(finite):
                lim = max(np.max(np.abs(dev[finite, r])),
                          np.nanpercentile(3 * sigma[:, r], 90) if np.any(np.isfinite(sigma[:, r])) else 0)
                ax.set_ylim(-1.15 * lim - 1e-3, 1.15 * lim + 1e-3)
    if not names:
        axes[0, 0].text(0.5, 0.5, "no EKF estimate", ha="center", va="center")
    fig.suptitle(title or f"EKF deviation from the smoother ({smoother.estimator})")
    return _save(fig, path)


def plot_nees(
    path,
    series: Mapping[str, np.ndarray],
    dof: int,
    n_runs: int = 1,
    times: np.ndarray | None = None,
    title: str = "",
    ylabel: str | None = None,
) -> Path:
    """NEES (or ANEES over ``n_runs``) over time per estimator with the two-sided 95 %
    chi-square band ``chi2.ppf([0.025, 0.975], n_runs dof) / n_runs``; log scale."""
    lo, hi = chi2.ppf([0.025, 0.975], n_runs * dof) / n_runs
    fig = Figure(figsize=(8, 4.5))
    ax = fig.add_subplot()
    n = max((len(v) for v in series.values()), default=0)
    x = np.arange(n) if times is None else np.asarray(times)[:n]
    ax.axhspan(lo, hi, color="0.85", label=f"95 % band [{lo:.2f}, {hi:.2f}]")
    ax.axhline(dof, color="0.4", linewidth=0.8, linestyle=":", label=f"expected ({dof})")
    for i, (name, values) in enumerate(series.items()):
        v = np.asarray(values, dtype=float)
        ok = np.isfinite(v) & (v > 0)
        ax.plot(x[: len(v)][ok], v[ok], color=_colour(name, i), linewidth=1.0,
                label=f"{name} (mean {np.mean(v[np.isfinite(v)]):.2f})" if np.any(ok) else name)
    ax.set_yscale("log")
    ax.set_xlabel("time (s)" if times is not None else "step")
    ax.set_ylabel(ylabel or (f"pose NEES ({dof} dof)" if n_runs == 1 else f"ANEES over {n_runs} runs"))
    ax.set_title(title or "Pose NEES over time")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    return _save(fig, path)
