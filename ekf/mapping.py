"""EKF mapping on the dead-reckoned trajectory (paper eq. 7-8), the paper's second result set.

Each landmark is an independent 3-D Gaussian: initialised by stereo triangulation with its
first-order covariance ``J_z V J_z^T`` (the pose taken as exact), then updated with each later
observation by a 3x3 EKF (paper eq. 8). The landmarks of one frame are independent given the
pose, so the frame's updates run as one batched computation.
"""

from __future__ import annotations

import numpy as np

from ekf.config import FilterConfig
from ekf.dead_reckoning import dead_reckon
from ekf.estimate import Estimate
from ekf.runner import Progress, StepRecorder, blas_limits, build_estimate, prepare_sequence
from ekf.sequence import Sequence
from ekf.stereo_update import StereoModel, batched_landmark_update


class LandmarkMap:
    """Per-track landmark means and 3x3 covariances (no cross-covariances): the mapping EKF."""

    def __init__(self, n_tracks: int):
        self.mean = np.full((n_tracks, 3), np.nan)
        self.cov = np.full((n_tracks, 3, 3), np.nan)
        self.initialised = np.zeros(n_tracks, dtype=bool)

    def observe(self, model: StereoModel, U: np.ndarray, tracks: np.ndarray, z: np.ndarray):
        """Update the initialised tracks (paper eq. 8), initialise the new ones.

        Returns ``(n_updates, n_rejected, n_initialised)``.
        """
        valid = model.valid_observations(z)
        known = self.initialised[tracks]
        upd = valid & known
        n_upd = 0
        if np.any(upd):
            tr = tracks[upd]
            m, P, acc = batched_landmark_update(model, U, self.mean[tr], self.cov[tr], z[upd])
            self.mean[tr], self.cov[tr] = m, P
            n_upd = int(acc.sum())
        new = valid & ~known
        if np.any(new):
            tr = tracks[new]
            m, _, cov = model.initialise_with_cov(U, z[new])  # the pose is taken as exact
            self.mean[tr] = m
            self.cov[tr] = 0.5 * (cov + np.swapaxes(cov, 1, 2))
            self.initialised[tr] = True
        n_rej = int(tracks.size - n_upd - int(new.sum()))
        return n_upd, n_rej, int(new.sum())


def run_mapping(
    seq: Sequence, config: FilterConfig = FilterConfig(), progress: Progress = None
) -> Estimate:
    """Dead-reckoned poses, then the landmark EKF along them."""
    seq, info = prepare_sequence(seq, config)
    rec = StepRecorder(seq.n_frames)
    model = StereoModel.from_config(seq.calibration, config)
    lm = LandmarkMap(seq.n_tracks)
    with blas_limits(config):
        Us, _ = dead_reckon(seq, config, rec, None)
        for t in range(seq.n_frames):
            tracks, z = seq.frame(t)
            with rec.step(t):
                n_upd, n_rej, n_init = lm.observe(model, Us[t], tracks, z)
            rec.n_updates[t], rec.n_rejected[t], rec.n_initialised[t] = n_upd, n_rej, n_init
            if progress is not None and ((t + 1) % 10 == 0 or t + 1 == seq.n_frames):
                progress(t + 1)
    return build_estimate("mapping", seq, rec, lm.mean, lm.cov, config, info)
