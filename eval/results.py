"""A results folder as typed objects: :func:`load_results` reads what ``vislam bench``
(``results.json``, ``settings.json``, ``<drive>/<estimator>.estimate.npz`` and ``.tum``) and
``vislam nees`` (``nees.json``) wrote, checks it, and returns :class:`Results` (evo's
``file_interface.load_res_file``)::

    import vislam

    res = vislam.load_results("results/latest")
    for drive in res.bench.drives.values():
        for est in drive.estimators.values():
            print(drive.name, est.name, est.ate_aligned_m, est.nees_pose_mean)
            if est.rpe_drive is not None:  # the drive-fitted RPE: mean % over its segments
                print(est.rpe_drive_trans_pct, est.rpe_drive.lengths_text, est.rpe_drive.note)
    joint = res.bench.drives["sim-seed0"].estimators["ekf-joint"].load_estimate()

A folder may hold either kind or both (``Results.bench``, ``Results.nees``; None where absent).
Figures are floats, None where the folder has no value (null, NaN or infinity in the file).
Every fault (no such folder, neither file, a file that is not JSON or not UTF-8, an unknown
schema, a key missing or of the wrong type) is an :class:`~ekf.errors.InputError` naming the
file and the key. Nothing here writes.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from vislam.ekf.errors import InputError
from vislam.eval.drive_data import DriveData, read_drive_data
from vislam.eval.inertial_truth import GyroAgreement
# DriveRpe, ErrorStats and SegmentLengthRpe are the types of EstimatorResult.rpe_drive, read here
from vislam.eval.results_rpe import DriveRpe, ErrorStats, SegmentLengthRpe, drive_rpe_of  # noqa: F401
from vislam.eval.json_reading import (
    count,
    named_objects,
    number,
    read_json,
    require,
    short,
    text_or_none,
)

RESULTS_FILE = "results.json"
NEES_FILE = "nees.json"
SETTINGS_FILE = "settings.json"
#: The results.json schema written today (eval.bench_scores.SCHEMA) ...
BENCH_SCHEMA = 2
#: ... and every schema read: 1 lacks the drive-fitted RPE (its figures read as None).
BENCH_SCHEMAS = (1, 2)
#: The figures of one estimator on one drive of a bench folder (results.json's keys).
BENCH_FIGURE_KEYS = ("runtime_s", "frames_per_s", "ate_m", "ate_aligned_m", "rpe_trans_pct",
                     "rpe_rot_deg_per_100m", "rpe_drive_trans_pct", "rpe_drive_rot_deg_per_m",
                     "nees_pose_mean", "map_rmse_m", "nees_landmark_mean")
#: The figures against the reference smoother (results.json's ``vs_smoother``).
VS_SMOOTHER_KEYS = ("ate_m", "ate_aligned_m", "map_rmse_m", "nees_pose_mean",
                    "inside_95_fraction")


# --- the objects -----------------------------------------------------------------------------


def _setting(settings: dict | None, key: str, kind: type):
    """``settings[key]`` where it is a ``kind``, else None."""
    value = (settings or {}).get(key)
    return value if isinstance(value, kind) else None


@dataclass(frozen=True)
class VersusSmoother:
    """An estimator against the drive's reference smoother (None: no value, or no smoother)."""

    ate_m: float | None = None
    ate_aligned_m: float | None = None
    map_rmse_m: float | None = None
    nees_pose_mean: float | None = None
    inside_95_fraction: float | None = None


