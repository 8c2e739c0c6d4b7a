"""Registry of the EKF estimators by name: ``ESTIMATORS[name](seq, config, progress)``.

Every entry has the signature
``run_xxx(seq: Sequence, config: FilterConfig = FilterConfig(),
progress: Callable[[int], None] | None = None) -> Estimate``.
"""

from __future__ import annotations

from functools import partial
from typing import Callable

from vislam.ekf.decoupled import run_decoupled
from vislam.ekf.dead_reckoning import run_dead_reckoning
from vislam.ekf.estimate import Estimate
from vislam.ekf.invariant import run_invariant
from vislam.ekf.joint import run_joint
from vislam.ekf.mapping import run_mapping

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
