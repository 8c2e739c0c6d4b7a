"""The stereo measurement model shared by every EKF variant (paper eq. 1-3, 7-9, 13-16).

All functions are batched over observations (leading axis n) so a frame's update needs no
Python loop over observations.

* Predicted pixels (eq. 1, 9, 16): ``z = M pi(q)``, ``q = cam_T_imu U m`` (homogeneous m).
* Landmark Jacobian (eq. 7-8): ``dz/dm = M dpi/dq(q) cam_T_imu U P^T``, ``P = [I3 0]``.
* Pose Jacobian (eq. 13-15) for the left perturbation ``U = exp(d^) mu``:
  ``dz/dd = M dpi/dq(q) cam_T_imu (U m)^odot``.
* Landmark initialisation by stereo triangulation: ``m = U^-1 imu_T_cam p_cam(z)``, with
  ``dm/dd = -R_U^T [I3, -s^]`` (``s = imu_T_cam p_cam``) and ``dm/dz = R_U^T R_ic dp_cam/dz``.

**Lossless 3-row reduction.** Rows 2 and 4 of ``M`` are identical (vL and vR carry the same
information), so ``z = A y(x) + v`` with ``y = [uL, v, uR]`` and ``A`` (4x3) repeating the v row.
``y_hat = C z``, ``C = R3 A^T V^-1``, ``R3 = (A^T V^-1 A)^-1``, is a sufficient statistic: updating
with ``(C z, C H, R3)`` gives exactly the same posterior as ``(z, H, V)`` with 3 rows instead of 4
(for ``V = s^2 I4``: ``[uL, (vL+vR)/2, uR]`` with ``R3 = s^2 diag(1, 1/2, 1)``). The 4x4
innovation covariance of each observation, used for gating, is recovered exactly as
``S4 = A S3 A^T + (V - A R3 A^T)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from vislam.ekf import chi_square as chi2

from vislam.ekf.camera import dpi_dq, triangulate_unscented, triangulate_with_jacobian
from vislam.ekf.geometry import hat, se3_inv
from vislam.ekf.numerics import all_finite, batched_solve, finite_rows
from vislam.ekf.sequence import Calibration

#: Maps the reduced rows [uL, v, uR] to the four stereo rows [uL, vL, uR, vR].
REDUCE_A = np.array([[1.0, 0, 0], [0, 1, 0], [0, 0, 1], [0, 1, 0]])

#: Predicted camera depth below which a point counts as behind the camera (m).
MIN_DEPTH = 1e-3


def chi2_gate(probability: float | None, dof: int = 4) -> float:
    """Gate threshold ``chi2.ppf(probability, dof)`` (inf when gating is off)."""
    return float("inf") if probability is None else float(chi2.ppf(probability, dof))


@dataclass(frozen=True)
class StereoModel:
    """Calibration, noise and rejection settings of the stereo measurement, precomputed.

    ``M`` (4x4) paper eq. 2; ``cam_T_imu``; ``V`` (4x4) pixel covariance; ``C`` (3x4) and ``R3``
    (3x3) the lossless reduction (module docstring); ``S4_extra = V - A R3 A^T``;
    ``gate`` the chi-square threshold on the 4-dof NIS; ``min_disparity`` (px) and ``max_depth``
    (m, None: no limit) the rejection limits; ``triangulation`` "linear" or "unscented" (the
    landmark initialisation of :meth:`initialise_with_cov`).
    """

    K: np.ndarray
    baseline: float
    M: np.ndarray
    cam_T_imu: np.ndarray
    imu_T_cam: np.ndarray
    V: np.ndarray
    C: np.ndarray
    R3: np.ndarray
    M3: np.ndarray
    S4_extra: np.ndarray
    gate: float
    min_disparity: float
    max_depth: float | None
    triangulation: str = "linear"

    @classmethod
    def create(
        cls,
        calibration: Calibration,
        pixel_cov: np.ndarray,
        gate_probability: float | None = 0.99,
        min_disparity: float = 1.0,
        max_depth: float | None = None,
        triangulation: str = "linear",
    ) -> "StereoModel":
        V = np.asarray(pixel_cov, dtype=float)
        Vinv = np.linalg.inv(V)
        R3 = np.linalg.inv(REDUCE_A.T @ Vinv @ REDUCE_A)
        R3 = 0.5 * (R3 + R3.T)
        C = R3 @ REDUCE_A.T @ Vinv
        M = calibration.M
        extra = V - REDUCE_A @ R3 @ REDUCE_A.T
        return cls(
            K=np.asarray(calibration.K, dtype=float),
            baseline=float(calibration.baseline),
            M=M,
            cam_T_imu=np.asarray(calibration.cam_T_imu, dtype=float),
            imu_T_cam=se3_inv(calibration.cam_T_imu),
            V=V,
            C=C,
            R3=R3,
            M3=C @ M,
            S4_extra=0.5 * (extra + extra.T),
            gate=chi2_gate(gate_probability, 4),
            min_disparity=float(min_disparity),
            max_depth=None if max_depth is None else float(max_depth),
            triangulation=str(triangulation),
        )

    @classmethod
    def from_config(cls, calibration: Calibration, config) -> "StereoModel":
        """From a :class:`ekf.config.FilterConfig`."""
        return cls.create(
            calibration,
            config.pixel_cov,
            config.gate_probability,
            config.min_disparity,
            config.max_depth,
            getattr(config, "triangulation", "linear"),
        )

    # --- observation checks -------------------------------------------------------------
    def valid_observations(self, z: np.ndarray, depth_limit: bool = True) -> np.ndarray:
        """Boolean (n,): finite pixels, disparity > max(min_disparity, 0), and (``depth_limit``)
        the depth they triangulate to <= max_depth.

        The depth limit is for starting a landmark. An observation of a landmark already in the
        state is checked by its *predicted* depth (:meth:`valid_predictions`) instead: keeping
        only the observations whose own noisy disparity is large enough keeps the noise draws
        that make a point look near, a biased sample that makes the filter overconfident."""
        z = np.asarray(z, dtype=float)
        disparity = z[:, 0] - z[:, 2]
        ok = np.all(np.isfinite(z), axis=1) & (disparity > 0) & (disparity >= self.min_disparity)
        if depth_limit:
            ok &= self.within_max_depth(z)
        return ok

    def within_max_depth(self, z: np.ndarray) -> np.ndarray:
        """Boolean (n,): the depth the pixels ``z`` triangulate to is <= max_depth (all True
        without a limit; False where the disparity is not positive)."""
        if self.max_depth is None:
            return np.ones(len(z), dtype=bool)
        disparity = z[:, 0] - z[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            depth = self.K[0, 0] * self.baseline / disparity
        return (disparity > 0) & (depth <= self.max_depth)

    def valid_predictions(self, q: np.ndarray) -> np.ndarray:
        """Boolean (n,): predicted camera point in front of the camera and within max_depth.

        ``q`` (n, 4) is homogeneous: depth ``q3 / q4`` (``q4 = 1`` for a Euclidean landmark,
        ``rho > 0`` for an inverse-depth one, :mod:`ekf.inverse_depth`)."""
        w = q[:, 3]
        ok = (w > 0) & (q[:, 2] > MIN_DEPTH * w)
        if self.max_depth is not None:
            ok &= q[:, 2] <= self.max_depth * w
        return ok

    # --- prediction and Jacobians -------------------------------------------------------
    def camera_points(self, U: np.ndarray, m: np.ndarray) -> np.ndarray:
        """``q = cam_T_imu U [m; 1]`` (n, 4) for world landmarks ``m`` (n, 3)."""
        CU = self.cam_T_imu @ U
        q = np.empty((m.shape[0], 4))
        q[:, :3] = m @ CU[:3, :3].T + CU[:3, 3]
        q[:, 3] = 1.0
        return q

    def predicted_pixels(self, q: np.ndarray) -> np.ndarray:
        """Paper eq. 9 / 16: ``z_hat = M pi(q)`` (n, 4)."""
        return (q / q[:, 2:3]) @ self.M.T

    def landmark_jacobian(self, U: np.ndarray, q: np.ndarray, reduced: bool = False) -> np.ndarray:
        """Paper eq. 7-8: ``M dpi/dq(q) cam_T_imu U P^T`` (n, 4, 3), or (n, 3, 3) reduced."""
        Mx = self.M3 if reduced else self.M
        CU = self.cam_T_imu @ U
        return (Mx @ dpi_dq(q))[:, :, :3] @ CU[:3, :3]

    def pose_jacobian(self, U: np.ndarray, m: np.ndarray, q: np.ndarray, reduced: bool = False):
        """Paper eq. 13-15: ``M dpi/dq(q) cam_T_imu (U m)^odot`` (n, 4, 6), or (n, 3, 6) reduced.

        ``(U m)^odot = [[I3, -s^], [0, 0]]`` with ``s = U m``, so
        ``cam_T_imu (U m)^odot = [[R_c, -R_c s^], [0, 0]]``.
        """
        Mx = self.M3 if reduced else self.M
        A = (Mx @ dpi_dq(q))[:, :, :3]  # (n, r, 3): only the first 3 rows of cam_T_imu odot are nonzero
        s = m @ U[:3, :3].T + U[:3, 3]
        Rc = self.cam_T_imu[:3, :3]
        H = np.empty((q.shape[0], Mx.shape[0], 6))
        H[:, :, :3] = A @ Rc
        H[:, :, 3:] = -(A @ Rc) @ hat(s)
        return H

    def jacobians(self, U: np.ndarray, m: np.ndarray, q: np.ndarray, reduced: bool = True):
        """Both Jacobians at once: ``(H_pose (n, r, 6), H_landmark (n, r, 3))``."""
        Mx = self.M3 if reduced else self.M
        A = (Mx @ dpi_dq(q))[:, :, :3]
        CU = self.cam_T_imu @ U
        s = m @ U[:3, :3].T + U[:3, 3]
        ARc = A @ self.cam_T_imu[:3, :3]
        Hp = np.empty((q.shape[0], Mx.shape[0], 6))
        Hp[:, :, :3] = ARc
        Hp[:, :, 3:] = -ARc @ hat(s)
        return Hp, A @ CU[:3, :3]

    def homogeneous_jacobians(
        self, U: np.ndarray, m_h: np.ndarray, G: np.ndarray, q: np.ndarray, reduced: bool = True
    ):
        """:meth:`jacobians` for a landmark held as a homogeneous world point ``m_h`` (n, 4)
        with ``dm_h/dx = G`` (n, 4, 3) (an inverse-depth landmark, ID-2 of
        :mod:`ekf.inverse_depth`), ``q = cam_T_imu U m_h``:
        ``H_x = M dpi/dq(q) cam_T_imu U G`` and
        ``H_pose = M dpi/dq(q) cam_T_imu (U m_h)^odot``, ``(s; w)^odot = [[w I, -s^], [0, 0]]``."""
        Mx = self.M3 if reduced else self.M
        A = Mx @ dpi_dq(q)  # (n, r, 4)
        CU = self.cam_T_imu @ U
        s = m_h @ U.T  # U m_h, (n, 4)
        ARc = A[:, :, :3] @ self.cam_T_imu[:3, :3]
        Hp = np.empty((q.shape[0], Mx.shape[0], 6))
        Hp[:, :, :3] = ARc * s[:, 3, None, None]
        Hp[:, :, 3:] = -ARc @ hat(s[:, :3])
        return Hp, A @ CU @ G

    def reduced_innovation(self, z: np.ndarray, q: np.ndarray) -> np.ndarray:
        """``C (z - M pi(q))`` (n, 3): the innovation in the reduced rows."""
        return z @ self.C.T - (q / q[:, 2:3]) @ self.M3.T

    # --- gating -------------------------------------------------------------------------
    def full_innovation_cov(self, S3: np.ndarray) -> np.ndarray:
        """Per-observation 4x4 innovation covariance from the reduced 3x3 one (exact)."""
        return REDUCE_A @ S3 @ REDUCE_A.T + self.S4_extra

    def nis(self, innovation4: np.ndarray, S4: np.ndarray) -> np.ndarray:
        """Normalised innovation squared ``r^T S^-1 r`` per observation (n,); NaN where ``S``
        is singular or the result is not finite (an absurd but finite observation)."""
        x = batched_solve(S4, innovation4[..., None])[..., 0]
        return np.einsum("ni,ni->n", innovation4, x)

    def gate_mask(self, z: np.ndarray, q: np.ndarray, S3: np.ndarray) -> np.ndarray:
        """Chi-square gate of each stereo observation against its own 4x4 S (True: accept)."""
        return self.gate_check(z, q, S3)[0]

    def gate_check(self, z: np.ndarray, q: np.ndarray, S3: np.ndarray) -> tuple[np.ndarray, int]:
        """:meth:`gate_mask` and the number of observations it rejected because their NIS
        could not be computed (singular or non-finite ``S``, overflow): ``(accept (n,), n_bad)``.
        Without gating, observations whose ``S3`` is not finite are rejected the same way."""
        if not np.isfinite(self.gate):
            ok = finite_rows(S3)
            return ok, int(ok.size - ok.sum())
        return self.gate_innovations(z - self.predicted_pixels(q), S3)

    def gate_innovations(self, r4: np.ndarray, S3: np.ndarray,
                         noise_scale: np.ndarray | None = None) -> tuple[np.ndarray, int]:
        """:meth:`gate_check` of 4-row innovations ``r4`` (n, 4) with reduced covariances ``S3``
        (n, 3, 3); ``noise_scale`` (n,) scales each row's pixel noise (``S3`` holds it scaled
        already; the rows' 4th dimension takes the same scale): a differenced AR(1) row has
        ``1 - a^2`` (ekf/joint.py)."""
        if not np.isfinite(self.gate):
            ok = finite_rows(S3)
            return ok, int(ok.size - ok.sum())
        S4 = self.full_innovation_cov(S3)
        if noise_scale is not None:
            S4 = S4 + (noise_scale - 1.0)[:, None, None] * self.S4_extra
        m2 = self.nis(r4, S4)
        n_bad = 0 if math.isfinite(m2.sum()) else int(m2.size - np.isfinite(m2).sum())
        return m2 <= self.gate, n_bad

    # --- initialisation -----------------------------------------------------------------
    def _camera_to_world(self, U: np.ndarray, p_cam: np.ndarray):
        """``m = U^-1 imu_T_cam p_cam`` (n, 3), ``J_d = dm/dd`` (n, 3, 6) for ``U = exp(d^) mu``,
        and the camera-to-world rotation ``R_wc`` (3, 3)."""
        Ric, tic = self.imu_T_cam[:3, :3], self.imu_T_cam[:3, 3]
        s = p_cam @ Ric.T + tic
        Rt = U[:3, :3].T
        m = (s - U[:3, 3]) @ Rt.T
        J_d = np.empty((p_cam.shape[0], 3, 6))
        J_d[:, :, :3] = -Rt
        J_d[:, :, 3:] = Rt @ hat(s)
        return m, J_d, Rt @ Ric

    def initialise(self, U: np.ndarray, z: np.ndarray):
        """Stereo triangulation into the world: ``(m (n,3), J_d (n,3,6), J_z (n,3,4))``.

        ``m = U^-1 imu_T_cam p_cam(z)``; ``J_d = dm/dd`` for ``U = exp(d^) mu``;
        ``J_z = dm/dz``. The caller checks :meth:`valid_observations` first.
        """
        p_cam, Jtri = triangulate_with_jacobian(z, self.K, self.baseline)
        m, J_d, R_wc = self._camera_to_world(U, p_cam)
        return m, J_d, R_wc @ Jtri

    def initialise_with_cov(self, U: np.ndarray, z: np.ndarray):
        """Like :meth:`initialise` but with the pixel part of the covariance: ``(m, J_d, C_z)``.

        ``C_z`` (n, 3, 3) is the world covariance of ``m`` due to the pixel noise alone: ``J_z V
        J_z^T`` ("linear") or the rotated unscented camera-frame covariance ("unscented", whose
        mean also replaces ``m``). The pose error enters linearly through ``J_d`` either way, so
        the full covariance is ``C_z + J_d Sigma_pose J_d^T`` with cross-covariance
        ``J_d Sigma_pose,x``.
        """
        if self.triangulation != "unscented":
            m, J_d, J_z = self.initialise(U, z)
            return m, J_d, J_z @ self.V @ np.swapaxes(J_z, 1, 2)
        p_cam, cov_cam = triangulate_unscented(z, self.K, self.baseline, self.V)
        m, J_d, R_wc = self._camera_to_world(U, p_cam)
        return m, J_d, R_wc @ cov_cam @ R_wc.T

    def initial_landmark_cov(
        self, J_d: np.ndarray, J_z: np.ndarray, Sigma_pose: np.ndarray | None = None
    ) -> np.ndarray:
        """``J_z V J_z^T (+ J_d Sigma_pose J_d^T)`` (n, 3, 3): first-order covariance."""
        cov = J_z @ self.V @ np.swapaxes(J_z, 1, 2)
        if Sigma_pose is not None:
            cov = cov + J_d @ Sigma_pose @ np.swapaxes(J_d, 1, 2)
        return 0.5 * (cov + np.swapaxes(cov, 1, 2))


def batched_landmark_update(
    model: StereoModel,
    U: np.ndarray,
    m: np.ndarray,
    P: np.ndarray,
    z: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Independent 3x3 landmark EKF updates (paper eq. 8), all landmarks of a frame at once.

    ``m`` (n, 3), ``P`` (n, 3, 3), ``z`` (n, 4) with the pose ``U`` taken as exact. Applies the
    prediction checks (cheirality, depth) and the chi-square gate; rejected rows keep their
    prior. Joseph form keeps each ``P`` symmetric PD. Returns ``(m, P, accepted (n,))``.
    """
    m, P, accepted, _ = batched_landmark_update_checked(model, U, m, P, z)
    return m, P, accepted