@dataclass(frozen=True)
class EstimatorResult:
    """One estimator on one drive of a bench folder: its figures (None: no value), the error
    that stopped it (None: it ran), and the files it left (None: not in the folder)."""

    name: str
    error: str | None
    runtime_s: float | None
    frames_per_s: float | None
    landmarks: int | None
    ate_m: float | None
    ate_aligned_m: float | None
    rpe_trans_pct: float | None
    rpe_rot_deg_per_100m: float | None
    nees_pose_mean: float | None
    map_rmse_m: float | None
    nees_landmark_mean: float | None
    vs_smoother: VersusSmoother
    #: the drive-fitted RPE (mean over its segments; None: no value, or a schema 1 folder)
    rpe_drive_trans_pct: float | None = None
    rpe_drive_rot_deg_per_m: float | None = None
    #: its detail: the lengths used, per length the statistics, or why there is none (None:
    #: no ground truth, the estimator failed, or a schema 1 folder)
    rpe_drive: DriveRpe | None = None
    #: the whole estimate (``ekf.estimate.Estimate.save_npz``)
    estimate_path: Path | None = None
    #: the trajectory in TUM format
    trajectory_path: Path | None = None

    @property
    def ok(self) -> bool:
        return self.error is None

    def figure(self, key: str) -> float | None:
        """A figure by its results.json key; ``"vs_smoother.KEY"`` for those against the
        smoother."""
        if key.startswith("vs_smoother."):
            return getattr(self.vs_smoother, key.split(".", 1)[1])
        return getattr(self, key)

    def load_estimate(self):
        """The saved estimate (:class:`ekf.estimate.Estimate`); InputError where the folder has
        none (the estimator failed, or its estimate could not be saved)."""
        if self.estimate_path is None:
            raise InputError(f"{self.name}: no saved estimate in the results folder")
        from vislam.ekf.estimate import Estimate

        return Estimate.load_npz(self.estimate_path)


@dataclass(frozen=True)
class DriveResult:
    """One drive of a bench folder: what it was, the model it ran under, and per estimator its
    result (in the order the benchmark ran them)."""

    name: str
    folder: Path
    path: str | None
    frames: int | None
    has_ground_truth: bool
    has_landmark_truth: bool
    model: dict | None
    reference_smoother: str | None
    estimators: dict[str, EstimatorResult]
    #: how the drive was made (settings.json's entry: ``simulation`` settings, ``path``,
    #: ``filter`` under its model); empty without settings.json
    settings: dict = field(default_factory=dict)
    #: a raw-IMU drive's ground truth against its gyro (results.json's ``truth_check``:
    #: :class:`eval.inertial_truth.GyroAgreement`); None where bench made none
    truth_check: GyroAgreement | None = None

    @property
    def simulation(self) -> dict | None:
        """The simulator's settings (``SimConfig`` fields) of a simulated drive, else None."""
        sim = self.settings.get("simulation")
        return sim if isinstance(sim, dict) else None

    def filter_settings(self, folder_filter: dict | None = None) -> dict | None:
        """The filter settings the drive ran under (its model's), else ``folder_filter``."""
        own = self.settings.get("filter")
        return own if isinstance(own, dict) else folder_filter

    def load_drive(self) -> DriveData:
        """The drive made again: simulated with its settings, or read from its data file
        (with the ground truth and true landmarks found beside it), as the benchmark read it
        before applying its model."""
        sim = self.simulation
        if sim is not None:
            from vislam.eval.simulate import SimConfig, simulate

            try:
                made = simulate(SimConfig(**sim))
            except TypeError as exc:
                raise InputError(f"{self.folder.parent / SETTINGS_FILE}: simulation of "
                                 f"{self.name!r}: {exc}") from None
            frames = np.arange(made.sequence.n_frames)
            return DriveData(made.sequence, frames, made.poses, made.landmarks)
        path = self.path or self.settings.get("path")
        if not isinstance(path, str) or not path:
            raise InputError(f"{self.folder.parent}: neither {RESULTS_FILE} nor {SETTINGS_FILE} "
                             f"names a simulation or a data file for drive {self.name!r}")
        return read_drive_data(Path(path))


@dataclass(frozen=True)
class BenchResults:
    """A ``vislam bench`` folder: per drive, per estimator the figures (``drives``), the
    alignment of the aligned ATE, the settings (``settings.json``, None without it)."""

    folder: Path
    schema: int
    alignment: str | None
    alignment_definition: str | None
    rpe_definition: str | None
    estimators: list[str]
    drives: dict[str, DriveResult]
    wall_s: float | None
    settings: dict | None
    #: what the drive-fitted RPE means (None in a schema 1 folder)
    rpe_drive_definition: str | None = None

    @property
    def filter(self) -> dict | None:
        """The filter settings of the run (settings.json's ``filter``)."""
        return _setting(self.settings, "filter", dict)

    @property
    def command(self) -> str | None:
        """The command line that made the folder."""
        return _setting(self.settings, "command", str)


