"""Compare result folders of ``vislam bench`` (``results.json``) and ``vislam nees``
(``nees.json``) side by side: the library behind ``vislam compare`` (no printing or writing
here: the text is :mod:`eval.compare_text`, the figure :mod:`eval.compare_plots`; the numbers
and readings :mod:`eval.compare_readings`, the settings :mod:`eval.compare_settings`). The
folders are read by :func:`eval.results.load_results`.

The first folder is the baseline (A); every other folder (B, C, ...) is compared with it. A
folder may hold either kind or both; each kind is compared among the folders that hold it,
provided the baseline holds it too. Sequences, estimators and figures present in only some
folders are kept, with "–" where absent ("n/a" where present without a value, "failed" where the
estimator failed).

Per figure the change ``B − A`` is given absolutely and relative to ``|A|`` (%), with a reading:

* "lower is better" figures (ATE, ATE aligned, t_rel, r_rel, the drive-fitted RPE, map RMSE,
  the vs-smoother ATE and map RMSE, runtime): better / worse / same ("same" when they differ by
  at most 0.1 % of the larger); when two folders' drives gave the RPE different segment lengths
  (:func:`eval.rpe_segments.drive_segment_lengths`), a note says so;
* NEES figures: the one closer to the two-sided 95 % chi-square band is better (distance on a
  log scale, zero inside the band); "both inside the band" when neither is outside. Bench's
  mean pose NEES (and the vs-smoother NEES) uses the band of one 6-dof NEES, its landmark NEES
  the band of one 3-dof NEES (:func:`eval.consistency.chi2_bounds` with one run); ``nees``'s
  ANEES use the bounds each ``nees.json`` carries;
* other figures (share of steps inside the 95 % band vs the smoother): the change only.

Monte Carlo runs (``nees.json``'s ``nees_pose_per_run_mean``) are summarised as
"mean, median (min, max)", and the change of the mean is *beyond the run-to-run spread* when
Welch's two-sample t-test (unequal variances, :func:`scipy.stats.ttest_ind` with
``equal_var=False``) on the two folders' per-run means rejects equal means at the 5 % level
(two-sided). Runs without a value are left out; with fewer than two runs in a folder the test is
not made ("n/a"); with no spread in either folder, different means count as beyond it.

Settings that differ between folders are listed above the tables: ``settings.json`` beside
``results.json`` (or, without it, the results' own estimators and alignment), and ``nees.json``'s
``runs``, ``seed``, ``frames``, ``simulation``, ``filter``, ``smoother`` and ``settings``. Numbers
equal within a relative 1e-3 count as equal; the command line and creation time (shown per
folder instead), the model cache's bookkeeping and the model identification's diagnostics
(``identification``) are not compared.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from vislam.ekf.errors import InputError
from vislam.eval.compare_readings import (
    ABSENT,
    NO_VALUE,
    Change,
    change,
    clip,
    num,
    relative,
    run_summary,
    spread_test,
)
from vislam.eval.compare_settings import settings_diff, union
from vislam.eval.rpe_segments import lengths_text
from vislam.eval.results import (
    NEES_FILE,
    RESULTS_FILE,
    BenchResults,
    DriveResult,
    EstimatorResult,
    NeesResults,
    Results,
    load_results,
)

FAILED = "failed"

POSE_DOF, LANDMARK_DOF = 6, 3

#: Bench figures, in table order: (key, label, sense, dof). ``sense``: "lower" (lower is
#: better), "band" (closer to the chi-square band of ``dof`` is better), "none" (no reading).
#: Keys "vs_smoother.X" are in the row's ``vs_smoother`` table.
BENCH_FIGURES = (
    ("ate_m", "ATE (m)", "lower", None),
    ("ate_aligned_m", "ATE al. (m)", "lower", None),
    ("rpe_trans_pct", "t_rel (%)", "lower", None),
    ("rpe_rot_deg_per_100m", "r_rel (°/100m)", "lower", None),
    ("rpe_drive_trans_pct", "RPE (%)", "lower", None),
    ("rpe_drive_rot_deg_per_m", "RPE (°/m)", "lower", None),
    ("nees_pose_mean", "NEES", "band", POSE_DOF),
    ("map_rmse_m", "map RMSE (m)", "lower", None),
    ("nees_landmark_mean", "lm NEES", "band", LANDMARK_DOF),
    ("vs_smoother.ate_m", "vs sm. ATE (m)", "lower", None),
    ("vs_smoother.ate_aligned_m", "vs sm. ATE al. (m)", "lower", None),
    ("vs_smoother.map_rmse_m", "vs sm. map (m)", "lower", None),
    ("vs_smoother.nees_pose_mean", "vs sm. NEES", "band", POSE_DOF),
    ("vs_smoother.inside_95_fraction", "vs sm. in 95%", "none", None),
    ("runtime_s", "runtime (s)", "lower", None),
)
#: The bench figures drawn in compare.png (those with a value somewhere).
PLOT_FIGURES = ("ate_m", "ate_aligned_m", "rpe_trans_pct", "rpe_rot_deg_per_100m",
                "rpe_drive_trans_pct", "rpe_drive_rot_deg_per_m", "nees_pose_mean", "map_rmse_m",
                "nees_landmark_mean", "runtime_s")

SPREAD_NOTE = ("beyond the spread: Welch's t-test (unequal variances) on the two folders' "
               "per-run mean pose NEES rejects equal means at 5 % (two-sided); "
               "within: it does not; n/a: fewer than two runs")


# --- loading ---------------------------------------------------------------------------------


@dataclass
class Folder:
    """One input folder: its label (A, B, ...), the path as given and what it holds."""

    label: str
    shown: str
    results: Results

    @property
    def path(self) -> Path:
        return self.results.folder

    @property
    def bench(self) -> BenchResults | None:
        return self.results.bench

    @property
    def nees(self) -> NeesResults | None:
        return self.results.nees

    @property
    def kinds(self) -> list[str]:
        return self.results.kinds

    @property
    def files(self) -> list[str]:
        """The names of the results files it holds."""
        return [n for n, held in ((RESULTS_FILE, self.bench), (NEES_FILE, self.nees))
                if held is not None]

    def command(self) -> str | None:
        for held in (self.bench, self.nees):
            if held is not None and held.command is not None:
                return held.command
        return None


def folder_label(i: int) -> str:
    """A, B, ..., Z, AA, AB, ..."""
    s = ""
    i += 1
    while i:
        i, r = divmod(i - 1, 26)
        s = chr(65 + r) + s
    return s


def load_folder(path: str | os.PathLike, label: str = "A") -> Folder:
    """Read one result folder (or a results.json / nees.json file, standing for its folder)."""
    return Folder(label=label, shown=str(path), results=load_results(path))


def load_folders(paths) -> list[Folder]:
    """Read every folder (at least two); the first is the baseline."""
    paths = list(paths)
    if len(paths) < 2:
        raise InputError(f"give at least two result folders to compare, got {len(paths)}")
    return [load_folder(p, folder_label(i)) for i, p in enumerate(paths)]


def input_files(folders: list[Folder]) -> list[Path]:
    """The files read: for the output folder's checks."""
    return [p for f in folders for p in f.results.files]


