"""Smooth 6-DoF trajectories with analytic derivatives, for the raw-IMU simulator.

Each trajectory gives, at any times ``t``, the IMU's pose ``world_T_imu``, its world velocity and
acceleration and its body angular rate, all from closed forms (no numerical differentiation), so
the simulated IMU (:mod:`eval.imu_sim`) is the trajectory's own derivative.

World frame: gravity-aligned, **z up** (gravity along world -z). IMU body frame: x forward,
y left, z up. Orientation is Z-Y-X Euler, ``R = Rz(yaw) Ry(pitch) Rx(roll)``, and the body
angular rate follows from the Euler rates exactly::

    w_body = [roll' - yaw' sin(pitch),
              pitch' cos(roll) + yaw' sin(roll) cos(pitch),
              -pitch' sin(roll) + yaw' cos(roll) cos(pitch)]

Rest, then motion. Every trajectory is a path ``f(s)`` (position and Euler angles as functions of
a path time ``s``) run through a time warp ``s = tau(t)``: ``tau = 0`` for ``t <= rest_s`` (the
rig stands still: an estimator initialises gravity and the gyro bias there), then ``tau'``
rises from 0 to 1 over ``ramp_s`` seconds along the quintic smoothstep ``6x^5 - 15x^4 + 10x^3``
(so acceleration is continuous), then ``tau' = 1``. Chain rule: ``p = f(tau)``,
``v = f'(tau) tau'``, ``a = f''(tau) tau'^2 + f'(tau) tau''``, Euler rates ``e'(tau) tau'``.

Scenarios (every amplitude, frequency and phase drawn from the seed):

* ``room``: a drone in a 10 x 8 x 3 m room (world origin at the centre of the floor, x along the
  room's long walls): within about 2.5 m of the centre horizontally, 0.6-2.4 m high, yaw
  sweeping through about +-2 rad plus a slow turn, roll and pitch up to about 0.3 rad.
* ``handheld``: a rig carried through the same room at walking pace: a 1.5 m loop at 1.3 m
  height with the 2 Hz bob of steps, yaw +-1.2 rad, roll and pitch up to about 0.35 rad.
* ``road``: a car on a road along world x from the origin: about 10 m/s, curves that swing
  the heading through about +-30 degrees (the heading follows the path's tangent, as a car's
  does), gentle hills (z within +-1 m), roll and pitch within about 1.5 degrees.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Scenarios :func:`make_trajectory` knows.
SCENARIOS = ("room", "handheld", "road")

#: Default ramp (s) from rest to full motion per scenario: a car takes longer to reach speed.
DEFAULT_RAMP_S = {"room": 1.0, "handheld": 1.0, "road": 5.0}

#: The room of the ``room`` and ``handheld`` scenarios: half extents x, y and the height (m).
ROOM_HALF_X, ROOM_HALF_Y, ROOM_HEIGHT = 5.0, 4.0, 3.0


@dataclass(frozen=True)
class TrajectoryPoint:
    """The trajectory at ``n`` times: ``R`` (n, 3, 3) world_R_imu, ``p`` (n, 3) m, ``v`` (n, 3)
    m/s and ``a`` (n, 3) m/s^2 in the world frame, ``w`` (n, 3) rad/s the body angular rate."""

    R: np.ndarray
    p: np.ndarray
    v: np.ndarray
    a: np.ndarray
    w: np.ndarray

    @property
    def poses(self) -> np.ndarray:
        """``world_T_imu`` (n, 4, 4)."""
        T = np.zeros((self.p.shape[0], 4, 4))
        T[:, :3, :3] = self.R
        T[:, :3, 3] = self.p
        T[:, 3, 3] = 1.0
        return T


@dataclass(frozen=True)
class Sinusoids:
    """``offset + rate s + sum_i amp_i sin(freq_i s + phase_i)`` per column, with its
    derivatives; ``amp``, ``freq``, ``phase`` (k, d), ``offset`` and ``rate`` (d,)."""

    offset: np.ndarray
    rate: np.ndarray
    amp: np.ndarray
    freq: np.ndarray
    phase: np.ndarray

    def __call__(self, s: np.ndarray, order: int = 0) -> np.ndarray:
        s = np.asarray(s, dtype=float)[:, None, None]
        arg = self.freq * s + self.phase
        if order == 0:
            return self.offset + self.rate * s[:, 0] + np.sum(self.amp * np.sin(arg), axis=1)
        if order == 1:
            return self.rate + np.sum(self.amp * self.freq * np.cos(arg), axis=1)
        if order == 2:
            return -np.sum(self.amp * self.freq**2 * np.sin(arg), axis=1)
        raise ValueError(f"order {order} not supported")


@dataclass(frozen=True)
class TimeWarp:
    """``tau(t)``: zero up to ``rest_s``, then a quintic ramp of ``tau'`` over ``ramp_s``
    (module docstring). Returns ``(tau, tau', tau'')``."""

    rest_s: float
    ramp_s: float

    def __call__(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        t = np.asarray(t, dtype=float)
        if self.ramp_s <= 0:
            after = t > self.rest_s
            return (np.where(after, t - self.rest_s, 0.0), after.astype(float), np.zeros_like(t))
        x = np.clip((t - self.rest_s) / self.ramp_s, 0.0, 1.0)
        d1 = x**3 * (10.0 - 15.0 * x + 6.0 * x**2)
        d2 = 30.0 * x**2 * (1.0 - x) ** 2 / self.ramp_s
        ramp = self.ramp_s * x**4 * (2.5 - 3.0 * x + x**2)
        tau = np.where(t > self.rest_s + self.ramp_s,
                       0.5 * self.ramp_s + (t - self.rest_s - self.ramp_s), ramp)
        return tau, d1, d2


def euler_rotation(yaw: np.ndarray, pitch: np.ndarray, roll: np.ndarray) -> np.ndarray:
    """``Rz(yaw) Ry(pitch) Rx(roll)`` (n, 3, 3)."""
    cy, sy, cp, sp, cr, sr = (np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch),
                              np.cos(roll), np.sin(roll))
    R = np.empty(np.shape(yaw) + (3, 3))
    R[..., 0, 0] = cy * cp
    R[..., 0, 1] = cy * sp * sr - sy * cr
    R[..., 0, 2] = cy * sp * cr + sy * sr
    R[..., 1, 0] = sy * cp
    R[..., 1, 1] = sy * sp * sr + cy * cr
    R[..., 1, 2] = sy * sp * cr - cy * sr
    R[..., 2, 0] = -sp
    R[..., 2, 1] = cp * sr
    R[..., 2, 2] = cp * cr
    return R


def euler_body_rate(pitch, roll, yaw_d, pitch_d, roll_d) -> np.ndarray:
    """Body angular rate (n, 3) of Z-Y-X Euler angles and their rates (module docstring)."""
    cp, sp, cr, sr = np.cos(pitch), np.sin(pitch), np.cos(roll), np.sin(roll)
    return np.stack([roll_d - yaw_d * sp,
                     pitch_d * cr + yaw_d * sr * cp,
                     -pitch_d * sr + yaw_d * cr * cp], axis=-1)


@dataclass(frozen=True)
class Trajectory:
    """A scenario's path (``position`` and ``euler`` [yaw, pitch, roll] in path time) under a
    :class:`TimeWarp`. ``heading_from_path``: the yaw is the direction of the path's horizontal
    tangent plus ``euler``'s yaw column (a car), instead of ``euler``'s yaw alone."""

    scenario: str
    position: Sinusoids
    euler: Sinusoids
    warp: TimeWarp
    heading_from_path: bool = False

    def __call__(self, t: np.ndarray) -> TrajectoryPoint:
        t = np.atleast_1d(np.asarray(t, dtype=float))
        s, s1, s2 = self.warp(t)
        f0, f1, f2 = self.position(s), self.position(s, 1), self.position(s, 2)
        e0, e1 = self.euler(s), self.euler(s, 1)
        if self.heading_from_path:
            dx, dy, ddx, ddy = f1[:, 0], f1[:, 1], f2[:, 0], f2[:, 1]
            e0 = e0.copy()
            e1 = e1.copy()
            e0[:, 0] += np.arctan2(dy, dx)
            e1[:, 0] += (dx * ddy - dy * ddx) / (dx * dx + dy * dy)
        p = f0
        v = f1 * s1[:, None]
        a = f2 * (s1**2)[:, None] + f1 * s2[:, None]
        rates = e1 * s1[:, None]
        R = euler_rotation(e0[:, 0], e0[:, 1], e0[:, 2])
        w = euler_body_rate(e0[:, 1], e0[:, 2], rates[:, 0], rates[:, 1], rates[:, 2])
        return TrajectoryPoint(R, p, v, a, w)


def _sinusoids(rng: np.random.Generator, amp, freq_range, offset, rate=(0.0, 0.0, 0.0),
               k: int = 2) -> Sinusoids:
    """``k`` sinusoids per column with amplitudes ``amp`` (d,) split at random between them,
    angular frequencies uniform in ``freq_range`` (rad/s) and uniform phases."""
    amp = np.asarray(amp, dtype=float)
    d = amp.size
    share = rng.dirichlet(np.ones(k), size=d).T  # (k, d), columns sum to 1
    freq = rng.uniform(*freq_range, size=(k, d))
    phase = rng.uniform(0.0, 2 * np.pi, size=(k, d))
    return Sinusoids(np.asarray(offset, float), np.asarray(rate, float), share * amp, freq, phase)


def _start_at(sin: Sinusoids, value: np.ndarray) -> Sinusoids:
    """The same sinusoids shifted so that ``sin(0) == value``."""
    return Sinusoids(sin.offset + value - sin(np.zeros(1))[0], sin.rate, sin.amp, sin.freq,
                     sin.phase)


def make_trajectory(scenario: str, seed: int, rest_s: float, ramp_s: float) -> Trajectory:
    """The scenario's trajectory for ``seed`` (module docstring)."""
    rng = np.random.default_rng([seed, 0x1A7])
    warp = TimeWarp(rest_s, ramp_s)
    if scenario == "room":
        pos = _sinusoids(rng, [2.2, 1.8, 0.6], (0.25, 0.7), [0.0, 0.0, 1.5])
        eul = _sinusoids(rng, [1.6, 0.25, 0.25], (0.3, 1.0), [0.0, 0.0, 0.0],
                         rate=[rng.choice([-1.0, 1.0]) * 0.15, 0.0, 0.0])
        return Trajectory(scenario, pos, eul, warp)
    if scenario == "handheld":
        loop = _sinusoids(rng, [1.0, 1.0, 0.15], (0.4, 0.9), [0.0, 0.0, 1.3])
        bob = Sinusoids(np.zeros(3), np.zeros(3), np.array([[0.0, 0.0, 0.02]]),
                        np.full((1, 3), 2 * np.pi * 2.0), rng.uniform(0, 2 * np.pi, (1, 3)))
        pos = Sinusoids(loop.offset, loop.rate, np.vstack([loop.amp, bob.amp]),
                        np.vstack([loop.freq, bob.freq]), np.vstack([loop.phase, bob.phase]))
        eul = _sinusoids(rng, [1.2, 0.3, 0.3], (0.5, 2.0), [0.0, 0.0, 0.0], k=3)
        return Trajectory(scenario, pos, eul, warp)
    if scenario == "road":
        speed = rng.uniform(8.0, 12.0)
        pos = _sinusoids(rng, [0.0, 50.0, 1.0], (0.1, 0.22), [0.0, 0.0, 0.0],
                         rate=[speed, 0.0, 0.0])
        pos = _start_at(pos, np.zeros(3))
        eul = _sinusoids(rng, [0.0, 0.02, 0.025], (0.2, 0.8), [0.0, 0.0, 0.0])
        return Trajectory(scenario, pos, eul, warp, heading_from_path=True)
    raise ValueError(f"unknown scenario {scenario!r}")