@dataclass(frozen=True)
class NeesEstimatorResult:
    """One estimator of a ``vislam nees`` folder: the ANEES of poses (6 dof) and landmarks
    (3 dof) with their two-sided 95 % bounds and verdicts, and the per-run and per-step
    arrays (NaN: no value)."""

    name: str
    anees_pose: float | None
    anees_landmark: float | None
    bounds_pose: tuple[float, float] | None
    bounds_landmark: tuple[float, float] | None
    verdict_pose: str | None
    verdict_landmark: str | None
    inside_fraction_pose: float | None
    inside_fraction_landmark: float | None
    landmarks_scored: int | None
    runs_failed: int
    errors: list[str]
    runtime_s_mean: float | None
    #: (runs,) each run's mean pose NEES over steps 1..T-1 (NaN: the run has none)
    nees_pose_per_run_mean: np.ndarray | None
    #: (T,) the pose NEES averaged over runs, per step (NaN at step 0)
    nees_pose_over_time: np.ndarray | None

    def per_run(self) -> list[float]:
        """The per-run mean pose NEES of the runs that have one."""
        if self.nees_pose_per_run_mean is None:
            return []
        v = self.nees_pose_per_run_mean
        return [float(x) for x in v[np.isfinite(v)]]


@dataclass(frozen=True)
class NeesResults:
    """A ``vislam nees`` folder: ``runs`` Monte Carlo runs of ``frames`` steps of the
    simulated drive (``simulation``: its SimConfig fields), per estimator the ANEES."""

    folder: Path
    runs: int
    seed: int | None
    frames: int | None
    simulation: dict | None
    filter: dict | None
    smoother: dict | None
    settings: dict | None
    estimators: dict[str, NeesEstimatorResult]
    #: (T,) seconds since the first step
    timestamps: np.ndarray | None = None

    @property
    def command(self) -> str | None:
        """The command line that made the folder."""
        return _setting(self.settings, "command", str)


@dataclass(frozen=True)
class Results:
    """A results folder: its bench results, its Monte Carlo results, or both."""

    folder: Path
    bench: BenchResults | None = None
    nees: NeesResults | None = None

    @property
    def kinds(self) -> list[str]:
        return [k for k, v in (("bench", self.bench), ("nees", self.nees)) if v is not None]

    @property
    def files(self) -> list[Path]:
        """The files read."""
        out = []
        if self.bench is not None:
            out.append(self.folder / RESULTS_FILE)
            if self.bench.settings is not None:
                out.append(self.folder / SETTINGS_FILE)
        if self.nees is not None:
            out.append(self.folder / NEES_FILE)
        return out


# --- reading ---------------------------------------------------------------------------------


def load_results(folder: str | os.PathLike) -> Results:
    """Read a results folder of ``vislam bench`` and/or ``vislam nees`` (or its
    ``results.json`` / ``nees.json``, standing for its folder)."""
    shown = str(folder)
    p = Path(folder)
    if p.is_file() and p.name in (RESULTS_FILE, NEES_FILE):
        p = p.parent
    if not p.exists():
        raise InputError(f"{shown}: no such folder")
    if not p.is_dir():
        raise InputError(f"{shown}: not a folder (give a folder written by vislam bench or "
                         "vislam nees)")
    results, nees = p / RESULTS_FILE, p / NEES_FILE
    if not results.is_file() and not nees.is_file():
        raise InputError(f"{shown}: holds neither {RESULTS_FILE} (vislam bench) nor "
                         f"{NEES_FILE} (vislam nees)")
    bench = nees_results = None
    if results.is_file():
        data = read_json(results)
        bench_results(data, results)  # results.json's faults first, then settings.json's
        settings = None
        settings_file = p / SETTINGS_FILE
        if settings_file.is_file():
            settings = read_json(settings_file)
            if not isinstance(settings, dict):
                raise InputError(f"{settings_file}: expected a JSON object, got "
                                 f"{type(settings).__name__}")
        bench = bench_results(data, results, settings)
    if nees.is_file():
        nees_results = nees_results_of(read_json(nees), nees)
    return Results(p, bench, nees_results)


