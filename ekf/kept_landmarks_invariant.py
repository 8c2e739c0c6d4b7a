"""Landmarks of ended tracks that ``ekf-invariant`` keeps with ``keep_landmarks``: :mod:`ekf.kept_landmarks`'s regressions
``x_j = F_j x_A + eps_j`` (RL-1) under the invariant filter's steps.

The invariant filter differs from the joint one in three places, each handled exactly:

* **Prediction.** The error transition is ``Phi_A = I + F_A S_b`` (the coupling of the twist
  errors ``x_b = [xi_b; xi_s]``, gyro bias and speed scale where configured, columns 6 to
  ``off``), and a group landmark's error coordinates take the pose's twist noise too (the
  landmark rows ``[0, l^ R]`` of the adjoint): ``x_j' = x_j + F_j^b x_b + N_j n`` with
  ``x_A' = Phi_A x_A + N_A n`` (``N_A`` also carries the random walks; ``F_j^b = -tau B_j E(u)``
  as the active rows', ekf.invariant). With ``A_j = (F_j + F_j^b S_b) Phi_A^-1`` and
  ``D_j = A_j N_A - N_j``:  ``F_j' = A_j - D_j N_A^T P'^-1``,
  ``E_j' = E_j + D_j (I - N_A^T P'^-1 N_A) D_j^T``.                                    (RI-1)
  (RL-2 is the case ``N_j = 0``.)
* **Update.** The means follow the group retraction ``l <- R_d l + J dl`` (``dl = F_j dx``);
  inverse-depth ones are additive and transported as in ekf-joint, without a pose ``Ad``.
* **Joining the group** (ID-6 in right-invariant coordinates ``xi_l = J dx + l^ xi_R``): a retired
  one takes ``F' = J F + l^ S_R``; an active one's columns take ``J^-1`` and the rotation
  columns ``- F_.l J^-1 l^``.
"""

from __future__ import annotations

import numpy as np

from vislam.ekf import inverse_depth as idp
from vislam.ekf.geometry import hat
from vislam.ekf.prediction import se3_left_jacobian, so3_exp_and_left_jacobian, twist_error_coupling
from vislam.ekf.kept_landmarks import KeptLandmarks, landmark_blocks, solve_spd

R_COLS = slice(3, 6)