def check_out_dir(out: str | os.PathLike, folders: list[Folder]) -> None:
    """An output folder that is, or is inside, an input folder is refused."""
    target = Path(os.path.realpath(os.path.abspath(out)))
    for f in folders:
        src = Path(os.path.realpath(f.path))
        if target == src or src in target.parents:
            raise InputError(f"--out {out}: is inside the input folder {f.shown}; choose "
                             "another folder (vislam never writes among its inputs)")



# --- the comparison --------------------------------------------------------------------------


@dataclass
class Row:
    """One figure of one estimator across the folders of a section.

    ``values``: per folder the number (None: no value); ``cells``: per folder the text;
    ``changes``: per folder ``Change`` against the baseline (None for the baseline and where
    either side has no value)."""

    estimator: str
    key: str
    label: str
    values: list
    cells: list[str]
    changes: list[Change | None]
    bands: list | None = None
    runs: list | None = None


@dataclass
class Section:
    """A table: one bench sequence, or the Monte Carlo NEES of the nees folders."""

    kind: str  # "bench" or "nees"
    title: str
    folders: list[Folder]  # the columns (the baseline first)
    estimators: list[str]
    rows: list[Row]
    notes: list[str] = field(default_factory=list)
    #: per estimator, per folder: whether the folder holds the estimator (and its sequence)
    present: dict[str, list[bool]] = field(default_factory=dict)


