"""The per-frame filter protocol: what a filter does at each camera frame, and what it is given.

A filter is an object with filterpy's verbs, driven frame by frame by one loop,
:func:`ekf.driver.run_filter` (as kiss-icp's pipeline drives ``register_frame``)::

    filter.initialise(seq, config, guard)          # once, before frame 0
    for t in range(T):
        if t > 0:
            filter.predict(motion[t])              # MotionInput of the interval [t-1, t]
        counts = filter.update(frame[t])           # FrameObservations of frame t
        filter.marginalise(ended[t])               # tracks whose last observation is frame t
        pose[t], pose_cov[t] = filter.pose(), filter.pose_cov()
    landmarks = filter.landmark_map() + filter.active_landmarks()

so ``predict`` is called ``T - 1`` times, ``update`` and ``marginalise`` ``T`` times each.

**Conventions** (DESIGN.md, :mod:`ekf.conventions`). ``pose()`` is ``world_T_imu`` (4, 4), the world
frame being the IMU frame at frame 0; ``pose_cov()`` (6, 6) the covariance of the right
perturbation ``world_T_imu_true = world_T_imu @ se3_exp(xi)``, ``xi = [rho; phi]`` translation
first (m, rad). Landmarks are world points (m) with 3x3 covariances. A filter keeps its state in
whatever form it likes (the EKFs hold ``imu_T_world`` or a group element) and converts in its
read-outs.

**Motion input.** Each interval between two camera frames comes as one :class:`MotionInput`:
its length ``dt`` and the body twist ``[v; w]`` that velocity-driven filters integrate (paired
from the sequence's per-frame velocities by ``FilterConfig.velocity_pairing``). Raw inertial
samples inside the interval (accelerometer and gyro at a higher rate than the camera) travel in
the same object as an :class:`ImuSamples` block, so an inertial filter uses the same loop, the same
``predict`` call per interval, and integrates the block itself; a filter that needs them checks
``motion.imu is not None``. The driver builds every MotionInput from the drive: from a
velocity drive (:class:`ekf.sequence.Sequence`) its twists, ``imu`` None; from a raw-IMU drive
(:class:`ekf.inertial.InertialDrive`) its samples (how an interval's samples are cut:
:func:`ekf.driver.inertial_motion_inputs`), ``start`` and ``end`` the interval's frame times,
``twist`` NaN (none).

**Observations.** ``FrameObservations.z`` holds the frame's pixels as the drive has them: four
columns ``[uL, vL, uR, vR]`` for a stereo drive (every velocity drive), two ``[u, v]`` for a
monocular raw-IMU drive. A raw-IMU filter's ``initialise`` is given the InertialDrive.

**Numerical failures** (:mod:`ekf.numerics`). An update that cannot be computed is rejected with
``guard.reject(t, why, n)`` and the state kept; a failure that cannot be rejected (a pose or
covariance not finite after a prediction) raises ``guard.error(t, why)``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol, runtime_checkable

import numpy as np

if TYPE_CHECKING:
    from vislam.ekf.config import FilterConfig
    from vislam.ekf.numerics import NumericalGuard
    from vislam.ekf.sequence import Sequence


@dataclass(frozen=True)
class ImuSamples:
    """Raw inertial samples inside one interval ``(t_k, t_k+1]``, IMU frame, SI units.

    ``time`` (n,) s, increasing; ``accel`` (n, 3) specific force, m/s^2; ``gyro`` (n, 3) angular
    rate, rad/s. The driver fills it on raw-IMU drives only (velocity drives: ``None``); its
    cut at the interval's ends: :func:`ekf.driver.inertial_motion_inputs`."""

    time: np.ndarray
    accel: np.ndarray
    gyro: np.ndarray


