"""Dead reckoning: the pose EKF's prediction alone (paper eq. 11), the paper's first result set.

:class:`DeadReckoning` is also the pose half that :class:`ekf.mapping.Mapping` and
:class:`ekf.decoupled.DecoupledEKF` build on: the state is the inverse pose ``U = imu_T_world``
with its 6x6 covariance ``Sigma`` in the EKF convention (``U_true = exp(d^) U``).

With ``config.speed_scale`` the velocities' slow speed-scale error ``s`` (``v_true = (1 + s)
v``, a random walk) is a state too: nothing observes it, so its mean stays 0, but its variance
grows and reaches the pose through the prediction's coupling
(:func:`ekf.prediction.error_state_transition`), so that the pose covariance holds a slow speed
error the white velocity noise cannot (a position error growing with the distance driven).
``Sigma`` is then the pose block of the 7x7 ``P``. :class:`ekf.decoupled.DecoupledEKF`, which
updates ``Sigma`` with vision, does not carry it (``carries_speed_scale``).
"""

from __future__ import annotations

import numpy as np

from vislam.ekf.config import FilterConfig
from vislam.ekf.conventions import ekf_cov_to_estimate
from vislam.ekf.driver import run_filter
from vislam.ekf.estimate import Estimate
from vislam.ekf.filter import FrameObservations, Landmarks, MotionInput, UpdateCounts
from vislam.ekf.geometry import se3_inv
from vislam.ekf.numerics import NumericalGuard
from vislam.ekf.prediction import (error_state_transition, predict_mean, predict_pose, process_noise,
                                  twist_error_matrix)
from vislam.ekf.runner import Progress
from vislam.ekf.sequence import Sequence


class DeadReckoning:
    """Prediction only: ``U <- exp(-tau u^) U``, ``Sigma <- F Sigma F^T + tau^2 W``.

    A pose or covariance that is not finite after a prediction (an absurd but finite twist or
    time step) is an EstimationError naming the frame."""

    name = "dead-reckoning"
    #: Whether ``config.speed_scale`` adds the speed-scale state (module docstring).
    carries_speed_scale = True

    def initialise(self, seq: Sequence, config: FilterConfig, guard: NumericalGuard) -> None:
        self.config = config
        self.guard = guard
        self.n_tracks = seq.n_tracks
        self.W = config.velocity_cov
        self.U, self.Sigma = np.eye(4), config.initial_pose_cov
        #: [pose; scale] covariance with a speed-scale state, else None
        self.P = None
        if config.speed_scale and self.carries_speed_scale:
            self.P = np.zeros((7, 7))
            self.P[:6, :6] = self.Sigma
            self.P[6, 6] = config.speed_scale_sigma**2
        guard.check_state(0, self.U, self.Sigma)

    def predict(self, motion: MotionInput) -> None:
        if self.P is None:
            self.U, self.Sigma = predict_pose(self.U, self.Sigma, motion.dt, motion.twist, self.W)  # eq. 11
        else:  # eq. 11 with the scale's column (its mean stays 0: nothing observes it)
            tau, u = motion.dt, motion.twist
            B = twist_error_matrix(u, False, True)
            u_c, Phi, _ = error_state_transition(tau, u, np.zeros(1), B)
            self.U = predict_mean(self.U, tau, u_c)
            P = Phi @ self.P @ Phi.T
            P[:6, :6] += process_noise(tau, self.W)
            P[6, 6] += self.config.speed_scale_walk**2 * tau
            self.P = 0.5 * (P + P.T)
            self.Sigma = self.P[:6, :6]
        self.guard.check_state(motion.frame, self.U, self.Sigma)

    def update(self, frame: FrameObservations) -> UpdateCounts:
        return UpdateCounts()

    def marginalise(self, tracks: np.ndarray) -> None:
        pass

    def pose(self) -> np.ndarray:
        return se3_inv(self.U)

    def pose_cov(self) -> np.ndarray:
        return ekf_cov_to_estimate(self.Sigma)

    def active_landmarks(self) -> Landmarks:
        return Landmarks.none()

    def landmark_map(self) -> tuple[np.ndarray, np.ndarray]:
        return np.full((self.n_tracks, 3), np.nan), np.full((self.n_tracks, 3, 3), np.nan)

    def info(self) -> dict:
        if self.P is None:
            return {}
        return {"speed_scale": 0.0, "speed_scale_sigma_final": float(np.sqrt(self.P[6, 6]))}


def run_dead_reckoning(
    seq: Sequence, config: FilterConfig = FilterConfig(), progress: Progress = None
) -> Estimate:
    """:class:`DeadReckoning` over ``seq`` (:func:`ekf.driver.run_filter`)."""
    return run_filter(DeadReckoning(), seq, config, progress)
