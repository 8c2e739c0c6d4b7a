"""Landmarks of ended tracks that a joint EKF keeps in its state (``config.keep_landmarks``), held
exactly and without the dense update. (A landmark *retires* when its track ends.)

With ``config.keep_landmarks`` the joint EKF keeps every landmark in its state (textbook EKF
SLAM), so that each later update still refines the landmarks of ended tracks through their
cross-covariance with the pose. Written as one dense covariance that costs ``O(N^2)`` per update
for ``N`` = 3 x every landmark ever seen, which grows with the drive without bound. The same numbers are cheap (in the spirit of Guivant and Nebot's compressed
EKF, 2001: a landmark that is not observed needs no per-update work of its own):

A retired landmark ``x_j`` (its track has ended) is never observed again. Write it as its
regression on the active state ``A = [pose, (bias), active landmarks]``:

    x_j = F_j x_A + eps_j,   eps_j independent of x_A,   cov(x_j) = F_j P_AA F_j^T + E_j.  (RL-1)

* **Update** (paper eq. 8, 14): the measurement depends on ``x_A`` only, so ``p(x_j | x_A)``
  does not change: ``F_j`` and ``E_j`` stay, and the mean moves by ``F_j dx_A`` (the dense
  gain's rows ``P_jA H^T S^-1 r`` with ``P_jA = F_j P_AA``). No per-update covariance work.
* **Prediction** ``x_A' = Phi x_A + w`` (``w ~ Q`` on the core rows): ``F' = F Phi^-1 (I - Q
  P'^-1)`` and ``E' = E + G (Q - Q P'^-1 Q) G^T`` with ``G = (F Phi^-1)_core``.     (RL-2)
* **Gauge transport** ``P <- T P T^T``, ``T = [[T_A, 0], [C_r, I]]`` (:func:`ekf.joint.transport`):
  ``F' = (F + C_r S_pose) T_A^-1``, ``E`` unchanged.                                (RL-3)
* **New active landmarks** ``x_new = J x_pose + v`` with ``v`` independent: ``F' = [F, 0]``.
* **A landmark retires** (``x_L`` leaves ``A``, the rest ``x_R`` stays): ``F_L = P_LR P_RR^-1``,
  ``E_L`` the blocks of ``P_LL - F_L P_RL``; the others take ``F' = F_R + F_.L F_L``,
  ``E' = E + F_.L (P_LL - F_L P_RL) F_.L^T``.                                         (RL-4)
* **Inverse depth -> Euclidean** (ID-6) with ``J``: of a retired one ``F' = J F``,
  ``E' = J E J^T``; of an active one, its columns of ``F`` take ``J^-1``.

Only each landmark's own 3x3 block is kept: nothing the filter computes needs the covariance
between two retired landmarks. The cost is ``O(n dim(A))`` per frame for ``n`` retired rows
instead of the dense ``O((n + dim A)^2 3a)``. ``run_joint(..., textbook=True)`` keeps the dense
form as the reference; ``tests/test_ekf_estimators.py`` checks both agree to 1e-9.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import cho_factor, cho_solve
from scipy.linalg.blas import dgemm

from vislam.ekf import inverse_depth as idp
from vislam.ekf.geometry import adjoint, hat, se3_inv


def landmark_blocks(F: np.ndarray) -> np.ndarray:
    """(3n, m) rows as (n, 3, m) landmark blocks."""
    return F.reshape(-1, 3, F.shape[1])


def oc_transport_rows(dm: np.ndarray, x_prior: np.ndarray, x_new: np.ndarray, inverse: np.ndarray,
                      anchor_R: np.ndarray, anchor_p: np.ndarray, U_prior: np.ndarray) -> np.ndarray:
    """The landmark rows ``C`` (n, 3, 6) of ekf-joint's observability-constrained transport
    (:func:`ekf.joint.transport`) after an update that moved landmarks ``x_prior`` to ``x_new``
    by ``dm``: ``C_j = (N_j- - N_j+) Ad(U-)^-1`` (``N_j`` the gauge rows: ID-7 for an
    inverse-depth one, ``[I, -m^]`` for a Euclidean one, where it is ``[0, dm^ R-^T]``), so that
    ``T N(U-, x-) = N(E U-, x+)``. For active and retired landmarks alike."""
    C = np.zeros((dm.shape[0], 3, 6))
    eu, ids = np.flatnonzero(~inverse), np.flatnonzero(inverse)
    if eu.size:
        C[eu, :, 3:] = hat(dm[eu]) @ U_prior[:3, :3].T
    if ids.size:
        R_a, p_a = anchor_R[ids], anchor_p[ids]
        dN = idp.gauge_rows_change(x_new[ids], x_prior[ids], R_a, p_a)  # N(x-) - N(x+)
        C[ids] = dN @ adjoint(se3_inv(U_prior))
    return C


def solve_spd(P: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``P^-1 B`` for a symmetric positive definite ``P`` (Cholesky; LU if that fails)."""
    try:
        return cho_solve(cho_factor(P, lower=True, check_finite=False), B, check_finite=False)
    except np.linalg.LinAlgError:
        return np.linalg.solve(P, B)


