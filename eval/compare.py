"""Compare result folders of ``vislam bench`` (``results.json``) and ``vislam nees``
(``nees.json``) side by side: the library behind ``vislam compare`` (no printing here).

The first folder is the baseline (A); every other folder (B, C, ...) is compared with it. A
folder may hold either kind or both; each kind is compared among the folders that hold it,
provided the baseline holds it too. Sequences, estimators and figures present in only some
folders are kept, with "–" where absent ("n/a" where present without a value, "failed" where the
estimator failed).

Per figure the change ``B − A`` is given absolutely and relative to ``|A|`` (%), with a reading:

* "lower is better" figures (ATE, ATE aligned, t_rel, r_rel, map RMSE, the vs-smoother ATE and
  map RMSE, runtime): better / worse / same ("same" when they differ by at most 0.1 % of the
  larger);
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

import json
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from vislam.ekf.errors import InputError

RESULTS_FILE = "results.json"
NEES_FILE = "nees.json"
SETTINGS_FILE = "settings.json"
#: The files ``vislam compare`` writes into its output folder.
COMPARE_FILES = ("compare.md", "compare.tex", "compare.png")
#: Largest JSON file read (bytes).
MAX_JSON_BYTES = 256 * 1024 * 1024
#: Significance level of the run-to-run spread test.
SPREAD_ALPHA = 0.05
#: Relative change under which a figure reads "same" (neither better nor worse).
SAME_RTOL = 1e-3
#: Relative tolerance under which two numeric settings count as equal.
SETTINGS_RTOL = 1e-3
#: Path components of settings never compared (bookkeeping, not settings).
SETTINGS_IGNORED = frozenset({"created", "command", "cache_entry", "cached", "identification"})

ABSENT = "–"
NO_VALUE = "n/a"
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
                "nees_pose_mean", "map_rmse_m", "nees_landmark_mean", "runtime_s")

SPREAD_NOTE = ("beyond the spread: Welch's t-test (unequal variances) on the two folders' "
               "per-run mean pose NEES rejects equal means at 5 % (two-sided); "
               "within: it does not; n/a: fewer than two runs")


# --- loading ---------------------------------------------------------------------------------


@dataclass
class Folder:
    """One input folder: its label (A, B, ...), the path as given and what it holds."""

    label: str
    shown: str
    path: Path
    bench: dict | None = None
    bench_settings: dict | None = None
    nees: dict | None = None

    @property
    def kinds(self) -> list[str]:
        return [k for k, v in (("bench", self.bench), ("nees", self.nees)) if v is not None]

    def command(self) -> str | None:
        for source in (self.bench_settings, (self.nees or {}).get("settings")):
            if isinstance(source, dict) and isinstance(source.get("command"), str):
                return source["command"]
        return None


def folder_label(i: int) -> str:
    """A, B, ..., Z, AA, AB, ..."""
    s = ""
    i += 1
    while i:
        i, r = divmod(i - 1, 26)
        s = chr(65 + r) + s
    return s


def _read_json(path: Path) -> object:
    try:
        size = path.stat().st_size
        if size > MAX_JSON_BYTES:
            raise InputError(f"{path}: {size} bytes, more than the {MAX_JSON_BYTES} a results "
                             "file may have")
        with open(path, "rb") as fh:
            text = fh.read().decode("utf-8")
        return json.loads(text, parse_constant=lambda c: None)  # NaN / Infinity: no value
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: not valid JSON ({exc.msg} at line {exc.lineno}, "
                         f"column {exc.colno})") from None
    except RecursionError:
        raise InputError(f"{path}: JSON nested too deeply") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror or exc})") from None


def _number(x, where: str) -> float | None:
    """A figure: a finite float, or None for null / non-finite; anything else is an error."""
    if x is None:
        return None
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        raise InputError(f"{where}: expected a number or null, got {_short(x)}")
    x = float(x)
    return x if math.isfinite(x) else None


def _short(x) -> str:
    text = json.dumps(x) if not isinstance(x, str) else repr(x)
    return text if len(text) <= 40 else text[:37] + "..."


def _require(obj, key: str, kind, where: str):
    if not isinstance(obj, dict) or key not in obj:
        raise InputError(f"{where}: missing key {key!r}")
    value = obj[key]
    if not isinstance(value, kind) or isinstance(value, bool) and kind is not bool:
        name = getattr(kind, "__name__", None) or "/".join(k.__name__ for k in kind)
        raise InputError(f"{where}.{key}: expected {name}, got {_short(value)}")
    return value


def _named_objects(items: list, where: str, what: str, within: str = ""):
    """(place, object, name) of each item of ``items`` (placed ``where[i]`` in messages): an
    object with a text ``name`` no other item has (a duplicate is a ``what`` that appears
    twice ``within``)."""
    seen = set()
    for i, item in enumerate(items):
        place = f"{where}[{i}]"
        if not isinstance(item, dict):
            raise InputError(f"{place}: expected an object, got {_short(item)}")
        name = _require(item, "name", str, place)
        if name in seen:
            raise InputError(f"{place}.name: {what} {name!r} appears twice{within}")
        seen.add(name)
        yield place, item, name


def _check_bench(data, path: Path) -> dict:
    from vislam.eval.benchmark import SCHEMA

    if not isinstance(data, dict):
        raise InputError(f"{path}: expected a JSON object, got {type(data).__name__}")
    schema = data.get("schema")
    if schema != SCHEMA:
        raise InputError(f"{path}: key 'schema' is {_short(schema)}; vislam compare reads "
                         f"schema {SCHEMA} (results.json of vislam bench)")
    seqs = _require(data, "sequences", list, str(path))
    for where, s, name in _named_objects(seqs, f"{path}: sequences", "sequence"):
        rows = _require(s, "estimators", list, where)
        for w, r, _ in _named_objects(rows, f"{where}.estimators", "estimator", f" in {name!r}"):
            if r.get("error") is not None and not isinstance(r["error"], str):
                raise InputError(f"{w}.error: expected text or null, got {_short(r['error'])}")
            vs = r.get("vs_smoother")
            if vs is not None and not isinstance(vs, dict):
                raise InputError(f"{w}.vs_smoother: expected an object, got {_short(vs)}")
            for key, *_ in BENCH_FIGURES:
                _number(_cell(r, key), f"{w}.{key}")
        frames = s.get("frames")
        if frames is not None:
            _number(frames, f"{where}.frames")
    return data


def _check_nees(data, path: Path) -> dict:
    if not isinstance(data, dict):
        raise InputError(f"{path}: expected a JSON object, got {type(data).__name__}")
    where = str(path)
    runs = _require(data, "runs", int, where)
    if runs < 1:
        raise InputError(f"{path}: key 'runs' is {runs}, expected at least 1")
    ests = _require(data, "estimators", dict, where)
    for name, r in ests.items():
        w = f"{path}: estimators.{name}"
        if not isinstance(r, dict):
            raise InputError(f"{w}: expected an object, got {_short(r)}")
        for key in ("anees_pose", "anees_landmark", "runtime_s_mean"):
            _number(r.get(key), f"{w}.{key}")
        for key in ("bounds_pose", "bounds_landmark"):
            b = r.get(key)
            if b is None:
                continue
            if (not isinstance(b, list) or len(b) != 2
                    or any(_number(v, f"{w}.{key}") is None for v in b)):
                raise InputError(f"{w}.{key}: expected two numbers, got {_short(b)}")
        per_run = r.get("nees_pose_per_run_mean")
        if per_run is not None:
            if not isinstance(per_run, list):
                raise InputError(f"{w}.nees_pose_per_run_mean: expected a list, got "
                                 f"{_short(per_run)}")
            for k, v in enumerate(per_run):
                _number(v, f"{w}.nees_pose_per_run_mean[{k}]")
        failed = r.get("runs_failed", 0)
        if isinstance(failed, bool) or not isinstance(failed, int):
            raise InputError(f"{w}.runs_failed: expected an integer, got {_short(failed)}")
    return data


def load_folder(path: str | os.PathLike, label: str = "A") -> Folder:
    """Read one result folder (or a results.json / nees.json file, standing for its folder)."""
    shown = str(path)
    p = Path(path)
    if p.is_file() and p.name in (RESULTS_FILE, NEES_FILE):
        p = p.parent
    if not p.exists():
        raise InputError(f"{shown}: no such folder")
    if not p.is_dir():
        raise InputError(f"{shown}: not a folder (give a folder written by vislam bench or "
                         "vislam nees)")
    folder = Folder(label=label, shown=shown, path=p)
    results, nees = p / RESULTS_FILE, p / NEES_FILE
    if not results.is_file() and not nees.is_file():
        raise InputError(f"{shown}: holds neither {RESULTS_FILE} (vislam bench) nor "
                         f"{NEES_FILE} (vislam nees)")
    if results.is_file():
        folder.bench = _check_bench(_read_json(results), results)
        settings = p / SETTINGS_FILE
        if settings.is_file():
            data = _read_json(settings)
            if not isinstance(data, dict):
                raise InputError(f"{settings}: expected a JSON object, got {type(data).__name__}")
            folder.bench_settings = data
    if nees.is_file():
        folder.nees = _check_nees(_read_json(nees), nees)
    return folder


def load_folders(paths) -> list[Folder]:
    """Read every folder (at least two); the first is the baseline."""
    paths = list(paths)
    if len(paths) < 2:
        raise InputError(f"give at least two result folders to compare, got {len(paths)}")
    return [load_folder(p, folder_label(i)) for i, p in enumerate(paths)]


def input_files(folders: list[Folder]) -> list[Path]:
    """The files read: for the output folder's checks."""
    out = []
    for f in folders:
        for name, held in ((RESULTS_FILE, f.bench), (SETTINGS_FILE, f.bench_settings),
                           (NEES_FILE, f.nees)):
            if held is not None:
                out.append(f.path / name)
    return out


