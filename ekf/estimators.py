"""Registry of the EKF estimators by name: ``ESTIMATORS[name](seq, config, progress)``.

Every entry has the signature
``run_xxx(seq: Sequence, config: FilterConfig = FilterConfig(),
progress: Callable[[int], None] | None = None) -> Estimate``.
"""

from __future__ import annotations

from functools import partial
from typing import Callable

from ekf.decoupled import run_decoupled
from ekf.dead_reckoning import run_dead_reckoning
from ekf.estimate import Estimate
from ekf.invariant import run_invariant
from ekf.joint import run_joint
from ekf.mapping import run_mapping

Estimator = Callable[..., Estimate]

ESTIMATORS: dict[str, Estimator] = {
    "dead-reckoning": run_dead_reckoning,
    "mapping": run_mapping,
    # The paper's Algorithm 1 exactly as written: landmark means exact in the pose update,
    # no cross-covariance. ``run_decoupled(as_written=False)`` is the variant that widens each
    # observation's noise by its landmark's covariance (kept for comparison, not registered).
    "ekf-decoupled": partial(run_decoupled, as_written=True),
    "ekf-joint": run_joint,
    "ekf-invariant": run_invariant,
}

__all__ = ["ESTIMATORS", "Estimator"]
