"""``ekf-imu-invariant``: the right-invariant EKF on raw IMU, state on SE_{2+K}(3).

**State** (:mod:`ekf.imu_invariant_propagation`, RI-1): the IMU's ``R``, ``v``, ``p`` and the
*group landmarks* (world points) form one element of SE_{2+K}(3) with the right-invariant error
``X_true = exp(xi) X`` (Barrau and Bonnabel; the invariant VIO filters of the literature, e.g.
Wu et al., "An invariant-EKF VINS algorithm", 2017; Brossard et al., 2018). Beside the group:

* the gyro and accelerometer biases (additive error). Their coupling makes this the "imperfect
  IEKF": the transition's bias columns depend on the estimate (RI-3); everything else of the
  group part propagates exactly (log-linearly);
* *inverse-depth landmarks* (:mod:`ekf.imu_landmarks`, anchored at the camera of their first
  observation, a constant of the chart): every monocular track starts there, with the
  inverse-depth prior of :class:`ekf.imu_landmarks.DepthPrior`, since a point whose depth is
  not yet known is not a Gaussian world point. Their error is additive, outside the group
  (they do not move in the propagation). Once Civera's linearity index (ID-5) falls below
  ``FilterSettings.inverse_depth_linearity`` such a landmark joins the group (IIE-4).
  Stereo tracks start in the group (triangulated, IIE-3); a stereo pair too far for a
  useful triangulation (disparity under ``min_disparity``) is not used.

Error order: ``[xi_R, xi_v, xi_p, dbg, dba]`` (15) then 3 per landmark slot, group or
inverse-depth (``in_group`` says which).

**Propagation** (per frame interval): the core's mean, transition ``Phi`` and noise ``Qc``
sample by sample (RI-2 .. RI-4, :func:`ekf.imu_invariant_propagation.propagate`), then the whole
covariance once (RI-5, :func:`~ekf.imu_invariant_propagation.frame_covariance`).

**Observations** (IIE-1). A group landmark ``l`` seen from ``(R, p)``: the IMU-frame point
``q = R^T (l - p)``, exactly ``R^T (l - p) + R^T Exp(-xi_R) J (xi_l - xi_p)`` under the error, so
``H = B [0 at xi_R, -I at xi_p, I at xi_l]`` with ``B = dz/dq R^T``: it does not depend on
``l`` or ``p`` (the invariant filter's property). An inverse-depth landmark: the Jacobians of
:mod:`ekf.imu_landmarks` (IL-2) chained onto this error, ``H_pose = dz/dq_i dq_i/dxi E`` with
``E`` the Estimate-convention map of RI-6 (``xi_est = [R^T (xi_p - p^ xi_R); R^T xi_R]``).
Each observation is gated at ``gate_probability`` (chi-square of its own innovation), the rest
update together (one Cholesky of the stacked innovation covariance).

**New landmarks** (IIE-2 monocular / IIE-3 stereo). Inverse depth: ``x`` from the first pixels
(IL-3's chart), error ``dx = C Ad(cam_T_imu) E xi - n`` with ``C`` the chart change (the
anchor is the estimated camera: its error is the pose's), so the new rows are ``J P`` with
``J = C Ad(cam_T_imu) E``. Stereo, in the group: ``l = p + R (t_ic + R_ic p_c)`` with ``p_c``
the triangulated point, and ``xi_l = xi_p + R R_ic dp_c`` to first order (the rotation error
moves ``l`` and the coordinates alike: ``l^`` cancels), so the rows are those of ``xi_p`` plus
the pixel noise ``G V G^T``, ``G = R R_ic dp_c/dz``.

**Joining the group** (IIE-4): ``l = m(x)`` (ID-1) and ``xi_l = J dx + l^ xi_R`` (``J = dm/dx``,
ID-6; ``l - l^ xi_R`` is the world error), ``P <- T P T^T`` on the slot's rows.

**State size.** At most ``max_landmarks`` slots: new tracks wait while it is full; a landmark
not seen for ``max_unseen`` frames leaves the state for the map (and a track that comes back
later starts again as a new landmark: the old one's information is dropped, which is
conservative, not overconfident).

**Read-outs** in the Estimate convention of :mod:`ekf.inertial_dead_reckoning` (gravity-aligned
world from the rest at frame 0, right perturbation of ``world_T_imu``, translation first):
``pose_cov = E P_core E^T`` (RI-6); a landmark's world covariance ``G P G^T`` with
``dl = xi_l - l^ xi_R`` (group) or ``dm = J dx`` (inverse depth).

**Initialisation**: the rest at the start (:mod:`ekf.imu_init`, as ``dead-reckoning-imu``),
its covariance moved into the invariant error by RI-6's ``S``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.linalg import solve_triangular
from scipy.linalg.lapack import dpotrf
from scipy.stats import chi2

from vislam.ekf import imu_landmarks as iml
from vislam.ekf import inverse_depth as idp
from vislam.ekf.camera import triangulate_with_jacobian
from vislam.ekf.errors import InputError
from vislam.ekf.filter import FrameObservations, Landmarks, MotionInput, UpdateCounts
from vislam.ekf.geometry import adjoint, hat
from vislam.ekf.imu_init import InitialState, RestConfig, detect_rest, rest_initial_state
from vislam.ekf.imu_invariant_propagation import (
    N_CORE, POS, ROT, estimate_pose_jacobian, frame_covariance, propagate, retract,
    retract_landmarks, strapdown_to_invariant)
from vislam.ekf.inertial import InertialDrive
from vislam.ekf.numerics import UpdateRejected
from vislam.ekf.strapdown import NavState

ESTIMATOR_NAME = "ekf-imu-invariant"

#: The columns of the core that observations see: ``xi_R`` then ``xi_p``.
POSE_COLS = np.r_[ROT.start:ROT.stop, POS.start:POS.stop]

#: World gravity direction (z up), as :mod:`ekf.inertial_dead_reckoning`.
_DOWN = np.array([0.0, 0.0, -1.0])


@dataclass(frozen=True)
class FilterSettings:
    """Settings of ``ekf-imu-invariant`` (module docstring). ``pixel_sigma`` px per coordinate;
    ``gate_probability`` of each observation's chi-square gate (None: no gate);
    ``min_depth`` of the monocular depth prior (m); ``inverse_depth_linearity`` the linearity
    index below which an inverse-depth landmark joins the group (0: never);
    ``min_disparity`` px of a stereo pair to triangulate; ``max_landmarks`` slots;
    ``max_unseen`` frames before a landmark leaves; ``max_depth`` m of a usable prediction."""

    pixel_sigma: float = 1.0
    gate_probability: float | None = 0.999
    min_depth: float = 1.0
    inverse_depth_linearity: float = 0.1
    min_disparity: float = 1.0
    max_landmarks: int = 40
    max_unseen: int = 2
    max_depth: float = 200.0
    transport: bool | str = True
    iterations: int = 1
    rest: RestConfig = RestConfig()

    def __post_init__(self) -> None:
        for key in ("pixel_sigma", "min_depth", "max_depth"):
            value = getattr(self, key)
            if not np.isfinite(value) or value <= 0:
                raise InputError(f"{ESTIMATOR_NAME}: {key} must be positive, got {value!r}")
        if self.gate_probability is not None and not 0 < self.gate_probability < 1:
            raise InputError(f"{ESTIMATOR_NAME}: gate_probability must be in (0, 1), got "
                             f"{self.gate_probability!r}")
        if self.max_landmarks < 0 or self.max_unseen < 0:
            raise InputError(f"{ESTIMATOR_NAME}: max_landmarks and max_unseen must be >= 0")


class ImuInvariantEKF:
    """The right-invariant raw-IMU EKF (module docstring) in the per-frame protocol of
    :mod:`ekf.filter`: ``initialise`` takes the :class:`ekf.inertial.InertialDrive`; each
    ``predict`` integrates ``motion.imu``; ``update`` takes monocular (n, 2) or stereo (n, 4)
    pixels."""

    name = ESTIMATOR_NAME
    drive_kind = "raw-imu"

    def __init__(self, settings: FilterSettings = FilterSettings(),
                 initial: InitialState | None = None):
        self.settings = settings
        self.initial = initial

    # ------------------------------------------------------------------ protocol
    def initialise(self, drive: InertialDrive, config=None, guard=None) -> None:
        """Start at frame 0 from the rest (or the given initial state). From ``config``
        (:class:`ekf.config.FilterConfig`, as every filter of the bench gets it) the pixel sigma
        and the gate probability; the rest from :class:`FilterSettings`."""
        s = self.settings
        if config is not None:
            s = replace(s, pixel_sigma=float(config.pixel_sigma),
                        gate_probability=config.gate_probability)
            self.settings = s
        cal = drive.calibration
        self.guard = guard
        self.times = np.asarray(drive.timestamps, dtype=float)
        self.g_world = cal.gravity * _DOWN
        self.noise = cal.noise
        self.cam_T_imu = np.asarray(cal.cam_T_imu, dtype=float)
        self.imu_T_cam = cal.imu_T_cam
        self.ad_cam = adjoint(self.cam_T_imu)
        self.camera = iml.PixelModel(np.asarray(cal.K, dtype=float), self.cam_T_imu, cal.baseline)
        self.K, self.baseline = np.asarray(cal.K, dtype=float), cal.baseline
        self.rows = self.camera.rows
        self.pixel_var = s.pixel_sigma ** 2
        self.prior = iml.DepthPrior(s.min_depth)
        self.gate = None if s.gate_probability is None else chi2.ppf(s.gate_probability, self.rows)
        initial = self.initial
        if initial is None:
            t0 = float(self.times[0])
            rest = detect_rest(drive.imu, s.rest, t0)
            initial = rest_initial_state(drive.imu, t0, cal.gravity, cal.noise, s.rest, rest)
        if initial.time != self.times[0]:
            raise InputError(f"{ESTIMATOR_NAME}: the initial state's time {initial.time:.6f} s "
                             f"is not frame 0's ({self.times[0]:.6f} s)")
        self.initial_used = initial
        self.x = initial.state
        S = strapdown_to_invariant(initial.state)
        self.P = S @ np.asarray(initial.cov, dtype=float) @ S.T
        n_tracks = int(drive.n_tracks)
        self.lm = np.zeros((0, 3))
        self.tracks = np.zeros(0, dtype=np.int64)
        self.in_group = np.zeros(0, dtype=bool)
        self.anchor_R = np.zeros((0, 3, 3))
        self.anchor_p = np.zeros((0, 3))
        self.last_seen = np.zeros(0, dtype=np.int64)
        self.slot_of = -np.ones(n_tracks, dtype=np.int64)
        self.map_mean = np.full((n_tracks, 3), np.nan)
        self.map_cov = np.full((n_tracks, 3, 3), np.nan)
        self.frame = 0
        self.counts = {"n_joined_group": 0, "n_dropped_unseen": 0, "n_gated": 0}

    def predict(self, motion: MotionInput) -> None:
        k = int(motion.frame)
        if motion.imu is None:
            raise InputError(f"{ESTIMATOR_NAME}: frame {k}: no IMU samples in the motion input")
        t0 = float(self.times[k - 1] if motion.start is None else motion.start)
        t1 = float(self.times[k] if motion.end is None else motion.end)
        x, Phi, Qc = propagate(self.x, motion.imu, t0, t1, self.g_world, self.noise)
        self.P = frame_covariance(self.P, Phi, Qc, self.lm, self.in_group)
        self.x = x
        self.frame = k
        if not (np.isfinite(x.pose).all() and np.isfinite(self.P[:N_CORE, :N_CORE]).all()):
            raise self._error(k, "state or covariance not finite after prediction")

    def update(self, frame: FrameObservations) -> UpdateCounts:
        t = int(frame.frame)
        self.frame = t
        tracks = np.asarray(frame.tracks, dtype=np.int64)
        z = np.asarray(frame.z, dtype=float)
        if z.ndim != 2 or (tracks.size and z.shape[1] != self.rows):
            raise InputError(f"{ESTIMATOR_NAME}: frame {t}: pixels of shape {z.shape}, "
                             f"expected (n, {self.rows})")
        slots = self.slot_of[tracks] if tracks.size else np.zeros(0, dtype=np.int64)
        old = slots >= 0
        n_used, n_rej = 0, 0
        if old.any():
            try:
                n_used, n_rej = self._update(slots[old], z[old])
            except UpdateRejected as exc:
                if self.guard is not None:
                    self.guard.reject(t, str(exc), int(old.sum()))
                n_used, n_rej = 0, int(old.sum())
            self.last_seen[slots[old]] = t
        n_init, n_rej_new = self._augment(tracks[~old], z[~old], t)
        self._join_group()
        return UpdateCounts(n_used, n_rej + n_rej_new, n_init)

    def marginalise(self, tracks: np.ndarray) -> None:
        gone = np.zeros(self.tracks.size, dtype=bool)
        tracks = np.asarray(tracks, dtype=np.int64)
        if tracks.size:
            s = self.slot_of[tracks]
            gone[s[s >= 0]] = True
        unseen = self.frame - self.last_seen > self.settings.max_unseen
        self.counts["n_dropped_unseen"] += int((unseen & ~gone).sum())
        self._drop(gone | unseen)

    def pose(self) -> np.ndarray:
        return self.x.pose

    def pose_cov(self) -> np.ndarray:
        E = estimate_pose_jacobian(self.x)
        C = E @ self.P[:N_CORE, :N_CORE] @ E.T
        return 0.5 * (C + C.T)

    def active_landmarks(self) -> Landmarks:
        slots = np.arange(self.tracks.size)
        mean, cov = self._world(slots)
        return Landmarks(self.tracks.copy(), mean, cov)

    def landmark_map(self) -> tuple[np.ndarray, np.ndarray]:
        return self.map_mean.copy(), self.map_cov.copy()

    def info(self) -> dict:
        init = self.initial_used
        return {
            "initialisation": init.source,
            "initial_time_s": init.time,
            "rest_s": None if init.rest is None else [init.rest.start, init.rest.end],
            "world_frame": "gravity-aligned, z up",
            "final_velocity": self.x.v.tolist(),
            "final_gyro_bias": self.x.bg.tolist(),
            "final_accel_bias": self.x.ba.tolist(),
            "scheme": "right-invariant EKF on SE_2+K(3), biases beside the group (imperfect "
                      "IEKF); strapdown mean per sample; inverse-depth landmarks join the group",
            **{k: int(v) for k, v in self.counts.items()},
        }

    # ------------------------------------------------------------------ internals
    def _error(self, t: int, what: str):
        from vislam.ekf.errors import EstimationError
        if self.guard is not None:
            return self.guard.error(t, what)
        return EstimationError(f"{ESTIMATOR_NAME}: frame {t}: {what}")

    def state_nav(self) -> NavState:
        return self.x

    def _jacobians(self, slots: np.ndarray):
        """Predicted pixels (k, m), ``H_pose`` (k, m, 6) on ``[xi_R, xi_p]``, ``H_l`` (k, m, 3)
        and the camera depth (k,) of the landmarks in ``slots`` (IIE-1)."""
        T = self.x.pose
        R, p = T[:3, :3], T[:3, 3]
        k = slots.size
        q = np.empty((k, 4))
        g = self.in_group[slots]
        q[g, :3] = (self.lm[slots[g]] - p) @ R
        q[g, 3] = 1.0
        i = ~g
        if i.any():
            s = slots[i]
            q[i] = iml.imu_points(self.lm[s], self.anchor_R[s], self.anchor_p[s], T)
        z, dz_dq, depth = self.camera.predict(q)
        Hp = np.zeros((k, self.rows, 6))
        Hl = np.empty((k, self.rows, 3))
        if g.any():
            B = dz_dq[g, :, :3] @ R.T
            Hl[g] = B
            Hp[g, :, 3:] = -B
        if i.any():
            s = slots[i]
            Hl[i] = dz_dq[i] @ iml.landmark_jacobian(self.lm[s], self.anchor_R[s],
                                                      self.anchor_p[s], T)
            E = estimate_pose_jacobian(self.x)[:, POSE_COLS]
            Hp[i] = dz_dq[i] @ iml.pose_jacobian(q[i]) @ E
        with np.errstate(divide="ignore", invalid="ignore"):
            depth = np.where(g, depth, depth / q[:, 3])
        return z, Hp, Hl, depth

    def _stacked(self, slots: np.ndarray, Hp: np.ndarray, Hl: np.ndarray):
        """``P H^T`` (n, k m) and ``S = H P H^T + V`` (k m, k m) of the observations of
        ``slots`` with Jacobians ``Hp`` (k, m, 6), ``Hl`` (k, m, 3) (IIE-1's sparse rows)."""
        P = self.P
        n, m, k = P.shape[0], self.rows, slots.size
        li = N_CORE + 3 * slots[:, None] + np.arange(3)  # (k, 3)
        PHt = (P[:, POSE_COLS] @ Hp.reshape(k * m, 6).T).reshape(n, k, m)
        PHt += np.einsum("nkc,kmc->nkm", P[:, li], Hl)
        PHt = PHt.reshape(n, k * m)
        S = Hp.reshape(k * m, 6) @ PHt[POSE_COLS, :]
        S += np.einsum("kmc,kcx->kmx", Hl, PHt[li]).reshape(k * m, k * m)
        S = 0.5 * (S + S.T)
        S[np.diag_indices(k * m)] += self.pixel_var
        return PHt, S

    def _update(self, slots: np.ndarray, z: np.ndarray) -> tuple[int, int]:
        """The frame's update (IIE-1): gate each observation at the prior, then iterate
        (``FilterSettings.iterations``, the iterated EKF: Jacobians and residuals at the last
        iterate ``exp(d_i) X``, ``d_i+1 = K_i (r_i + H_i d_i)``), ``P <- P - K S K^T`` with the
        last iterate's gain."""
        s = self.settings
        zhat, Hp, Hl, depth = self._jacobians(slots)
        r = z - zhat
        ok = np.isfinite(r).all(axis=1) & (depth > 1e-6) & (depth <= s.max_depth)
        if self.rows == 4:
            ok &= z[:, 0] - z[:, 2] > 0
        n_rej = int((~ok).sum())
        if not ok.any():
            return 0, n_rej
        slots, z, r, Hp, Hl = slots[ok], z[ok], r[ok], Hp[ok], Hl[ok]
        m = self.rows
        PHt, S = self._stacked(slots, Hp, Hl)
        if self.gate is not None:
            k = slots.size
            blocks = S.reshape(k, m, k, m)[np.arange(k), :, np.arange(k), :]  # (k, m, m)
            with np.errstate(all="ignore"):
                m2 = np.einsum("ki,ki->k", r, np.linalg.solve(blocks, r[:, :, None])[:, :, 0])
            keep = m2 <= self.gate
            n_gate = int((~keep).sum())
            self.counts["n_gated"] += n_gate
            n_rej += n_gate
            if not keep.any():
                return 0, n_rej
            if n_gate:
                rows = (np.flatnonzero(keep)[:, None] * m + np.arange(m)).ravel()
                S = S[np.ix_(rows, rows)]
                PHt = PHt[:, rows]
                slots, z, r, Hp, Hl = slots[keep], z[keep], r[keep], Hp[keep], Hl[keep]
        k = slots.size
        li = N_CORE + 3 * slots[:, None] + np.arange(3)
        P = self.P
        x0, lm0 = self.x, self.lm.copy()
        delta = np.zeros(P.shape[0])
        for it in range(max(int(s.iterations), 1)):
            if it:
                self.x, self.lm = x0, lm0.copy()
                self._apply(delta)
                zhat, Hp, Hl, _ = self._jacobians(slots)
                r = z - zhat
                PHt, S = self._stacked(slots, Hp, Hl)
            L, info = dpotrf(S, lower=1, clean=1)
            if info != 0:
                self.x, self.lm = x0, lm0
                raise UpdateRejected(f"innovation covariance of {k} observations not positive "
                                     "definite")
            y = r.ravel()
            if it:  # r_i + H_i d_i
                y = y + (np.einsum("kmc,kc->km", Hp, delta[POSE_COLS][None].repeat(k, 0))
                         + np.einsum("kmc,kc->km", Hl, delta[li])).ravel()
            Wt = solve_triangular(L, PHt.T, lower=True, check_finite=False)  # L^-1 H P
            new = Wt.T @ solve_triangular(L, y, lower=True, check_finite=False)
            if not np.isfinite(new).all():
                self.x, self.lm = x0, lm0
                raise UpdateRejected(f"correction of {k} observations not finite")
            step = np.abs(new - delta).max()
            delta = new
            if step < 1e-9:
                break
        KSKt = Wt.T @ Wt
        self.x, self.lm = x0, lm0
        if not (P.diagonal() - KSKt.diagonal()).min() > 0:
            raise UpdateRejected(f"gain of {k} observations leaves a variance not positive")
        self.P = P - KSKt
        x_prior = self.lm.copy()
        self._apply(delta)
        self._transport(x_prior)
        self.P = 0.5 * (self.P + self.P.T)
        return k, n_rej

    def _transport(self, x_prior: np.ndarray) -> None:
        """Keep the four unobservable directions (translation, yaw) of the inverse-depth slots
        moving with their estimate (IIE-5): ``P <- T P T^T`` with ``T`` adding
        ``N_j(x+) - N_j(x-)`` (ID-7, restricted to the translation and the rotation about
        gravity) times the core's ``[xi_p; xi_R]`` to the rows of slot j."""
        ids = np.flatnonzero(~self.in_group)
        if ids.size == 0 or not self.settings.transport:
            return
        dN = idp.gauge_rows_change(x_prior[ids], self.lm[ids], self.anchor_R[ids],
                                   self.anchor_p[ids])  # (k, 3, 6) on [v; w]
        n = self.P.shape[0]
        Cz = np.zeros((n, N_CORE))
        rows = (N_CORE + 3 * ids[:, None] + np.arange(3)).ravel()
        C = np.zeros((ids.size, 3, N_CORE))
        C[:, :, POS] = dN[:, :, :3]
        if self.settings.transport == "all":
            C[:, :, ROT] = dN[:, :, 3:]
        else:
            C[:, :, ROT.start + 2] = dN[:, :, 5]  # yaw: the rotation about world z
        Cz[rows] = C.reshape(-1, N_CORE)
        P = self.P
        W = P[:, :N_CORE].copy()
        V = W + Cz @ W[:N_CORE]
        self.P = P + W @ Cz.T + Cz @ V.T

    def _apply(self, delta: np.ndarray) -> None:
        """``X <- exp(delta) X`` on the group; additive on the biases and inverse-depth slots."""
        self.x = retract(self.x, delta[:N_CORE])
        if self.lm.shape[0]:
            dl = delta[N_CORE:].reshape(-1, 3)
            g = self.in_group
            if g.any():
                self.lm[g] = retract_landmarks(self.lm[g], delta[ROT], dl[g])
            self.lm[~g] += dl[~g]

    def _augment(self, tracks: np.ndarray, z: np.ndarray, t: int) -> tuple[int, int]:
        """New landmarks (IIE-2, IIE-3) for tracks not in the state, while slots are free."""
        s = self.settings
        room = s.max_landmarks - self.tracks.size
        if tracks.size == 0 or room <= 0:
            return 0, 0
        n_rej = 0
        if self.rows == 4:
            ok = z[:, 0] - z[:, 2] >= s.min_disparity
            n_rej = int((~ok).sum())
            tracks, z = tracks[ok], z[ok]
        if tracks.size > room:
            tracks, z = tracks[:room], z[:room]
        k = tracks.size
        if k == 0:
            return 0, n_rej
        T = self.x.pose
        R = T[:3, :3]
        E = estimate_pose_jacobian(self.x)
        P = self.P
        n = P.shape[0]
        if self.rows == 4:
            pc, Jt = triangulate_with_jacobian(z, self.K, self.baseline)
            good = np.isfinite(pc).all(axis=1) & (pc[:, 2] > 0) & (pc[:, 2] <= s.max_depth)
            n_rej += int((~good).sum())
            tracks, pc, Jt = tracks[good], pc[good], Jt[good]
            k = tracks.size
            if k == 0:
                return 0, n_rej
            Ric = self.imu_T_cam[:3, :3]
            lm_new = (pc @ Ric.T + self.imu_T_cam[:3, 3]) @ R.T + T[:3, 3]
            G = (R @ Ric) @ Jt  # (k, 3, 4)
            Cn = self.pixel_var * G @ np.swapaxes(G, 1, 2)
            J = np.zeros((k, 3, n))
            J[:, :, POS] = np.eye(3)
            in_group = np.ones(k, dtype=bool)
            R_a = np.zeros((k, 3, 3))
            p_a = np.zeros((k, 3))
        else:
            lm_new, Cn = iml.initial_landmarks(z, self.K, None, self.pixel_var, self.prior)
            world_T_cam = T @ self.imu_T_cam
            Cx = iml.chart_change_jacobian(lm_new)  # (k, 3, 6)
            Jcore = Cx @ (self.ad_cam @ E)  # (k, 3, 15)
            J = np.zeros((k, 3, n))
            J[:, :, :N_CORE] = Jcore
            in_group = np.zeros(k, dtype=bool)
            R_a = np.broadcast_to(world_T_cam[:3, :3], (k, 3, 3)).copy()
            p_a = np.broadcast_to(world_T_cam[:3, 3], (k, 3)).copy()
        Jf = J.reshape(3 * k, n)
        cross = Jf @ P  # (3k, n)
        Pn = np.empty((n + 3 * k, n + 3 * k))
        Pn[:n, :n] = P
        Pn[n:, :n] = cross
        Pn[:n, n:] = cross.T
        Pn[n:, n:] = cross @ Jf.T
        for j in range(k):
            Pn[n + 3 * j:n + 3 * j + 3, n + 3 * j:n + 3 * j + 3] += Cn[j]
        self.P = Pn
        self.lm = np.vstack([self.lm, lm_new])
        self.slot_of[tracks] = self.tracks.size + np.arange(k)
        self.tracks = np.concatenate([self.tracks, tracks])
        self.in_group = np.concatenate([self.in_group, in_group])
        self.anchor_R = np.concatenate([self.anchor_R, R_a])
        self.anchor_p = np.concatenate([self.anchor_p, p_a])
        self.last_seen = np.concatenate([self.last_seen, np.full(k, t)])
        return k, n_rej

    def _join_group(self) -> None:
        """Inverse-depth slots whose linearity index is below the setting join the group
        (IIE-4)."""
        lin = self.settings.inverse_depth_linearity
        ids = np.flatnonzero(~self.in_group)
        if lin <= 0 or ids.size == 0:
            return
        T = self.x.pose
        centre = T[:3, :3] @ self.imu_T_cam[:3, 3] + T[:3, 3]
        rho_rows = N_CORE + 3 * ids + 2
        L = idp.linearity_index(self.lm[ids], self.P[rho_rows, rho_rows], self.anchor_R[ids],
                                self.anchor_p[ids], centre)
        ids = ids[L < lin]
        if ids.size == 0:
            return
        x, R_a = self.lm[ids], self.anchor_R[ids]
        J = idp.world_jacobian(x, R_a)
        m = idp.world_point(x, R_a, self.anchor_p[ids])
        Lh = hat(m)
        rows = N_CORE + 3 * ids[:, None] + np.arange(3)
        P = self.P
        P[rows] = J @ P[rows] + Lh @ P[ROT]
        P[:, rows] = (np.einsum("nkj,kij->nki", P[:, rows], J)
                      + np.einsum("nj,kij->nki", P[:, ROT], Lh))
        self.lm[ids] = m
        self.in_group[ids] = True
        self.counts["n_joined_group"] += int(ids.size)

    def _world(self, slots: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World means (k, 3) and covariances (k, 3, 3) of ``slots``."""
        k = slots.size
        mean = np.empty((k, 3))
        cov = np.empty((k, 3, 3))
        if k == 0:
            return mean, cov
        rows = N_CORE + 3 * slots[:, None] + np.arange(3)
        g = self.in_group[slots]
        if g.any():
            s, rr = slots[g], rows[g]
            idx = np.concatenate([np.broadcast_to(np.arange(3), rr.shape), rr], axis=1)
            sub = self.P[idx[:, :, None], idx[:, None, :]]
            G = np.zeros((s.size, 3, 6))
            G[:, :, :3] = -hat(self.lm[s])
            G[:, :, 3:] = np.eye(3)
            mean[g] = self.lm[s]
            cov[g] = G @ sub @ np.swapaxes(G, 1, 2)
        i = ~g
        if i.any():
            s, rr = slots[i], rows[i]
            J = idp.world_jacobian(self.lm[s], self.anchor_R[s])
            mean[i] = idp.world_point(self.lm[s], self.anchor_R[s], self.anchor_p[s])
            cov[i] = J @ self.P[rr[:, :, None], rr[:, None, :]] @ np.swapaxes(J, 1, 2)
        return mean, cov

    def _drop(self, gone: np.ndarray) -> None:
        """Slots ``gone`` (bool per slot) leave the state for the map."""
        if not gone.any():
            return
        out = np.flatnonzero(gone)
        keep = np.flatnonzero(~gone)
        tr = self.tracks[out]
        mean, cov = self._world(out)
        self.map_mean[tr], self.map_cov[tr] = mean, cov
        self.slot_of[tr] = -1
        idx = np.concatenate([np.arange(N_CORE), (N_CORE + 3 * keep[:, None] + np.arange(3)).ravel()])
        self.P = self.P[np.ix_(idx, idx)]
        self.lm = self.lm[keep]
        self.tracks = self.tracks[keep]
        self.in_group = self.in_group[keep]
        self.anchor_R = self.anchor_R[keep]
        self.anchor_p = self.anchor_p[keep]
        self.last_seen = self.last_seen[keep]
        self.slot_of[self.tracks] = np.arange(keep.size)
