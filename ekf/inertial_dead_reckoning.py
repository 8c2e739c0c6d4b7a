"""Dead reckoning on the raw IMU: strapdown integration (:mod:`ekf.strapdown`) from an initial
state (:mod:`ekf.imu_init`: a rest at the start, or given), with its propagated covariance, read
out at the camera frames as an :class:`ekf.estimate.Estimate`.

The Estimate's world frame for a raw-IMU drive is gravity-aligned, z up (not the IMU frame at
frame 0 as for a velocity drive). From a rest (looked for from frame 0 on:
:func:`ekf.imu_init.detect_rest`), its origin is the IMU's position at frame 0 and its yaw the
IMU's there, levelled; from a given state, the frame that state is written in. ``pose_cov[k]`` is
in the Estimate convention (right perturbation of ``world_T_imu``, translation first): with the
strapdown's world-frame position error ``dp`` and body rotation error ``dth``,
``xi = [R^T dp; dth]`` (first order). At frame 0 from a rest its position and yaw blocks are the
gauge's small sigmas (:class:`ekf.imu_init.RestConfig`).

When a given state's time is before frame 0 the state is integrated forward to frame 0 first.
``info`` holds the initialisation, the rest, the final velocity and biases, and the scheme.
"""

from __future__ import annotations

import time as _time
from dataclasses import dataclass

import numpy as np

from vislam.ekf.errors import EstimationError
from vislam.ekf.estimate import Estimate
from vislam.ekf.filter import ImuSamples
from vislam.ekf.imu_init import InitialState, RestConfig, detect_rest, rest_initial_state
from vislam.ekf.inertial import InertialDrive
from vislam.ekf.strapdown import N_ERROR, POS, ROT, NavState, integrate

#: Gravity direction of vislam's raw-IMU world frame (z up).
WORLD_GRAVITY_DIRECTION = np.array([0.0, 0.0, -1.0])


@dataclass(frozen=True)
class StrapdownTrack:
    """The dead-reckoned states at the camera frames: ``states`` (T,) and their error-state
    covariances ``cov`` (T, 15, 15) (:mod:`ekf.strapdown`), and the initial state used."""

    timestamps: np.ndarray
    states: tuple[NavState, ...]
    cov: np.ndarray
    initial: InitialState

    @property
    def poses(self) -> np.ndarray:
        return np.stack([s.pose for s in self.states])

    def pose_cov(self) -> np.ndarray:
        """(T, 6, 6) in the Estimate convention (module docstring)."""
        out = np.empty((len(self.states), 6, 6))
        for k, (s, P) in enumerate(zip(self.states, self.cov)):
            J = np.zeros((6, N_ERROR))
            J[:3, POS] = s.R.T
            J[3:, ROT] = np.eye(3)
            out[k] = J @ P @ J.T
        return out


def strapdown_frames(drive: InertialDrive, initial: InitialState | None = None,
                     rest: RestConfig = RestConfig()) -> StrapdownTrack:
    """Integrate the drive's IMU from ``initial`` (None: from the rest at the start) through
    every camera frame."""
    calib = drive.calibration
    g_world = calib.gravity * WORLD_GRAVITY_DIRECTION
    ts = np.asarray(drive.timestamps, dtype=float)
    if initial is None:
        found = detect_rest(drive.imu, rest, float(ts[0]))
        initial = rest_initial_state(drive.imu, float(ts[0]), calib.gravity, calib.noise, rest,
                                     found)
    if initial.time > ts[0]:
        raise EstimationError(f"dead reckoning: the initial state's time {initial.time:.6f} s is "
                              f"after frame 0 ({ts[0]:.6f} s)")
    imu_t = drive.imu.time
    state, P = initial.state, np.asarray(initial.cov, dtype=float)
    if initial.time < ts[0]:
        a = max(int(np.searchsorted(imu_t, initial.time, side="right")) - 1, 0)
        b = int(np.searchsorted(imu_t, ts[0], side="right"))
        block = ImuSamples(imu_t[a:b], drive.imu.accel[a:b], drive.imu.gyro[a:b])
        state, P = integrate(state, P, block, initial.time, float(ts[0]), g_world, calib.noise)
    states, covs = [state], [P]
    for k in range(1, ts.size):
        state, P = integrate(state, P, drive.imu_between(k), float(ts[k - 1]), float(ts[k]),
                             g_world, calib.noise)
        if not (np.all(np.isfinite(state.pose)) and np.all(np.isfinite(P))):
            raise EstimationError(f"dead reckoning: frame {k} (t={ts[k]:.2f} s): state or "
                                  "covariance not finite")
        states.append(state)
        covs.append(P)
    return StrapdownTrack(ts.copy(), tuple(states), np.stack(covs), initial)


def run_inertial_dead_reckoning(drive: InertialDrive, initial: InitialState | None = None,
                                rest: RestConfig = RestConfig()) -> Estimate:
    """:func:`strapdown_frames` read out as an Estimate (module docstring)."""
    start = _time.perf_counter()
    track = strapdown_frames(drive, initial, rest)
    elapsed = _time.perf_counter() - start
    est = Estimate.empty("dead-reckoning-imu", track.timestamps, drive.n_tracks)  # its registry name
    est.poses = track.poses
    est.pose_cov = track.pose_cov()
    est.step_time_s = np.full(track.timestamps.size, elapsed / track.timestamps.size)
    last = track.states[-1]
    est.info = {
        "numerical_rejections": 0,
        "numerical_rejection_frames": [],
        **track.initial.info(last),
        "scheme": "strapdown: exact SO(3) exponential per sample, second-order position",
    }
    est.check_finite()
    return est
