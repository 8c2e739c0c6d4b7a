"""Dead reckoning: the pose EKF's prediction alone (paper eq. 11), the paper's first result set.

:class:`DeadReckoning` is also the pose half that :class:`ekf.mapping.Mapping` and
:class:`ekf.decoupled.DecoupledEKF` build on: the state is the inverse pose ``U = imu_T_world``
with its 6x6 covariance ``Sigma`` in the EKF convention (``U_true = exp(d^) U``).
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
from vislam.ekf.prediction import predict_pose
from vislam.ekf.runner import Progress
from vislam.ekf.sequence import Sequence


class DeadReckoning:
    """Prediction only: ``U <- exp(-tau u^) U``, ``Sigma <- F Sigma F^T + tau^2 W``.

    A pose or covariance that is not finite after a prediction (an absurd but finite twist or
    time step) is an EstimationError naming the frame."""

    name = "dead-reckoning"

    def initialise(self, seq: Sequence, config: FilterConfig, guard: NumericalGuard) -> None:
        self.config = config
        self.guard = guard
        self.n_tracks = seq.n_tracks
        self.W = config.velocity_cov
        self.U, self.Sigma = np.eye(4), config.initial_pose_cov
        guard.check_state(0, self.U, self.Sigma)

    def predict(self, motion: MotionInput) -> None:
        self.U, self.Sigma = predict_pose(self.U, self.Sigma, motion.dt, motion.twist, self.W)  # eq. 11
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
        return {}


def run_dead_reckoning(
    seq: Sequence, config: FilterConfig = FilterConfig(), progress: Progress = None
) -> Estimate:
    """:class:`DeadReckoning` over ``seq`` (:func:`ekf.driver.run_filter`)."""
    return run_filter(DeadReckoning(), seq, config, progress)