@dataclass
class Comparison:
    folders: list[Folder]
    settings: dict[str, list[tuple[str, list[str]]]]  # kind -> [(setting, values per folder)]
    settings_folders: dict[str, list[Folder]]
    sections: list[Section]
    notes: list[str]


def _band(dof: int) -> tuple[float, float]:
    from vislam.eval.consistency import chi2_bounds

    return chi2_bounds(1, dof)


def _bench_section(name: str, folders: list[Folder]) -> Section:
    seqs: list[DriveResult | None] = [f.bench.drives.get(name) for f in folders]
    rows_by = [None if s is None else s.estimators for s in seqs]
    estimators = union([list(r) for r in rows_by if r is not None])
    frames = [None if s is None else s.frames for s in seqs]
    present = [s for s in seqs if s is not None]
    gt = "ground truth" if any(s.has_ground_truth for s in present) else "no ground truth"
    if len({fr for s, fr in zip(seqs, frames) if s is not None}) <= 1:
        fr = next((fr for fr in frames if fr is not None), None)
        what = f"{fr} frames, {gt}" if fr is not None else gt
    else:
        what = "; ".join(f"{f.label}: {fr} frames" for f, fr in zip(folders, frames)
                         if fr is not None) + f"; {gt}"
    notes = [f"sequence {name!r} is not in {f.label} ({f.shown})"
             for f, s in zip(folders, seqs) if s is None]
    notes += _rpe_lengths_notes(folders, seqs)
    rows: list[Row] = []
    present = {}
    for est in estimators:
        per: list[EstimatorResult | None] = [None if r is None else r.get(est) for r in rows_by]
        present[est] = [r is not None for r in per]
        est_rows = []
        errors = [None if r is None else r.error for r in per]
        if any(e is not None for e in errors):
            cells = [ABSENT if r is None else (f"{FAILED}: {clip(e)}" if e else "ok")
                     for r, e in zip(per, errors)]
            est_rows.append(Row(est, "error", "error", [None] * len(folders), cells,
                                [None] * len(folders)))
        for key, label, sense, dof in BENCH_FIGURES:
            values = [None if r is None else r.figure(key) for r in per]
            if all(v is None for v in values):
                continue
            band = _band(dof) if sense == "band" else None
            if band:
                label = f"{label} [{band[0]:.2f}, {band[1]:.2f}]"
            cells = [ABSENT if r is None else (FAILED if r.error and v is None else num(v))
                     for r, v in zip(per, values)]
            changes = [None] + [change(sense, values[0], v, band, band) for v in values[1:]]
            est_rows.append(Row(est, key, label, values, cells, changes,
                                bands=[band] * len(folders) if band else None))
        if not est_rows:
            cells = [ABSENT if r is None else NO_VALUE for r in per]
            est_rows.append(Row(est, "none", "(no figures)", [None] * len(folders), cells,
                                [None] * len(folders)))
        missing = [f.label for f, r, s in zip(folders, per, seqs) if r is None and s is not None]
        if missing:
            notes.append(f"{est} is not in {', '.join(missing)}")
        rows += est_rows
    return Section("bench", f"{name} ({what})", folders, estimators, rows, notes, present)


