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

from vislam.ekf.errors import EstimationError
from vislam.ekf.filter import ImuSamples
from vislam.ekf.inertial import ImuNoise
from vislam.ekf.strapdown import (N_ERROR, ROT, NavState, _jacobian, _noise_without_rotation,
                                  exp_and_right_jacobian)


def propagate(state: NavState, P: np.ndarray, imu: ImuSamples, t0: float, t1: float,
              g_world: np.ndarray, noise: ImuNoise
              ) -> tuple[NavState, np.ndarray, np.ndarray]:
    """``(state, P_II, Phi)`` carried from ``t0`` to ``t1`` over ``imu`` (module docstring):
    the same mean and covariance as :func:`ekf.strapdown.integrate`, plus the transition
    ``Phi`` (15, 15) of the whole interval. EstimationError when no sample is at or before
    ``t0``."""
    time = np.asarray(imu.time, dtype=float)
    if time.size == 0 or time[0] > t0:
        first = "none" if time.size == 0 else f"the first at {time[0]:.6f} s"
        raise EstimationError(f"IMU propagation: no IMU sample at or before t={t0:.6f} s ({first})")
    ends = np.append(time[1:], t1)
    R, v, p, bg, ba = state.R, state.v, state.p, state.bg, state.ba
    Phi = np.eye(N_ERROR)
    sg2 = noise.gyro_noise_density ** 2
    q_cache: dict[float, np.ndarray] = {}
    for j in range(time.size):
        dt = float(min(ends[j], t1) - max(time[j], t0))
        if dt <= 0:
            continue
        dR, Jr = exp_and_right_jacobian((imu.gyro[j] - bg) * dt)
        a = imu.accel[j] - ba
        acc = g_world + R @ a
        F = _jacobian(R, dR, Jr, a, dt)
        Q = q_cache.get(dt)
        if Q is None:
            Q = q_cache[dt] = _noise_without_rotation(dt, noise)
        P = F @ P @ F.T + Q
        P[ROT, ROT] += sg2 * dt * (Jr @ Jr.T)
        Phi = F @ Phi
        p = p + v * dt + 0.5 * dt * dt * acc
        v = v + acc * dt
        R = R @ dR
    return NavState(R, v, p, bg, ba), P, Phi
