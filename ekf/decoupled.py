"""The paper's Algorithm 1 as written ("decoupled" SLAM): no pose-landmark cross-covariance.

Per frame: predict the pose (paper eq. 11); update it with all observations of initialised
landmarks, taking the landmark means as exact (paper eq. 13-16, stacked); then update each
observed landmark given the updated pose (paper eq. 8, batched as in :mod:`ekf.mapping`), and
initialise new landmarks by triangulation from the updated pose.

The stacked pose update is computed in information form,
``Sigma+ = (Sigma^-1 + H^T (I (x) R)^-1 H)^-1``, ``d = Sigma+ H^T (I (x) R)^-1 r``, which equals the
Kalman form of eq. 14 exactly and stays symmetric positive definite (6x6 inverses only).
Each observation is gated against its own 4x4 innovation covariance including its landmark's
covariance, ``S_i = Hp Sigma Hp^T + Hm Sigma_m Hm^T + V``.
"""

from __future__ import annotations

import numpy as np

from vislam.ekf.config import FilterConfig
from vislam.ekf.driver import run_filter
from vislam.ekf.estimate import Estimate
from vislam.ekf.filter import FrameObservations, UpdateCounts
from vislam.ekf.mapping import Mapping
from vislam.ekf.numerics import UpdateRejected, all_finite
from vislam.ekf.prediction import se3_exp_single
from vislam.ekf.runner import Progress
from vislam.ekf.sequence import Sequence
from vislam.ekf.stereo_update import StereoModel


def pose_update_exact_landmarks(
    model: StereoModel,
    U: np.ndarray,
    Sigma: np.ndarray,
    m: np.ndarray,
    z: np.ndarray,
    landmark_cov: np.ndarray | None = None,
    widen: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Paper eq. 13-16: stacked pose update linearised at the landmark means ``m`` (n,3).

    ``landmark_cov`` (n,3,3): the landmark covariances, used for the per-observation gate.
    With ``widen`` they also widen each observation's noise, ``R_i = Hm_i Sigma_m,i Hm_i^T + R``
    (no cross-covariance is kept either way); without it the landmarks are exact, as the paper
    writes it. Returns ``(U, Sigma, accepted (n,))``.
    """
    U, Sigma, accepted, _ = pose_update_checked(model, U, Sigma, m, z, landmark_cov, widen)
    return U, Sigma, accepted


def pose_update_checked(
    model: StereoModel,
    U: np.ndarray,
    Sigma: np.ndarray,
    m: np.ndarray,
    z: np.ndarray,
    landmark_cov: np.ndarray | None = None,
    widen: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """:func:`pose_update_exact_landmarks` and the number of observations the gate rejected
    because their innovation covariance could not be used (singular, not finite).

    Raises :class:`~ekf.numerics.UpdateRejected` (nothing changed) when the stacked update
    itself cannot be computed: a singular or non-finite information matrix, a posterior
    covariance that is not finite or not positive definite, a non-finite correction."""
    q = model.camera_points(U, m)
    ok = model.valid_predictions(q)
    idx = np.nonzero(ok)[0]
    accepted = np.zeros(m.shape[0], dtype=bool)
    if idx.size == 0:
        return U, Sigma, accepted, 0
    q, m_i, z_i = q[idx], m[idx], z[idx]
    Hp, Hm = model.jacobians(U, m_i, q, reduced=True)  # (k,3,6), (k,3,3)
    R = np.broadcast_to(model.R3, (idx.size, 3, 3))
    Rm = R if landmark_cov is None else R + Hm @ landmark_cov[idx] @ np.swapaxes(Hm, 1, 2)
    S3 = Hp @ Sigma @ np.swapaxes(Hp, 1, 2) + Rm
    acc, n_bad = model.gate_check(z_i, q, S3)
    if not np.any(acc):
        return U, Sigma, accepted, n_bad
    H = Hp[acc]  # (a, 3, 6)
    r = model.reduced_innovation(z_i[acc], q[acc])  # (a, 3)
    try:
        Rinv = np.linalg.inv((Rm if widen else R)[acc])
        HtRinv = np.swapaxes(H, 1, 2) @ Rinv  # (a, 6, 3)
        info = np.linalg.inv(Sigma) + np.einsum("aij,ajk->ik", HtRinv, H)
        Sigma_new = np.linalg.inv(info)
    except np.linalg.LinAlgError:
        raise UpdateRejected("pose information matrix singular") from None
    Sigma_new = 0.5 * (Sigma_new + Sigma_new.T)
    d = Sigma_new @ np.einsum("aij,aj->i", HtRinv, r)
    if not (all_finite(Sigma_new, d) and Sigma_new.ravel()[::7].min() > 0):
        raise UpdateRejected("pose covariance or correction not finite, or a variance not positive")
    accepted[idx[acc]] = True
    return se3_exp_single(d) @ U, Sigma_new, accepted, n_bad  # paper eq. 14: mu <- exp((K r)^) mu


class DecoupledEKF(Mapping):
    """Paper Algorithm 1: pose update at the landmark means, then landmark updates
    (:class:`ekf.mapping.LandmarkMap`), no pose-landmark cross-covariance.

    ``as_written=True`` (the registered ``ekf-decoupled``) reproduces the paper exactly
    (landmarks exact in the pose update, noise V only); ``False`` widens each observation's
    noise by its landmark's covariance, which the paper's model omits, still with no
    cross-covariance."""

    name = "ekf-decoupled"
    #: The paper's pose update has no speed-scale row: config.speed_scale is ignored here.
    carries_speed_scale = False

    def __init__(self, as_written: bool = True):
        self.as_written = bool(as_written)

    def update(self, frame: FrameObservations) -> UpdateCounts:
        t, tracks, z = frame.frame, frame.tracks, frame.z
        model, lm, guard = self.model, self.lm, self.guard
        valid = model.valid_observations(z, depth_limit=False)  # by predicted depth
        known = valid & lm.initialised[tracks]
        n_pose = n_num = 0
        if np.any(known):
            tr = tracks[known]
            try:
                self.U, self.Sigma, acc, n_num = pose_update_checked(
                    model, self.U, self.Sigma, lm.mean[tr], z[known], lm.cov[tr],
                    widen=not self.as_written
                )
            except UpdateRejected as exc:
                guard.reject(t, str(exc), int(tr.size))
                acc = np.zeros(tr.size, dtype=bool)
            n_pose = int(acc.sum())
            # Observations rejected by the pose gate are not used for mapping either.
            drop = np.nonzero(known)[0][~acc]
            valid[drop] = False
        _, _, n_init, n_num_map = lm.observe(model, self.U, tracks[valid], z[valid])
        if n_num + n_num_map:
            guard.reject(t, "innovation covariance singular or not finite", n_num + n_num_map)
        return UpdateCounts(n_pose, tracks.size - n_pose - n_init, n_init)

    def info(self) -> dict:
        return {"decoupled_as_written": self.as_written}


def run_decoupled(
    seq: Sequence,
    config: FilterConfig = FilterConfig(),
    progress: Progress = None,
    *,
    as_written: bool = False,
) -> Estimate:
    """:class:`DecoupledEKF` over ``seq`` (:func:`ekf.driver.run_filter`); note the default here,
    ``as_written=False``, is the widened variant (kept for comparison, not registered)."""
    return run_filter(DecoupledEKF(as_written), seq, config, progress)
