"""vislam.ekf: the primary estimator (numpy and scipy only).

Lie-group and stereo-camera math, the shared data types (:class:`Sequence`,
:class:`Estimate`), the covariance conventions and the filter variants.
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
