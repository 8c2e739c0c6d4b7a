"""Strapdown integration of raw IMU samples with its error-state covariance.

State (:class:`NavState`): ``R`` world_R_imu, ``v`` and ``p`` the IMU's world velocity and
position, ``bg`` and ``ba`` the gyro and accelerometer biases. The world frame is gravity-aligned
with gravity ``g_world`` (vislam: ``[0, 0, -g]``, z up).

The discrete scheme (the one preintegration uses: Forster et al., "On-manifold preintegration",
T-RO 2017, its discrete-time IMU model; GTSAM's ``PreintegratedImuMeasurements`` /
``NavState::update``). A sample ``(w_m, a_m)`` stamped ``t_j`` is
held over ``[t_j, t_j+1)`` (clipped to the interval integrated); with ``w = w_m - bg``,
``a = a_m - ba`` and the step ``dt``::

    R' = R Exp(w dt)                                  (exact SO(3) exponential)
    v' = v + (g_world + R a) dt
    p' = p + v dt + (g_world + R a) dt^2 / 2
    bg' = bg,  ba' = ba

When a sample holds its interval's delta angle and delta velocity (divided by dt; the
simulator's samples, :mod:`eval.imu_sim`) the scheme is exact in rotation and velocity and its
position has the trapezoid rule's error, bounded by ``dt^2 / 12 max|a(t) - a(0)|``. For samples
of the instantaneous rate and specific force its error is first order in dt, the same as the
preintegrated factors'.

Error state (15, order :data:`ERROR_STATE`): ``R_true = R Exp(dth)`` (body frame, right),
``v_true = v + dv``, ``p_true = p + dp`` (world frame), ``bg_true = bg + dbg``,
``ba_true = ba + dba``. The exact Jacobian of one step, ``F = d x' / d x`` (checked against
finite differences in tests/test_strapdown.py), with ``dR = Exp(w dt)``, ``Jr = Jr(w dt)`` the
right Jacobian of SO(3) and ``A = R [a]x``::

    dth' = dR^T dth                     - Jr dt dbg
    dv'  = dv  - A dt dth                            - R dt dba
    dp'  = dp  - A dt^2/2 dth  + dt dv                - R dt^2/2 dba

Noise (:class:`ekf.inertial.ImuNoise`, continuous-time densities; as in Forster et al. 2017, the
discrete white noise of a step of length dt has covariance ``density^2 / dt``, the bias random
walk over dt ``walk^2 dt``). It enters through ``G`` (gyro noise into dth with ``-Jr dt``,
accelerometer noise into dv with ``-R dt`` and into dp with ``-R dt^2/2``), so ``P' = F P F^T + Q``
with::

    Q_thth = sg^2 dt Jr Jr^T
    Q_vv = sa^2 dt I,   Q_vp = sa^2 dt^2/2 I,   Q_pp = sa^2 dt^3/4 I
    Q_bgbg = wg^2 dt I, Q_baba = wa^2 dt I

(``sg``, ``sa`` the noise densities, ``wg``, ``wa`` the random walks). The first four are
Forster's iterative noise propagation ``B Cov(eta_d) B^T`` (its appendix) with
``Cov(eta_d) = Cov(eta) / dt``, written in the world-frame velocity and position used here; the
bias walk is that of GTSAM's ``CombinedImuFactor`` (``Cov(eta_bd) = Cov(eta_b) dt``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vislam.ekf.errors import EstimationError
from vislam.ekf.filter import ImuSamples
from vislam.ekf.geometry import theta_coeffs_scalar
from vislam.ekf.inertial import ImuNoise

#: The error state's blocks, in order (3 each): rotation (body), velocity, position (world),
#: gyro bias, accelerometer bias.
ERROR_STATE = ("rotation", "velocity", "position", "gyro_bias", "accel_bias")
ROT, VEL, POS, BG, BA = (slice(3 * i, 3 * i + 3) for i in range(5))
N_ERROR = 15

_I3 = np.eye(3)


@dataclass(frozen=True)
class NavState:
    """The integrated state (module docstring): ``R`` (3, 3), ``v``, ``p``, ``bg``, ``ba`` (3,)."""

    R: np.ndarray
    v: np.ndarray
    p: np.ndarray
    bg: np.ndarray
    ba: np.ndarray

    @property
    def pose(self) -> np.ndarray:
        """``world_T_imu`` (4, 4)."""
        T = np.eye(4)
        T[:3, :3] = self.R
        T[:3, 3] = self.p
        return T

    def retract(self, dx: np.ndarray) -> NavState:
        """The state moved by an error-state vector ``dx`` (15,) (module docstring)."""
        dx = np.asarray(dx, dtype=float)
        return NavState(self.R @ exp_and_right_jacobian(dx[ROT])[0], self.v + dx[VEL],
                        self.p + dx[POS], self.bg + dx[BG], self.ba + dx[BA])


def exp_and_right_jacobian(phi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``Exp(phi)`` and the right Jacobian ``Jr(phi)`` of SO(3) (one vector; closed form,
    series near zero): ``Exp(phi + d) ~ Exp(phi) Exp(Jr(phi) d)``."""
    x, y, z = float(phi[0]), float(phi[1]), float(phi[2])
    A, B, C = theta_coeffs_scalar(math.sqrt(x * x + y * y + z * z))
    W = _hat(x, y, z)
    W2 = W @ W
    return _I3 + A * W + B * W2, _I3 - B * W + C * W2


