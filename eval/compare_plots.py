"""``compare.png`` of ``vislam compare``: the folders' figures side by side.

One block per table of the comparison (:class:`eval.compare.Comparison`):

* a bench sequence: one panel per key figure (ATE, ATE aligned, t_rel, r_rel, NEES, map RMSE,
  landmark NEES, runtime; those with a value somewhere), each a dot plot with one row per
  estimator (every estimator of any folder is listed) and one marker per folder (colour and
  shape per folder, named in the legend), joined to the baseline's marker by a thin line, the
  value written beside it; "–" where the estimator is not in a folder, "n/a" where it has no
  value. NEES panels are on a log scale with the two-sided 95 % chi-square band shaded; other
  panels on a log scale when their values span more than a factor of 30.
* the Monte Carlo NEES: the per-run mean pose NEES of every run (dots) with a box per folder,
  the ANEES (diamond) and the ANEES bounds of that folder shaded behind its row; the landmark
  ANEES with its bounds likewise.

Drawn with matplotlib's object API on the Agg canvas, written atomically (as :mod:`eval.plots`).
"""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib
import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch
from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter
from vislam.eval.compare import PLOT_FIGURES, Comparison, Row, Section
from vislam.eval.compare_readings import ABSENT, NO_VALUE, num
from vislam.eval.plots import COLOURS, save_figure

FOLDER_COLOURS = ("black", "tab:blue", "tab:orange", "tab:purple", "tab:cyan", "tab:olive",
                  "tab:pink", "tab:brown")
FOLDER_MARKERS = ("o", "s", "^", "D", "v", "P", "X", "h")
BAND_COLOUR = "#cfe8cf"
PANELS_PER_ROW = 4
#: ``Axes.boxplot``'s horizontal boxes: ``orientation`` from matplotlib 3.10, ``vert`` before.
_HORIZONTAL = ({"orientation": "horizontal"}
               if tuple(int(x) for x in matplotlib.__version__.split(".")[:2]) >= (3, 10)
               else {"vert": False})


def _folder_style(j: int) -> dict:
    """Colour and marker of the ``j``-th folder of the comparison (the same in every block)."""
    return {"color": FOLDER_COLOURS[j % len(FOLDER_COLOURS)],
            "marker": FOLDER_MARKERS[j % len(FOLDER_MARKERS)]}


def _slots(n_folders: int) -> np.ndarray:
    """Vertical offsets of the folders within an estimator's row (first folder on top)."""
    h = 0.8 / max(n_folders, 1)
    return (np.arange(n_folders) - (n_folders - 1) / 2) * h


def _rows_for(section: Section, key: str) -> dict[str, Row]:
    return {r.estimator: r for r in section.rows if r.key == key}


def _estimator_axis(ax, estimators: list[str], labels: bool) -> None:
    ax.set_yticks(range(len(estimators)))
    if labels:
        ax.set_yticklabels(estimators)
        for tick, name in zip(ax.get_yticklabels(), estimators):
            tick.set_color(COLOURS.get(name, "black"))
    else:
        ax.tick_params(labelleft=False)
    ax.set_ylim(len(estimators) - 0.5, -0.5)
    for y in np.arange(len(estimators) - 1) + 0.5:
        ax.axhline(y, color="0.85", linewidth=0.8, zorder=0)


def _scale(ax, values: list[float], log_always: bool, band=None) -> None:
    pos = [v for v in values if v is not None and v > 0]
    everything = [v for v in values if v is not None]
    if band is not None:
        pos += list(band)
    if pos and (log_always or (len(pos) == len(everything) and max(pos) / min(pos) > 30)):
        ax.set_xscale("log")
        lo, hi = min(pos), max(pos)
        ax.set_xlim(lo / 2.5, hi * 2.5)
        _plain_log_axis(ax)
    elif everything:
        lo, hi = min(everything + [0.0]), max(everything + [0.0])
        span = (hi - lo) or 1.0
        ax.set_xlim(lo - 0.05 * span, hi + 0.25 * span)


def _missing_word(section: Section, est: str, j: int, row: Row | None) -> str:
    """What stands where a folder has no value: absent, failed or n/a."""
    if not section.present.get(est, [True] * (j + 1))[j]:
        return f"{ABSENT} absent"
    if row is not None and row.cells[j].startswith("failed"):
        return "failed"
    return NO_VALUE


def _mark_missing(ax, y: float, text: str, colour: str) -> None:
    ax.text(0.02, y, text, transform=ax.get_yaxis_transform(), fontsize=7.5, color=colour,
            va="center", ha="left", style="italic")