def check_out_dir(out: str | os.PathLike, folders: list[Folder]) -> None:
    """An output folder that is, or is inside, an input folder is refused."""
    target = Path(os.path.realpath(os.path.abspath(out)))
    for f in folders:
        src = Path(os.path.realpath(f.path))
        if target == src or src in target.parents:
            raise InputError(f"--out {out}: is inside the input folder {f.shown}; choose "
                             "another folder (vislam never writes among its inputs)")


# --- numbers and readings --------------------------------------------------------------------


def num(x: float | None) -> str:
    """A figure at 4 significant digits (powers of ten as 6.18e-5); None as n/a."""
    if x is None:
        return NO_VALUE
    if x == 0:
        return "0"
    a = abs(x)
    if a >= 1e5 or a < 1e-3:
        mantissa, exponent = f"{x:.3e}".split("e")
        return f"{mantissa}e{int(exponent)}"
    decimals = max(0, 3 - math.floor(math.log10(a)))
    text = f"{x:.{decimals}f}"
    return "0" if float(text) == 0 else text


def signed(x: float) -> str:
    text = num(x)
    return text if text.startswith("-") or text == "0" else "+" + text


def relative(delta: float, base: float | None) -> str | None:
    if base is None or base == 0:
        return None
    r = 100.0 * delta / abs(base)
    if r == 0:
        return "0 %"
    if abs(r) < 10:
        return f"{r:+.2f} %"
    return f"{r:+.1f} %" if abs(r) < 1000 else f"{r:+.0f} %"


