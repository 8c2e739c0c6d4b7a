"""Registry of the EKF estimators by name: ``ESTIMATORS[name](seq, config, progress)``.

Every entry has the signature
``run_xxx(seq: Sequence, config: FilterConfig = FilterConfig(),
progress: Callable[[int], None] | None = None) -> Estimate``.
"""

from __future__ import annotations

from typing import Callable

from ekf.decoupled import run_decoupled
from ekf.dead_reckoning import run_dead_reckoning
from ekf.estimate import Estimate
from ekf.joint import run_joint
from ekf.mapping import run_mapping

Estimator = Callable[..., Estimate]

ESTIMATORS: dict[str, Estimator] = {
    "dead-reckoning": run_dead_reckoning,
    "mapping": run_mapping,
    "ekf-decoupled": run_decoupled,
    "ekf-joint": run_joint,
}

# --- invariant EKF (ekf/invariant.py, written by another helper) -------------------------
# Registered here when its module is present; remove the guard once it has landed.
try:
    from ekf.invariant import run_invariant
except ModuleNotFoundError as exc:  # pragma: no cover - until ekf/invariant.py lands
    if exc.name != "ekf.invariant":
        raise
else:
    ESTIMATORS["ekf-invariant"] = run_invariant
# -----------------------------------------------------------------------------------------

__all__ = ["ESTIMATORS", "Estimator"]