class InvariantKeptLandmarks(KeptLandmarks):
    """:class:`ekf.kept_landmarks.KeptLandmarks` for the right-invariant EKF (see the module
    docstring); ``off`` the first landmark column (6, plus 3 with a gyro bias, plus 1 with a
    speed scale)."""

    def __init__(self, off: int):
        super().__init__(off)
        self.off = off

    def predict(self, T, twist, tau, W_chol, N_A, F_A, P_new, scale_velocity=None) -> None:
        """(RI-1) after the active block's prediction ``P_new = Phi_A P Phi_A^T + N_A N_A^T``;
        ``T`` the pose at the start of the step, ``twist = tau u``; ``F_A`` (dim A, m) the
        coupling of the bias and speed scale (None with neither); ``scale_velocity`` the
        measured linear velocity ``v`` with a speed-scale state (its last column), else None."""
        n = self.n
        group = ~self.inverse
        Bj = np.zeros((n, 3, 6))  # each retired landmark's rows of noise_jacobian
        Bj[group, :, 3:] = hat(self.mean[group]) @ T[:3, :3]
        Bj = Bj @ se3_left_jacobian(twist)
        F = self.F
        if F_A is not None:  # H_j = F_j + F_j^b S_b, then A_j = H_j (I - F_A S_b)
            e = slice(6, 6 + F_A.shape[1])
            has_scale = scale_velocity is not None
            F[:, e] += twist_error_coupling(Bj.reshape(-1, 6), tau,
                                            scale_velocity if has_scale else np.zeros(3),
                                            F_A.shape[1] > has_scale, has_scale)
            F[:, e] -= F @ F_A
        N_j = (tau * Bj @ W_chol).reshape(-1, 6)
        N_j = np.concatenate([N_j, np.zeros((N_j.shape[0], N_A.shape[1] - 6))], axis=1)
        D = F @ N_A - N_j  # (3n, m)
        Z = solve_spd(P_new, N_A).T  # N_A^T P'^-1 (m, dim A)
        K = np.eye(N_A.shape[1]) - Z @ N_A
        Db = landmark_blocks(D)
        self.E = self.E + Db @ (0.5 * (K + K.T)) @ Db.transpose(0, 2, 1)
        F -= D @ Z

    def update(self, dx: np.ndarray, C_active: np.ndarray | None) -> None:
        """The means move by ``F dx`` through the group retraction (inverse-depth ones
        additively, then transported: ``C_active`` (3m, 6) the active landmarks' transport
        rows, zero for group ones, or None when no active one is in inverse depth)."""
        dm = (self.F @ dx).reshape(-1, 3)
        Rd, J = so3_exp_and_left_jacobian(dx[R_COLS])
        x_prior = self.mean
        new = self.mean @ Rd.T + dm @ J.T
        ids = np.flatnonzero(self.inverse)
        new[ids] = x_prior[ids] + dm[ids]
        self.mean = new
        if ids.size == 0 and C_active is None:
            return
        F = self.F
        pose = F[:, :6]
        if ids.size:
            R_a, p_a = self.anchor_R[ids], self.anchor_p[ids]
            C = idp.gauge_rows_change(x_prior[ids], new[ids], R_a, p_a)
            rows = (3 * ids[:, None] + np.arange(3)).ravel()
            pose[rows] += C.reshape(-1, 6)
        if C_active is not None:
            pose -= F[:, self.off :] @ C_active
        F[:, :6] = pose

    def active_to_group(self, cols: np.ndarray, J: np.ndarray, L: np.ndarray) -> None:
        """Active slots at ``cols`` (k, 3) joined the group: ``x' = J x + L xi_R``."""
        F = self.F
        Jinv = np.linalg.inv(J)
        Fl = np.einsum("nkj,kji->nki", F[:, cols], Jinv)  # F_.l J^-1 (3n, k, 3)
        F[:, cols] = Fl
        F[:, R_COLS] -= np.einsum("nkj,kji->ni", Fl, L)

    def convert_linear(self, P, centre, threshold) -> None:
        """Retired inverse-depth landmarks whose linearity index is below ``threshold`` join
        the group (ID-6): ``F' = J F + l^ S_R``, ``E' = J E J^T``."""
        ids = self.linear_enough(P, centre, threshold)
        if ids.size == 0:
            return
        x, R_a = self.mean[ids], self.anchor_R[ids]
        J = idp.world_jacobian(x, R_a)
        m = idp.world_point(x, R_a, self.anchor_p[ids])
        rows = (3 * ids[:, None] + np.arange(3)).ravel()
        G = J @ landmark_blocks(self.F[rows])
        G[:, :, R_COLS] += hat(m)
        self.F[rows] = G.reshape(3 * ids.size, -1)
        self.E[ids] = J @ self.E[ids] @ J.transpose(0, 2, 1)
        self.mean[ids] = m
        self.inverse[ids] = False

    def world(self, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World means and covariances: a group landmark's ``dl = xi_l - l^ xi_R`` from the
        joint covariance of ``[xi_R, x_j]``; an inverse-depth one first order (ID-6)."""
        cov_x = self.covariances(P)  # RL-1
        cross = landmark_blocks(self.F) @ P[:, R_COLS]  # cov(x_j, xi_R)
        mean, cov = self.mean.copy(), cov_x.copy()
        g = np.flatnonzero(~self.inverse)
        if g.size:
            Lh = hat(self.mean[g])
            c = cross[g] @ Lh.transpose(0, 2, 1)  # cov(x_j, xi_R) (-l^)^T
            cov[g] = cov_x[g] - c - c.transpose(0, 2, 1) + Lh @ P[R_COLS, R_COLS] @ Lh.transpose(0, 2, 1)
        self._inverse_depth_to_world(mean, cov)
        return mean, cov