def band_distance(x: float, band: tuple[float, float]) -> float:
    """How far ``x`` lies outside ``band`` on a log scale (0 inside)."""
    lo, hi = band
    if x <= 0:
        return math.inf
    if x > hi:
        return math.log(x / hi)
    if x < lo:
        return math.log(lo / x)
    return 0.0


def same(a: float, b: float) -> bool:
    """Equal within :data:`SAME_RTOL` of the larger magnitude."""
    return abs(b - a) <= SAME_RTOL * max(abs(a), abs(b))


def reading(sense: str, a: float, b: float, band_a=None, band_b=None) -> str:
    """The word for ``b`` against the baseline ``a``."""
    if sense == "lower":
        if same(a, b):
            return "same"
        return "better" if b < a else "worse"
    if sense == "band" and band_a is not None and band_b is not None:
        da, db = band_distance(a, band_a), band_distance(b, band_b)
        if da == 0 and db == 0:
            return "same" if same(a, b) else "both inside the band"
        if same(a, b) and same(band_a[0], band_b[0]) and same(band_a[1], band_b[1]):
            return "same"
        if db < da:
            return "better (closer to the band)" if db else "better (inside the band)"
        if db > da:
            return "worse (further from the band)" if da else "worse (outside the band)"
        return "same"
    return "same" if same(a, b) else ""