@dataclass(frozen=True)
class MotionInput:
    """The motion between frames ``frame - 1`` and ``frame``: what one ``predict`` consumes.

    ``dt`` the interval's length (s, > 0); ``twist`` (6,) the body twist ``[v (m/s); w (rad/s)]``
    held over the interval (paper eq. 4: ``U <- exp(-dt twist^) U``; NaN on a raw-IMU drive);
    ``imu`` the raw samples of the interval, or None when the drive has none; ``start`` and
    ``end`` the interval's frame times (s; raw-IMU drives, None otherwise), which the samples
    are integrated between (:func:`ekf.driver.inertial_motion_inputs`)."""

    frame: int
    dt: float
    twist: np.ndarray
    imu: ImuSamples | None = None
    start: float | None = None
    end: float | None = None


@dataclass(frozen=True)
class FrameObservations:
    """One camera frame's observations: what one ``update`` consumes.

    ``tracks`` (n,) track indices (rows of the Estimate's landmarks), ``z`` (n, 4) stereo pixels
    ``[uL, vL, uR, vR]`` or, on a monocular raw-IMU drive, (n, 2) pixels ``[u, v]``; ``frame``
    the frame index and ``time`` its time stamp (s)."""

    frame: int
    time: float
    tracks: np.ndarray
    z: np.ndarray


@dataclass(frozen=True)
class UpdateCounts:
    """What an update did with a frame's observations (the Estimate's per-frame counters):
    used to update the state, rejected (gated out, invalid, numerically unusable), and
    landmarks initialised from them."""

    n_updates: int = 0
    n_rejected: int = 0
    n_initialised: int = 0


@dataclass(frozen=True)
class Landmarks:
    """World landmarks of some tracks: ``tracks`` (k,), ``mean`` (k, 3) m, ``cov`` (k, 3, 3)."""

    tracks: np.ndarray
    mean: np.ndarray
    cov: np.ndarray

    @classmethod
    def none(cls) -> "Landmarks":
        return cls(np.zeros(0, dtype=np.int64), np.zeros((0, 3)), np.zeros((0, 3, 3)))


@runtime_checkable
class Filter(Protocol):
    """A per-frame filter (module docstring). ``name`` labels its Estimate and its errors."""

    name: str

    def initialise(self, seq: "Sequence", config: "FilterConfig", guard: "NumericalGuard") -> None:
        """Start at frame 0: pose identity with ``config.initial_pose_cov``, no landmarks.
        ``seq`` is the sequence as the driver runs it (validated, cleaned when
        ``config.clean_tracks``): calibration, number of tracks, track ends. On a raw-IMU
        drive ``seq`` is the :class:`ekf.inertial.InertialDrive` (tracks carried, not cleaned)
        and the world frame is the filter's (vislam's: gravity-aligned, z up)."""

    def predict(self, motion: MotionInput) -> None:
        """Propagate the state over one interval (``motion.frame`` the frame it ends at)."""

    def update(self, frame: FrameObservations) -> UpdateCounts:
        """Use frame ``frame.frame``'s observations: update with those of known landmarks,
        initialise new ones."""

    def marginalise(self, tracks: np.ndarray) -> None:
        """``tracks`` (sorted) made their last observation at the frame just updated: their
        landmarks leave the active state for the map (or stay, if the filter keeps them)."""

    def pose(self) -> np.ndarray:
        """``world_T_imu`` (4, 4) now."""

    def pose_cov(self) -> np.ndarray:
        """Covariance (6, 6) of ``pose()``'s right perturbation, translation first."""

    def active_landmarks(self) -> Landmarks:
        """Landmarks in the state now (tracks not yet marginalised)."""

    def landmark_map(self) -> tuple[np.ndarray, np.ndarray]:
        """Means (n_tracks, 3) and covariances (n_tracks, 3, 3) of the marginalised tracks'
        landmarks, NaN elsewhere (new arrays: the caller may write into them)."""

    def info(self) -> dict:
        """Entries for ``Estimate.info`` (JSON-able), read once after the last frame."""


#: The methods a :class:`Filter` has (besides its ``name``).
FILTER_METHODS = ("initialise", "predict", "update", "marginalise", "pose", "pose_cov",
                  "active_landmarks", "landmark_map", "info")


def is_filter_class(obj) -> bool:
    """Whether ``obj`` is a class with every method of the :class:`Filter` protocol."""
    return isinstance(obj, type) and all(callable(getattr(obj, m, None)) for m in FILTER_METHODS)
