"""``ekf-imu-invariant``: the right-invariant EKF on raw IMU, state on SE_{2+K}(3).

**State** (:mod:`ekf.imu_invariant_propagation`, RI-1): the IMU's ``R``, ``v``, ``p`` and the
*group landmarks* (world points) form one element of SE_{2+K}(3) with the right-invariant error
``X_true = exp(xi) X`` (Barrau and Bonnabel; the invariant VIO filters of the literature, e.g.
Wu et al., "An invariant-EKF VINS algorithm", 2017; Brossard et al., 2018). Beside the group:

* the gyro and accelerometer biases (additive error). Their coupling makes this the "imperfect
  IEKF": the transition's bias columns depend on the estimate (RI-3: ``F[., bg]`` through
  ``Ad_{X'}``, ``F[v, ba]``, ``F[p, ba]`` through ``R``); everything else of the group part
  propagates exactly (log-linearly);
* *anchor clones*: copies of the pose ``(R, p)`` at the frames where inverse-depth landmarks
  start (at most ``max_anchors``), each with the same right-invariant error ``[xi_R, xi_p]``
  (6 rows, constant in the propagation);
* *inverse-depth landmarks* (:mod:`ekf.imu_landmarks`, Civera, Davison and Montiel 2008):
  ``x = [alpha, beta, rho]`` in the camera of an anchor clone. These cannot join the group as
  they are (a point whose depth is not known is not a Gaussian world point), so their error is
  additive, beside it; they do not move in the propagation. Every track starts here (monocular
  with an inverse-depth prior, stereo from its disparity: IIE-2) and joins the group once
  Civera's linearity index (ID-5) falls below ``inverse_depth_linearity`` (IIE-4).

Error order: ``[xi_R, xi_v, xi_p, dbg, dba]`` (15), then 6 per anchor clone
(``max_anchors`` of them, zero rows when unused), then 3 per landmark slot, group or inverse
depth (``in_group`` says which).

**Propagation** (per frame interval): the core's mean, transition ``Phi`` and noise ``Qc``
sample by sample (RI-2 .. RI-4, :func:`ekf.imu_invariant_propagation.propagate`), then the whole
covariance once (RI-5, :func:`~ekf.imu_invariant_propagation.frame_covariance`; the clones'
and inverse-depth rows as rows that do not move).

**Observations** (IIE-1). A group landmark ``l`` seen from ``(R, p)``: the IMU-frame point
``q = R^T (l - p)``, exactly ``R^T (l - p) + R^T Exp(-xi_R) J (xi_l - xi_p)`` under the error, so
``H = B [0 at xi_R, -I at xi_p, I at xi_l]`` with ``B = dz/dq R^T``: it does not depend on
``l`` or ``p`` (the invariant filter's property). An inverse-depth landmark: the Jacobians of
:mod:`ekf.imu_landmarks` (IL-2) chained onto this error: on the pose
``dz/dq_i dq_i/dxi E`` with ``E`` the Estimate-convention map of RI-6
(``xi_est = [R^T (xi_p - p^ xi_R); R^T xi_R]``), on its anchor clone
``dz/dq_i dq_i/dxi_a Ad(cam_T_imu) E_a`` (the clone's own ``E``), on ``x`` ``dz/dq_i dq_i/dx``,
all at the current estimates. Each observation is gated at ``gate_probability`` (chi-square of
its own innovation); the rest update together (one Cholesky of the stacked innovation
covariance).

**New landmarks** (IIE-2). The anchor clone of the frame (made if needed: the pose's rows and
columns copied), and ``x`` read from the first pixels in its camera (IL-3's chart with the
anchor *in the state*): its error is the pixels' (and the prior's) alone, uncorrelated with the
rest. Why a clone: an anchor fixed as numbers carries the anchor's error as a correlation
evaluated once, at the first estimate of ``rho``; as ``rho`` moves, the current Jacobians no
longer cancel it, and a monocular camera at rest learned its tilt from nothing (the road
scenario at rest: the tilt's sigma fell from 5 to 0.8 mrad with a 5 mrad error). With the
clone every Jacobian is evaluated at the current estimate and the pose directions the anchor
shares stay as unobservable as they are.

*The monocular inverse-depth prior* (IIE-5): :class:`ekf.imu_landmarks.DepthPrior`
(``min_depth``) until ``learn_prior`` landmarks have joined the group, then the mean and spread
(floored at a quarter of the mean) of those landmarks' inverse depths in their anchors: an
empirical prior, the scene's own depths, one rule for every drive. A prior that covers the
depths but is biased for the scene (the default's mean depth of 2 m against a room's 3-8 m)
makes every new landmark err the same way, which the filter takes as independent errors: the
room's monocular pose NEES was 13-14 with the default prior, 6-11 with this one (3 seeds), and
the road's monocular run stopped diverging.

**Joining the group** (IIE-4): ``l = m(x, anchor)`` (ID-1) and
``xi_l = J dx + A xi_a + l^ xi_R`` (``J = dm/dx``, ID-6; ``A`` the anchor's share,
``R_a [I, -q^] Ad(cam_T_imu) E_a`` with ``q = b / rho``; ``l - l^ xi_R`` is the world error),
``P <- T P T^T`` on the slot's rows. A clone no landmark uses any more leaves the state.

**State size.** At most ``max_landmarks`` slots and ``max_anchors`` clones: new tracks wait
while either is full; a landmark not seen for ``max_unseen`` frames leaves the state for the map
(and a track that comes back later starts again as a new landmark: the old one's information is
dropped, which is conservative, not overconfident). ``stereo_start = "group"`` starts stereo
tracks in the group instead (triangulated, ``xi_l = xi_p + R R_ic dp_c``).

**Read-outs** in the Estimate convention of :mod:`ekf.inertial_dead_reckoning` (gravity-aligned
world from the rest at frame 0, right perturbation of ``world_T_imu``, translation first):
``pose_cov = E P_core E^T`` (RI-6); a landmark's world covariance ``G P G^T`` with
``dl = xi_l - l^ xi_R`` (group) or ``dm = J dx + A xi_a`` (inverse depth).

**Initialisation**: the rest at the start (:mod:`ekf.imu_init`, as ``dead-reckoning-imu``),
its covariance moved into the invariant error by RI-6's ``S``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.linalg import solve_triangular
from scipy.linalg.lapack import dpotrf
from vislam.ekf import chi_square as chi2
from vislam.ekf import imu_landmarks as iml
from vislam.ekf import inverse_depth as idp
from vislam.ekf.camera import triangulate_with_jacobian
from vislam.ekf.errors import EstimationError, InputError
from vislam.ekf.filter import FrameObservations, Landmarks, MotionInput, UpdateCounts
from vislam.ekf.geometry import adjoint, hat
from vislam.ekf.imu_init import (
    InitialState,
    RestConfig,
    detect_rest,
    rest_initial_state,
)
from vislam.ekf.imu_invariant_propagation import (
    N_CORE,
    POS,
    ROT,
    estimate_pose_jacobian,
    frame_covariance,
    propagate,
    retract,
    retract_landmarks,
    strapdown_to_invariant,
)
from vislam.ekf.inertial import ImuNoise, InertialDrive
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
    ``max_unseen`` frames before a landmark leaves; ``max_depth`` m of a usable prediction;
    ``max_anchors`` anchor poses held at once (IIE-2)."""

    pixel_sigma: float = 1.0
    gate_probability: float | None = 0.999
    min_depth: float = 1.0
    inverse_depth_linearity: float = 0.1
    min_disparity: float = 1.0
    max_landmarks: int = 40
    max_unseen: int = 2
    max_depth: float = 200.0
    max_anchors: int = 10
    inverse_depth_prior: tuple[float, float] | None = None
    learn_prior: int = 10
    prior_spread: float = 1.0
    stereo_start: str = "inverse-depth"
    rest: RestConfig = field(default_factory=RestConfig)

    def __post_init__(self) -> None:
        for key in ("pixel_sigma", "min_depth", "max_depth"):
            value = getattr(self, key)
            if not np.isfinite(value) or value <= 0:
                raise InputError(f"{ESTIMATOR_NAME}: {key} must be positive, got {value!r}")
        if self.gate_probability is not None and not 0 < self.gate_probability < 1:
            raise InputError(f"{ESTIMATOR_NAME}: gate_probability must be in (0, 1), got "
                             f"{self.gate_probability!r}")
        if self.stereo_start not in ("inverse-depth", "group"):
            raise InputError(f"{ESTIMATOR_NAME}: stereo_start must be 'inverse-depth' or "
                             f"'group', got {self.stereo_start!r}")
        if self.max_landmarks < 0 or self.max_unseen < 0 or self.max_anchors < 1:
            raise InputError(f"{ESTIMATOR_NAME}: max_landmarks and max_unseen must be >= 0, "
                             "max_anchors >= 1")