@dataclass
class Change:
    """``B − A`` for one figure: absolute, relative (text) and the reading."""

    delta: float
    rel: str | None
    verdict: str
    p_value: float | None = None
    beyond: bool | None = None

    def text(self) -> str:
        return signed(self.delta) + (f" ({self.rel})" if self.rel else "")


def change(sense: str, a: float | None, b: float | None, band_a=None, band_b=None) -> Change | None:
    if a is None or b is None:
        return None
    d = b - a
    return Change(d, relative(d, a), reading(sense, a, b, band_a, band_b))


def spread_test(a: list[float], b: list[float], alpha: float = SPREAD_ALPHA):
    """Welch's t-test on two sets of per-run means: (p value, beyond the spread), or
    (None, None) with fewer than two values on a side."""
    from scipy import stats

    x = np.asarray([v for v in a if v is not None], dtype=float)
    y = np.asarray([v for v in b if v is not None], dtype=float)
    if x.size < 2 or y.size < 2:
        return None, None
    if np.var(x) == 0 and np.var(y) == 0:  # no spread: any difference is beyond it
        same = float(np.mean(x)) == float(np.mean(y))
        return (1.0, False) if same else (0.0, True)
    p = float(stats.ttest_ind(x, y, equal_var=False).pvalue)
    return p, bool(p < alpha)


def run_summary(values: list[float | None]) -> str:
    """'mean, median (min, max)' of the per-run values that have one."""
    v = np.asarray([x for x in values if x is not None], dtype=float)
    if v.size == 0:
        return NO_VALUE
    return (f"{num(float(v.mean()))}, {num(float(np.median(v)))} "
            f"({num(float(v.min()))}, {num(float(v.max()))})")


def _cell(row: dict, key: str):
    if key.startswith("vs_smoother."):
        return (row.get("vs_smoother") or {}).get(key.split(".", 1)[1])
    return row.get(key)


def _band(dof: int) -> tuple[float, float]:
    from vislam.eval.consistency import chi2_bounds

    return chi2_bounds(1, dof)


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


def _union(lists) -> list[str]:
    out: list[str] = []
    for names in lists:
        for n in names:
            if n not in out:
                out.append(n)
    return out


