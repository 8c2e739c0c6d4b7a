"""The initial state of a raw-IMU drive: from a rest at its start, or given.

Rest detection (:func:`detect_rest`). The IMU stream is cut into windows of ``window_s`` from its
first sample; the rest is the leading run of windows in which every axis of the accelerometer
and of the gyro varies by at most ``accel_std_max`` and ``gyro_std_max`` (standard deviation
within the window). The last window of the run is left out (the motion may start inside it).
A rest shorter than ``min_rest_s`` is an EstimationError saying that the drive cannot be
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
  ``velocity_sigma``; position and yaw zero (the gauge).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vislam.ekf.errors import EstimationError, InputError
from vislam.ekf.filter import ImuSamples
from vislam.ekf.geometry import hat, so3_exp
from vislam.ekf.inertial import ImuNoise
from vislam.ekf.strapdown import BA, BG, N_ERROR, ROT, VEL, NavState


@dataclass(frozen=True)
class RestConfig:
    """Settings of the rest detection and of the rest's initial state (module docstring)."""

    window_s: float = 0.2
    accel_std_max: float = 0.2
    gyro_std_max: float = 0.02
    min_rest_s: float = 0.4
    accel_bias_sigma: float = 0.05
    velocity_sigma: float = 0.0

    def __post_init__(self) -> None:
        for key in ("window_s", "accel_std_max", "gyro_std_max", "min_rest_s"):
            value = getattr(self, key)
            if not np.isfinite(value) or value <= 0:
                raise InputError(f"rest initialisation: {key} must be positive, got {value!r}")
        for key in ("accel_bias_sigma", "velocity_sigma"):
            value = getattr(self, key)
            if not np.isfinite(value) or value < 0:
                raise InputError(f"rest initialisation: {key} must be >= 0, got {value!r}")


@dataclass(frozen=True)
class InitialState:
    """A state and its error-state covariance (15, 15; :mod:`ekf.strapdown`) at ``time``; how
    it was made (``source``: ``"rest"`` or ``"given"``) and the rest's end where it was one."""

    time: float
    state: NavState
    cov: np.ndarray
    source: str = "given"
    rest_end: float | None = None


def detect_rest(imu: ImuSamples, config: RestConfig = RestConfig()) -> float:
    """The time the leading rest ends (module docstring)."""
    t = np.asarray(imu.time, dtype=float)
    if t.size < 2:
        raise EstimationError("rest initialisation: fewer than two IMU samples")
    window = np.floor((t - t[0]) / config.window_s).astype(np.int64)
    end = None
    n_windows = int(window[-1])  # the last, possibly partial, window is not judged
    for k in range(n_windows):
        m = window == k
        if m.sum() < 2:
            continue
        a_std, w_std = imu.accel[m].std(axis=0).max(), imu.gyro[m].std(axis=0).max()
        if a_std > config.accel_std_max or w_std > config.gyro_std_max:
            end = k
            why = (f"window {k} ({t[0] + k * config.window_s:.2f} s): accelerometer std "
                   f"{a_std:.3g} m/s^2, gyro std {w_std:.3g} rad/s")
            break
    else:
        end, why = n_windows, "the IMU never moves"
    rest_end = t[0] + max(end - 1, 0) * config.window_s
    if rest_end - t[0] < config.min_rest_s:
        raise EstimationError(
            f"rest initialisation: the drive cannot be initialised from a rest at its start: "
            f"the rest lasts {rest_end - t[0]:.2f} s, under {config.min_rest_s:g} s ({why}); "
            "give an initial state")
    return float(rest_end)


def level_rotation(u: np.ndarray) -> np.ndarray:
    """The rotation of smallest angle taking the unit vector ``u`` to ``e_z``."""
    ez = np.array([0.0, 0.0, 1.0])
    axis = np.cross(u, ez)
    s, c = np.linalg.norm(axis), float(u @ ez)
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    return so3_exp(axis / s * np.arctan2(s, c))


def rest_initial_state(imu: ImuSamples, time: float, gravity: float, noise: ImuNoise,
                       config: RestConfig = RestConfig(), rest_end: float | None = None
                       ) -> InitialState:
    """The initial state at ``time`` from the rest at the drive's start (module docstring);
    ``rest_end`` as :func:`detect_rest` finds it when not given. EstimationError when ``time``
    is after the rest."""
    if rest_end is None:
        rest_end = detect_rest(imu, config)
    t = np.asarray(imu.time, dtype=float)
    if time > rest_end:
        raise EstimationError(f"rest initialisation: the initial time {time:.3f} s is after the "
                              f"rest at the start (it ends at {rest_end:.3f} s)")
    m = t <= rest_end
    T = float(t[m][-1] - t[0]) + float(np.median(np.diff(t)))
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
    return InitialState(float(time), state, P, "rest", float(rest_end))