def _rpe_lengths(drive: DriveResult | None) -> tuple[float, ...] | None:
    """The segment lengths of a drive's RPE (None: the folder has none for the drive)."""
    if drive is None:
        return None
    return next((e.rpe_drive.lengths_m for e in drive.estimators.values()
                 if e.rpe_drive is not None and e.rpe_drive.lengths_m), None)


def _rpe_lengths_notes(folders: list[Folder], seqs: list[DriveResult | None]) -> list[str]:
    """A note on the RPE's segment lengths: which ones, and a warning where the folders used
    different ones (their RPE rows then compare different segments)."""
    held = [(f, _rpe_lengths(s)) for f, s in zip(folders, seqs)]
    held = [(f, lengths) for f, lengths in held if lengths is not None]
    if not held:
        return []
    if len({lengths for _, lengths in held}) == 1:
        return [f"RPE over segments of {lengths_text(held[0][1])}"]
    per = "; ".join(f"{f.label}: {lengths_text(lengths)}" for f, lengths in held)
    return [f"RPE over different segment lengths ({per}): the RPE rows compare different "
            "segments (the lengths follow each folder's true path)"]


def _nees_section(folders: list[Folder]) -> Section:
    ests = [f.nees.estimators for f in folders]
    estimators = union([list(e) for e in ests])
    runs = [f.nees.runs for f in folders]
    frames = [f.nees.frames for f in folders]
    if len(set(runs)) == 1 and len(set(frames)) == 1:
        title = f"Monte Carlo NEES ({runs[0]} runs, {frames[0]} frames)"
    else:
        title = "Monte Carlo NEES (" + "; ".join(
            f"{f.label}: {r} runs, {fr} frames" for f, r, fr in zip(folders, runs, frames)) + ")"
    rows: list[Row] = []
    notes = [SPREAD_NOTE + "."]
    n = len(folders)
    present = {}
    for est in estimators:
        per = [e.get(est) for e in ests]
        present[est] = [r is not None for r in per]
        missing = [f.label for f, r in zip(folders, per) if r is None]
        if missing:
            notes.append(f"{est} is not in {', '.join(missing)}")
        for which, dof in (("pose", POSE_DOF), ("landmark", LANDMARK_DOF)):
            values = [None if r is None else getattr(r, f"anees_{which}") for r in per]
            if all(v is None for v in values):
                continue
            bands = []
            for f, r in zip(folders, per):
                b = None if r is None else getattr(r, f"bounds_{which}")
                if b is None and r is not None:
                    from vislam.eval.consistency import chi2_bounds

                    b = chi2_bounds(f.nees.runs, dof)
                bands.append(None if b is None else (float(b[0]), float(b[1])))
            cells = []
            for r, v, b in zip(per, values, bands):
                if r is None:
                    cells.append(ABSENT)
                elif v is None:
                    cells.append(NO_VALUE)
                else:
                    verdict = getattr(r, f"verdict_{which}") or ""
                    cells.append(f"{num(v)} [{num(b[0])}, {num(b[1])}] {verdict}".rstrip())
            changes = [None] + [change("band", values[0], v, bands[0], b)
                                for v, b in zip(values[1:], bands[1:])]
            rows.append(Row(est, f"anees_{which}", f"ANEES {which} [bounds]", values, cells,
                            changes, bands=bands))
        per_run = [None if r is None or r.nees_pose_per_run_mean is None else r.per_run()
                   for r in per]
        if any(p for p in per_run):
            means = [None if not p or all(v is None for v in p)
                     else float(np.mean([v for v in p if v is not None])) for p in per_run]
            cells = [ABSENT if r is None else run_summary(p or []) for r, p in zip(per, per_run)]
            changes: list[Change | None] = [None]
            for p, m in zip(per_run[1:], means[1:]):
                if m is None or means[0] is None:
                    changes.append(None)
                    continue
                pv, beyond = spread_test(per_run[0], p)
                if beyond is None:
                    verdict = "spread n/a (fewer than 2 runs)"
                else:
                    where = "beyond" if beyond else "within"
                    verdict = f"{where} the run-to-run spread (Welch p = {pv:.2g})"
                d = m - means[0]
                changes.append(Change(d, relative(d, means[0]), verdict, pv, beyond))
            rows.append(Row(est, "nees_pose_per_run_mean",
                            "pose NEES per run: mean, median (min, max)", means, cells, changes,
                            runs=[[v for v in (p or []) if v is not None] for p in per_run]))
        values = [None if r is None else r.runtime_s_mean for r in per]
        if any(v is not None for v in values):
            cells = [ABSENT if r is None else num(v) for r, v in zip(per, values)]
            rows.append(Row(est, "runtime_s_mean", "runtime per run (s)", values, cells,
                            [None] + [change("lower", values[0], v) for v in values[1:]]))
        failed = [None if r is None else r.runs_failed for r in per]
        if any(x for x in failed):
            cells = [ABSENT if x is None else str(x) for x in failed]
            rows.append(Row(est, "runs_failed", "runs failed", [float(x) if x is not None
                            else None for x in failed], cells, [None] * n))
    return Section("nees", title, folders, estimators, rows, notes, present)