def _bench_section(name: str, folders: list[Folder]) -> Section:
    seqs = []
    for f in folders:
        found = next((s for s in f.bench["sequences"] if s["name"] == name), None)
        seqs.append(found)
    rows_by = [{r["name"]: r for r in s["estimators"]} if s else None for s in seqs]
    estimators = _union([list(r) for r in rows_by if r is not None])
    frames = [None if s is None else s.get("frames") for s in seqs]
    present = [s for s in seqs if s is not None]
    gt = "ground truth" if any(s.get("has_ground_truth") for s in present) else "no ground truth"
    if len({fr for s, fr in zip(seqs, frames) if s is not None}) <= 1:
        fr = next((fr for fr in frames if fr is not None), None)
        what = f"{fr} frames, {gt}" if fr is not None else gt
    else:
        what = "; ".join(f"{f.label}: {fr} frames" for f, fr in zip(folders, frames)
                         if fr is not None) + f"; {gt}"
    notes = [f"sequence {name!r} is not in {f.label} ({f.shown})"
             for f, s in zip(folders, seqs) if s is None]
    rows: list[Row] = []
    present = {}
    for est in estimators:
        per = [None if r is None else r.get(est) for r in rows_by]
        present[est] = [r is not None for r in per]
        est_rows = []
        errors = [None if r is None else r.get("error") for r in per]
        if any(e is not None for e in errors):
            cells = [ABSENT if r is None else (f"{FAILED}: {_clip(e)}" if e else "ok")
                     for r, e in zip(per, errors)]
            est_rows.append(Row(est, "error", "error", [None] * len(folders), cells,
                                [None] * len(folders)))
        for key, label, sense, dof in BENCH_FIGURES:
            values = [None if r is None else _number(_cell(r, key), key) for r in per]
            if all(v is None for v in values):
                continue
            band = _band(dof) if sense == "band" else None
            if band:
                label = f"{label} [{band[0]:.2f}, {band[1]:.2f}]"
            cells = [ABSENT if r is None else (FAILED if r.get("error") and v is None else num(v))
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


def _clip(text: str, n: int = 60) -> str:
    text = " ".join(str(text).split())
    return text if len(text) <= n else text[: n - 3] + "..."


def _nees_section(folders: list[Folder]) -> Section:
    ests = [f.nees["estimators"] for f in folders]
    estimators = _union([list(e) for e in ests])
    runs = [f.nees.get("runs") for f in folders]
    frames = [f.nees.get("frames") for f in folders]
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
            values = [None if r is None else _number(r.get(f"anees_{which}"), "anees")
                      for r in per]
            if all(v is None for v in values):
                continue
            bands = []
            for f, r in zip(folders, per):
                b = None if r is None else r.get(f"bounds_{which}")
                if b is None and r is not None:
                    from vislam.eval.consistency import chi2_bounds

                    b = chi2_bounds(int(f.nees["runs"]), dof)
                bands.append(None if b is None else (float(b[0]), float(b[1])))
            cells = []
            for r, v, b in zip(per, values, bands):
                if r is None:
                    cells.append(ABSENT)
                elif v is None:
                    cells.append(NO_VALUE)
                else:
                    verdict = r.get(f"verdict_{which}") or ""
                    cells.append(f"{num(v)} [{num(b[0])}, {num(b[1])}] {verdict}".rstrip())
            changes = [None] + [change("band", values[0], v, bands[0], b)
                                for v, b in zip(values[1:], bands[1:])]
            rows.append(Row(est, f"anees_{which}", f"ANEES {which} [bounds]", values, cells,
                            changes, bands=bands))
        per_run = [None if r is None else r.get("nees_pose_per_run_mean") for r in per]
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
        values = [None if r is None else _number(r.get("runtime_s_mean"), "runtime")
                  for r in per]
        if any(v is not None for v in values):
            cells = [ABSENT if r is None else num(v) for r, v in zip(per, values)]
            rows.append(Row(est, "runtime_s_mean", "runtime per run (s)", values, cells,
                            [None] + [change("lower", values[0], v) for v in values[1:]]))
        failed = [None if r is None else int(r.get("runs_failed") or 0) for r in per]
        if any(x for x in failed):
            cells = [ABSENT if x is None else str(x) for x in failed]
            rows.append(Row(est, "runs_failed", "runs failed", [float(x) if x is not None
                            else None for x in failed], cells, [None] * n))
    return Section("nees", title, folders, estimators, rows, notes, present)


# --- settings --------------------------------------------------------------------------------


def _flatten(obj, prefix: str = "") -> dict[str, object]:
    """{dotted key: leaf}; lists of named objects keyed by name, lists of numbers kept whole."""
    out: dict[str, object] = {}
    if isinstance(obj, dict):
        for k, v in obj.items():
            if str(k) in SETTINGS_IGNORED:
                continue
            out.update(_flatten(v, f"{prefix}.{k}" if prefix else str(k)))
    elif isinstance(obj, list) and obj and all(isinstance(x, dict) for x in obj):
        named = all(isinstance(x.get("name"), str) for x in obj)
        for i, x in enumerate(obj):
            out.update(_flatten(x, f"{prefix}[{x['name'] if named else i}]"))
    else:
        out[prefix] = obj
    return out


def _same_setting(a, b) -> bool:
    if isinstance(a, bool) or isinstance(b, bool):
        return a == b
    if isinstance(a, (int, float)) and isinstance(b, (int, float)):
        return math.isclose(a, b, rel_tol=SETTINGS_RTOL, abs_tol=1e-12)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same_setting(x, y) for x, y in zip(a, b))
    return a == b


def _show_setting(x) -> str:
    if x is _MISSING:
        return ABSENT
    if isinstance(x, bool) or x is None:
        return json.dumps(x)
    if isinstance(x, (int, float)):
        return num(float(x)) if isinstance(x, float) else str(x)
    if isinstance(x, list):
        return "[" + ", ".join(_show_setting(v) for v in x) + "]"
    return _clip(str(x), 80)


_MISSING = object()


