"""Benchmark figures (PNG), drawn with matplotlib's object API on the Agg canvas (no pyplot, no
global backend switch, safe in worker processes and headless machines).

Every function takes the output path first and writes it atomically (rendered to memory, then
written through a temporary file and a rename). Axes: a velocity drive's world frame is the IMU frame at step
0 (x forward, y left, z up), a raw-IMU drive's is gravity-aligned (z up); the top views
(:mod:`eval.plots_top_view`) plot x (m) against y (m).

Every estimator stays visible where curves coincide (ekf-joint under ekf-invariant, dead
reckoning under mapping): each has its own colour, line style, width, drawing order and marker
(:data:`STYLES`); the pairs that often coincide put a wide solid line under a narrow dashed one,
and markers are placed every few per cent of the axes diagonal (``markevery``) at offsets that
differ per estimator. A legend entry says when a curve is identical to another one. Legends sit
outside the axes (constrained layout, ``loc="outside ..."``).
"""

from __future__ import annotations

import io
import os
import zlib
from collections.abc import Mapping
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch
from matplotlib.ticker import LogFormatter
from vislam.ekf.estimate import Estimate
from vislam.eval.atomic import write_bytes
from vislam.eval.consistency import chi2_bounds

#: Per estimator: colour, line style, line width, marker and drawing order (zorder), stable
#: across figures. Pairs that often draw the same curve (dead-reckoning / mapping, ekf-joint /
#: ekf-invariant) put a wide solid line first and a narrow dashed one on top, with other markers.
STYLES: dict[str, dict] = {
    "dead-reckoning": {"color": "tab:gray", "linestyle": "-", "linewidth": 3.4, "marker": "o",
                       "zorder": 2.0},
    "mapping": {"color": "tab:brown", "linestyle": (0, (5, 3)), "linewidth": 1.4, "marker": "x",
                "zorder": 2.6},
    "ekf-decoupled": {"color": "tab:orange", "linestyle": "-", "linewidth": 1.5, "marker": "s",
                      "zorder": 2.2},
    "ekf-joint": {"color": "tab:blue", "linestyle": "-", "linewidth": 3.4, "marker": "o",
                  "zorder": 2.1},
    "ekf-invariant": {"color": "tab:green", "linestyle": (0, (5, 3)), "linewidth": 1.4,
                      "marker": "^", "zorder": 2.7},
    "smoother": {"color": "tab:red", "linestyle": "-.", "linewidth": 1.5, "marker": "D",
                 "zorder": 2.4},
    "smoother-isam2": {"color": "tab:purple", "linestyle": ":", "linewidth": 2.0, "marker": "v",
                       "zorder": 2.5},
    "smoother-fixed-lag": {"color": "darkred", "linestyle": (0, (3, 1, 1, 1)), "linewidth": 1.6,
                           "marker": "*", "zorder": 2.45},
}
#: One colour per estimator (the colours of :data:`STYLES`).
COLOURS = {name: style["color"] for name, style in STYLES.items()}
#: Colours of estimators without a style of their own (a user's, MODULE:FUNCTION): none of
#: :data:`STYLES`' colours, so a user's estimator never looks like the smoother or an EKF.
_FALLBACK_COLOURS = ("tab:pink", "tab:olive", "tab:cyan", "navy", "goldenrod", "teal",
                     "magenta", "darkslategray")
_FALLBACK_LINESTYLES = ("-", (0, (5, 3)), "-.", ":", (0, (1, 1)), (0, (8, 2, 1, 2)))
_FALLBACK_MARKERS = ("P", "X", "*", "h", "<", ">", "p", "d")
#: Markers every this fraction of the axes diagonal; estimator k starts at k * _MARK_OFFSET.
_MARK_EVERY = 0.09
_MARK_OFFSET = 0.013
GT_STYLE = {"color": "black", "linestyle": "--", "linewidth": 1.2, "label": "ground truth"}
DPI = 110


def _colour(name: str, i: int = 0) -> str:
    """The estimator's colour: its own, or for a user's estimator one of
    :data:`_FALLBACK_COLOURS` chosen by its name, so that it is the same in every figure."""
    if name in COLOURS:
        return COLOURS[name]
    return _FALLBACK_COLOURS[zlib.crc32(name.encode()) % len(_FALLBACK_COLOURS)]


