"""EKF mapping on the dead-reckoned trajectory (paper eq. 7-8), the paper's second result set.

Each landmark is an independent 3-D Gaussian: initialised by stereo triangulation with its
first-order covariance ``J_z V J_z^T`` (the pose taken as exact), then updated with each later
observation by a 3x3 EKF (paper eq. 8). The landmarks of one frame are independent given the
pose, so the frame's updates run as one batched computation.
"""

from __future__ import annotations

import numpy as np

from vislam.ekf.config import FilterConfig
from vislam.ekf.dead_reckoning import DeadReckoning
from vislam.ekf.driver import run_filter
from vislam.ekf.estimate import Estimate
from vislam.ekf.filter import FrameObservations, Landmarks, UpdateCounts
from vislam.ekf.numerics import NumericalGuard, all_finite, finite_rows
from vislam.ekf.runner import Progress
from vislam.ekf.sequence import Sequence
from vislam.ekf.stereo_update import StereoModel, batched_landmark_update_checked


class LandmarkMap:
    """Per-track landmark means and 3x3 covariances (no cross-covariances): the mapping EKF."""

    def __init__(self, n_tracks: int):
        self.mean = np.full((n_tracks, 3), np.nan)
        self.cov = np.full((n_tracks, 3, 3), np.nan)
        self.initialised = np.zeros(n_tracks, dtype=bool)

    def observe(self, model: StereoModel, U: np.ndarray, tracks: np.ndarray, z: np.ndarray):
        """Update the initialised tracks (paper eq. 8), initialise the new ones.

        Returns ``(n_updates, n_rejected, n_initialised, n_numerical)``, the last the
        observations (included in ``n_rejected``) whose update or initialisation could not be
        computed (:mod:`ekf.numerics`; the landmark keeps its prior or stays uninitialised).
        """
        valid = model.valid_observations(z, depth_limit=False)  # known: by predicted depth
        known = self.initialised[tracks]
        upd = valid & known
        valid &= model.within_max_depth(z)
        n_upd = n_num = 0
        if np.any(upd):
            tr = tracks[upd]
            m, P, acc, n_num = batched_landmark_update_checked(
                model, U, self.mean[tr], self.cov[tr], z[upd]
            )
            self.mean[tr], self.cov[tr] = m, P
            n_upd = int(acc.sum())
        new = valid & ~known
        n_init = 0
        if np.any(new):
            tr = tracks[new]
            m, _, cov = model.initialise_with_cov(U, z[new])  # the pose is taken as exact
            if not all_finite(m, cov):
                ok = finite_rows(m) & finite_rows(cov)
                n_num += int(ok.size - ok.sum())
                tr, m, cov = tr[ok], m[ok], cov[ok]
            self.mean[tr] = m
            self.cov[tr] = 0.5 * (cov + np.swapaxes(cov, 1, 2))
            self.initialised[tr] = True
            n_init = int(tr.size)
        n_rej = int(tracks.size - n_upd - n_init)
        return n_upd, n_rej, n_init, n_num

    def landmarks(self, tracks: np.ndarray) -> Landmarks:
        """Means and covariances of ``tracks`` (copies)."""
        return Landmarks(tracks, self.mean[tracks], self.cov[tracks])

    def ended_map(self, ended: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Means and covariances of the ``ended`` tracks (n_tracks,) bool, NaN elsewhere (copies)."""
        return (np.where(ended[:, None], self.mean, np.nan),
                np.where(ended[:, None, None], self.cov, np.nan))


class Mapping(DeadReckoning):
    """Dead-reckoned poses (:class:`ekf.dead_reckoning.DeadReckoning`), the landmark EKF
    (:class:`LandmarkMap`) along them."""

    name = "mapping"

    def initialise(self, seq: Sequence, config: FilterConfig, guard: NumericalGuard) -> None:
        super().initialise(seq, config, guard)
        self.model = StereoModel.from_config(seq.calibration, config)
        self.lm = LandmarkMap(seq.n_tracks)
        self.ended = np.zeros(seq.n_tracks, dtype=bool)

    def update(self, frame: FrameObservations) -> UpdateCounts:
        n_upd, n_rej, n_init, n_num = self.lm.observe(self.model, self.U, frame.tracks, frame.z)
        if n_num:
            self.guard.reject(frame.frame, "landmark update or initialisation not finite", n_num)
        return UpdateCounts(n_upd, n_rej, n_init)

    def marginalise(self, tracks: np.ndarray) -> None:
        self.ended[tracks] = True

    def active_landmarks(self) -> Landmarks:
        return self.lm.landmarks(np.flatnonzero(self.lm.initialised & ~self.ended))

    def landmark_map(self) -> tuple[np.ndarray, np.ndarray]:
        return self.lm.ended_map(self.ended)


def run_mapping(
    seq: Sequence, config: FilterConfig = FilterConfig(), progress: Progress = None
) -> Estimate:
    """:class:`Mapping` over ``seq`` (:func:`ekf.driver.run_filter`)."""
    return run_filter(Mapping(), seq, config, progress)