def bench_settings(f: Folder) -> dict:
    if f.bench_settings is not None:
        return f.bench_settings
    return {k: f.bench.get(k) for k in ("estimators", "alignment") if k in f.bench}


def nees_settings(f: Folder) -> dict:
    return {k: f.nees[k] for k in ("runs", "seed", "frames", "simulation", "filter", "smoother",
                                   "settings") if k in f.nees}


def settings_diff(settings: list[dict]) -> list[tuple[str, list[str]]]:
    """The settings whose value differs from the baseline's in some folder:
    [(dotted key, shown value per folder)]."""
    flat = [_flatten(s) for s in settings]
    keys = _union([list(f) for f in flat])
    out = []
    for k in keys:
        vals = [f.get(k, _MISSING) for f in flat]
        base = vals[0]
        if all(v is not _MISSING and base is not _MISSING and _same_setting(base, v)
               for v in vals[1:]):
            continue
        out.append((k, [_show_setting(v) for v in vals]))
    return out


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
            names = _union([[s["name"] for s in f.bench["sequences"]] for f in holders])
            sections += [_bench_section(n, holders) for n in names]
            settings["bench"] = settings_diff([bench_settings(f) for f in holders])
        else:
            sections.append(_nees_section(holders))
            settings["nees"] = settings_diff([nees_settings(f) for f in holders])
        settings_folders[kind] = holders
    if not compared:
        held = "; ".join(f"{f.label} ({f.shown}): {', '.join(_files_of(f))}" for f in folders)
        raise InputError(f"nothing to compare: no other folder holds the same kind of results as "
                         f"the baseline ({held})")
    return Comparison(folders, settings, settings_folders, sections, notes)


def _files_of(f: Folder) -> list[str]:
    return [n for n, held in ((RESULTS_FILE, f.bench), (NEES_FILE, f.nees)) if held is not None]


def compare_folders(paths) -> Comparison:
    """Load ``paths`` and build their comparison."""
    return build_comparison(load_folders(paths))


# --- rendering -------------------------------------------------------------------------------

BENCH_NOTE = ("Changes are B − A against the baseline A (relative to |A|). Lower is better for "
              "ATE, t_rel, r_rel, map RMSE, the vs-smoother ATE and map, and runtime; for NEES "
              "the value closer to its two-sided 95 % chi-square band (shown beside it) is "
              "better. \"same\": within 0.1 %. "
              f"{ABSENT}: not in that folder; {NO_VALUE}: no value.")


def _header(section: Section) -> list[str]:
    cols = ["estimator", "figure", f"{section.folders[0].label} (baseline)"]
    for f in section.folders[1:]:
        b = section.folders[0].label
        cols += [f.label, f"{f.label} − {b}", f"{f.label} vs {b}"]
    return cols


def _body(section: Section) -> list[list[str]]:
    out = []
    for row in section.rows:
        cells = [row.estimator, row.label, row.cells[0]]
        for cell, ch in zip(row.cells[1:], row.changes[1:]):
            cells += [cell, ch.text() if ch else ABSENT if ABSENT in (cell, row.cells[0]) else "",
                      ch.verdict if ch else ""]
        out.append(cells)
    return out


