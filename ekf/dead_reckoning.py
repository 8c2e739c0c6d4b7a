"""Dead reckoning: the pose EKF's prediction alone (paper eq. 11), the paper's first result set."""

from __future__ import annotations

import numpy as np

from vislam.ekf.config import FilterConfig
from vislam.ekf.estimate import Estimate
from vislam.ekf.numerics import NumericalGuard, check_finite_trajectory
from vislam.ekf.prediction import predict_pose
from vislam.ekf.runner import (
    Progress,
    StepRecorder,
    blas_limits,
    build_estimate,
    interval_twists,
    prepare_sequence,
    report_progress,
)
from vislam.ekf.sequence import Sequence


def dead_reckon(
    seq: Sequence, config: FilterConfig, rec: StepRecorder, progress: Progress = None,
    name: str = "dead-reckoning",
) -> tuple[np.ndarray, np.ndarray]:
    """Fill ``rec`` with the predicted poses; returns the inverse poses (T,4,4) and covs.

    A pose or covariance that is not finite (an absurd but finite twist or time step) is an
    EstimationError of estimator ``name`` naming the first such frame."""
    tau, u = interval_twists(seq, config)
    W = config.velocity_cov
    T = seq.n_frames
    Us = np.empty((T, 4, 4))
    Sigmas = np.empty((T, 6, 6))
    U, Sigma = np.eye(4), config.initial_pose_cov
    for t in range(T):
        with rec.step(t):
            if t > 0:
                U, Sigma = predict_pose(U, Sigma, tau[t - 1], u[t - 1], W)  # paper eq. 11
            rec.record_pose(t, U, Sigma)
            Us[t], Sigmas[t] = U, Sigma
        report_progress(progress, t, T)
    check_finite_trajectory(NumericalGuard(name, seq.timestamps), Us, Sigmas, " after prediction")
    return Us, Sigmas


def run_dead_reckoning(
    seq: Sequence, config: FilterConfig = FilterConfig(), progress: Progress = None
) -> Estimate:
    """Prediction only: ``mu <- exp(-tau u^) mu``, ``Sigma <- F Sigma F^T + tau^2 W``."""
    seq, info = prepare_sequence(seq, config)
    rec = StepRecorder(seq.n_frames)
    with blas_limits(config):
        dead_reckon(seq, config, rec, progress)
    return build_estimate("dead-reckoning", seq, rec, None, None, config, info)