def _estimator(r: dict, w: str, folder: Path) -> EstimatorResult:
    from vislam.eval.registry import file_stem

    vs = r.get("vs_smoother")
    if vs is not None and not isinstance(vs, dict):
        raise InputError(f"{w}.vs_smoother: expected an object, got {short(vs)}")
    vs = vs or {}
    versus = VersusSmoother(**{k: number(vs.get(k), f"{w}.vs_smoother.{k}")
                               for k in VS_SMOOTHER_KEYS})
    figures = {k: number(r.get(k), f"{w}.{k}") for k in BENCH_FIGURE_KEYS}
    figures["rpe_drive"] = drive_rpe_of(r.get("rpe_drive"), f"{w}.rpe_drive")
    stem = file_stem(r["name"])
    estimate = next((f for f in (folder / f"{stem}.estimate.npz", folder / f"{stem}.npz")
                     if f.is_file()), None)
    trajectory = folder / f"{stem}.tum"
    return EstimatorResult(
        name=r["name"], error=text_or_none(r.get("error"), f"{w}.error"),
        landmarks=count(r.get("landmarks"), f"{w}.landmarks"), vs_smoother=versus,
        estimate_path=estimate, trajectory_path=trajectory if trajectory.is_file() else None,
        **figures)


def _truth_check(value, where: str) -> GyroAgreement | None:
    """results.json's ``truth_check`` of one drive (None: none made)."""
    if value is None:
        return None
    if not isinstance(value, dict):
        raise InputError(f"{where}: expected an object or null, got {short(value)}")
    try:
        check = GyroAgreement.from_dict(value)
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"{where}: not a truth check as vislam bench writes it ({exc!r})") from None
    if len(check.rms_mrad) != 3 or not np.all(np.isfinite((*check.rms_mrad, check.sheet_mrad))):
        raise InputError(f"{where}: rms_mrad must be three finite numbers and sheet_mrad finite")
    return check


def bench_results(data, path: Path, settings: dict | None = None) -> BenchResults:
    """The :class:`BenchResults` of results.json's content ``data`` (read from ``path``)."""
    if not isinstance(data, dict):
        raise InputError(f"{path}: expected a JSON object, got {type(data).__name__}")
    schema = data.get("schema")
    if isinstance(schema, bool) or schema not in BENCH_SCHEMAS:
        raise InputError(f"{path}: key 'schema' is {short(schema)}; vislam reads schema "
                         f"{' or '.join(map(str, BENCH_SCHEMAS))} (results.json of vislam bench)")
    seqs = require(data, "sequences", list, str(path))
    entries = {}
    if settings is not None and isinstance(settings.get("sequences"), list):
        entries = {e.get("name"): e for e in settings["sequences"] if isinstance(e, dict)}
    drives = {}
    for where, s, name in named_objects(seqs, f"{path}: sequences", "sequence"):
        rows = require(s, "estimators", list, where)
        ests = {}
        for w, r, est in named_objects(rows, f"{where}.estimators", "estimator",
                                        f" in {name!r}"):
            ests[est] = _estimator(r, w, path.parent / name)
        frames = number(s.get("frames"), f"{where}.frames")
        model = s.get("model")
        drives[name] = DriveResult(
            name=name, folder=path.parent / name, path=text_or_none(s.get("path"), f"{where}.path"),
            frames=None if frames is None else int(frames),
            has_ground_truth=bool(s.get("has_ground_truth")),
            has_landmark_truth=bool(s.get("has_landmark_truth")),
            model=model if isinstance(model, dict) else None,
            reference_smoother=text_or_none(s.get("reference_smoother"),
                                     f"{where}.reference_smoother"),
            estimators=ests, settings=entries.get(name, {}),
            truth_check=_truth_check(s.get("truth_check"), f"{where}.truth_check"))
    names = data.get("estimators")
    names = [n for n in names if isinstance(n, str)] if isinstance(names, list) else []
    return BenchResults(
        folder=path.parent, schema=schema, alignment=text_or_none(data.get("alignment"), f"{path}: alignment"),
        alignment_definition=text_or_none(data.get("alignment_definition"),
                                   f"{path}: alignment_definition"),
        rpe_definition=text_or_none(data.get("rpe_definition"), f"{path}: rpe_definition"),
        rpe_drive_definition=text_or_none(data.get("rpe_drive_definition"),
                                          f"{path}: rpe_drive_definition"),
        estimators=names, drives=drives, wall_s=number(data.get("wall_s"), f"{path}: wall_s"),
        settings=settings)