def _md_table(header: list[str], body: list[list[str]]) -> list[str]:
    def esc(s: str) -> str:
        return str(s).replace("|", "\\|").replace("\r", "\\r").replace("\n", "\\n")

    lines = ["| " + " | ".join(esc(h) for h in header) + " |",
             "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(esc(c) for c in row) + " |" for row in body]
    return lines


def to_markdown(comp: Comparison) -> str:
    """The comparison as Markdown: folders, settings that differ, one table per section."""
    lines = ["# vislam compare", ""]
    rows = []
    for f in comp.folders:
        label = f.label + (" (baseline)" if f is comp.folders[0] else "")
        rows.append([label, f.shown, ", ".join(_files_of(f)), f.command() or ""])
    lines += _md_table(["folder", "path", "holds", "command"], rows) + [""]
    for kind, diff in comp.settings.items():
        folders = comp.settings_folders[kind]
        what = "vislam bench: settings.json" if kind == "bench" else "vislam nees: nees.json"
        lines.append(f"## Settings that differ ({what})")
        lines.append("")
        if diff:
            lines += _md_table(["setting"] + [f.label for f in folders],
                               [[k] + v for k, v in diff]) + [""]
        else:
            lines += [("None (numbers equal within a relative 1e-3; command line, time and the "
                       "model identification's diagnostics not compared)."), ""]
    for note in comp.notes:
        lines.append(f"Note: {note}.")
    if comp.notes:
        lines.append("")
    for s in comp.sections:
        lines.append(f"## {'Benchmark: ' if s.kind == 'bench' else ''}{s.title}")
        lines.append("")
        lines += _md_table(_header(s), _body(s)) + [""]
        notes = list(s.notes)
        if s.kind == "bench":
            notes.append(BENCH_NOTE)
        else:
            notes.append("ANEES: value [two-sided 95 % bounds] verdict; the change of the "
                         "per-run row is that of the mean.")
        lines += [f"- {n}" for n in notes] + [""]
    return "\n".join(lines).rstrip() + "\n"


_LATEX = {
    "\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#", "_": r"\_",
    "{": r"\{", "}": r"\}", "~": r"\textasciitilde{}", "^": r"\textasciicircum{}",
    "–": "--", "−": "$-$", "°": r"\textdegree{}", "±": r"$\pm$", "<": r"\textless{}",
    ">": r"\textgreater{}", "|": r"\textbar{}", "\n": " ", "\r": " ", "χ": r"$\chi$",
    "²": r"\textsuperscript{2}",
}


def latex_escape(text: str) -> str:
    """Text safe in a LaTeX table cell (special characters and the few non-ASCII ones here)."""
    out = []
    for ch in str(text):
        if ch in _LATEX:
            out.append(_LATEX[ch])
        elif ord(ch) < 128:
            out.append(ch)
        else:
            out.append("?")
    # a leading minus of a number as a math minus (not a hyphen): "-0.5" -> "$-$0.5"
    return re.sub(r"(?<![\w.])-(?=\d)", "$-$", "".join(out))


def to_latex(comp: Comparison) -> str:
    """The comparison as LaTeX: one booktabs longtable per section (needs ``\\usepackage{
    booktabs,longtable,textcomp}``), the differing settings first."""
    e = latex_escape
    lines = ["% vislam compare: needs \\usepackage{booktabs,longtable,textcomp}",
             "% folders: " + "; ".join(f"{f.label} = {e(f.shown)}" for f in comp.folders), ""]

    def table(header, body, caption, footnotes=()):
        spec = "l" * 2 + "r" * (len(header) - 2) if header[0] == "estimator" else \
            "l" * len(header)
        out = [f"\\begin{{longtable}}{{{spec}}}",
               f"\\caption{{{e(caption)}}}\\\\",
               "\\toprule",
               " & ".join(e(h) for h in header) + " \\\\",
               "\\midrule", "\\endfirsthead",
               "\\toprule", " & ".join(e(h) for h in header) + " \\\\", "\\midrule",
               "\\endhead", "\\bottomrule", "\\endlastfoot"]
        last = None
        for row in body:
            if header[0] == "estimator" and last is not None and row[0] != last:
                out.append("\\midrule")
            last = row[0]
            out.append(" & ".join(e(c) for c in row) + " \\\\")
        out.append("\\end{longtable}")
        out += [f"\\noindent\\footnotesize {e(n)}\\par\\normalsize" for n in footnotes]
        return out + [""]

    for kind, diff in comp.settings.items():
        folders = comp.settings_folders[kind]
        if diff:
            lines += table(["setting"] + [f.label for f in folders], [[k] + v for k, v in diff],
                           f"Settings that differ ({'vislam bench' if kind == 'bench' else 'vislam nees'})")
    for s in comp.sections:
        notes = list(s.notes)
        notes.append(BENCH_NOTE if s.kind == "bench" else
                     "ANEES: value [two-sided 95 % bounds] verdict; the change of the per-run "
                     "row is that of the mean.")
        caption = ("Benchmark: " if s.kind == "bench" else "") + s.title + "; " + ", ".join(
            f"{f.label} = {f.shown}" for f in s.folders)
        lines += table(_header(s), _body(s), caption, notes)
    return "\n".join(lines).rstrip() + "\n"