# --- settings --------------------------------------------------------------------------------



def bench_settings(f: Folder) -> dict:
    """settings.json, or without it the results' own estimators and alignment."""
    if f.bench.settings is not None:
        return f.bench.settings
    return {"estimators": f.bench.estimators, "alignment": f.bench.alignment}


def nees_settings(f: Folder) -> dict:
    n = f.nees
    held = {"runs": n.runs, "seed": n.seed, "frames": n.frames, "simulation": n.simulation,
            "filter": n.filter, "smoother": n.smoother, "settings": n.settings}
    return {k: v for k, v in held.items() if v is not None}


# --- building --------------------------------------------------------------------------------


def build_comparison(folders: list[Folder]) -> Comparison:
    """Every table of the comparison of ``folders`` (the first is the baseline)."""
    base = folders[0]
    notes: list[str] = []
    sections: list[Section] = []
    settings: dict[str, list] = {}
    settings_folders: dict[str, list[Folder]] = {}
    compared = False
    for kind, attr, fname in (("bench", "bench", RESULTS_FILE), ("nees", "nees", NEES_FILE)):
        holders = [f for f in folders if getattr(f, attr) is not None]
        if getattr(base, attr) is None:
            if holders:
                notes.append(f"{fname} of {', '.join(f.label for f in holders)} not compared: "
                             f"the baseline {base.label} holds none")
            continue
        lacking = [f for f in folders if getattr(f, attr) is None]
        if lacking:
            notes.append(f"{', '.join(f.label for f in lacking)} hold{'s' if len(lacking) == 1 else ''} "
                         f"no {fname}: not in the {kind} tables")
        if len(holders) < 2:
            continue
        compared = True
        if kind == "bench":
            names = union([list(f.bench.drives) for f in holders])
            sections += [_bench_section(n, holders) for n in names]
            settings["bench"] = settings_diff([bench_settings(f) for f in holders])
        else:
            sections.append(_nees_section(holders))
            settings["nees"] = settings_diff([nees_settings(f) for f in holders])
        settings_folders[kind] = holders
    if not compared:
        held = "; ".join(f"{f.label} ({f.shown}): {', '.join(f.files)}" for f in folders)
        raise InputError(f"nothing to compare: no other folder holds the same kind of results as "
                         f"the baseline ({held})")
    return Comparison(folders, settings, settings_folders, sections, notes)


def compare_folders(paths) -> Comparison:
    """Load ``paths`` and build their comparison."""
    return build_comparison(load_folders(paths))

