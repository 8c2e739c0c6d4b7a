"""Joint EKF SLAM: one state ``[d, (b_g), m_1 .. m_n]`` with the full joint covariance.

* State: the inverse IMU pose ``U`` (left perturbation ``d``, paper convention), optionally a
  gyro bias ``b_g`` (rad/s, random walk; the prediction uses ``w - b_g``), a speed scale ``s``
  (relative, random walk; the prediction uses ``(1 + s) v``; ``config.speed_scale``), and the
  landmarks of the *active* tracks. Layout of the covariance ``P``: pose rows 0:6, bias rows
  6:9 when ``config.gyro_bias``, the scale's row after them when ``config.speed_scale`` (the
  *core* rows), then 3 rows per active landmark in slot order.
* Prediction (paper eq. 11): pose/bias block ``Phi P Phi^T + Q``, cross block ``Phi P_cx``.
* Update: every accepted observation of the frame in one stacked update, with the lossless
  3-row stereo reduction of :mod:`ekf.stereo_update`; ``P <- P - Y^T Y`` with
  ``Y = L^-1 (P H^T)^T``, ``L L^T = S`` (Cholesky), which is ``P - K S K^T`` (the Joseph form's
  value for the optimal gain) at a fraction of its cost; ``P`` is symmetrised after each step.
* New landmarks: ``m = U^-1 imu_T_cam p_cam(z)`` with covariance ``J_d P_dd J_d^T + J_z V J_z^T``
  and cross-covariance ``J_d P_d,x`` to the pose, bias and every other active landmark.
* Landmark parameterisation (``config.landmark_parameterisation``): world ``m`` ("euclidean"),
  or anchored inverse depth ``x = [alpha, beta, rho]`` (:mod:`ekf.inverse_depth`), whose rows
  are turned into ``m`` (``P <- J P J^T``, ID-6) once the linearity index (ID-5) allows; the two
  kinds share the state, each landmark has 3 rows either way.
* Tracks whose last observation has passed are marginalised out (deleting their rows and
  columns is exact for a Gaussian); their final mean and 3x3 covariance go to the map.
  ``config.keep_landmarks`` keeps every landmark in the state instead (textbook EKF SLAM): an
  ended track's landmark keeps being refined through its cross-covariance with the pose. Its
  rows are kept exactly, and cheaply, by :class:`ekf.kept_landmarks.KeptLandmarks`;
  ``run_joint(..., textbook=True)`` runs the dense ``O(n^2)`` form instead (the reference).

**Pixel errors as AR(1)** (``config.pixel_reading = "ar1"``). A feature tracker's pixel error
drifts along a track: ``e_k = a e_(k-1) + w_k`` with ``a = config.pixel_ar1``, marginal sigma
``s = pixel_sigma sqrt((1 - a) / (1 + a))`` (``pixel_sigma`` is the long-run sigma) and
innovation ``w_k`` of sigma ``s sqrt(1 - a^2)``, independent of every earlier error. Read as
independent rows of sigma ``s`` such errors make the filter overconfident; of the long-run
sigma, too wide for the frame-to-frame motion. The exact reading (Bryson and Henrikson's
measurement differencing, in the stochastic-cloning form of Roumeliotis and Burdick 2002):
the state carries a clone ``c`` of the previous frame's pose (6 more core rows, ``P``'s copy
of the pose's rows made at each prediction, held fixed by it), a track's first row (and any row
whose previous one was not accepted in the previous frame) is read as it is with ``s``, and
every later row as

    y_k = z_k - a z_(k-1) = h(U_k, m) - a h(U_c, m) + w_k,   R = (1 - a^2) R3,

with Jacobians ``[H_U(U_k), -a H_U(U_c), H_m(U_k) - a H_m(U_c)]`` on pose, clone and landmark.
The rows' noises are then independent, so the stacked update is exact for a linear model.
Not with ``keep_landmarks`` (the kept landmarks' regression on the state would have to follow
each clone).
"""

from __future__ import annotations

import numpy as np
from scipy.linalg.blas import dtrsm
from scipy.linalg.lapack import dpotrf

from vislam.ekf.config import FilterConfig
from vislam.ekf.errors import InputError
from vislam.ekf.estimate import Estimate
from vislam.ekf.numerics import (NumericalGuard, Scratch, UpdateRejected, add_pose_rows,
                                 all_finite, finite_norm2, finite_rows)
from vislam.ekf import inverse_depth as idp
from vislam.ekf.geometry import adjoint, hat, se3_inv
from vislam.ekf.kept_landmarks import KeptLandmarks, map_with_kept, oc_transport_rows
from vislam.ekf.prediction import (
    se3_exp_single,
    error_state_transition,
    twist_error_matrix,
    predict_mean,
    prediction_jacobian,
    process_noise,
)
from vislam.ekf.conventions import ekf_cov_to_estimate
from vislam.ekf.driver import run_filter
from vislam.ekf.filter import FrameObservations, Landmarks, MotionInput, UpdateCounts
from vislam.ekf.runner import Progress
from vislam.ekf.sequence import Sequence
from vislam.ekf.stereo_update import StereoModel

_AR3 = np.arange(3)


