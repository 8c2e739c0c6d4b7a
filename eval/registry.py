"""Estimator names -> callables ``run(seq, config, progress=None, initial=None) -> Estimate``.

Modules are imported only when an estimator is asked for, so ``vislam run --estimator
ekf-joint`` never imports GTSAM. The batch smoother accepts an already computed EKF estimate
as its initial guess (``initial``), which saves the benchmark from running the EKF twice; the
other estimators ignore ``initial``.
"""

from __future__ import annotations

from typing import Callable, Protocol

from vislam.ekf.errors import InputError
from vislam.graph.settings import SmootherSettings

#: Every estimator, in the order tables and plots list them.
ESTIMATOR_NAMES: tuple[str, ...] = (
    "dead-reckoning",
    "mapping",
    "ekf-decoupled",
    "ekf-joint",
    "ekf-invariant",
    "smoother",
    "smoother-isam2",
)

#: What ``vislam bench`` runs unless told otherwise (iSAM2 is the slow incremental variant).
DEFAULT_BENCH: tuple[str, ...] = tuple(n for n in ESTIMATOR_NAMES if n != "smoother-isam2")

#: The EKFs whose estimate the batch smoother starts from, first available wins (the same order
#: as graph.smoother.EKF_INITIALISERS, which the smoother uses when it must run an EKF itself).
SMOOTHER_INITIAL_FROM: tuple[str, ...] = ("ekf-invariant", "ekf-joint")

#: Names of the smoothers (the references the EKFs are cross-validated against).
SMOOTHERS: tuple[str, ...] = ("smoother", "smoother-isam2")

_EKF_NAMES = ("dead-reckoning", "mapping", "ekf-decoupled", "ekf-joint", "ekf-invariant")


class EstimatorFn(Protocol):
    def __call__(self, seq, config, progress=None, initial=None, smoother=None): ...


def get_estimator(name: str) -> Callable:
    """The callable running estimator ``name``; unknown name -> :class:`InputError`. Its
    Estimate is checked (:meth:`ekf.estimate.Estimate.check_finite`): no NaN reaches a result."""
    run = _lookup(name)

    def checked(seq, config, progress=None, initial=None, smoother=None):
        est = run(seq, config, progress=progress, initial=initial, smoother=smoother)
        est.check_finite()
        return est

    return checked


def _lookup(name: str) -> Callable:
    if name in _EKF_NAMES:
        from vislam.ekf.estimators import ESTIMATORS

        fn = ESTIMATORS[name]

        def run_ekf(seq, config, progress=None, initial=None, smoother=None):
            return fn(seq, config, progress)

        return run_ekf
    if name == "smoother":
        from vislam.graph.smoother import run_smoother

        def run_batch(seq, config, progress=None, initial=None, smoother=None):
            settings = smoother if smoother is not None else SmootherSettings()
            return run_smoother(seq, config, initial=initial, progress=progress, settings=settings)

        return run_batch
    if name == "smoother-isam2":
        from vislam.graph.isam2 import run_isam2

        def run_incremental(seq, config, progress=None, initial=None, smoother=None):
            settings = smoother if smoother is not None else SmootherSettings()
            return run_isam2(seq, config, progress=progress, settings=settings)

        return run_incremental
    raise InputError(f"unknown estimator {name!r}; valid names: {', '.join(ESTIMATOR_NAMES)}")


def parse_estimator_list(text: str | None, default: tuple[str, ...]) -> list[str]:
    """Comma-separated names (``all`` for every estimator) -> validated list in registry order."""
    if text is None or not text.strip():  # absent or empty: the default list
        return list(default)
    names = [n.strip() for n in text.split(",") if n.strip()]
    if not names:
        raise InputError(
            f"--estimators {text!r} names no estimator; valid names: {', '.join(ESTIMATOR_NAMES)}"
            " (or 'all')"
        )
    if names == ["all"]:
        return list(ESTIMATOR_NAMES)
    unknown = [n for n in names if n not in ESTIMATOR_NAMES]
    if unknown:
        raise InputError(
            f"unknown estimator(s) {', '.join(map(repr, unknown))}; "
            f"valid names: {', '.join(ESTIMATOR_NAMES)}"
        )
    return [n for n in ESTIMATOR_NAMES if n in names]


def estimators_from_flag(text: str | None, default: tuple[str, ...]) -> list[str]:
    """``--estimators``: as :func:`parse_estimator_list`, but an empty value is an error (on
    the command line it is a mistake; the API's empty string means the default)."""
    if text is not None and not text.strip():
        raise InputError("--estimators: empty; name estimators, or leave the flag out for the "
                         "default list")
    return parse_estimator_list(text, default)


def uses_initial(name: str, smoother: SmootherSettings | None = None) -> bool:
    """Whether estimator ``name`` starts from another estimator's result (the batch smoother,
    when it is initialised from the EKF)."""
    return name == "smoother" and (smoother is None or smoother.init == "ekf")