def map_with_kept(map_mean: np.ndarray, map_cov: np.ndarray, kept: "KeptLandmarks | None",
                  P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A filter's map: the ended tracks' ``map_mean``/``map_cov`` (copies), with the rows of the
    landmarks ``kept`` in the state (``keep_landmarks``) read out at the current ``P``."""
    mean, cov = map_mean.copy(), map_cov.copy()
    if kept is not None and kept.n:
        mean[kept.track], cov[kept.track] = kept.world(P)
    return mean, cov


class KeptLandmarks:
    """Retired landmarks as regressions on the active state (RL-1): ``F`` (3n, dim A), the
    residual covariances ``E`` (n, 3, 3), the means, and what the map output needs."""

    def __init__(self, n_active: int):
        self.F = np.zeros((0, n_active))
        self.E = np.zeros((0, 3, 3))
        self.mean = np.zeros((0, 3))
        self.first = np.zeros((0, 3))
        self.track = np.zeros(0, dtype=np.int64)
        self.inverse = np.zeros(0, dtype=bool)  # anchored inverse depth (else world xyz)
        self.anchor_R = np.zeros((0, 3, 3))
        self.anchor_p = np.zeros((0, 3))

    @property
    def n(self) -> int:
        return int(self.track.size)

    def covariances(self, P: np.ndarray, which: np.ndarray | None = None) -> np.ndarray:
        """(RL-1) ``F_j P F_j^T + E_j`` (k, 3, 3) for ``which`` (all by default); ``P`` the
        active covariance."""
        Fb = landmark_blocks(self.F)
        E = self.E
        if which is not None:
            Fb, E = Fb[which], E[which]
        FP = Fb @ P
        return np.einsum("nim,njm->nij", FP, Fb) + E

    # --- the active state changes shape --------------------------------------------------
    def retire(self, P, keep, rows, mean, first, track, inverse, anchor_R, anchor_p) -> None:
        """(RL-4) Landmarks at ``rows`` (k, 3) of the active covariance ``P`` leave it; ``keep``
        the indices of the active state that remains."""
        L = rows.ravel()
        P_RR, P_LR = P[np.ix_(keep, keep)], P[np.ix_(L, keep)]
        F_L = solve_spd(P_RR, P_LR.T).T  # (3k, dim R)
        cond = P[np.ix_(L, L)] - F_L @ P_LR.T  # cov(x_L | x_R)
        cond = 0.5 * (cond + cond.T)
        n3 = self.F.shape[0]
        F = np.empty((n3 + L.size, keep.size))  # the retired rows, then the new ones
        np.take(self.F, keep, axis=1, out=F[:n3])
        if n3:
            F_old = self.F[:, L]
            dgemm(1.0, F_L.T, F_old.T, beta=1.0, c=F[:n3].T, overwrite_c=1)  # += F_.L F_L
            self.E = self.E + np.einsum("nim,njm->nij", landmark_blocks(F_old @ cond), landmark_blocks(F_old))
        F[n3:] = F_L
        k = track.size
        own = cond.reshape(k, 3, k, 3)[np.arange(k), :, np.arange(k), :]
        self.F = F
        self.E = np.concatenate([self.E, own])
        self.mean = np.concatenate([self.mean, mean])
        self.first = np.concatenate([self.first, first])
        self.track = np.concatenate([self.track, track])
        self.inverse = np.concatenate([self.inverse, inverse])
        self.anchor_R = np.concatenate([self.anchor_R, anchor_R])
        self.anchor_p = np.concatenate([self.anchor_p, anchor_p])

    def augment(self, m: int) -> None:
        """``m`` new active rows that depend on the pose and independent noise: zero columns."""
        self.F = np.concatenate([self.F, np.zeros((self.F.shape[0], m))], axis=1)

    def transform_columns(self, cols: np.ndarray, J: np.ndarray) -> None:
        """Active landmarks in ``cols`` (k, 3) reparameterised as ``x' = J x`` (J (k, 3, 3))."""
        F = self.F
        F[:, cols] = np.einsum("nkj,kji->nki", F[:, cols], np.linalg.inv(J))

    # --- the filter's steps ----------------------------------------------------------------
    def predict(self, Phi: np.ndarray, Q: np.ndarray, P_new: np.ndarray) -> None:
        """(RL-2) after the active block's prediction ``P_new = Phi P Phi^T + Q`` (core rows)."""
        c = Phi.shape[0]
        F = self.F
        F[:, :c] = F[:, :c] @ np.linalg.inv(Phi)
        I_c = np.zeros((P_new.shape[0], c))
        I_c[np.arange(c), np.arange(c)] = 1.0
        Pinv_c = solve_spd(P_new, I_c).T  # rows 0:c of P_new^-1
        G = landmark_blocks(F[:, :c])
        K = Q - Q @ Pinv_c[:, :c] @ Q
        self.E = self.E + G @ (0.5 * (K + K.T)) @ G.transpose(0, 2, 1)
        dgemm(-1.0, (Q @ Pinv_c).T, F[:, :c].T, beta=1.0, c=F.T, overwrite_c=1)  # F -= F_c Q P'^-1_c.

    def update(self, dx: np.ndarray, linearisation: str, E: np.ndarray,
               C_active: np.ndarray | None, U_prior: np.ndarray) -> None:
        """The mean moves by ``F dx`` (``dx`` the active state's increment); then the transport
        (RL-3): ``T_A`` is ``Ad(E)`` on the pose and ``C_active`` (3m, 6) on the active landmarks,
        ``C_r`` the retired rows' own (:func:`oc_transport_rows`) with "oc"; "fej" moves the
        pose only, "standard" does not transport."""
        dm = (self.F @ dx).reshape(-1, 3)
        x_prior = self.mean
        self.mean = self.mean + dm
        if linearisation == "standard":
            return
        F = self.F
        pose = F[:, :6]
        if linearisation == "oc":
            C = oc_transport_rows(dm, x_prior, self.mean, self.inverse, self.anchor_R,
                                  self.anchor_p, U_prior)
            pose += C.reshape(-1, 6)
            if C_active is not None and C_active.size:
                pose -= F[:, F.shape[1] - C_active.shape[0] :] @ C_active
        F[:, :6] = pose @ np.linalg.inv(adjoint(E))

    def convert_linear(self, P: np.ndarray, centre: np.ndarray, threshold: float,
                       linearisation: str) -> None:
        """(ID-6) Retired inverse-depth landmarks whose linearity index seen from ``centre`` is
        below ``threshold`` become world points, as active ones do (``P`` the active covariance)."""
        ids = self.linear_enough(P, centre, threshold)
        if ids.size == 0:
            return
        x, R_a, p_a = self.mean[ids], self.anchor_R[ids], self.anchor_p[ids]
        J = idp.world_jacobian(self.first[ids] if linearisation == "fej" else x, R_a)
        rows = (3 * ids[:, None] + np.arange(3)).ravel()
        self.F[rows] = (J @ landmark_blocks(self.F[rows])).reshape(3 * ids.size, -1)
        self.E[ids] = J @ self.E[ids] @ J.transpose(0, 2, 1)
        self.mean[ids] = idp.world_point(x, R_a, p_a)
        self.first[ids] = idp.world_point(self.first[ids], R_a, p_a)
        self.inverse[ids] = False

    def linear_enough(self, P: np.ndarray, centre: np.ndarray, threshold: float) -> np.ndarray:
        """The inverse-depth landmarks whose linearity index (ID-5) seen from ``centre`` is
        below ``threshold``, their inverse-depth variance from RL-1 (``P`` the active covariance)."""
        ids = np.flatnonzero(self.inverse)
        if threshold <= 0 or ids.size == 0:
            return ids[:0]
        f = self.F[3 * ids + 2]  # the inverse-depth rows
        var_rho = np.einsum("nm,nm->n", f @ P, f) + self.E[ids, 2, 2]
        L = idp.linearity_index(self.mean[ids], var_rho, self.anchor_R[ids], self.anchor_p[ids], centre)
        return ids[L < threshold]

    def world(self, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World means (n, 3) and covariances (n, 3, 3), first order for inverse-depth ones."""
        mean, cov = self.mean.copy(), self.covariances(P)
        self._inverse_depth_to_world(mean, cov)
        return mean, cov

    def _inverse_depth_to_world(self, mean: np.ndarray, cov: np.ndarray) -> None:
        """(ID-6) The inverse-depth landmarks' rows of ``mean`` and ``cov`` (their own
        coordinates on entry) as world points, in place; first order for the covariance."""
        i = np.flatnonzero(self.inverse)
        if i.size:
            J = idp.world_jacobian(self.mean[i], self.anchor_R[i])
            mean[i] = idp.world_point(self.mean[i], self.anchor_R[i], self.anchor_p[i])
            cov[i] = J @ cov[i] @ J.transpose(0, 2, 1)