def _plain_log_axis(ax) -> None:
    """Log-axis labels as plain numbers (0.5, 2, 50): at 1, 2 and 5 of each decade over up to
    two and a half decades, at the powers of ten over up to five; matplotlib's beyond."""
    lo, hi = ax.get_xlim()
    decades = math.log10(hi / lo)
    if decades > 5:
        return
    subs = (1.0, 2.0, 5.0) if decades <= 2.5 else (1.0,)
    ax.xaxis.set_major_locator(LogLocator(base=10, subs=subs))
    ax.xaxis.set_major_formatter(FuncFormatter(lambda x, _: f"{x:g}"))
    ax.xaxis.set_minor_formatter(NullFormatter())


def _dot_panel(ax, section: Section, styles: list[dict], rows: dict[str, Row], title: str,
               band=None, labels: bool = True) -> None:
    ests = section.estimators
    slots = _slots(len(section.folders))
    _estimator_axis(ax, ests, labels)
    values = [v for r in rows.values() for v in r.values]
    _scale(ax, values, log_always=band is not None, band=band)
    if band is not None:
        ax.axvspan(band[0], band[1], color=BAND_COLOUR, zorder=0)
    for i, est in enumerate(ests):
        row = rows.get(est)
        points = []
        for j, f in enumerate(section.folders):
            style = styles[j]
            y = i + slots[j]
            v = None if row is None else row.values[j]
            if v is None or (ax.get_xscale() == "log" and v <= 0):
                _mark_missing(ax, y, _missing_word(section, est, j, row), style["color"])
                points.append(None)
                continue
            ax.plot([v], [y], linestyle="none", markersize=6.5, zorder=3,
                    markerfacecolor="white" if j == 0 else style["color"],
                    markeredgecolor=style["color"], markeredgewidth=1.4, marker=style["marker"])
            ax.annotate(num(v), (v, y), xytext=(5, 0), textcoords="offset points", fontsize=6.5,
                        va="center", color=style["color"])
            points.append((v, y))
        if points and points[0] is not None:
            for p in points[1:]:
                if p is not None:
                    ax.plot([points[0][0], p[0]], [points[0][1], p[1]], color="0.6",
                            linewidth=0.8, zorder=2)
    ax.set_title(title, fontsize=9)
    ax.tick_params(labelsize=8)
    ax.grid(True, axis="x", which="major", alpha=0.3)


def _bench_block(subfig, section: Section, styles: list[dict]) -> None:
    keys = [k for k in PLOT_FIGURES if any(v is not None for r in _rows_for(section, k).values()
                                           for v in r.values)]
    if not keys:
        ax = subfig.subplots()
        ax.axis("off")
        ax.text(0.5, 0.5, "no figures with a value", ha="center", va="center")
        subfig.suptitle(f"Benchmark: {section.title}", fontsize=10, fontweight="bold")
        return
    ncols = min(PANELS_PER_ROW, len(keys))
    nrows = math.ceil(len(keys) / ncols)
    axes = np.atleast_1d(subfig.subplots(nrows, ncols, squeeze=False)).ravel()
    for k, (ax, key) in enumerate(zip(axes, keys)):
        rows = _rows_for(section, key)
        any_row = next(iter(rows.values()))
        band = any_row.bands[0] if any_row.bands else None
        title = any_row.label
        _dot_panel(ax, section, styles, rows, title, band=band, labels=k % ncols == 0)
    for ax in axes[len(keys):]:
        ax.axis("off")
    subfig.suptitle(f"Benchmark: {section.title}", fontsize=10, fontweight="bold")


def _per_slot_band(ax, y: float, h: float, band) -> None:
    if band is not None:
        ax.fill_betweenx([y - h / 2, y + h / 2], band[0], band[1], color=BAND_COLOUR, zorder=0,
                         linewidth=0)