def line_style(name: str, i: int = 0, n_points: int | None = None) -> dict:
    """Keyword arguments of ``Axes.plot`` for estimator ``name`` (``i``: its index in the
    figure, for names without a fixed style): colour, line style and width, drawing order and
    markers every :data:`_MARK_EVERY` of the axes diagonal, at an offset of its own; with
    ``n_points`` (noisy series, whose length on screen says little) about 14 markers by index."""
    k = list(STYLES).index(name) if name in STYLES else len(STYLES) + i
    style = dict(STYLES.get(name) or {
        "color": _colour(name),
        "linestyle": _FALLBACK_LINESTYLES[i % len(_FALLBACK_LINESTYLES)],
        "linewidth": 1.5, "marker": _FALLBACK_MARKERS[i % len(_FALLBACK_MARKERS)], "zorder": 2.3,
    })
    wide = style["linewidth"] > 2.5
    if n_points:
        step = max(n_points // 14, 1)
        markevery = (k * step // 7 % step, step)
    else:
        markevery = ((k * _MARK_OFFSET) % _MARK_EVERY, _MARK_EVERY)
    style.update(
        markevery=markevery,
        markersize=7.5 if wide else 6.0,
        markerfacecolor="white" if wide else style["color"],
        markeredgecolor=style["color"],
        markeredgewidth=1.5,
    )
    return style


def coincident(curves: Mapping[str, np.ndarray], rtol: float = 1e-3) -> dict[str, list[str]]:
    """For each name, the other names whose curve (array of the same shape) is the same within
    ``rtol`` of the curves' largest finite magnitude (NaN where the other is NaN): the curves
    that draw on top of each other."""
    out: dict[str, list[str]] = {name: [] for name in curves}
    arrays = {n: np.asarray(c, dtype=float) for n, c in curves.items()}
    names = list(arrays)
    for a, na in enumerate(names):
        for nb in names[a + 1:]:
            x, y = arrays[na], arrays[nb]
            if x.shape != y.shape or x.size == 0:
                continue
            both = np.isfinite(x) & np.isfinite(y)
            if not np.array_equal(np.isfinite(x), np.isfinite(y)) or not np.any(both):
                continue
            scale = max(float(np.max(np.abs(x[both]))), float(np.max(np.abs(y[both]))), 1e-12)
            if np.all(np.abs(x[both] - y[both]) <= rtol * scale):
                out[na].append(nb)
                out[nb].append(na)
    return out


def curve_label(name: str, same: Mapping[str, list[str]], extra: str = "") -> str:
    parts = [extra] if extra else []
    if same.get(name):
        parts.append("same curve as " + ", ".join(same[name]))
    return f"{name} ({'; '.join(parts)})" if parts else name


def readable(x: float | None) -> str:
    """A number for a legend: 3 significant digits, powers of ten as 2.0e10."""
    if x is None or not np.isfinite(x):
        return "n/a"
    if x != 0 and not 1e-2 <= abs(x) < 1e4:
        mantissa, exponent = f"{x:.1e}".split("e")
        return f"{mantissa}e{int(exponent)}"
    return f"{x:.3g}"


def save_figure(fig: Figure, path: str | os.PathLike) -> Path:
    """The figure as a PNG at DPI, written atomically. Every figure is laid out by matplotlib's
    constrained layout, which keeps its labels and outside legends inside the canvas, so the
    canvas is saved as it is: ``bbox_inches="tight"`` would draw the whole figure a second time
    only to trim its margin."""
    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI)
    write_bytes(path, buf.getvalue())
    return Path(path)


def legend_outside(fig: Figure, axes, **kwargs):
    """One legend for ``axes`` (unique labels), outside the data on the right."""
    handles, labels = [], []
    for ax in np.atleast_1d(axes).ravel():
        for h, label in zip(*ax.get_legend_handles_labels()):
            if label not in labels:
                handles.append(h)
                labels.append(label)
    if handles:
        kwargs.setdefault("loc", "outside right upper")
        kwargs.setdefault("fontsize", 8)
        return fig.legend(handles, labels, handlelength=4, **kwargs)
    return None


def distance_travelled(positions: np.ndarray) -> np.ndarray:
    """Cumulative path length (T,) along positions (T, 3)."""
    steps = np.linalg.norm(np.diff(positions, axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(steps)])


def plot_error_over_distance(
    path, estimates: Mapping[str, Estimate], gt_frames: np.ndarray,
    gt_poses: np.ndarray | Mapping[str, np.ndarray], title: str = "",
) -> Path:
    """Translation error (m, not aligned) of each estimate against ground truth, over the
    distance travelled along the ground truth. ``gt_poses`` (n, 4, 4), or one such array per
    estimate where each is scored against the truth in its own gauge (a raw-IMU drive's:
    :func:`eval.bench_scores.truth_in_gauge`; the distance is the same in every gauge)."""
    frames = np.asarray(gt_frames, dtype=np.int64)
    truth = gt_poses if isinstance(gt_poses, Mapping) else {n: gt_poses for n in estimates}
    dist = distance_travelled(next(iter(truth.values()))[:, :3, 3]) if truth else np.zeros(0)
    fig = Figure(figsize=(9.5, 4.8), layout="constrained")
    ax = fig.add_subplot()
    curves = {}
    for name, est in estimates.items():
        ok = frames < est.n_frames
        err = np.full(len(frames), np.nan)
        err[ok] = np.linalg.norm(est.positions[frames[ok]] - truth[name][ok, :3, 3], axis=1)
        curves[name] = err
    same = coincident(curves)
    for i, (name, err) in enumerate(curves.items()):
        ok = np.isfinite(err)
        ax.plot(dist[ok], err[ok], label=curve_label(name, same), **line_style(name, i))
    ax.set_xlabel("distance travelled (m)")
    ax.set_ylabel("translation error (m)")
    ax.set_title(title or "Translation error over distance (no alignment)")
    ax.grid(True, alpha=0.3)
    legend_outside(fig, ax)
    return save_figure(fig, path)


#: vs_smoother: a ±3σ band whose 90th percentile is under this share of the axis half-range is
#: not drawn (no visible width); one
#: whose 90th percentile is more than _BAND_DWARFS times the largest deviation is clipped.
_BAND_VISIBLE = 0.05
_BAND_DWARFS = 3.0


def plot_vs_smoother(path, ekfs: Mapping[str, Estimate], smoother: Estimate, title: str = "") -> Path:
    """Each EKF's world-frame position deviation from the smoother (x, y, z over time) with the
    EKF's own ±3σ band (R Σ_ρρ R^T, the Estimate's position covariance in the world frame).

    The y range follows the deviation and the band: a band with no visible width (under
    :data:`_BAND_VISIBLE` of the axis) is not drawn, and a band that dwarfs the deviation
    (:data:`_BAND_DWARFS`) is clipped to the deviation's range; a note in the panel says so."""
    from vislam.eval.consistency import position_deviation

    names = list(ekfs)
    ncol = max(len(names), 1)
    fig = Figure(figsize=(4.2 * ncol + 1.0, 7.8), layout="constrained")
    axes = fig.subplots(3, ncol, sharex=True, squeeze=False)
    t = smoother.timestamps - smoother.timestamps[0]
    band_drawn = False
    for c, name in enumerate(names):
        dev, sigma = position_deviation(ekfs[name], smoother)
        colour = _colour(name, c)
        for r, axis in enumerate("xyz"):
            ax = axes[r, c]
            d, s3 = dev[:, r], 3 * sigma[:, r]
            fd, fs = np.isfinite(d), np.isfinite(s3)
            dev_lim = float(np.max(np.abs(d[fd]))) if np.any(fd) else 0.0
            band = float(np.percentile(s3[fs], 90)) if np.any(fs) else 0.0
            band_max = float(np.max(s3[fs])) if np.any(fs) else 0.0
            note = ""
            if band > _BAND_DWARFS * dev_lim and dev_lim > 0:
                lim = dev_lim
                note = f"±3σ clipped (up to {readable(band_max)} m)"
            else:
                lim = max(dev_lim, band)
            lim = 1.15 * lim + 1e-3
            if band >= _BAND_VISIBLE * lim:
                ax.fill_between(t, -s3, s3, color=colour, alpha=0.2, linewidth=0, label="EKF ±3σ")
                band_drawn = True
            else:
                note = f"±3σ mostly under {readable(band)} m: too narrow to draw"
            ax.plot(t, d, color=colour, linewidth=1.0, label="EKF − smoother")
            ax.axhline(0, color="k", linewidth=0.5)
            ax.set_ylim(-lim, lim)
            ax.grid(True, alpha=0.3)
            if note:
                ax.text(0.01, 0.02, note, transform=ax.transAxes, fontsize=7, va="bottom",
                        bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "0.7"})
            if c == 0:
                ax.set_ylabel(f"{axis} deviation (m)")
            if r == 0:
                ax.set_title(name, color=colour)
            if r == 2:
                ax.set_xlabel("time (s)")
    if not names:
        axes[0, 0].text(0.5, 0.5, "no EKF estimate", ha="center", va="center")
    handles = [Line2D([], [], color="0.3", linewidth=1.0, label="EKF − smoother (column colour)")]
    if band_drawn:
        handles.append(Patch(color="0.3", alpha=0.25, label="EKF ±3σ"))
    fig.legend(handles=handles, loc="outside lower center", ncols=len(handles), fontsize=8)
    fig.suptitle(title or f"EKF deviation from the smoother ({smoother.estimator})")
    return save_figure(fig, path)


