"""The Monte Carlo study behind the consistency and agreement tests, made with the public pytest
helpers (:func:`vislam.testing.monte_carlo`): one simulated drive, its velocity and pixel noise
redrawn per run (``eval.montecarlo.redraw_noise``), every estimator on every run
(``eval.study.run_jobs``, 2 worker processes, the smoother starting from the invariant EKF).
The study keeps pose NEES against truth, landmark NEES per source track, and each EKF's pose NEES
against the smoother of the same run (normalised by the EKF's covariance)."""

from __future__ import annotations

from vislam.ekf.config import FilterConfig
from vislam.testing import NEAR_FIELD, MonteCarloStudy, monte_carlo

#: Monte Carlo size: runs x frames (2 worker processes).
RUNS = 10
FRAMES = 120
SEED = 0
#: Logical estimators studied (the deliberate break may run another registry name for one).
ESTIMATORS = ("ekf-decoupled", "ekf-joint", "ekf-invariant", "smoother")
REFERENCE = "smoother"

__all__ = ["ESTIMATORS", "FRAMES", "NEAR_FIELD", "REFERENCE", "RUNS", "SEED", "run_monte_carlo"]


def run_monte_carlo(config: FilterConfig, run_name, runs: int = RUNS, frames: int = FRAMES,
                    seed: int = SEED, jobs: int = 2, sim_changes: dict | None = None) -> MonteCarloStudy:
    """The study for ``config``; ``run_name(logical) -> registry name`` (the deliberate break:
    each logical estimator is studied under its own label, whatever runs for it);
    ``sim_changes`` alter the default simulation (e.g. :data:`NEAR_FIELD`)."""
    return monte_carlo({n: run_name(n) for n in ESTIMATORS}, runs=runs, frames=frames, seed=seed,
                       config=config, sim={"name": f"regression-seed{seed}", **(sim_changes or {})},
                       jobs=jobs, reference=REFERENCE)
