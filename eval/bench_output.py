"""`vislam bench`'s folder: every estimator on every drive run (:func:`eval.study.run_jobs`),
scored (:mod:`eval.bench_scores`), drawn (:mod:`eval.drive_figures`), put in words
(:mod:`eval.readings`) and written: ``results.json``, ``summary.md``, ``report.html``,
``settings.json`` and per drive its TUM trajectories, estimates and figures. Every output is
built in a temporary folder and renamed into place at the end (:mod:`eval.output_dir`).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path

from vislam.ekf.config import FilterConfig
from vislam.ekf.errors import EstimationError, InputError
from vislam.ekf.estimate import Estimate
from vislam.eval.atomic import atomic_symlink, write_json, write_text
from vislam.eval.bench_scores import (
    RPE_DEFINITION,
    RPE_DRIVE_DEFINITION,
    SCHEMA,
    default_alignment,
    score_sequence,
)
from vislam.eval.drive_figures import sequence_figures
from vislam.eval.drives import BenchSequence
from vislam.eval.export import write_tum
from vislam.eval.metrics import ALIGN_DESCRIPTIONS, check_align_mode
from vislam.eval.output_dir import OutputDir
from vislam.eval.readings import summary_markdown
from vislam.eval.registry import (DEFAULT_BENCH, DEFAULT_BENCH_INERTIAL, applicable, drive_kind,
                                  file_stem)
from vislam.eval.report import report_html
from vislam.eval.signals import deferred
from vislam.eval.study import JobResult, run_jobs
from vislam.graph.settings import SmootherSettings

log = logging.getLogger(__name__)


@dataclass
class BenchOutput:
    out_dir: Path
    results: dict
    summary: str
    wall_s: float
    #: One line per estimator run that failed ("SEQUENCE ESTIMATOR: error"), empty when none.
    failures: list[str] = field(default_factory=list)


#: What ``vislam bench`` writes at the top of its folder (a folder per sequence besides).
BENCH_FILES = ("results.json", "summary.md", "report.html", "settings.json")


def default_out_dir(root: Path = Path("results")) -> Path:
    return root / time.strftime("%Y%m%d-%H%M%S")


def run_benchmark(
    sequences: list[BenchSequence],
    estimators: list[str],
    config: FilterConfig,
    out_dir: Path,
    jobs: int = 1,
    show_progress: bool = True,
    settings: dict | None = None,
    latest_link: Path | None = None,
    smoother: SmootherSettings | None = None,
    force: bool = False,
    extra_inputs: tuple = (),
    align: str = "se3",
    executor: str = "local",
    scheduler: str | None = None,
) -> BenchOutput:
    """Run, score, plot and write everything into ``out_dir``; ``smoother`` the smoothers'
    settings (defaults when None); ``align`` the alignment before every aligned ATE
    (eval.metrics.ALIGN_MODES, recorded as results.json's ``alignment``). The folder is checked
    before the first job starts and written as :mod:`eval.output_dir` says (``force``: write
    beside files vislam did not write, never over them). ``executor`` and ``scheduler``: where
    the jobs run (:func:`eval.study.run_jobs`)."""
    if align is not None:
        check_align_mode(align)
    t0 = time.perf_counter()
    # the estimators that run on at least one drive (each drive runs those of its kind)
    estimators = [n for n in estimators if any(n in applicable([n], b.sequence) for b in sequences)]
    if not estimators:
        raise InputError("no estimator given runs on these drives: velocity drives take "
                         f"{', '.join(DEFAULT_BENCH)}, raw-IMU drives {', '.join(DEFAULT_BENCH_INERTIAL)}")
    by_key = {bs.name: bs.sequence for bs in sequences}
    smoother = smoother if smoother is not None else SmootherSettings()
    inputs = [b.path for b in sequences if b.path]
    inputs += [getattr(b.gt, "source", None) for b in sequences if b.gt is not None]
    inputs += list(extra_inputs)
    out = OutputDir(out_dir, force=force, inputs=inputs, expected=[*BENCH_FILES, *by_key])
    with out as tmp:
        configs = {bs.name: bs.config if bs.config is not None else config for bs in sequences}
        outcomes = run_jobs(by_key, estimators, configs, jobs, show_progress, smoother=smoother,
                            executor=executor, scheduler=scheduler)
        with deferred():  # a signal waits until the files are written (matplotlib's C code
            # must not be cut short), then ends the command and the staging folder goes
            results, summary = _write_results(tmp, sequences, estimators, outcomes, config, jobs,
                                              smoother, settings, t0, align=align)
    if latest_link is not None:
        atomic_symlink(Path(out_dir).name, latest_link)
    failures = [f"{s['name']} {r['name']}: {r['error']}"
                for s in results["sequences"] for r in s["estimators"] if r["error"]]
    return BenchOutput(Path(out_dir), results, summary, time.perf_counter() - t0, failures)


def _alignment_definition(align: str | None, sequences) -> str:
    """results.json's ``alignment_definition``: one mode, or each kind of drive's by default."""
    used = {kind: default_alignment(align, b.sequence)
            for kind, b in ((drive_kind(b.sequence), b) for b in sequences)}
    words = {kind: ALIGN_DESCRIPTIONS[mode] for kind, mode in used.items()}
    if len(set(words.values())) <= 1:
        return "ate_aligned_m (ATE al.): the ATE after " + next(iter(words.values()), "")
    return "ate_aligned_m (ATE al.): the ATE after " + "; ".join(
        f"{text} on {kind} drives" for kind, text in words.items())


def _write_results(tmp: Path, sequences, estimators, outcomes, config, jobs, smoother, settings,
                   t0: float, align: str = "se3") -> tuple[dict, str]:
    results = {
        "schema": SCHEMA,
        "rpe_definition": RPE_DEFINITION,
        "rpe_drive_definition": RPE_DRIVE_DEFINITION,
        "reference": "vs_smoother compares with the batch smoother ('smoother'), or with "
                     "'smoother-isam2' when only that ran",
        "alignment": align or "se3",
        "alignment_definition": _alignment_definition(align, sequences),
        "estimators": list(estimators),
        "sequences": [],
    }
    for bs in sequences:
        names = applicable(estimators, bs.sequence)
        outs = {n: outcomes[(bs.name, n)] for n in names if (bs.name, n) in outcomes}
        results["sequences"].append(score_sequence(bs, names, outs,
                                                   align=default_alignment(align, bs.sequence)))
        ests = {n: o.estimate for n, o in outs.items() if isinstance(o, JobResult)}
        folder = tmp / bs.name
        for name, est in ests.items():
            write_tum(folder / f"{file_stem(name)}.tum", est.timestamps, est.poses)
            _save_estimate(folder / f"{file_stem(name)}.estimate.npz", est)
        sequence_figures(folder, bs, ests)
    results["wall_s"] = time.perf_counter() - t0
    summary = summary_markdown(results)
    write_json(tmp / "results.json", results)
    write_text(tmp / "summary.md", summary)
    write_text(tmp / "report.html", report_html(results, tmp))
    write_json(tmp / "settings.json", {
        "estimators": list(estimators),
        "jobs": jobs,
        "alignment": align or "se3",
        "filter": config.to_dict(),
        "smoother": smoother.to_dict(),
        "sequences": [{"name": b.name, "path": b.path, **(b.origin or {}),
                       "model": b.model,
                       "filter": None if b.config is None else b.config.to_dict()}
                      for b in sequences],
        **(settings or {}),
    })
    return results, summary


def _save_estimate(path: Path, est: Estimate) -> None:
    """The whole estimate (poses, covariances, map) for the notebook, which then loads it
    instead of running the estimator again; one that cannot be saved (not finite) is left out
    with a warning: the notebook re-runs that one."""
    try:
        est.save_npz(path)
    except EstimationError as exc:
        log.warning("%s not written: %s", path.name, exc)