class JointState:
    """Mean and joint covariance of ``[pose, (gyro bias), active landmarks]``."""

    def __init__(self, config: FilterConfig, n_tracks: int, textbook: bool = False):
        base = (9 if config.gyro_bias else 6) + (1 if config.speed_scale else 0)
        #: AR(1) pixel errors (module docstring): their coefficient, the first row of the
        #: previous pose's clone (None: no clone), its pose and the frame it is of.
        self.ar1 = float(config.pixel_ar1) if config.pixel_reading == "ar1" else 0.0
        self.clone = base if self.ar1 > 0 else None
        if self.clone is not None and config.keep_landmarks:
            raise InputError("setting 'pixel_reading' = \"ar1\" cannot be combined with "
                             "'keep_landmarks' in ekf-joint (ekf/joint.py)")
        self.base = base  # rows of pose, bias and scale
        self.core = base + (6 if self.clone is not None else 0)
        self.Uc = np.eye(4)
        self.frame = -1  # the frame of the last update
        self.clone_frame = -1
        self.U = np.eye(4)
        self.bias = np.zeros(3)
        self.scale = 0.0
        self.has_bias = bool(config.gyro_bias)
        self.P = np.zeros((self.core, self.core))
        self.P[:6, :6] = config.initial_pose_cov
        self.W = config.velocity_cov  # the twist noise of every prediction
        if config.gyro_bias:
            self.P[6:9, 6:9] = config.gyro_bias_sigma**2 * np.eye(3)
        #: the speed scale's row of P (None without one)
        self.scale_row = base - 1 if config.speed_scale else None
        if config.speed_scale:
            self.P[self.scale_row, self.scale_row] = config.speed_scale_sigma**2
        self.lm_mean = np.zeros((0, 3))
        self.lm_first = np.zeros((0, 3))  # first estimates (FEJ linearisation points)
        self.linearisation = config.joint_linearisation
        self.n_numerical = 0  # observations the last update gated out for numerical reasons
        #: the last update's accepted slots and their log predictive density (None: no update)
        self.last_loglik: float | None = None
        self.last_accepted: np.ndarray | None = None
        self.lm_track = np.zeros(0, dtype=np.int64)
        # AR(1) rows: each landmark's last accepted pixels and their frame.
        self.lm_prev_z = np.zeros((0, 4))
        self.lm_prev_frame = np.zeros(0, dtype=np.int64)
        # Inverse-depth landmarks: which slots, and each one's anchor (world_T_camera).
        self.inverse_depth = config.landmark_parameterisation == "inverse-depth"
        self.linearity = config.inverse_depth_linearity
        self.lm_id = np.zeros(0, dtype=bool)
        self.n_converted = 0  # inverse-depth landmarks turned Euclidean so far
        self.anchor_R = np.zeros((0, 3, 3))
        self.anchor_p = np.zeros((0, 3))
        self.slot = -np.ones(n_tracks, dtype=np.int64)
        self.ever = np.zeros(n_tracks, dtype=bool)
        # The map: final landmark means and covariances (NaN where none).
        self.map_mean = np.full((n_tracks, 3), np.nan)
        self.map_cov = np.full((n_tracks, 3, 3), np.nan)
        # keep_landmarks: ended tracks' landmarks leave the active state but keep their rows.
        self.retired = KeptLandmarks(self.core) if config.keep_landmarks and not textbook else None
        self.scratch = Scratch()

    @property
    def n_landmarks(self) -> int:
        return int(self.lm_track.size)

    def landmark_rows(self, slots: np.ndarray) -> np.ndarray:
        """Rows of ``P`` (k, 3) for landmark slots (k,)."""
        return self.core + 3 * slots[:, None] + _AR3

    # --- the measurement of either kind of landmark --------------------------------------
    def camera_points(self, model: StereoModel, slots: np.ndarray, x: np.ndarray,
                      U: np.ndarray | None = None) -> np.ndarray:
        """``q = cam_T_imu U m_h`` (k, 4) of landmark coordinates ``x`` (k, 3) in ``slots``
        (``U`` the current pose unless given)."""
        U = self.U if U is None else U
        i = self.lm_id[slots] if self.inverse_depth else None
        if i is None or not i.any():
            return model.camera_points(U, x)
        q = np.empty((x.shape[0], 4))
        s = slots[i]
        m_h = idp.homogeneous_point(x[i], self.anchor_R[s], self.anchor_p[s])
        q[i] = m_h @ (model.cam_T_imu @ U).T
        if not i.all():
            q[~i] = model.camera_points(U, x[~i])
        return q

    def jacobians(self, model: StereoModel, slots, x, q, U: np.ndarray | None = None):
        """Reduced ``(H_pose (k, 3, 6), H_landmark (k, 3, 3))`` at coordinates ``x`` (and at
        pose ``U``, the current one unless given)."""
        U = self.U if U is None else U
        i = self.lm_id[slots] if self.inverse_depth else None
        if i is None or not i.any():
            return model.jacobians(U, x, q, reduced=True)
        s = slots[i]
        R_a, p_a = self.anchor_R[s], self.anchor_p[s]
        m_h = idp.homogeneous_point(x[i], R_a, p_a)
        G = idp.homogeneous_jacobian(R_a, p_a)
        if i.all():
            return model.homogeneous_jacobians(U, m_h, G, q)
        Hp, Hm = np.empty((x.shape[0], 3, 6)), np.empty((x.shape[0], 3, 3))
        Hp[i], Hm[i] = model.homogeneous_jacobians(U, m_h, G, q[i])
        Hp[~i], Hm[~i] = model.jacobians(U, x[~i], q[~i], reduced=True)
        return Hp, Hm

    # --- prediction ---------------------------------------------------------------------
    def predict(self, tau: float, u: np.ndarray, config: FilterConfig) -> None:
        """Paper eq. 11 on the pose (and bias) block; cross-covariances follow ``Phi``. With
        AR(1) pixels the clone first takes the pose's rows, and ``Phi`` holds it fixed."""
        u_c, Phi, Q = self.transition(tau, u, config)
        if self.clone is not None:
            self.copy_pose_to_clone()
            Phi = _block_diagonal(Phi, np.eye(6))
            Q = _block_diagonal(Q, np.zeros((6, 6)))
        self.propagate(tau, u_c, Phi, Q)

    def transition(self, tau: float, u: np.ndarray, config: FilterConfig):
        """``(u_c, Phi, Q)`` of one prediction on the rows of pose, bias and scale (the first
        ``self.base`` rows): the corrected twist, the error transition and its noise."""
        c = self.base
        if c > 6:  # the twist errors [b_g; s] where configured (ekf.prediction.error_state_transition)
            B = twist_error_matrix(u, config.gyro_bias, config.speed_scale)
            errors = np.r_[self.bias if config.gyro_bias else [], [self.scale] if config.speed_scale else []]
            u_c, Phi, _ = error_state_transition(tau, u, errors, B)
            Q = np.zeros((c, c))
            Q[:6, :6] = process_noise(tau, self.W)
            if config.gyro_bias:
                Q[6:9, 6:9] = config.gyro_bias_walk**2 * tau * np.eye(3)
            if config.speed_scale:
                Q[-1, -1] = config.speed_scale_walk**2 * tau
            return u_c, Phi, Q
        return u, prediction_jacobian(tau, u), process_noise(tau, self.W)

    def propagate(self, tau: float, u_c: np.ndarray, Phi: np.ndarray, Q: np.ndarray) -> None:
        """The mean along ``u_c`` and ``P <- Phi P Phi^T + Q`` on the first ``len(Phi)`` (core)
        rows, their cross-covariances by ``Phi``, and the retired landmarks' share."""
        c = Phi.shape[0]
        self.U = predict_mean(self.U, tau, u_c)
        P = self.P
        Pcc = Phi @ P[:c, :c] @ Phi.T + Q
        P[:c, :c] = 0.5 * (Pcc + Pcc.T)
        if P.shape[0] > c:
            P[:c, c:] = Phi @ P[:c, c:]
            P[c:, :c] = P[:c, c:].T
        if self.retired is not None and self.retired.n:
            self.retired.predict(Phi, Q, P)

    def copy_pose_to_clone(self) -> None:
        """The clone becomes the current pose: its rows and columns of ``P`` the pose's."""
        k = self.clone
        P = self.P
        P[k : k + 6, :] = P[:6, :]
        P[:, k : k + 6] = P[:, :6]
        self.Uc = self.U.copy()
        self.clone_frame = self.frame

    def differenced_rows(self, model: StereoModel, slots, m, z, m_lin):
        """The AR(1) rows of an update (module docstring) among observations of ``slots``
        (landmark estimates ``m``, linearisation points ``m_lin``, pixels ``z``): which rows are
        differenced ``d`` (indices), the clone's Jacobians ``-a H_U(U_c)`` (len(d), 3, 6), the
        landmark Jacobians' share ``-a H_m(U_c)`` (len(d), 3, 3), the previous rows' reduced and
        4-row residuals at ``U_c`` times ``a``."""
        d = np.flatnonzero(self.lm_prev_frame[slots] == self.clone_frame)
        if self.clone_frame < 0 or d.size == 0:
            return None
        sd = slots[d]
        qc = self.camera_points(model, sd, m[d], self.Uc)
        ok = model.valid_predictions(qc)
        qc_lin = qc if m_lin is None else self.camera_points(model, sd, m_lin[d], self.Uc)
        if m_lin is not None:
            ok &= model.valid_predictions(qc_lin)
        d, sd, qc, qc_lin = d[ok], sd[ok], qc[ok], qc_lin[ok]
        if d.size == 0:
            return None
        Hpc, Hmc = self.jacobians(model, sd, m[d] if m_lin is None else m_lin[d], qc_lin, self.Uc)
        a = self.ar1
        z_prev = self.lm_prev_z[sd]
        return (d, -a * Hpc, -a * Hmc, a * model.reduced_innovation(z_prev, qc),
                a * (z_prev - model.predicted_pixels(qc)))

    # --- update -------------------------------------------------------------------------
    def update(self, model: StereoModel, tracks: np.ndarray, z: np.ndarray) -> tuple[int, int]:
        """One stacked update with the observations of active landmarks (paper eq. 8 + 14
        jointly). ``tracks`` must all be active. Returns ``(n_accepted, n_rejected)``.

        Observations whose own innovation covariance is unusable (singular, not finite) are
        gated out and counted in ``self.n_numerical``. Raises
        :class:`~ekf.numerics.UpdateRejected`, with the state unchanged, when the stacked
        update cannot be computed (``S`` not positive definite, a non-finite gain or
        correction, a pose or bias variance that would not stay positive)."""
        self.n_numerical = 0
        self.last_loglik, self.last_accepted = None, None
        if tracks.size == 0:
            return 0, 0
        slots = self.slot[tracks]
        m = self.lm_mean[slots]
        q = self.camera_points(model, slots, m)
        ok = model.valid_predictions(q)
        fej = self.linearisation == "fej"
        if fej:  # Jacobians at the landmarks' first estimates (FEJ), residuals at the current ones
            m_lin = self.lm_first[slots]
            q_lin = self.camera_points(model, slots, m_lin)
            ok &= model.valid_predictions(q_lin)
        if not np.all(ok):
            slots, m, q, z = slots[ok], m[ok], q[ok], z[ok]
            if fej:
                m_lin, q_lin = m_lin[ok], q_lin[ok]
        k = slots.size
        if k == 0:
            return 0, int(tracks.size)
        P = self.P
        N = P.shape[0]
        if fej:
            Hp, Hm = self.jacobians(model, slots, m_lin, q_lin)
        else:
            Hp, Hm = self.jacobians(model, slots, m, q)  # (k,3,6), (k,3,3)
        # AR(1) pixels: the differenced rows' clone columns, landmark Jacobians, residuals and
        # noise (w: each row's pixel-noise scale, 1 - a^2 where differenced).
        ar = None if self.clone is None else self.differenced_rows(model, slots, m, z,
                                                                   m_lin if fej else None)
        if ar is None:
            Hx, pose_cols = Hp.reshape(3 * k, 6), slice(0, 6)
        else:
            d, Hc, Hmc, r_prev, r4_prev = ar
            Hm = Hm.copy()
            Hm[d] += Hmc
            Hx3 = np.zeros((k, 3, self.core))
            Hx3[:, :, :6] = Hp
            Hx3[d, :, self.clone : self.clone + 6] = Hc
            Hx, pose_cols = Hx3.reshape(3 * k, self.core), slice(0, self.core)
            w = np.ones(k)
            w[d] = 1.0 - self.ar1**2
        rows = self.landmark_rows(slots).ravel()  # (3k,)
        # P H^T (N, 3k), using the sparsity of H: 6 pose columns (core ones with a clone) + 3
        # landmark columns per row; it and S = H P H^T + I (x) R3 in reused memory (Scratch),
        # with one spare row of B for the residual below.
        work = self.scratch
        B = work.array("B", (N + 1, 3 * k))
        PHt = np.matmul(P[:, pose_cols], Hx.T, out=B[:N])
        Pc = np.take(P, rows, axis=1, out=work.array("Pc", (N, 3 * k)), mode="clip")
        # += Pc_j Hm_j^T for each landmark j: one batched GEMM (np.einsum's loop took 10x longer)
        PcHm = np.matmul(Pc.reshape(N, k, 3).transpose(1, 0, 2), Hm.transpose(0, 2, 1),
                         out=work.array("PcHm", (k, N, 3)))
        PHt.reshape(N, k, 3)[...] += PcHm.transpose(1, 0, 2)
        S = np.matmul(Hx, PHt[pose_cols], out=work.array("S", (3 * k, 3 * k)))
        PHt_l = np.take(PHt, rows, axis=0, out=work.array("PHt_l", (3 * k, 3 * k)), mode="clip")
        S += np.matmul(Hm, PHt_l.reshape(k, 3, 3 * k), out=work.array("HmPHt", (k, 3, 3 * k))).reshape(
            3 * k, 3 * k
        )
        if ar is None:
            S3_diag = S.reshape(k, 3, k, 3)[np.arange(k), :, np.arange(k), :] + model.R3
            acc, self.n_numerical = model.gate_check(z, q, S3_diag)
        else:
            R_rows = w[:, None, None] * model.R3
            S3_diag = S.reshape(k, 3, k, 3)[np.arange(k), :, np.arange(k), :] + R_rows
            r4 = z - model.predicted_pixels(q)
            r4[d] -= r4_prev
            acc, self.n_numerical = model.gate_innovations(r4, S3_diag, w)
        a = int(acc.sum())
        if a == 0:
            return 0, int(tracks.size)
        if ar is None:
            r = model.reduced_innovation(z[acc], q[acc]).ravel()
        else:
            r_all = model.reduced_innovation(z, q)
            r_all[d] -= r_prev
            r = r_all[acc].ravel()
        if a < k:
            sel = (3 * np.nonzero(acc)[0][:, None] + _AR3).ravel()
            S_rows = np.take(S, sel, axis=0, out=work.array("S_rows", (3 * a, 3 * k)), mode="clip")
            S = np.take(S_rows, sel, axis=1, out=work.array("S_a", (3 * a, 3 * a)), mode="clip")
            B_a = work.array("B_a", (N + 1, 3 * a))
            np.take(PHt, sel, axis=1, out=B_a[:N], mode="clip")
            B = B_a
        # Only the lower triangle of S is read by the Cholesky factorisation.
        S.reshape(a, 3, a, 3)[np.arange(a), :, np.arange(a), :] += (
            model.R3 if ar is None else R_rows[acc])
        # LAPACK and BLAS directly (scipy.linalg's wrappers cost 10-15 us a call here).
        L, info = dpotrf(S, lower=1, clean=0, overwrite_a=1)
        if info != 0:
            raise UpdateRejected(f"innovation covariance of {a} observations not positive definite")
        # One triangular solve for Y = L^-1 (P H^T)^T and e = L^-1 r (r as an extra column).
        B[N] = r
        Ye = dtrsm(1.0, L, B.T, lower=1, overwrite_b=1)
        Y, e = Ye[:, :N], Ye[:, N]
        # The accepted rows' log predictive density given everything before (their stacked
        # innovation's): a reading's out-of-sample score (benchmarks/ar1_pixel_ekf.py).
        self.last_loglik = float(-0.5 * e @ e - np.log(np.diag(L)).sum() - 1.5 * a * np.log(2 * np.pi))
        self.last_accepted = slots[acc]
        dx = Y.T @ e  # = K r
        c = self.core
        if not (
            np.isfinite(dx).all()
            and finite_norm2(Ye)
            and np.all(np.einsum("ij,ij->j", Y[:, :c], Y[:, :c]) < P.diagonal()[:c])
        ):
            raise UpdateRejected(
                f"gain of {a} observations not finite or pose covariance not positive after it"
            )
        symmetric_downdate(P, Y, work.array("YtY", (N, N)))  # P <- P - Y^T Y = P - K S K^T
        if self.clone is not None:  # the rows the next frame's AR(1) rows difference against
            self.lm_prev_z[slots[acc]] = z[acc]
            self.lm_prev_frame[slots[acc]] = self.frame
        E = se3_exp_single(dx[:6])
        U_prior = self.U
        self.U = E @ self.U  # paper eq. 14: mu <- exp((K r)^) mu
        if self.has_bias:
            self.bias = self.bias + dx[6:9]
        if self.scale_row is not None:
            self.scale = self.scale + float(dx[self.scale_row])
        dm = dx[self.core :].reshape(-1, 3)
        x_prior = self.lm_mean
        self.lm_mean = self.lm_mean + dm
        if self.retired is not None and self.retired.n:
            self.update_retired(dx, E, U_prior, dm, x_prior)
        if self.linearisation == "oc" and self.inverse_depth and self.lm_id.any():
            transport(self.P, self.core, E, self.transport_rows(dm, x_prior, U_prior))
        elif self.linearisation != "standard":
            gauge_transport(self.P, self.core, E, U_prior[:3, :3], dm if self.linearisation == "oc" else None)
        return a, int(tracks.size) - a

    def update_retired(self, dx, E, U_prior, dm, x_prior) -> None:
        """The retired landmarks' share of an update (``dx`` the active increment) and of the
        transport that follows it (:meth:`ekf.kept_landmarks.KeptLandmarks.update`)."""
        C_a = self.transport_rows(dm, x_prior, U_prior) if self.linearisation == "oc" else None
        self.retired.update(dx, self.linearisation, E, C_a, U_prior)

    def transport_rows(self, dm: np.ndarray, x_prior: np.ndarray, U_prior: np.ndarray) -> np.ndarray:
        """The landmark rows ``C`` (3n, 6) of :func:`transport` (:func:`ekf.kept_landmarks.oc_transport_rows`
        of the active landmarks; for Euclidean ones :func:`gauge_transport`'s ``[0, dm^ R-^T]``)."""
        inverse = self.lm_id if self.inverse_depth else np.zeros(self.n_landmarks, dtype=bool)
        return oc_transport_rows(dm, x_prior, self.lm_mean, inverse, self.anchor_R, self.anchor_p,
                                 U_prior).reshape(-1, 6)

    # --- landmark initialisation and marginalisation ------------------------------------
    def initialise(
        self, model: StereoModel, tracks: np.ndarray, z: np.ndarray, ends_now: np.ndarray
    ) -> None:
        """Add landmarks of ``tracks`` (new, valid observations ``z``) with cross-covariances.

        Tracks with ``ends_now`` go straight to the map (they will never be observed again).
        Returns the number of tracks not initialised because their triangulation is not
        finite (an absurd but finite observation).
        """
        if tracks.size == 0:
            return 0
        m, J_d, Cz = model.initialise_with_cov(self.U, z)  # Cz: the pixel-noise part
        n_bad = 0
        if not all_finite(m, J_d, Cz):
            fin = finite_rows(m) & finite_rows(J_d) & finite_rows(Cz)
            n_bad = int(fin.size - fin.sum())
            tracks, m, J_d, Cz, ends_now = tracks[fin], m[fin], J_d[fin], Cz[fin], ends_now[fin]
            z = z[fin]
            if tracks.size == 0:
                return n_bad
        Pdd = self.P[:6, :6]
        self.ever[tracks] = True
        if np.any(ends_now):
            tr = tracks[ends_now]
            self.map_mean[tr] = m[ends_now]
            Je = J_d[ends_now]
            cov = Cz[ends_now] + Je @ Pdd @ np.swapaxes(Je, 1, 2)
            self.map_cov[tr] = 0.5 * (cov + np.swapaxes(cov, 1, 2))
        add = ~ends_now
        n = int(add.sum())
        if n == 0:
            return n_bad
        m, J_d, Cz = m[add], J_d[add], Cz[add]
        if self.inverse_depth:  # the same landmarks in anchored inverse depth (ID-3, ID-4)
            m, R_a, p_a, Cz = idp.new_landmarks(z[add], model.K, model.baseline, model.V,
                                                se3_inv(self.U) @ model.imu_T_cam)
            J_d = idp.inverse_jacobian(m, R_a) @ J_d
        Jd = J_d.reshape(3 * n, 6)
        B = Jd @ self.P[:6, :]  # cross-covariance with the whole state (3n, N)
        if self.retired is not None:
            self.retired.augment(3 * n)
        C = B[:, :6] @ Jd.T
        C.reshape(n, 3, n, 3)[np.arange(n), :, np.arange(n), :] += Cz
        N = self.P.shape[0]
        P = self.scratch.covariance(self.P, N + 3 * n)
        P[:N, :N] = self.P
        P[N:, :N] = B
        P[:N, N:] = B.T
        P[N:, N:] = 0.5 * (C + C.T)
        self.P = P
        first = self.n_landmarks
        self.lm_mean = np.concatenate([self.lm_mean, m])
        self.lm_first = np.concatenate([self.lm_first, m])
        self.lm_track = np.concatenate([self.lm_track, tracks[add]])
        self.lm_prev_z = np.concatenate([self.lm_prev_z, z[add]])
        self.lm_prev_frame = np.concatenate([self.lm_prev_frame, np.full(n, self.frame)])
        self.slot[tracks[add]] = first + np.arange(n)
        if self.inverse_depth:
            self.lm_id = np.concatenate([self.lm_id, np.ones(n, dtype=bool)])
            self.anchor_R = np.concatenate([self.anchor_R, R_a])
            self.anchor_p = np.concatenate([self.anchor_p, p_a])
        return n_bad

    # --- inverse depth -> Euclidean ----------------------------------------------------
    def convert_linear(self, model: StereoModel) -> int:
        """Turn every inverse-depth landmark whose linearity index (ID-5) seen from the current
        camera is below ``inverse_depth_linearity`` into world ``m`` (ID-6); returns how many."""
        if not self.inverse_depth or self.linearity <= 0:
            return 0
        centre = (se3_inv(self.U) @ model.imu_T_cam)[:3, 3]
        if self.retired is not None:
            self.retired.convert_linear(self.P, centre, self.linearity, self.linearisation)
        if not self.lm_id.any():
            return 0
        ids = np.flatnonzero(self.lm_id)
        rho_rows = self.core + 3 * ids + 2
        L = idp.linearity_index(
            self.lm_mean[ids], self.P[rho_rows, rho_rows], self.anchor_R[ids], self.anchor_p[ids], centre
        )
        ids = ids[L < self.linearity]
        if ids.size:
            self.to_euclidean(ids)
            self.n_converted += int(ids.size)
        return int(ids.size)

    def to_euclidean(self, ids: np.ndarray) -> None:
        """(ID-6) Inverse-depth slots ``ids`` to world ``m``: ``P <- J P J^T`` on their rows.

        ``J`` is taken at the linearisation point of the landmark's Jacobians: the current
        estimate, or with "fej" the first one (so that ``J N(x_first) = [I, -m_first^]``, the
        Euclidean first-estimate nullspace; taken at the current estimate, FEJ's nullspace would
        be lost)."""
        x, R_a, p_a = self.lm_mean[ids], self.anchor_R[ids], self.anchor_p[ids]
        J = idp.world_jacobian(self.lm_first[ids] if self.linearisation == "fej" else x, R_a)
        rows = self.landmark_rows(ids)  # (k, 3)
        P = self.P
        P[rows] = J @ P[rows]
        P[:, rows] = np.einsum("nkj,kij->nki", P[:, rows], J)
        if self.retired is not None:
            self.retired.transform_columns(rows, J)
        self.lm_mean[ids] = idp.world_point(x, R_a, p_a)
        self.lm_first[ids] = idp.world_point(self.lm_first[ids], R_a, p_a)
        self.lm_id[ids] = False

    def world_landmarks(self, slots: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World means (k, 3) and covariances (k, 3, 3) of ``slots`` (first order for
        inverse-depth ones, ID-6)."""
        mean, cov = self.lm_mean[slots].copy(), self.landmark_covs(slots)
        if self.inverse_depth:
            i = self.lm_id[slots]
            if i.any():
                s = slots[i]
                x, R_a = self.lm_mean[s], self.anchor_R[s]
                J = idp.world_jacobian(x, R_a)
                mean[i] = idp.world_point(x, R_a, self.anchor_p[s])
                cov[i] = J @ cov[i] @ np.swapaxes(J, 1, 2)
        return mean, cov

    def landmark_covs(self, slots: np.ndarray) -> np.ndarray:
        rows = self.landmark_rows(slots)
        return self.P[rows[:, :, None], rows[:, None, :]]

    def marginalise(self, tracks: np.ndarray) -> None:
        """Move the active landmarks of ``tracks`` to the map and delete them from the state
        (with ``keep_landmarks``: to the retired landmarks, which keep their rows)."""
        tracks = tracks[self.slot[tracks] >= 0]
        if tracks.size == 0:
            return
        slots = self.slot[tracks]
        keep_lm = np.ones(self.n_landmarks, dtype=bool)
        keep_lm[slots] = False
        keep = np.concatenate([np.ones(self.core, dtype=bool), np.repeat(keep_lm, 3)])
        ix = np.nonzero(keep)[0]
        if self.retired is None:
            self.map_mean[tracks], self.map_cov[tracks] = self.world_landmarks(slots)
        else:
            k = slots.size
            ids = self.lm_id[slots] if self.inverse_depth else np.zeros(k, dtype=bool)
            R_a = self.anchor_R[slots] if self.inverse_depth else np.zeros((k, 3, 3))
            p_a = self.anchor_p[slots] if self.inverse_depth else np.zeros((k, 3))
            self.retired.retire(self.P, ix, self.landmark_rows(slots), self.lm_mean[slots],
                                self.lm_first[slots], tracks, ids, R_a, p_a)
        self.P = self.scratch.submatrix(self.P, ix)
        self.slot[tracks] = -1
        self.lm_mean = self.lm_mean[keep_lm]
        self.lm_first = self.lm_first[keep_lm]
        self.lm_track = self.lm_track[keep_lm]
        self.lm_prev_z = self.lm_prev_z[keep_lm]
        self.lm_prev_frame = self.lm_prev_frame[keep_lm]
        if self.inverse_depth:
            self.lm_id = self.lm_id[keep_lm]
            self.anchor_R = self.anchor_R[keep_lm]
            self.anchor_p = self.anchor_p[keep_lm]
        self.slot[self.lm_track] = np.arange(self.n_landmarks)

    @property
    def state_dim(self) -> int:
        """Rows of the joint covariance, retired landmarks included."""
        return self.P.shape[0] + (0 if self.retired is None else self.retired.F.shape[0])


def _block_diagonal(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    out = np.zeros((A.shape[0] + B.shape[0], A.shape[1] + B.shape[1]))
    out[: A.shape[0], : A.shape[1]] = A
    out[A.shape[0] :, A.shape[1] :] = B
    return out


def symmetric_downdate(P: np.ndarray, Y: np.ndarray, work: np.ndarray) -> None:
    """``P <- P - Y^T Y`` in place, ``work`` (N, N) memory for ``Y^T Y``. NumPy computes
    ``Y^T Y`` with BLAS ``syrk`` and mirrors it, so the product is exactly symmetric and ``P``
    stays as symmetric as it was (and it is faster than ``syrk`` into ``P`` followed by a
    masked mirror copy)."""
    P -= np.matmul(Y.T, Y, out=work)


def gauge_nullspace(U: np.ndarray, m: np.ndarray, core: int = 6) -> np.ndarray:
    """The unobservable directions (``core + 3n``, 6) of the joint state at ``(U, m)``.

    A global change of world frame ``g = exp(xi^)`` (``xi = [v; w]`` in the world) maps
    ``U -> U g^-1`` and ``m -> g m`` and leaves every measurement unchanged. To first order the
    pose's left perturbation moves by ``d = -Ad(U) xi`` and each landmark by
    ``[I, -m^] xi``; bias and scale rows (6 to ``core``) are zero. Without gravity all 6 are unobservable.
    """
    n = m.shape[0]
    N = np.zeros((core + 3 * n, 6))
    N[:6] = -adjoint(U)
    blk = N[core:].reshape(n, 3, 6)
    blk[:, :, :3] = np.eye(3)
    blk[:, :, 3:] = -hat(m)
    return N


def gauge_transport(
    P: np.ndarray, core: int, E: np.ndarray, R_prior: np.ndarray, dm: np.ndarray | None
) -> None:
    """Observability-constrained correction of ``P`` after an update (in place).

    The standard EKF propagates its error with ``F = Ad(exp(-tau u^))``, which maps the gauge
    nullspace at ``U`` to the one at ``exp(-tau u^) U`` (:func:`gauge_nullspace`); but the update
    moves the estimate from the prior ``(U-, m-)`` to ``(E U-, m- + dm)``, so the nullspace the
    filter carries no longer matches the point where the next Jacobians are evaluated, and
    the filter gains spurious information along the unobservable directions (Huang et al.
    2010; Hesch et al. 2014). Here the error is mapped by ``T`` with
    ``T N(U-, m-) = N(E U-, m- + dm)``: ``T = [[Ad(E), 0], [C, I]]``,
    ``C_j = [0, dm_j^ R_prior^T]`` (``P <- T P T^T``). For the pose block this is the unique
    solution (the FEJ transition evaluated at the prior estimate); ``dm = None`` maps the pose
    only (FEJ, landmark nullspace rows stay at first estimates). With it, the exact Jacobians
    at the current estimate satisfy ``H N = 0`` at every step, the prediction ``F N(U) =
    N(F-predicted U)`` and the initialisation ``J_d N_pose = N_landmark`` as well.
    """
    A = adjoint(E)
    if dm is not None and dm.size:
        C = np.zeros((dm.shape[0], 3, 6))
        C[:, :, 3:] = hat(dm) @ R_prior.T  # C_j = [0, D_j R^T]: only the rotation rows enter
        add_pose_rows(P, core, C.reshape(-1, 6))
    P[:6] = A @ P[:6]
    P[:, :6] = P[:, :6] @ A.T


def transport(P: np.ndarray, core: int, E: np.ndarray, C: np.ndarray) -> None:
    """``P <- T P T^T`` in place with ``T = [[Ad(E), 0, 0], [0, I, 0], [C, 0, I]]`` (pose,
    bias, landmark rows; ``C`` (3n, 6)): :func:`gauge_transport` with general landmark rows."""
    A = adjoint(E)
    add_pose_rows(P, core, C)
    P[:6] = A @ P[:6]
    P[:, :6] = P[:, :6] @ A.T


class JointEKF:
    """Joint EKF SLAM with the full pose-landmark covariance (see the module docstring): the
    per-frame protocol (:mod:`ekf.filter`) around a :class:`JointState`.

    ``textbook`` (with ``config.keep_landmarks``): keep every landmark in one dense covariance,
    ``O(n^2)`` per update, instead of :class:`ekf.kept_landmarks.KeptLandmarks`' exact rows (the
    same numbers; the reference for the test of the latter)."""

    name = "ekf-joint"

    def __init__(self, textbook: bool = False):
        self.textbook = bool(textbook)

    def initialise(self, seq: Sequence, config: FilterConfig, guard: NumericalGuard) -> None:
        self.config = config
        self.guard = guard
        self.state = JointState(config, seq.n_tracks, self.textbook)
        if self.state.clone is not None:  # a row's own sigma (module docstring)
            a = self.state.ar1
            config = config.replace(pixel_sigma=config.pixel_sigma * np.sqrt((1 - a) / (1 + a)))
        self.model = StereoModel.from_config(seq.calibration, config)
        self.last = seq.track_last_frame()
        self.max_dim = self.state.state_dim

    def predict(self, motion: MotionInput) -> None:
        st = self.state
        st.predict(motion.dt, motion.twist, self.config)
        self.guard.check_state(motion.frame, st.U, st.P[:st.core, :st.core])

    def update(self, frame: FrameObservations) -> UpdateCounts:
        st, model, guard = self.state, self.model, self.guard
        t, tracks, z = frame.frame, frame.tracks, frame.z
        st.frame = t
        valid = model.valid_observations(z, depth_limit=False)
        active = st.slot[tracks] >= 0
        upd = valid & active
        valid &= model.within_max_depth(z)  # new landmarks: within max_depth too
        try:
            n_acc, n_rej = st.update(model, tracks[upd], z[upd])
            n_num = st.n_numerical
        except UpdateRejected as exc:
            guard.reject(t, str(exc), int(upd.sum()))
            n_acc, n_num = 0, 0
        new = valid & ~active & ~st.ever[tracks]
        n_bad_init = st.initialise(model, tracks[new], z[new], self.last[tracks[new]] <= t)
        n_init = int(new.sum()) - n_bad_init
        n_num += n_bad_init
        if n_num:
            guard.reject(t, "innovation covariance or triangulation not finite", n_num)
        st.convert_linear(model)
        self.max_dim = max(self.max_dim, st.state_dim)
        return UpdateCounts(n_acc, tracks.size - n_acc - n_init, n_init)

    def marginalise(self, tracks: np.ndarray) -> None:
        if not self.config.keep_landmarks or self.state.retired is not None:
            self.state.marginalise(tracks)

    def pose(self) -> np.ndarray:
        return se3_inv(self.state.U)

    def pose_cov(self) -> np.ndarray:
        return ekf_cov_to_estimate(self.state.P[:6, :6])

    def active_landmarks(self) -> Landmarks:
        st = self.state
        if not st.n_landmarks:
            return Landmarks.none()
        return Landmarks(st.lm_track.copy(), *st.world_landmarks(np.arange(st.n_landmarks)))

    def landmark_map(self) -> tuple[np.ndarray, np.ndarray]:
        st = self.state
        return map_with_kept(st.map_mean, st.map_cov, st.retired, st.P)

    def info(self) -> dict:
        info = {"max_state_dim": int(self.max_dim)}
        if self.state.inverse_depth:
            info["inverse_depth_converted"] = self.state.n_converted
        if self.config.gyro_bias:
            info["gyro_bias"] = self.state.bias.tolist()
        if self.state.scale_row is not None:
            r = self.state.scale_row
            info["speed_scale"] = float(self.state.scale)
            info["speed_scale_sigma_final"] = float(np.sqrt(self.state.P[r, r]))
        return info


def run_joint(
    seq: Sequence, config: FilterConfig = FilterConfig(), progress: Progress = None,
    textbook: bool = False,
) -> Estimate:
    """:class:`JointEKF` over ``seq`` (:func:`ekf.driver.run_filter`)."""
    return run_filter(JointEKF(textbook), seq, config, progress)