def _bounds(b, where: str) -> tuple[float, float] | None:
    if b is None:
        return None
    if not isinstance(b, list) or len(b) != 2 or any(number(v, where) is None for v in b):
        raise InputError(f"{where}: expected two numbers, got {short(b)}")
    return float(b[0]), float(b[1])


def _series(values, where: str) -> np.ndarray | None:
    if values is None:
        return None
    if not isinstance(values, list):
        raise InputError(f"{where}: expected a list, got {short(values)}")
    out = [number(v, f"{where}[{k}]") for k, v in enumerate(values)]
    return np.array([np.nan if v is None else v for v in out], dtype=float)


def _nees_estimator(name: str, r, w: str) -> NeesEstimatorResult:
    if not isinstance(r, dict):
        raise InputError(f"{w}: expected an object, got {short(r)}")
    failed = r.get("runs_failed", 0)
    if isinstance(failed, bool) or not isinstance(failed, int):
        raise InputError(f"{w}.runs_failed: expected an integer, got {short(failed)}")
    errors = r.get("errors") or []
    return NeesEstimatorResult(
        name=name,
        anees_pose=number(r.get("anees_pose"), f"{w}.anees_pose"),
        anees_landmark=number(r.get("anees_landmark"), f"{w}.anees_landmark"),
        bounds_pose=_bounds(r.get("bounds_pose"), f"{w}.bounds_pose"),
        bounds_landmark=_bounds(r.get("bounds_landmark"), f"{w}.bounds_landmark"),
        verdict_pose=text_or_none(r.get("verdict_pose"), f"{w}.verdict_pose"),
        verdict_landmark=text_or_none(r.get("verdict_landmark"), f"{w}.verdict_landmark"),
        inside_fraction_pose=number(r.get("inside_fraction_pose"), f"{w}.inside_fraction_pose"),
        inside_fraction_landmark=number(r.get("inside_fraction_landmark"),
                                        f"{w}.inside_fraction_landmark"),
        landmarks_scored=count(r.get("landmarks_scored"), f"{w}.landmarks_scored"),
        runs_failed=failed,
        errors=[str(e) for e in errors] if isinstance(errors, list) else [str(errors)],
        runtime_s_mean=number(r.get("runtime_s_mean"), f"{w}.runtime_s_mean"),
        nees_pose_per_run_mean=_series(r.get("nees_pose_per_run_mean"),
                                       f"{w}.nees_pose_per_run_mean"),
        nees_pose_over_time=_series(r.get("nees_pose_over_time"), f"{w}.nees_pose_over_time"))


def _object_or_none(data: dict, key: str, path: Path) -> dict | None:
    value = data.get(key)
    if value is not None and not isinstance(value, dict):
        raise InputError(f"{path}: key {key!r}: expected an object, got {short(value)}")
    return value


def nees_results_of(data, path: Path) -> NeesResults:
    """The :class:`NeesResults` of nees.json's content ``data`` (read from ``path``)."""
    if not isinstance(data, dict):
        raise InputError(f"{path}: expected a JSON object, got {type(data).__name__}")
    where = str(path)
    runs = require(data, "runs", int, where)
    if runs < 1:
        raise InputError(f"{path}: key 'runs' is {runs}, expected at least 1")
    ests = require(data, "estimators", dict, where)
    seed, frames = data.get("seed"), data.get("frames")
    for key, value in (("seed", seed), ("frames", frames)):
        if value is not None and (isinstance(value, bool) or not isinstance(value, int)):
            raise InputError(f"{path}: key {key!r}: expected an integer, got {short(value)}")
    return NeesResults(
        folder=path.parent, runs=runs, seed=seed, frames=frames,
        simulation=_object_or_none(data, "simulation", path),
        filter=_object_or_none(data, "filter", path),
        smoother=_object_or_none(data, "smoother", path),
        settings=_object_or_none(data, "settings", path),
        estimators={str(n): _nees_estimator(str(n), r, f"{path}: estimators.{n}")
                    for n, r in ests.items()},
        timestamps=_series(data.get("timestamps"), f"{path}: timestamps"))