def nees_axis_range(dof: int, n_runs: int = 1) -> tuple[float, float]:
    """The NEES axis of :func:`plot_nees`: whole decades around the 95 % band, from a fifth of
    its lower end to twenty times its upper end ([0.1, 1000] for 6 dof)."""
    lo, hi = chi2_bounds(n_runs, dof)
    return 10.0 ** np.floor(np.log10(lo / 5)), 10.0 ** np.ceil(np.log10(hi * 20))


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
    chi-square band ``chi2.ppf([0.025, 0.975], n_runs dof) / n_runs``; log scale.

    The main panel's axis is fixed to :func:`nees_axis_range` so the band reads the same on
    every drive; an estimator whose median NEES is outside that range is drawn apart, in a
    lower panel on its own scale, and the main panel lists it with its mean. Legend entries say
    each mean (2.0e10 style) and the share of steps clipped. The y label is the same for every
    call; ``ylabel`` (e.g. what the NEES is measured against) becomes the legend's title."""
    lo, hi = chi2_bounds(n_runs, dof)
    ylo, yhi = nees_axis_range(dof, n_runs)
    n = max((len(v) for v in series.values()), default=0)
    x = np.arange(n) if times is None else np.asarray(times, dtype=float)[:n]
    values = {name: np.asarray(v, dtype=float) for name, v in series.items()}
    wild = [name for name, v in values.items()
            if np.any(np.isfinite(v)) and not ylo <= np.median(v[np.isfinite(v)]) <= yhi]
    fig = Figure(figsize=(10, 6.8 if wild else 4.8), layout="constrained")
    if wild:
        main, apart = fig.subplots(2, 1, sharex=True, height_ratios=[2, 1])
    else:
        main, apart = fig.subplots(), None
    same = coincident(values)
    for ax in (main, apart):
        if ax is None:
            continue
        ax.axhspan(lo, hi, color="0.85", zorder=0, label=f"95 % band [{lo:.2f}, {hi:.2f}]")
        ax.axhline(dof, color="0.4", linewidth=0.8, linestyle=":", zorder=0.5,
                   label=f"expected ({dof})")
    for i, (name, v) in enumerate(values.items()):
        finite = np.isfinite(v)
        ok = finite & (v > 0)
        ax = apart if name in wild else main
        extra = ""
        if np.any(finite):
            extra = f"mean {readable(float(np.mean(v[finite])))}"
            if name in wild:
                extra += ", own panel below"
            else:
                off = float(np.mean((v[finite] > yhi) | (v[finite] < ylo)))
                if off > 0:
                    share = "<1" if off < 0.01 else f"{100 * off:.0f}"
                    extra += f", {share} % of steps off scale"
        ax.plot(x[: len(v)][ok], v[ok], label=curve_label(name, same, extra),
                **line_style(name, i, n_points=int(ok.sum())))
    what = f"pose NEES ({dof} dof)" if n_runs == 1 else f"pose ANEES over {n_runs} runs ({dof} dof)"
    main.set_yscale("log")
    main.set_ylim(ylo, yhi)
    main.yaxis.set_major_formatter(_PlainLogFormatter())
    main.set_ylabel(what)
    main.set_title(title or ("Pose NEES over time" if n_runs == 1 else "Pose ANEES over time"))
    if wild:
        means = ", ".join(f"{w} (mean {readable(float(np.nanmean(values[w])))})" for w in wild)
        main.text(0.01, 0.97, f"off this scale, drawn below: {means}", transform=main.transAxes,
                  fontsize=8, va="top",
                  bbox={"facecolor": "white", "alpha": 0.85, "edgecolor": "0.7"})
        apart.set_yscale("log")
        apart.set_ylabel(f"{what},\nown scale")
        apart.set_title("off the scale above", fontsize=9)
    for ax in (main, apart):
        if ax is not None:
            ax.grid(True, which="both", alpha=0.3)
    (apart if apart is not None else main).set_xlabel("time (s)" if times is not None else "step")
    legend_outside(fig, [main, apart] if apart is not None else main, title=ylabel,
                    title_fontsize=8)
    return save_figure(fig, path)


