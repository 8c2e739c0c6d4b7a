"""The initial state of a raw-IMU drive: from a rest at its start, or given.

Rest detection (:func:`detect_rest`). From a start time (a drive's frame 0) the IMU stream is cut
into windows of ``window_s``; the rest is the leading run of windows whose mean accelerometer and
mean gyro stay within ``accel_mean_tol`` (m/s^2) and ``gyro_mean_tol`` (rad/s, both as the norm
of the difference) of the mean of the rest so far. Window means, not the spread inside a window:
a drone standing with its motors running (EuRoC V1_01's first seconds: accelerometer spread
0.7-1.5 m/s^2 within a window, window means steady to 0.05 m/s^2) is at rest for initialisation.
The last ``margin_windows`` windows of the run are left out (the motion starts slowly inside
them). A rest shorter than ``min_rest_s`` is an EstimationError saying that the drive cannot be
initialised from a rest (give an initial state instead).

Initial state from the rest (:func:`rest_initial_state`), with ``f`` and ``w`` the mean
accelerometer and gyro over the rest (``n`` samples, ``T`` seconds), ``u = f / |f|`` (the body's
up direction) and ``g`` the calibration's gravity magnitude:

* orientation: the rotation of smallest angle with ``R u = e_z`` (world z up). The world's yaw is
  therefore the IMU's at the start, levelled; its origin the IMU's position at the initial time;
* velocity zero, position zero;
* gyro bias ``w``; accelerometer bias ``(|f| - g) u`` (its component along gravity, which the
  magnitude of gravity makes observable; the horizontal components cannot be told from a tilt
  and stay at zero);
* covariance, to first order: with ``ba`` the true bias (prior sigma ``accel_bias_sigma`` per axis)
  and ``n`` the mean accelerometer noise (variance ``accel_noise_density^2 / T``), the tilt error
  is ``dth = [u]x (ba + n) / g`` (its yaw part is zero: the world's yaw is defined by it) and the
  bias error ``dba = (I - u u^T) ba - u u^T n``, so their covariance (with the cross terms)
  follows exactly; the gyro bias error has variance ``gyro_noise_density^2 / T +
  gyro_random_walk^2 T`` (the mean's noise, and the walk over the rest); velocity sigma
  ``velocity_sigma``; position and yaw are the gauge, with sigmas ``position_sigma`` (1e-3 m)
  and ``yaw_sigma`` (1e-4 rad about gravity), the initial sigmas of the velocity-driven filters
  (:class:`ekf.config.FilterConfig`), so that frame 0's covariance is not singular.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vislam.ekf.errors import EstimationError, InputError
from vislam.ekf.filter import ImuSamples
from vislam.ekf.geometry import hat, so3_exp
from vislam.ekf.inertial import ACCEL_TURN_ON_BIAS_SIGMA, ImuNoise
from vislam.ekf.strapdown import BA, BG, N_ERROR, POS, ROT, VEL, NavState


@dataclass(frozen=True)
class RestConfig:
    """Settings of the rest detection and of the rest's initial state (module docstring)."""

    window_s: float = 0.2
    accel_mean_tol: float = 0.2
    gyro_mean_tol: float = 0.015
    margin_windows: int = 2
    min_rest_s: float = 0.4
    accel_bias_sigma: float = ACCEL_TURN_ON_BIAS_SIGMA
    velocity_sigma: float = 0.0
    position_sigma: float = 1e-3
    yaw_sigma: float = 1e-4

    def __post_init__(self) -> None:
        for key in ("window_s", "accel_mean_tol", "gyro_mean_tol", "min_rest_s"):
            value = getattr(self, key)
            if not np.isfinite(value) or value <= 0:
                raise InputError(f"rest initialisation: {key} must be positive, got {value!r}")
        for key in ("accel_bias_sigma", "velocity_sigma", "position_sigma", "yaw_sigma"):
            value = getattr(self, key)
            if not np.isfinite(value) or value < 0:
                raise InputError(f"rest initialisation: {key} must be >= 0, got {value!r}")
        if not isinstance(self.margin_windows, (int, np.integer)) or self.margin_windows < 0:
            raise InputError(f"rest initialisation: margin_windows must be an integer >= 0, "
                             f"got {self.margin_windows!r}")


@dataclass(frozen=True)
class Rest:
    """A rest: from ``start`` to ``end`` (s, the drive's times)."""

    start: float
    end: float


@dataclass(frozen=True)
class InitialState:
    """A state and its error-state covariance (15, 15; :mod:`ekf.strapdown`) at ``time``; how
    it was made (``source``: ``"rest"`` or ``"given"``) and the rest it was made from."""

    time: float
    state: NavState
    cov: np.ndarray
    source: str = "given"
    rest: Rest | None = None

    def info(self, now: NavState) -> dict:
        """A raw-IMU estimator's ``info`` entries on how it started and where it ended
        (``now``: its state after the last frame)."""
        return {
            "initialisation": self.source,
            "initial_time_s": self.time,
            "rest_s": None if self.rest is None else [self.rest.start, self.rest.end],
            "world_frame": "gravity-aligned, z up",
            "final_velocity": now.v.tolist(),
            "final_gyro_bias": now.bg.tolist(),
            "final_accel_bias": now.ba.tolist(),
        }