@dataclass(frozen=True)
class _Prior:
    """An inverse-depth prior given as its mean and sigma (1/m)."""

    rho: float
    sigma: float


class ImuInvariantEKF:
    """The right-invariant raw-IMU EKF (module docstring) in the per-frame protocol of
    :mod:`ekf.filter`: ``initialise`` takes the :class:`ekf.inertial.InertialDrive`; each
    ``predict`` integrates ``motion.imu``; ``update`` takes monocular (n, 2) or stereo (n, 4)
    pixels. ``initial``: the state at frame 0 (default: from the rest there); ``noise``: the IMU
    noise to assume (default: the drive's calibration; the rest's initial covariance keeps the
    drive's)."""

    name = ESTIMATOR_NAME
    drive_kind = "raw-imu"

    def __init__(self, settings: FilterSettings = FilterSettings(),
                 initial: InitialState | None = None, noise: ImuNoise | None = None):
        self.settings = settings
        self.initial = initial
        self.noise_override = noise

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
        self.noise = self.noise_override or cal.noise
        self.cam_T_imu = np.asarray(cal.cam_T_imu, dtype=float)
        self.imu_T_cam = cal.imu_T_cam
        self.ad_cam = adjoint(self.cam_T_imu)
        self.camera = iml.PixelModel(np.asarray(cal.K, dtype=float), self.cam_T_imu, cal.baseline)
        self.K, self.baseline = np.asarray(cal.K, dtype=float), cal.baseline
        self.rows = self.camera.rows
        self.pixel_var = s.pixel_sigma ** 2
        self.prior = (iml.DepthPrior(s.min_depth) if s.inverse_depth_prior is None
                      else _Prior(*s.inverse_depth_prior))
        self.joined_rho: list[float] = []
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
        self.n_anchor = int(s.max_anchors)
        self.L0 = N_CORE + 6 * self.n_anchor  # first landmark row
        self.P = np.zeros((self.L0, self.L0))
        self.P[:N_CORE, :N_CORE] = S @ np.asarray(initial.cov, dtype=float) @ S.T
        self.anchor_T = np.tile(np.eye(4), (self.n_anchor, 1, 1))  # cloned world_T_imu
        self.anchor_used = np.zeros(self.n_anchor, dtype=bool)
        self.anchor_frame = -np.ones(self.n_anchor, dtype=np.int64)
        n_tracks = int(drive.n_tracks)
        self.lm = np.zeros((0, 3))
        self.tracks = np.zeros(0, dtype=np.int64)
        self.in_group = np.zeros(0, dtype=bool)
        self.anchor_of = np.zeros(0, dtype=np.int64)  # the anchor of each slot (-1: in the group)
        self.last_seen = np.zeros(0, dtype=np.int64)
        self.slot_of = -np.ones(n_tracks, dtype=np.int64)
        self.map_mean = np.full((n_tracks, 3), np.nan)
        self.map_cov = np.full((n_tracks, 3, 3), np.nan)
        self.frame = 0
        self.counts = {"n_joined_group": 0, "n_dropped_unseen": 0, "n_gated": 0,
                       "n_waiting_for_anchor": 0}

    def predict(self, motion: MotionInput) -> None:
        k = int(motion.frame)
        if motion.imu is None:
            raise InputError(f"{ESTIMATOR_NAME}: frame {k}: no IMU samples in the motion input")
        t0 = float(self.times[k - 1] if motion.start is None else motion.start)
        t1 = float(self.times[k] if motion.end is None else motion.end)
        x, Phi, Qc = propagate(self.x, motion.imu, t0, t1, self.g_world, self.noise)
        # the anchors' rows do not move: as landmarks outside the group (RI-5)
        still = np.zeros((2 * self.n_anchor, 3))
        self.P = frame_covariance(self.P, Phi, Qc, np.vstack([still, self.lm]),
                                  np.r_[np.zeros(2 * self.n_anchor, dtype=bool), self.in_group])
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
        self._free_anchors()

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
        return {
            **self.initial_used.info(self.x),
            "scheme": "right-invariant EKF on SE_2+K(3), biases beside the group (imperfect "
                      "IEKF); strapdown mean per sample; inverse-depth landmarks join the group",
            **{k: int(v) for k, v in self.counts.items()},
        }

    # ------------------------------------------------------------------ internals
    def _error(self, t: int, what: str) -> EstimationError:
        if self.guard is not None:
            return self.guard.error(t, what)
        return EstimationError(f"{ESTIMATOR_NAME}: frame {t}: {what}")

    def _anchor_cams(self, slots: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``world_T_cam`` of the anchors of inverse-depth ``slots``: ``(R_a (k, 3, 3), p_a (k, 3))``."""
        T = self.anchor_T[self.anchor_of[slots]] @ self.imu_T_cam
        return T[:, :3, :3], T[:, :3, 3]

    def _anchor_rows(self, slots: np.ndarray) -> np.ndarray:
        """The state rows (k, 6) of the anchors of ``slots`` (``[xi_R, xi_p]`` of the clone)."""
        return N_CORE + 6 * self.anchor_of[slots][:, None] + np.arange(6)

    def _anchor_map(self, slots: np.ndarray) -> np.ndarray:
        """``Ad(cam_T_imu) E_a`` (k, 6, 6): the anchor camera's right perturbation of its
        clone's error ``[xi_R, xi_p]`` (RI-6 at the clone)."""
        T = self.anchor_T[self.anchor_of[slots]]
        out = np.empty((slots.size, 6, 6))
        for j in range(slots.size):
            nav = NavState(T[j, :3, :3], np.zeros(3), T[j, :3, 3], np.zeros(3), np.zeros(3))
            out[j] = self.ad_cam @ estimate_pose_jacobian(nav)[:, POSE_COLS]
        return out

    def _jacobians(self, slots: np.ndarray):
        """Predicted pixels (k, m), ``H_pose`` (k, m, 6) on ``[xi_R, xi_p]``, ``H_l`` (k, m, 3),
        ``H_a`` (k, m, 6) on the slot's anchor clone (zero for group landmarks) and the camera
        depth (k,) of the landmarks in ``slots`` (IIE-1)."""
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
            R_a, p_a = self._anchor_cams(s)
            q[i] = iml.imu_points(self.lm[s], R_a, p_a, T)
        z, dz_dq, depth = self.camera.predict(q)
        Hp = np.zeros((k, self.rows, 6))
        Hl = np.empty((k, self.rows, 3))
        Ha = np.zeros((k, self.rows, 6))
        if g.any():
            B = dz_dq[g, :, :3] @ R.T
            Hl[g] = B
            Hp[g, :, 3:] = -B
        if i.any():
            Hl[i] = dz_dq[i] @ iml.landmark_jacobian(self.lm[s], R_a, p_a, T)
            E = estimate_pose_jacobian(self.x)[:, POSE_COLS]
            Hp[i] = dz_dq[i] @ iml.pose_jacobian(q[i]) @ E
            Ha[i] = dz_dq[i] @ iml.anchor_jacobian(self.lm[s], R_a, T) @ self._anchor_map(s)
        with np.errstate(divide="ignore", invalid="ignore"):
            depth = np.where(g, depth, depth / q[:, 3])
        return z, Hp, Hl, Ha, depth

    def _slot_rows(self, slots: np.ndarray) -> np.ndarray:
        return self.L0 + 3 * slots[:, None] + np.arange(3)

    def _anchor_or_zero_rows(self, slots: np.ndarray) -> np.ndarray:
        """Anchor rows of ``slots`` (k, 6); group landmarks point at clone 0 (their ``H_a`` is
        zero)."""
        a = np.where(self.in_group[slots], 0, self.anchor_of[slots])
        return N_CORE + 6 * a[:, None] + np.arange(6)

    def _stacked(self, slots, Hp, Hl, Ha):
        """``P H^T`` (n, k m) and ``S = H P H^T + V`` (k m, k m) (IIE-1's sparse rows: the
        pose, the slot's own and its anchor's columns)."""
        P = self.P
        n, m, k = P.shape[0], self.rows, slots.size
        li = self._slot_rows(slots)
        ai = self._anchor_or_zero_rows(slots)
        PHt = (P[:, POSE_COLS] @ Hp.reshape(k * m, 6).T).reshape(n, k, m)
        PHt += np.einsum("nkc,kmc->nkm", P[:, li], Hl)
        PHt += np.einsum("nkc,kmc->nkm", P[:, ai], Ha)
        PHt = PHt.reshape(n, k * m)
        S = Hp.reshape(k * m, 6) @ PHt[POSE_COLS, :]
        S += np.einsum("kmc,kcx->kmx", Hl, PHt[li]).reshape(k * m, k * m)
        S += np.einsum("kmc,kcx->kmx", Ha, PHt[ai]).reshape(k * m, k * m)
        S = 0.5 * (S + S.T)
        S[np.diag_indices(k * m)] += self.pixel_var
        return PHt, S

    def _update(self, slots: np.ndarray, z: np.ndarray) -> tuple[int, int]:
        """The frame's update (IIE-1): each observation gated at the prior, the rest in one
        stacked update, ``P <- P - K S K^T`` by a Cholesky factor of ``S``."""
        s = self.settings
        zhat, Hp, Hl, Ha, depth = self._jacobians(slots)
        r = z - zhat
        ok = np.isfinite(r).all(axis=1) & (depth > 1e-6) & (depth <= s.max_depth)
        if self.rows == 4:
            ok &= z[:, 0] - z[:, 2] > 0
        n_rej = int((~ok).sum())
        if not ok.any():
            return 0, n_rej
        slots, r, Hp, Hl, Ha = slots[ok], r[ok], Hp[ok], Hl[ok], Ha[ok]
        m = self.rows
        PHt, S = self._stacked(slots, Hp, Hl, Ha)
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
                r = r[keep]
        k = r.shape[0]
        L, info = dpotrf(S, lower=1, clean=1)
        if info != 0:
            raise UpdateRejected(f"innovation covariance of {k} observations not positive definite")
        Wt = solve_triangular(L, PHt.T, lower=True, check_finite=False)  # L^-1 H P (km, n)
        delta = Wt.T @ solve_triangular(L, r.ravel(), lower=True, check_finite=False)
        KSKt = Wt.T @ Wt
        P = self.P
        used = np.flatnonzero(P.diagonal() > 0)
        if not ((P.diagonal() - KSKt.diagonal())[used].min() > 0 and np.isfinite(delta).all()):
            raise UpdateRejected(f"gain of {k} observations not finite or a variance not positive")
        P = P - KSKt
        self.P = 0.5 * (P + P.T)
        self._apply(delta)
        return k, n_rej

    def _apply(self, delta: np.ndarray) -> None:
        """``X <- exp(delta) X`` on the group and the anchor clones; additive on the biases and
        inverse-depth slots."""
        self.x = retract(self.x, delta[:N_CORE])
        for a in np.flatnonzero(self.anchor_used):
            d = delta[N_CORE + 6 * a:N_CORE + 6 * a + 6]
            T = self.anchor_T[a]
            nav = retract(NavState(T[:3, :3], np.zeros(3), T[:3, 3], np.zeros(3), np.zeros(3)),
                          np.r_[d[:3], np.zeros(3), d[3:], np.zeros(6)])
            self.anchor_T[a] = nav.pose
        if self.lm.shape[0]:
            dl = delta[self.L0:].reshape(-1, 3)
            g = self.in_group
            if g.any():
                self.lm[g] = retract_landmarks(self.lm[g], delta[ROT], dl[g])
            self.lm[~g] += dl[~g]

    def _new_anchor(self, t: int) -> int | None:
        """The anchor clone of frame ``t`` (the current pose), made if needed: its error is the
        pose's ``[xi_R, xi_p]`` (rows and columns copied). None when every clone is in use."""
        hit = np.flatnonzero(self.anchor_used & (self.anchor_frame == t))
        if hit.size:
            return int(hit[0])
        free = np.flatnonzero(~self.anchor_used)
        if free.size == 0:
            return None
        a = int(free[0])
        rows = N_CORE + 6 * a + np.arange(6)
        P = self.P
        P[rows, :] = P[POSE_COLS, :]
        P[:, rows] = P[:, POSE_COLS]
        self.anchor_T[a] = self.x.pose
        self.anchor_used[a] = True
        self.anchor_frame[a] = t
        return a

    def _free_anchors(self) -> None:
        """Clones no inverse-depth slot uses leave the state (rows and columns zeroed)."""
        held = np.zeros(self.n_anchor, dtype=bool)
        ids = ~self.in_group
        held[self.anchor_of[ids]] = True
        for a in np.flatnonzero(self.anchor_used & ~held):
            rows = N_CORE + 6 * a + np.arange(6)
            self.P[rows, :] = 0.0
            self.P[:, rows] = 0.0
            self.anchor_used[a] = False
            self.anchor_frame[a] = -1

    def _augment(self, tracks: np.ndarray, z: np.ndarray, t: int) -> tuple[int, int]:
        """New landmarks (IIE-2, IIE-3) for tracks not in the state, while slots are free."""
        s = self.settings
        room = s.max_landmarks - self.tracks.size
        if tracks.size == 0 or room <= 0:
            return 0, 0
        n_rej = 0
        group_start = self.rows == 4 and s.stereo_start == "group"
        if self.rows == 4:
            ok = z[:, 0] - z[:, 2] >= (s.min_disparity if group_start else 1e-3)
            n_rej = int((~ok).sum())
            tracks, z = tracks[ok], z[ok]
        if tracks.size > room:
            tracks, z = tracks[:room], z[:room]
        k = tracks.size
        if k == 0:
            return 0, n_rej
        T = self.x.pose
        R = T[:3, :3]
        P = self.P
        n = P.shape[0]
        anchor_of = -np.ones(k, dtype=np.int64)
        if group_start:
            pc, Jt = triangulate_with_jacobian(z, self.K, self.baseline)
            good = np.isfinite(pc).all(axis=1) & (pc[:, 2] > 0) & (pc[:, 2] <= s.max_depth)
            n_rej += int((~good).sum())
            tracks, pc, Jt = tracks[good], pc[good], Jt[good]
            k = tracks.size
            if k == 0:
                return 0, n_rej
            anchor_of = anchor_of[:k]
            Ric = self.imu_T_cam[:3, :3]
            lm_new = (pc @ Ric.T + self.imu_T_cam[:3, 3]) @ R.T + T[:3, 3]
            G = (R @ Ric) @ Jt  # (k, 3, 4)
            Cn = self.pixel_var * G @ np.swapaxes(G, 1, 2)
            Jf = np.zeros((3 * k, n))
            Jf[:, POS] = np.tile(np.eye(3), (k, 1))  # xi_l = xi_p + G dz
            cross = Jf @ P
            in_group = np.ones(k, dtype=bool)
        else:
            a = self._new_anchor(t)
            if a is None:
                self.counts["n_waiting_for_anchor"] += k
                return 0, n_rej
            lm_new, Cn = iml.initial_landmarks(z, self.K, self.baseline, self.pixel_var,
                                               self._prior())
            anchor_of[:] = a
            cross = np.zeros((3 * k, n))  # x is read in its anchor: only the pixels' noise
            in_group = np.zeros(k, dtype=bool)
        Pn = np.empty((n + 3 * k, n + 3 * k))
        Pn[:n, :n] = P
        Pn[n:, :n] = cross
        Pn[:n, n:] = cross.T
        Pn[n:, n:] = cross[:, POS] @ np.tile(np.eye(3), (1, k)) if group_start else 0.0
        for j in range(k):
            Pn[n + 3 * j:n + 3 * j + 3, n + 3 * j:n + 3 * j + 3] += Cn[j]
        self.P = Pn
        self.lm = np.vstack([self.lm, lm_new])
        self.slot_of[tracks] = self.tracks.size + np.arange(k)
        self.tracks = np.concatenate([self.tracks, tracks])
        self.in_group = np.concatenate([self.in_group, in_group])
        self.anchor_of = np.concatenate([self.anchor_of, anchor_of])
        self.last_seen = np.concatenate([self.last_seen, np.full(k, t)])
        return k, n_rej

    def _prior(self):
        """The inverse-depth prior of a new monocular landmark (IIE-2): the depth prior of the
        settings until ``learn_prior`` landmarks have joined the group, then the mean and spread
        of those landmarks' inverse depths in their anchors (an empirical prior: the scene's own
        depths, the same rule on every drive)."""
        n = self.settings.learn_prior
        if n <= 0 or len(self.joined_rho) < n:
            return self.prior
        r = np.asarray(self.joined_rho)
        spread = self.settings.prior_spread * r.std()
        return _Prior(float(r.mean()), float(max(spread, 0.25 * r.mean())))

    def _point_jacobians(self, slots: np.ndarray):
        """For inverse-depth ``slots``: world points ``m`` (k, 3), ``dm/dx`` (k, 3, 3) and
        ``dm/d(anchor clone error)`` (k, 3, 6): ``dm = R_a [I, -q^] xi_a``, ``q = b / rho``."""
        x = self.lm[slots]
        R_a, p_a = self._anchor_cams(slots)
        m = idp.world_point(x, R_a, p_a)
        J = idp.world_jacobian(x, R_a)
        q = idp.bearing(x) / x[:, 2:3]
        A = np.empty((slots.size, 3, 6))
        A[:, :, :3] = R_a
        A[:, :, 3:] = -R_a @ hat(q)
        return m, J, A @ self._anchor_map(slots)

    def _join_group(self) -> None:
        """Inverse-depth slots whose linearity index is below the setting join the group
        (IIE-4): ``xi_l = J dx + A xi_a + l^ xi_R`` (``A`` the anchor's share of the world
        error)."""
        lin = self.settings.inverse_depth_linearity
        ids = np.flatnonzero(~self.in_group)
        if lin <= 0 or ids.size == 0:
            return
        T = self.x.pose
        centre = T[:3, :3] @ self.imu_T_cam[:3, 3] + T[:3, 3]
        rho_rows = self.L0 + 3 * ids + 2
        R_a, p_a = self._anchor_cams(ids)
        L = idp.linearity_index(self.lm[ids], self.P[rho_rows, rho_rows], R_a, p_a, centre)
        ids = ids[L < lin]
        if ids.size == 0:
            return
        self.joined_rho.extend(self.lm[ids, 2].tolist())
        m, J, A = self._point_jacobians(ids)
        Lh = hat(m)
        rows = self._slot_rows(ids)
        arows = self._anchor_rows(ids)
        P = self.P
        P[rows] = J @ P[rows] + A @ P[arows] + Lh @ P[ROT]
        P[:, rows] = (np.einsum("nkj,kij->nki", P[:, rows], J)
                      + np.einsum("nkj,kij->nki", P[:, arows], A)
                      + np.einsum("nj,kij->nki", P[:, ROT], Lh))
        self.lm[ids] = m
        self.in_group[ids] = True
        self.anchor_of[ids] = -1
        self.counts["n_joined_group"] += int(ids.size)

    def _world(self, slots: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World means (k, 3) and covariances (k, 3, 3) of ``slots``."""
        k = slots.size
        mean = np.empty((k, 3))
        cov = np.empty((k, 3, 3))
        if k == 0:
            return mean, cov
        rows = self._slot_rows(slots)
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
            m, J, A = self._point_jacobians(s)
            idx = np.concatenate([rr, self._anchor_rows(s)], axis=1)  # (k, 9)
            sub = self.P[idx[:, :, None], idx[:, None, :]]
            G = np.concatenate([J, A], axis=2)
            mean[i] = m
            cov[i] = G @ sub @ np.swapaxes(G, 1, 2)
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
        idx = np.concatenate([np.arange(self.L0), self._slot_rows(keep).ravel()])
        self.P = self.P[np.ix_(idx, idx)]
        self.lm = self.lm[keep]
        self.tracks = self.tracks[keep]
        self.in_group = self.in_group[keep]
        self.anchor_of = self.anchor_of[keep]
        self.last_seen = self.last_seen[keep]
        self.slot_of[self.tracks] = np.arange(keep.size)