class _PlainLogFormatter(LogFormatter):
    """Log-axis labels as plain numbers (0.6, 6, 60), on the ticks LogFormatter labels."""

    def __call__(self, x, pos=None):
        return f"{x:g}" if super().__call__(x, pos) else ""


def plot_nees_depth_sweep(
    path,
    depths,
    pose: Mapping[tuple[str, str | None], np.ndarray | list],
    landmark: Mapping[tuple[str, str | None], np.ndarray | list],
    n_runs: int,
    title: str = "",
) -> Path:
    """Pose and landmark ANEES over ``n_runs`` runs (two panels, log scale) against the
    simulated landmark range ``depths`` (m). One line per key (estimator, landmark
    parameterisation or None): the estimator's colour, dashed for "inverse-depth"; the
    two-sided 95 % chi-square band of ``n_runs`` runs shaded; None or NaN values left out."""
    x = np.asarray(depths, dtype=float)
    fig = Figure(figsize=(11, 4.6), layout="constrained")
    axes = fig.subplots(1, 2, sharex=True)
    names = list(dict.fromkeys(name for name, _ in pose))
    for ax, series, dof, what in ((axes[0], pose, 6, "pose"), (axes[1], landmark, 3, "landmark")):
        lo, hi = chi2_bounds(n_runs, dof)
        ax.axhspan(lo, hi, color="0.85", label=f"95 % band, {n_runs} runs")
        ax.axhline(dof, color="0.4", linewidth=0.8, linestyle=":", label="expected (= dof)")
        for (name, param), values in series.items():
            v = np.array([np.nan if a is None else a for a in values], dtype=float)
            ok = np.isfinite(v) & (v > 0)
            style = STYLES.get(name, {})
            wide = style.get("linewidth", 1.6) > 2  # drawn under a narrower one it may coincide with
            ax.plot(x[ok], v[ok], color=_colour(name, names.index(name)), marker=style.get("marker", "o"),
                    markersize=8 if wide else 5, markerfacecolor="white" if wide else None,
                    linewidth=3.0 if wide else 1.4, zorder=style.get("zorder", 2.0),
                    linestyle=(0, (4, 2)) if param == "inverse-depth" else "-",
                    label=name if param is None else f"{name}, {param}")
        ax.set_yscale("log")
        ax.yaxis.set_major_formatter(_PlainLogFormatter())
        ax.yaxis.set_minor_formatter(_PlainLogFormatter(labelOnlyBase=False, minor_thresholds=(1, 0.4)))
        ax.set_xticks(x)
        ax.set_xticklabels([f"{d:g}" for d in x])
        ax.set_xlabel("maximum landmark depth of the simulated drive (m)")
        ax.set_ylabel(f"{what} ANEES ({dof} dof)")
        ax.set_title(f"{what.capitalize()} ANEES ({lo:.2f}-{hi:.2f} is consistent)")
        ax.grid(True, which="both", alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside right upper", fontsize=8, handlelength=4)
    fig.suptitle(title or f"ANEES against landmark range, {n_runs} runs")
    return save_figure(fig, path)