def _hat(x: float, y: float, z: float) -> np.ndarray:
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def step(state: NavState, gyro: np.ndarray, accel: np.ndarray, dt: float,
         g_world: np.ndarray) -> NavState:
    """One step of the discrete scheme (module docstring)."""
    dR = exp_and_right_jacobian((gyro - state.bg) * dt)[0]
    acc = g_world + state.R @ (accel - state.ba)
    return NavState(state.R @ dR, state.v + acc * dt, state.p + state.v * dt + 0.5 * dt * dt * acc,
                    state.bg, state.ba)


def step_jacobian(state: NavState, gyro: np.ndarray, accel: np.ndarray, dt: float
                  ) -> np.ndarray:
    """``F`` (15, 15) of one step (module docstring)."""
    dR, Jr = exp_and_right_jacobian((gyro - state.bg) * dt)
    return _jacobian(state.R, dR, Jr, accel - state.ba, dt)


def _jacobian(R, dR, Jr, a, dt) -> np.ndarray:
    F = np.eye(N_ERROR)
    A = R @ _hat(float(a[0]), float(a[1]), float(a[2]))
    F[ROT, ROT] = dR.T
    F[ROT, BG] = -Jr * dt
    F[VEL, ROT] = -A * dt
    F[VEL, BA] = -R * dt
    F[POS, ROT] = -0.5 * dt * dt * A
    F[POS, VEL] = _I3 * dt
    F[POS, BA] = -0.5 * dt * dt * R
    return F


def step_noise(Jr: np.ndarray, dt: float, noise: ImuNoise) -> np.ndarray:
    """``Q`` (15, 15) of one step of length ``dt`` (module docstring); ``Jr`` the right
    Jacobian of the step's rotation."""
    Q = _noise_without_rotation(dt, noise)
    Q[ROT, ROT] = noise.gyro_noise_density ** 2 * dt * (Jr @ Jr.T)
    return Q


def _noise_without_rotation(dt: float, noise: ImuNoise) -> np.ndarray:
    Q = np.zeros((N_ERROR, N_ERROR))
    sa2 = noise.accel_noise_density ** 2
    Q[VEL, VEL] = sa2 * dt * _I3
    Q[VEL, POS] = Q[POS, VEL] = 0.5 * sa2 * dt * dt * _I3
    Q[POS, POS] = 0.25 * sa2 * dt ** 3 * _I3
    Q[BG, BG] = noise.gyro_random_walk ** 2 * dt * _I3
    Q[BA, BA] = noise.accel_random_walk ** 2 * dt * _I3
    return Q