def detect_rest(imu: ImuSamples, config: RestConfig = RestConfig(), start: float | None = None
                ) -> Rest:
    """The rest from ``start`` (None: the first sample; module docstring)."""
    t = np.asarray(imu.time, dtype=float)
    t_start = float(t[0] if start is None else start)
    i0 = max(int(np.searchsorted(t, t_start, side="right")) - 1, 0)
    t, accel, gyro = t[i0:], imu.accel[i0:], imu.gyro[i0:]
    if t.size < 2:
        raise EstimationError(f"rest initialisation: fewer than two IMU samples from "
                              f"t={t_start:.3f} s")
    window = np.floor((t - t[0]) / config.window_s).astype(np.int64)
    n_windows = int(window[-1])  # the last, possibly partial, window is not judged
    a_sum, w_sum, count = np.zeros(3), np.zeros(3), 0
    end, why = n_windows, "the IMU never moves"
    for k in range(n_windows):
        m = window == k
        if not m.any():
            continue
        a_mean, w_mean = accel[m].mean(axis=0), gyro[m].mean(axis=0)
        if count:
            da = float(np.linalg.norm(a_mean - a_sum / count))
            dw = float(np.linalg.norm(w_mean - w_sum / count))
            if da > config.accel_mean_tol or dw > config.gyro_mean_tol:
                end = k
                why = (f"from {t[0] + k * config.window_s:.2f} s the mean accelerometer moves "
                       f"{da:.3g} m/s^2 and the mean gyro {dw:.3g} rad/s")
                break
        a_sum += a_mean
        w_sum += w_mean
        count += 1
    rest_end = t[0] + max(end - config.margin_windows, 0) * config.window_s
    if rest_end - t[0] < config.min_rest_s:
        raise EstimationError(
            f"rest initialisation: the drive cannot be initialised from a rest at "
            f"t={t[0]:.2f} s: the rest lasts {rest_end - t[0]:.2f} s (less {config.margin_windows} "
            f"margin windows), under {config.min_rest_s:g} s ({why}); give an initial state")
    return Rest(float(t[0]), float(rest_end))


def level_rotation(u: np.ndarray) -> np.ndarray:
    """The rotation of smallest angle taking the unit vector ``u`` to ``e_z``."""
    ez = np.array([0.0, 0.0, 1.0])
    axis = np.cross(u, ez)
    s, c = np.linalg.norm(axis), float(u @ ez)
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    return so3_exp(axis / s * np.arctan2(s, c))


def rest_initial_state(imu: ImuSamples, time: float, gravity: float, noise: ImuNoise,
                       config: RestConfig = RestConfig(), rest: Rest | None = None
                       ) -> InitialState:
    """The initial state at ``time`` from the rest that starts there (module docstring);
    ``rest`` as :func:`detect_rest` finds it from ``time`` when not given. EstimationError
    when ``time`` is outside the rest."""
    if rest is None:
        rest = detect_rest(imu, config, time)
    t = np.asarray(imu.time, dtype=float)
    if not rest.start <= time <= rest.end:
        raise EstimationError(f"rest initialisation: the initial time {time:.3f} s is outside "
                              f"the rest [{rest.start:.3f}, {rest.end:.3f}] s")
    m = (t >= rest.start) & (t <= rest.end)
    if m.sum() < 2:
        raise EstimationError(f"rest initialisation: fewer than two IMU samples in the rest "
                              f"[{rest.start:.3f}, {rest.end:.3f}] s")
    T = float(t[m][-1] - t[m][0]) + float(np.median(np.diff(t[m])))
    f = imu.accel[m].mean(axis=0)
    w = imu.gyro[m].mean(axis=0)
    u = f / np.linalg.norm(f)
    R = level_rotation(u)
    ba = (np.linalg.norm(f) - gravity) * u
    state = NavState(R, np.zeros(3), np.zeros(3), w, ba)

    par = np.outer(u, u)
    A = hat(u) / gravity
    J = np.zeros((N_ERROR, 6))  # error state <- [true accel bias, mean accel noise]
    J[ROT] = np.hstack([A, A])
    J[BA] = np.hstack([np.eye(3) - par, -par])
    S = np.diag([config.accel_bias_sigma ** 2] * 3 + [noise.accel_noise_density ** 2 / T] * 3)
    P = J @ S @ J.T
    P[BG, BG] = (noise.gyro_noise_density ** 2 / T + noise.gyro_random_walk ** 2 * T) * np.eye(3)
    P[VEL, VEL] = config.velocity_sigma ** 2 * np.eye(3)
    P[POS, POS] = config.position_sigma ** 2 * np.eye(3)
    P[ROT, ROT] += config.yaw_sigma ** 2 * par  # a world-yaw turn is a body turn about u
    return InitialState(float(time), state, P, "rest", rest)
