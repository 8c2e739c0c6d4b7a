"""pytest helpers: a consistency and accuracy regression test for any estimator, with vislam's
machinery (public as :mod:`vislam.testing`).

An estimator is given as vislam's name (``"ekf-invariant"``), a ``"MODULE:FUNCTION"`` string or
a module-level callable ``(seq, settings) -> Estimate`` (the protocol:
:mod:`vislam.eval.registry`); it appears under ``vislam.eval.registry.display_name``: its name,
or ``module:function`` for a callable. To show one under another label, pass a dict
``{label: estimator}``.

**Monte Carlo** (:func:`monte_carlo`): the engine of ``vislam nees``
(:func:`eval.montecarlo.run_monte_carlo`): one simulated drive, its velocity and pixel noise
redrawn per run (``numpy.random.default_rng([seed, run])``), every estimator on every run
(``jobs`` worker processes), and the reference (the smoother by default) beside them. A
:class:`MonteCarloStudy` keeps, per estimator and run, the pose NEES against truth (6 dof), the
landmark NEES per source track (3 dof) and the pose NEES against the reference of the same run
(normalised by the estimator's covariance).

**Checks** (each a :class:`Check`, whose ``message`` states the figure, the bounds and the
verdict), and the assertions that raise ``AssertionError(message)`` when one fails:

- :func:`assert_nees_consistent`: ANEES of poses and landmarks inside the two-sided chi-square
  bounds ``chi2.ppf([(1-p)/2, (1+p)/2], N d) / N`` (DESIGN.md, "Scoring"; step 0 left out, where
  the error is zero by construction). "above" = overconfident, "below" = underconfident.
- :func:`assert_agrees_with_smoother`: the smoother inside the estimator's own 3-sigma region
  (pose NEES against the smoother <= ``chi2.ppf(chi2.cdf(9, 1), 6)``) on at least the share the
  chi-square distribution predicts (0.9973), less a binomial allowance: the required share is
  ``binom.ppf(0.01, n, 0.9973) / n`` for ``n`` frames scored. A consistent filter passes: the
  smoother uses a superset of the data, so the difference has covariance
  ``P_filter - P_smoother <= P_filter``.
- :func:`assert_accuracy`: an estimator on a drive (a ``.npz`` with its ground truth beside it,
  as ``vislam bench`` finds it, or a simulated drive) within bounds on the ATE (raw or aligned,
  m) and the KITTI drift t_rel (%, 100-800 m segments).

A run that fails is never hidden: a check of an estimator with failed runs fails (unless
``max_failed_runs`` allows them) and its message names the runs and the first error. vislam's
own estimators that fail are recorded per run; a user's estimator that raises or breaks the
Estimate contract stops its own runs (:func:`eval.study.run_jobs` treats it as bad input), and
the study records the error and how many runs it had finished.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.stats import binom, chi2

from vislam.ekf.config import FilterConfig
from vislam.eval.consistency import (
    LANDMARK_DOF,
    POSE_DOF,
    VERDICT_INSIDE,
    VERDICT_WORDS,
    AneesResult,
    anees,
)
from vislam.eval.bench_scores import default_alignment, trajectory_scores, truth_in_gauge
from vislam.eval.drives import as_given, bench_sequence, identify_models
from vislam.eval.montecarlo import run_monte_carlo, study_sim_config
from vislam.eval.registry import display_name
from vislam.eval.study import JobFailure, labelled_estimators, run_groups
from vislam.graph.settings import SmootherSettings

__all__ = [
    "NEAR_FIELD",
    "THREE_SIGMA",
    "Check",
    "MonteCarloStudy",
    "DriveStudy",
    "monte_carlo",
    "run_drive",
    "assert_nees_consistent",
    "assert_agrees_with_smoother",
    "assert_accuracy",
]

#: The near field: landmarks within 25 m and no far points. At a test's size (a few runs of
#: 60-120 frames) the EKFs are consistent here; the default drive's far landmarks (to 60 m,
#: disparities down to ~6 px) need more frames.
NEAR_FIELD: dict[str, Any] = {"max_depth": 25.0, "far_fraction": 0.0}

#: Probability of the 1-D 3-sigma interval, chi2.cdf(9, 1) = 0.9973.
THREE_SIGMA = float(chi2.cdf(9.0, 1))



# --- checks ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class Check:
    """One figure of one estimator against its bounds.

    ``estimator`` the label; ``quantity`` what was measured ("pose ANEES", "landmark ANEES",
    "agreement with smoother", "aligned ATE", ...); ``value`` the figure (None when it could not
    be computed); ``bounds`` (low, high), an open side infinite; ``verdict`` one word: "inside",
    "above", "below" (ANEES), "agrees", "disagrees" (agreement), "within", "over" (accuracy),
    "failed" (runs failed), "missing" (nothing to score); ``ok`` whether the check passes;
    ``message`` the line an assertion fails with. ``bool(check)`` is ``ok``.
    """

    estimator: str
    quantity: str
    value: float | None
    bounds: tuple[float, float]
    verdict: str
    ok: bool
    message: str

    def __bool__(self) -> bool:
        return self.ok


def _fail_if_any(checks: Iterable[Check]) -> list[Check]:
    __tracebackhide__ = True
    checks = list(checks)
    bad = [c for c in checks if not c.ok]
    if bad:
        raise AssertionError("\n".join(c.message for c in bad))
    return checks


def _failures_text(failed: int, runs: int, errors: list[str]) -> str:
    first = errors[0] if errors else "no error recorded"
    more = f" (and {len(errors) - 1} more errors)" if len(errors) > 1 else ""
    return f"{failed} of {runs} runs failed: {first}{more}"


# --- Monte Carlo -----------------------------------------------------------------------------


@dataclass
class MonteCarloStudy:
    """What :func:`monte_carlo` measured. Arrays per estimator label:

    ``pose_nees`` (runs, T) against truth, NaN at step 0 and in failed runs; ``landmark_nees``
    (runs, n_source_tracks) against truth, NaN where no landmark was estimated;
    ``versus_reference`` (runs, T) pose NEES against the reference of the same run, normalised by
    the estimator's covariance (not kept for the reference itself); ``completed`` (runs,) which
    runs gave an estimate; ``errors`` one line per failure. ``subjects`` the estimators asked
    for, ``estimators`` every one run (the reference too)."""

    runs: int
    frames: int
    seed: int
    sim: Any  # eval.simulate.SimConfig
    config: FilterConfig
    reference: str | None
    subjects: tuple[str, ...]
    estimators: tuple[str, ...]
    pose_nees: dict[str, np.ndarray] = field(default_factory=dict)
    landmark_nees: dict[str, np.ndarray] = field(default_factory=dict)
    versus_reference: dict[str, np.ndarray] = field(default_factory=dict)
    completed: dict[str, np.ndarray] = field(default_factory=dict)
    errors: dict[str, list[str]] = field(default_factory=dict)
    wall_s: float = float("nan")

    def __repr__(self) -> str:  # pytest prints the locals of failing tests: keep it short
        return (f"MonteCarloStudy({', '.join(self.estimators)}; runs={self.runs}, "
                f"frames={self.frames}, wall_s={self.wall_s:.1f})")

    def name(self, name=None) -> str:
        """The label of ``name`` (a label, or the estimator as given); None: the only subject."""
        return _pick(self, name)

    def failed_runs(self, name=None) -> int:
        return int(np.count_nonzero(~self.completed[self.name(name)]))

    def pose_anees(self, name=None, probability: float = 0.95) -> AneesResult | None:
        """Pose ANEES (6 dof, steps 1..T-1) over the runs that completed; None without any."""
        label = self.name(name)
        nees = self.pose_nees[label][self.completed[label], 1:]
        return anees(nees, POSE_DOF, probability) if nees.shape[0] else None

    def landmark_anees(self, name=None, probability: float = 0.95) -> AneesResult | None:
        """Landmark ANEES (3 dof) over the runs that completed and the source tracks with a
        landmark in some run (a track counts when every run estimated it); None when no run
        estimated a landmark."""
        label = self.name(name)
        nees = self.landmark_nees[label][self.completed[label]]
        seen = np.any(np.isfinite(nees), axis=0)
        if not nees.shape[0] or not np.any(seen):
            return None
        return anees(nees[:, seen], LANDMARK_DOF, probability)

    def consistency(self, name=None, what: str = "pose", probability: float = 0.95,
                    max_failed_runs: int = 0) -> Check:
        """ANEES of ``what`` ("pose" or "landmark") against the two-sided chi-square bounds."""
        if what not in ("pose", "landmark"):
            raise ValueError(f"what: 'pose' or 'landmark', got {what!r}")
        label = self.name(name)
        quantity = f"{what} ANEES"
        res = (self.pose_anees if what == "pose" else self.landmark_anees)(label, probability)
        failed = self.failed_runs(label)
        pct = f"{100 * probability:g} %"
        if res is None:
            verdict = "failed" if failed else "missing"
            why = ("no run completed" if failed == self.runs else "no landmark estimated in any run "
                   "(pass what='pose' for an estimator without a map)")
            tail = f"; {_failures_text(failed, self.runs, self.errors[label])}" if failed else ""
            return Check(label, quantity, None, (math.nan, math.nan), verdict, False,
                         f"{label}: {quantity}: {why}{tail}")
        lo, hi = res.bounds
        items = int(np.count_nonzero(np.isfinite(res.per_item)))
        unit = "steps" if what == "pose" else "landmarks"
        verdict = res.verdict if res.verdict is not None else "missing"
        line = (f"{label}: {quantity} {res.mean:.2f} over {res.n_runs} runs x {items} {unit}, "
                f"{pct} bounds [{lo:.2f}, {hi:.2f}]: {VERDICT_WORDS.get(verdict, verdict)}")
        ok = verdict == VERDICT_INSIDE
        if failed > max_failed_runs:
            ok, verdict = False, "failed"
            line += f"; {_failures_text(failed, self.runs, self.errors[label])}"
        elif failed:
            line += f" ({_failures_text(failed, self.runs, self.errors[label])}, allowed {max_failed_runs})"
        return Check(label, quantity, res.mean, (lo, hi), verdict, ok, line)

    def agreement(self, name=None, sigma: float = 3.0, allowance: float = 0.01,
                  max_failed_runs: int = 0) -> Check:
        """The reference inside ``name``'s ``sigma``-sigma region on at least the share chi2
        predicts less the binomial ``allowance`` (module docstring)."""
        label = self.name(name)
        ref = self.reference
        quantity = f"agreement with {ref}"
        if ref is None:
            raise ValueError(f"{label!r}: the study has no reference to compare it with "
                             "(monte_carlo(..., reference=None))")
        if label == ref:
            raise ValueError(f"{label!r} is the study's reference")
        predicted = float(chi2.cdf(sigma**2, 1))
        nees = self.versus_reference[label][:, 1:]
        nees = nees[np.isfinite(nees)]
        failed = [(n, self.failed_runs(n)) for n in (label, ref)]
        failures = "; ".join(f"{n}: {_failures_text(k, self.runs, self.errors[n])}"
                             for n, k in failed if k)
        if not nees.size:
            return Check(label, quantity, None, (math.nan, 1.0), "failed" if failures else "missing",
                         False, f"{label}: no step compared with the {ref}"
                         + (f"; {failures}" if failures else ""))
        share = float(np.mean(nees <= chi2.ppf(predicted, POSE_DOF)))
        required = float(binom.ppf(allowance, nees.size, predicted) / nees.size)
        ok = share >= required
        verdict = "agrees" if ok else "disagrees"
        words = ("agrees" if ok else
                 f"disagrees (the {ref} is outside its {sigma:g}-sigma too often: overconfident)")
        line = (f"{label}: the {ref} inside its {sigma:g}-sigma on {share:.4f} of {nees.size} frames "
                f"(median NEES vs {ref} {np.median(nees):.2f}), chi-square predicts {predicted:.4f}, "
                f"required >= {required:.4f} (binomial {100 * allowance:g} % allowance): {words}")
        if any(k > max_failed_runs for _, k in failed):
            ok, verdict = False, "failed"
            line += f"; {failures}"
        elif failures:
            line += f" ({failures}, allowed {max_failed_runs})"
        return Check(label, quantity, share, (required, 1.0), verdict, ok, line)


def _pick(study, name) -> str:
    if name is None:
        if len(study.subjects) != 1:
            raise ValueError(f"the study has {len(study.subjects)} estimators "
                             f"({', '.join(study.subjects)}): name one")
        return study.subjects[0]
    label = name if isinstance(name, str) else display_name(name)
    if label not in study.estimators:
        raise KeyError(f"{label!r} is not in the study ({', '.join(study.estimators)})")
    return label


def monte_carlo(estimators, runs: int = 10, frames: int | None = None, seed: int | None = None,
                config: FilterConfig | None = None, sim=None, jobs: int = 1,
                reference: Any = "smoother", smoother=None) -> MonteCarloStudy:
    """Run ``estimators`` (one, a list, or a dict ``{label: estimator}``) and ``reference`` on
    ``runs`` noise draws of one simulated drive; returns the :class:`MonteCarloStudy`.

    The drive: the simulator's default (``seed`` 0, ``frames`` 120) with ``sim``'s changes (a
    dict of :class:`vislam.eval.simulate.SimConfig` fields, e.g. :data:`NEAR_FIELD`), or ``sim``
    a SimConfig used as it is. ``config`` the filter settings every estimator gets (default
    ``FilterConfig()``), ``smoother`` the smoothers' (default ``SmootherSettings()``).
    ``reference`` the estimator the others are compared with (a label among ``estimators`` or an
    estimator; None: none). ``jobs`` worker processes (1: in this process, where any callable
    works; more: a callable must be importable by its module and name)."""
    if int(runs) < 1:
        raise ValueError(f"runs must be >= 1, got {runs}")
    runs = int(runs)
    t0 = time.perf_counter()
    labelled = labelled_estimators(estimators)
    subjects = tuple(labelled)
    ref_label = None
    if reference is not None:
        given_label = isinstance(reference, str) and reference in labelled
        ref_label = reference if given_label else display_name(reference)
        if ref_label not in labelled:
            labelled.update(labelled_estimators({ref_label: reference}))
    config = config if config is not None else FilterConfig()
    sim_config = study_sim_config(sim, seed, frames)
    found = run_monte_carlo(sim_config, runs, labelled, config, reference=ref_label,
                            smoother=smoother, jobs=jobs, isolate_user_estimators=True)
    study = MonteCarloStudy(
        runs, found.frames, int(sim_config.seed), sim_config, config, ref_label, subjects,
        tuple(labelled), found.pose_nees, found.landmark_nees, found.versus_reference,
        found.completed, {n: [str(f) for f in fs] for n, fs in found.failures.items()})
    study.wall_s = time.perf_counter() - t0
    return study


def _study(study_or_estimator, name, study_kwargs, make):
    """(study, label): the study given, or one made by ``make`` for the estimator given."""
    if isinstance(study_or_estimator, (MonteCarloStudy, DriveStudy)):
        if study_kwargs:
            raise TypeError(f"a study is given: {', '.join(study_kwargs)} would not be used")
        return study_or_estimator, study_or_estimator.name(name)
    if name is not None:
        raise TypeError("name selects an estimator of a study; with an estimator given, leave it "
                        "out (or pass {label: estimator})")
    study = make(study_or_estimator, **study_kwargs)
    return study, study.name()


def assert_nees_consistent(study_or_estimator, name=None, *, what=("pose", "landmark"),
                           probability: float = 0.95, max_failed_runs: int = 0,
                           **study_kwargs) -> list[Check]:
    """Assert the ANEES of ``what`` ("pose", "landmark" or both) inside the two-sided
    ``probability`` chi-square bounds. ``study_or_estimator``: a :class:`MonteCarloStudy` (then
    ``name`` picks the estimator; None: its only one), or an estimator, run by
    :func:`monte_carlo` with ``study_kwargs`` (the smoother is not run). Fails with one line per
    failed check, e.g. ``my_pkg:estimate: pose ANEES 13.41 over 10 runs x 119 steps, 95 %
    bounds [4.05, 8.33]: above (overconfident)``; returns the checks."""
    __tracebackhide__ = True
    if not isinstance(study_or_estimator, MonteCarloStudy):
        study_kwargs.setdefault("reference", None)  # the smoother is not needed here
    study, label = _study(study_or_estimator, name, study_kwargs, monte_carlo)
    whats = (what,) if isinstance(what, str) else tuple(what)
    return _fail_if_any(study.consistency(label, w, probability, max_failed_runs) for w in whats)


def assert_agrees_with_smoother(study_or_estimator, name=None, *, sigma: float = 3.0,
                                allowance: float = 0.01, max_failed_runs: int = 0,
                                **study_kwargs) -> Check:
    """Assert that the study's reference (the smoother) lies inside the estimator's own
    ``sigma``-sigma region on at least the share chi2 predicts, less the binomial ``allowance``
    (module docstring). ``study_or_estimator`` as in :func:`assert_nees_consistent` (an
    estimator is run by :func:`monte_carlo` beside the smoother). Fails with e.g.
    ``my_pkg:estimate: the smoother inside its 3-sigma on 0.7655 of 1190 frames, chi-square
    predicts 0.9973, required >= 0.9933 (binomial 1 % allowance): disagrees (...)``."""
    __tracebackhide__ = True
    study, label = _study(study_or_estimator, name, study_kwargs, monte_carlo)
    return _fail_if_any([study.agreement(label, sigma, allowance, max_failed_runs)])[0]


# --- accuracy on a drive ---------------------------------------------------------------------

#: accuracy bound keyword -> (trajectory_scores key, words, unit)
ACCURACY_FIGURES = {
    "ate_max": ("ate_m", "ATE", "m"),
    "ate_aligned_max": ("ate_aligned_m", "aligned ATE", "m"),
    "t_rel_max": ("rpe_trans_pct", "KITTI t_rel", "%"),
}


@dataclass
class DriveStudy:
    """What :func:`run_drive` measured: ``scores`` per estimator label (the benchmark's
    trajectory scores against ground truth: ``ate_m``, ``ate_aligned_m``, ``rpe_trans_pct``,
    ``rpe_rot_deg_per_100m``, ``nees_pose_mean``; None where not computable), ``estimates``,
    ``errors`` (label -> the failure), ``model`` (the model used, as results.json records it)."""

    drive: str
    path: str | None
    frames: int
    has_ground_truth: bool
    subjects: tuple[str, ...]
    estimators: tuple[str, ...]
    scores: dict[str, dict] = field(default_factory=dict)
    estimates: dict[str, Any] = field(default_factory=dict)
    errors: dict[str, str] = field(default_factory=dict)
    model: dict | None = None
    config: FilterConfig | None = None
    wall_s: float = float("nan")

    def __repr__(self) -> str:
        return (f"DriveStudy({self.drive}: {', '.join(self.estimators)}; frames={self.frames}, "
                f"wall_s={self.wall_s:.1f})")

    def name(self, name=None) -> str:
        """The label of ``name`` (a label, or the estimator as given); None: the only subject."""
        return _pick(self, name)

    def accuracy(self, name=None, *, ate_max: float | None = None,
                 ate_aligned_max: float | None = None, t_rel_max: float | None = None) -> list[Check]:
        """One check per bound given (at least one): the figure at most the bound."""
        label = self.name(name)
        bounds = {"ate_max": ate_max, "ate_aligned_max": ate_aligned_max, "t_rel_max": t_rel_max}
        bounds = {k: v for k, v in bounds.items() if v is not None}
        if not bounds:
            raise ValueError("give at least one bound: ate_max, ate_aligned_max or t_rel_max")
        out = []
        for key, bound in bounds.items():
            score_key, words, unit = ACCURACY_FIGURES[key]
            quantity = f"{words}"
            head = f"{label} on {self.drive}: {words}"
            if label in self.errors:
                out.append(Check(label, quantity, None, (-math.inf, bound), "failed", False,
                                 f"{head}: the estimator failed: {self.errors[label]}"))
                continue
            value = self.scores[label].get(score_key)
            if value is None:
                why = ("the drive has no ground truth" if not self.has_ground_truth else
                       "the drive is shorter than the shortest KITTI segment (100 m)"
                       if score_key == "rpe_trans_pct" else "not computable")
                out.append(Check(label, quantity, None, (-math.inf, bound), "missing", False,
                                 f"{head}: no figure ({why}), bound {bound:g} {unit}"))
                continue
            ok = value <= bound
            verdict = "within" if ok else "over"
            words_v = "within" if ok else f"over by {value - bound:+.3f} {unit}"
            out.append(Check(label, quantity, float(value), (-math.inf, float(bound)), verdict, ok,
                             f"{head} {value:.3f} {unit}, bound {bound:g} {unit}: {words_v}"))
        return out


def run_drive(estimators, drive, *, config: FilterConfig | None = None, model: str = "as-given",
              smoother=None, jobs: int = 1, align: str | None = None) -> DriveStudy:
    """Run ``estimators`` (one, a list or ``{label: estimator}``) on one drive and score them
    against its ground truth (``eval.bench_scores.trajectory_scores``, ``align`` before the aligned
    ATE; None: as ``vislam bench`` does, se3 on a velocity drive and yaw on a raw-IMU drive,
    whose truth is scored in each estimate's frame-0 gauge as bench scores it). ``drive``: a path to a ``.npz`` (ground truth ``DIR/groundtruth/NAME.txt`` beside it,
    as ``vislam bench`` finds it), or a simulated drive (a SimConfig or a SimResult).
    ``model``: "as-given" (the file's values and ``config`` as given) or "identified" (the model
    identified from the drive's own data, as ``vislam bench`` does by default; cached)."""
    if model not in ("as-given", "identified"):
        raise ValueError(f"model: 'as-given' or 'identified', got {model!r}")
    t0 = time.perf_counter()
    labelled = labelled_estimators(estimators)
    config = config if config is not None else FilterConfig()
    smoother = smoother if smoother is not None else SmootherSettings()
    bs = bench_sequence(drive)
    if model == "identified":
        (bs,) = identify_models([bs], config, smoother)
    elif bs.model is None:
        (bs,) = as_given([bs])
    run_config = bs.config if bs.config is not None else config
    by_run: dict[str, list[str]] = {}
    for label, spec in labelled.items():
        by_run.setdefault(display_name(spec), []).append(label)
    study = DriveStudy(bs.name, bs.path, bs.sequence.n_frames, bs.gt is not None, tuple(labelled),
                       tuple(labelled), model=bs.model, config=run_config)

    def reduce(res) -> None:
        for n in by_run[res.estimator]:
            if isinstance(res, JobFailure):
                study.errors[n] = res.error
            else:
                study.estimates[n] = res.estimate
                study.scores[n] = trajectory_scores(
                    res.estimate, truth_in_gauge(bs.gt, bs.sequence, res.estimate),
                    align=default_alignment(align, bs.sequence))

    def stopped(run_label: str, message: str) -> None:
        for n in by_run[run_label]:
            study.errors[n] = message

    run_groups({bs.name: bs.sequence}, list(labelled.values()), run_config, jobs, smoother,
               reduce, stopped)
    study.wall_s = time.perf_counter() - t0
    return study


def assert_accuracy(study_or_estimator, drive=None, *, name=None, ate_max: float | None = None,
                    ate_aligned_max: float | None = None, t_rel_max: float | None = None,
                    **run_kwargs) -> list[Check]:
    """Assert an estimator's accuracy on a drive: ATE (``ate_max``, m), SE(3)-aligned ATE
    (``ate_aligned_max``, m) and KITTI drift t_rel (``t_rel_max``, %) at most their bounds.
    ``study_or_estimator``: a :class:`DriveStudy` (``name`` picks the estimator), or an
    estimator run on ``drive`` by :func:`run_drive` with ``run_kwargs``. Fails with one line per
    bound missed, e.g. ``my_pkg:estimate on 0027: aligned ATE 6.912 m, bound 6.49 m: over by
    +0.422 m``; returns the checks."""
    __tracebackhide__ = True
    if isinstance(study_or_estimator, DriveStudy):
        if drive is not None:
            raise TypeError("a DriveStudy is given: its drive is used; leave drive out")
        study, label = _study(study_or_estimator, name, run_kwargs, None)
    else:
        if drive is None:
            raise TypeError("give the drive the estimator runs on")
        study, label = _study(study_or_estimator, name, run_kwargs,
                              lambda est, **kw: run_drive(est, drive, **kw))
    return _fail_if_any(study.accuracy(label, ate_max=ate_max, ate_aligned_max=ate_aligned_max,
                                       t_rel_max=t_rel_max))
