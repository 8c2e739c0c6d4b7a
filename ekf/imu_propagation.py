"""The raw-IMU filters' propagation over one camera interval: the mean and the IMU block of the
covariance sample by sample, and the interval's accumulated transition for everything else.

The scheme, the error state and the noise are :mod:`ekf.strapdown`'s (its step ``F`` and
``Q``: each sample held until the next one or the interval's end, exact SO(3) exponential,
second-order position; white noise ``density^2 / dt`` per step, bias walk ``walk^2 dt``,
Forster et al. 2017). Over the samples ``j = 1..n`` of the interval::

    P_II <- F_j P_II F_j^T + Q_j          (every sample: 15 x 15)
    Phi  <- F_j Phi                        (Phi = F_n ... F_1)

and once per frame the filter moves the cross-covariances of the IMU state with everything
else (landmarks) by ``P_IL <- Phi P_IL``: the same as applying every ``F_j`` to them (the
landmarks do not move and take no noise), at ``O(n_landmarks)`` per frame instead of
``O(n_samples n_landmarks)``.

Which samples an interval ``(t0, t1]`` gets and how its ends are cut:
:class:`ekf.filter.MotionInput` (the sample at or before ``t0`` first, each sample held over
``[max(t_j, t0), min(t_j+1, t1))``, so every instant between two frames is integrated once).
"""

from __future__ import annotations

import numpy as np

from vislam.ekf.filter import ImuSamples
from vislam.ekf.inertial import ImuNoise
from vislam.ekf.strapdown import NavState, integrate_with_transition


def propagate(state: NavState, P: np.ndarray, imu: ImuSamples, t0: float, t1: float,
              g_world: np.ndarray, noise: ImuNoise
              ) -> tuple[NavState, np.ndarray, np.ndarray]:
    """``(state, P_II, Phi)`` carried from ``t0`` to ``t1`` over ``imu`` (module docstring):
    the same mean and covariance as :func:`ekf.strapdown.integrate`, plus the transition
    ``Phi`` (15, 15) of the whole interval (:func:`ekf.strapdown.integrate_with_transition`).
    EstimationError when no sample is at or before ``t0``."""
    return integrate_with_transition(state, P, imu, t0, t1, g_world, noise)
