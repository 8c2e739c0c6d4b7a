"""vislam.ekf: the primary estimator (numpy and scipy only).

Lie-group and stereo-camera math, the shared data types (:class:`Sequence`,
:class:`Estimate`), the covariance conventions, the per-frame filter protocol (:mod:`ekf.filter`)
with its one driver loop (:mod:`ekf.driver`), and the filters: :mod:`ekf.dead_reckoning`,
:mod:`ekf.mapping`, :mod:`ekf.decoupled`, :mod:`ekf.joint`, :mod:`ekf.invariant`. Their names are
registered once, in pyproject.toml (:mod:`ekf.estimators`).
"""

from vislam.ekf.errors import EstimationError, InputError
from vislam.ekf.estimate import Estimate
from vislam.ekf.sequence import Calibration, Observations, Sequence

__all__ = [
    "Calibration",
    "Estimate",
    "EstimationError",
    "InputError",
    "Observations",
    "Sequence",
]