def batched_landmark_update_checked(
    model: StereoModel,
    U: np.ndarray,
    m: np.ndarray,
    P: np.ndarray,
    z: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """:func:`batched_landmark_update` and the number of landmark updates it rejected because
    they could not be computed (singular ``S``, a mean or covariance not finite, a posterior
    variance not positive): those landmarks keep their prior."""
    q = model.camera_points(U, m)
    ok = model.valid_predictions(q)
    m, P = m.copy(), P.copy()
    if not np.any(ok):
        return m, P, ok, 0
    idx = np.nonzero(ok)[0]
    q, mi, Pi, zi = q[idx], m[idx], P[idx], z[idx]
    G = model.landmark_jacobian(U, q, reduced=True)  # (k, 3, 3)
    PGt = Pi @ np.swapaxes(G, 1, 2)
    S3 = G @ PGt + model.R3
    acc, n_bad = model.gate_check(zi, q, S3)
    K = np.swapaxes(batched_solve(S3, np.swapaxes(PGt, 1, 2)), 1, 2)  # P G^T S^-1
    r = model.reduced_innovation(zi, q)
    IKG = np.eye(3) - K @ G
    Pn = IKG @ Pi @ np.swapaxes(IKG, 1, 2) + K @ model.R3 @ np.swapaxes(K, 1, 2)
    Pn = 0.5 * (Pn + np.swapaxes(Pn, 1, 2))
    mn = mi + (K @ r[:, :, None])[:, :, 0]
    if not (all_finite(Pn, mn) and Pn.reshape(-1, 9)[:, ::4].min() > 0):  # fast path first
        sound = finite_rows(Pn) & finite_rows(mn) & np.all(Pn.reshape(-1, 9)[:, ::4] > 0, axis=1)
        n_bad += int(np.sum(acc & ~sound))
        acc &= sound
    sel = idx[acc]
    m[sel] = mn[acc]
    P[sel] = Pn[acc]
    accepted = np.zeros(ok.shape, dtype=bool)
    accepted[sel] = True
    return m, P, accepted, n_bad