def _nees_block(subfig, section: Section, styles: list[dict]) -> None:
    ests = section.estimators
    n = len(section.folders)
    slots = _slots(n)
    h = 0.8 / max(n, 1)
    per_run = _rows_for(section, "nees_pose_per_run_mean")
    pose = _rows_for(section, "anees_pose")
    landmark = _rows_for(section, "anees_landmark")
    panels = [("pose NEES: per-run means (dots, box), ANEES (diamond)", per_run, pose)]
    if landmark:
        panels.append(("landmark ANEES", None, landmark))
    axes = np.atleast_1d(subfig.subplots(1, len(panels), squeeze=False)).ravel()
    for k, (ax, (title, runs_rows, anees_rows)) in enumerate(zip(axes, panels)):
        _estimator_axis(ax, ests, labels=k == 0)
        ax.set_xscale("log")
        everything = []
        for i, est in enumerate(ests):
            arow = anees_rows.get(est)
            rrow = runs_rows.get(est) if runs_rows else None
            for j, f in enumerate(section.folders):
                style = styles[j]
                y = i + slots[j]
                band = arow.bands[j] if arow is not None and arow.bands else None
                _per_slot_band(ax, y, h, band)
                if band is not None:
                    everything += list(band)
                runs = [v for v in (rrow.runs[j] if rrow is not None else []) if v > 0]
                if runs:
                    ax.boxplot([runs], positions=[y], widths=h * 0.7, **_HORIZONTAL,
                               showfliers=False, manage_ticks=False, zorder=2,
                               boxprops={"color": style["color"]},
                               whiskerprops={"color": style["color"]},
                               capprops={"color": style["color"]},
                               medianprops={"color": style["color"], "linewidth": 1.8})
                    ax.plot(runs, np.full(len(runs), y), linestyle="none", marker=style["marker"],
                            markersize=3.5, alpha=0.55, color=style["color"], zorder=3)
                    everything += runs
                v = arow.values[j] if arow is not None else None
                if v is not None and v > 0:
                    ax.plot([v], [y], linestyle="none", marker="D", markersize=7,
                            markerfacecolor="white", markeredgecolor=style["color"],
                            markeredgewidth=1.6, zorder=4)
                    ax.annotate(num(v), (v, y), xytext=(0, 6), textcoords="offset points",
                                fontsize=6.5, ha="center", va="bottom", color=style["color"])
                    everything.append(v)
                elif not runs:
                    _mark_missing(ax, y, _missing_word(section, est, j, arow), style["color"])
        if everything:
            ax.set_xlim(min(everything) / 2, max(everything) * 2)
            _plain_log_axis(ax)
        ax.set_title(title, fontsize=9)
        ax.tick_params(labelsize=8)
        ax.grid(True, axis="x", which="both", alpha=0.3)
    subfig.suptitle(section.title, fontsize=10, fontweight="bold")


def plot_comparison(path, comp: Comparison) -> Path:
    """Write ``compare.png`` for ``comp`` (see the module's docstring)."""
    heights = []
    for s in comp.sections:
        n_est = max(len(s.estimators), 1)
        per_panel = 0.9 + 0.32 * n_est * max(len(s.folders), 2) / 2
        if s.kind == "bench":
            keys = [k for k in PLOT_FIGURES
                    if any(v is not None for r in _rows_for(s, k).values() for v in r.values)]
            rows = max(1, math.ceil(len(keys) / PANELS_PER_ROW))
            heights.append(0.5 + rows * per_panel)
        else:
            heights.append(0.5 + per_panel * 1.2)
    fig = Figure(figsize=(15, sum(heights) + 0.8), layout="constrained")
    subfigs = fig.subfigures(len(comp.sections), 1, height_ratios=heights, squeeze=False).ravel()
    for sub, section in zip(subfigs, comp.sections):
        # a folder keeps its colour and marker in every block, whichever folders the block has
        styles = [_folder_style(next(i for i, g in enumerate(comp.folders) if g is f))
                  for f in section.folders]
        (_bench_block if section.kind == "bench" else _nees_block)(sub, section, styles)
    handles = []
    for j, f in enumerate(comp.folders):
        st = _folder_style(j)
        handles.append(Line2D([], [], linestyle="none", marker=st["marker"], color=st["color"],
                              markerfacecolor="white" if j == 0 else st["color"],
                              markeredgewidth=1.4,
                              label=f"{f.label}: {f.shown}" + (" (baseline)" if j == 0 else "")))
    handles.append(Patch(color=BAND_COLOUR, label="95 % chi-square band (NEES)"))
    if any(s.kind == "nees" for s in comp.sections):
        handles.append(Line2D([], [], linestyle="none", marker="D", color="0.3",
                              markerfacecolor="white", label="ANEES (band: its 95 % bounds)"))
        handles.append(Line2D([], [], linestyle="none", marker="o", color="0.3", alpha=0.55,
                              markersize=3.5, label="one run's mean pose NEES"))
    fig.legend(handles=handles, loc="outside upper center", ncols=min(len(handles), 4),
               fontsize=8, frameon=False)
    return save_figure(fig, path)