def held_pieces(time: np.ndarray, t0: float, t1: float) -> list[tuple[int, float]]:
    """The scheme's pieces of ``[t0, t1]``: ``(j, dt)`` for each sample ``j`` held from
    ``max(t_j, t0)`` until ``min(t_j+1, t1)`` (the last one until ``t1``), pieces of zero
    length left out. The rule of every raw-IMU estimator: this integration and the smoother's
    preintegration (:func:`graph.inertial_factors.preintegrate`). Only the samples from the last
    one at or before ``t0`` to the last one before ``t1`` are read (two binary searches), so a
    whole drive's stream may be passed for each interval. EstimationError when no sample is at
    or before ``t0``."""
    time = np.asarray(time, dtype=float)
    if time.size == 0 or time[0] > t0:
        first = "none" if time.size == 0 else f"the first at {time[0]:.6f} s"
        raise EstimationError(f"strapdown: no IMU sample at or before t={t0:.6f} s ({first})")
    lo = int(np.searchsorted(time, t0, side="right")) - 1
    hi = max(int(np.searchsorted(time, t1, side="left")), lo + 1)
    last = time.size - 1
    pieces = []
    for j in range(lo, hi):
        end = time[j + 1] if j < last else t1
        dt = float(min(end, t1) - max(time[j], t0))
        if dt > 0:
            pieces.append((j, dt))
    return pieces


def integrate(state: NavState, P: np.ndarray | None, imu: ImuSamples, t0: float, t1: float,
              g_world: np.ndarray, noise: ImuNoise | None = None
              ) -> tuple[NavState, np.ndarray | None]:
    """The state (and covariance ``P`` (15, 15), when given) carried from ``t0`` to ``t1``
    over the samples ``imu``: the first sample at or before ``t0`` (as
    :meth:`ekf.inertial.InertialDrive.imu_between` gives them), each held until the next one
    or ``t1`` (:func:`held_pieces`). ``noise`` is needed with ``P``. EstimationError when no
    sample is at or before ``t0``."""
    state, P, _ = _carry(state, P, imu, t0, t1, g_world, noise, transition=False)
    return state, P


def integrate_with_transition(state: NavState, P: np.ndarray, imu: ImuSamples, t0: float,
                              t1: float, g_world: np.ndarray, noise: ImuNoise
                              ) -> tuple[NavState, np.ndarray, np.ndarray]:
    """:func:`integrate` with the covariance, and the interval's transition ``Phi = F_n ... F_1``
    (15, 15) beside it (the raw-IMU EKFs move their cross-covariances by it once per frame:
    :mod:`ekf.imu_propagation`)."""
    return _carry(state, P, imu, t0, t1, g_world, noise, transition=True)


def _carry(state: NavState, P: np.ndarray | None, imu: ImuSamples, t0: float, t1: float,
           g_world: np.ndarray, noise: ImuNoise | None, transition: bool
           ) -> tuple[NavState, np.ndarray | None, np.ndarray | None]:
    R, v, p, bg, ba = state.R, state.v, state.p, state.bg, state.ba
    Phi = np.eye(N_ERROR) if transition else None
    q_cache: dict[float, np.ndarray] = {}
    sg2 = 0.0 if noise is None else noise.gyro_noise_density ** 2
    for j, dt in held_pieces(imu.time, t0, t1):
        dR, Jr = exp_and_right_jacobian((imu.gyro[j] - bg) * dt)
        a = imu.accel[j] - ba
        acc = g_world + R @ a
        if P is not None:
            F = _jacobian(R, dR, Jr, a, dt)
            Q = q_cache.get(dt)
            if Q is None:
                Q = q_cache[dt] = _noise_without_rotation(dt, noise)
            P = F @ P @ F.T + Q
            P[ROT, ROT] += sg2 * dt * (Jr @ Jr.T)
            if transition:
                Phi = F @ Phi
        p = p + v * dt + 0.5 * dt * dt * acc
        v = v + acc * dt
        R = R @ dR
    return NavState(R, v, p, bg, ba), P, Phi
