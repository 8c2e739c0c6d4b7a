"""``ekf-imu``: the error-state EKF driven by the raw IMU, with anchored inverse-depth landmarks.

**State.** The IMU's :class:`ekf.strapdown.NavState` (orientation ``world_R_imu``, world velocity
and position, gyro and accelerometer biases) and the landmarks of the active tracks in anchored
inverse depth (:mod:`ekf.imu_landmarks`), each anchored in the camera of its first frame, whose
IMU pose is kept in the state as an *anchor clone* (one per frame where landmarks started, shared
by them, dropped with its last landmark). Error state ``[dth (body, right), dv, dp (world), dbg,
dba]`` (:mod:`ekf.strapdown`), then slots of 3 rows in the order they were added: a landmark's
``[alpha, beta, rho]``, or a clone's ``[dth_c]`` and ``[dp_c]`` (two slots); one dense
covariance.

**World frame.** Gravity-aligned, z up, as dead-reckoning-imu's (:mod:`ekf.inertial_dead_reckoning`):
the state at frame 0 comes from the rest at the start (:func:`ekf.imu_init.rest_initial_state`:
levelled orientation, the world's yaw and origin the IMU's at frame 0, gyro bias and the vertical
accelerometer bias from the rest, with their covariance).

**Propagation** (:mod:`ekf.imu_propagation`): the mean and the 15 x 15 IMU block sample by sample
(strapdown's exact discrete step and its discrete noise: white noise ``density^2 / dt`` per step,
bias walks ``walk^2 dt``), the cross-covariances of the IMU state with the landmarks and clones
(which do not move) once per frame by the interval's accumulated transition.

**Update.** Every observation of a known landmark in one stacked update: ``z`` two pixels
(monocular) or four (stereo, ``[uL, vL, uR, vR]``), each with variance ``pixel_sigma^2``
(:class:`ekf.config.FilterConfig`); the measurement and its Jacobians are
:mod:`ekf.imu_landmarks`'s (IL-1, IL-2): with respect to the landmark, the IMU pose (its
right perturbation ``xi = [R^T dp; dth]``) and the anchor clone (the anchor camera's right
perturbation ``Ad(cam_T_imu) [R_c^T dp_c; dth_c]``), all at the current estimates.
An observation whose point is not in front of the camera, or whose innovation fails the
chi-square gate at ``gate_probability`` (per observation, 2 or 4 degrees of freedom), is rejected.
The gain by a Cholesky factor of the innovation covariance, ``P <- P - Y^T Y`` with
``Y = L^-1 (P H^T)^T``; the error injected into the mean (``NavState.retract``, landmarks added,
each clone's rotation and position moved and its landmarks' anchors with it).

**New landmarks.** A track's first observation starts its landmark (tracks seen once never
start one: they hold no information): monocular with the honest inverse-depth prior of
:class:`ekf.imu_landmarks.DepthPrior`, stereo from its disparity (non-positive disparity:
rejected, tried again at the next observation). Its covariance is its pixels' and prior's, with
no cross-covariance: the anchor's error is the clone's, a copy of the pose's rows and columns
at that frame. Why a clone and not a fixed anchor (the velocity filters' chart, with the
anchor's error folded into the landmark by the chart change IL-3): that change scales the
anchor's translation error by ``rho``, and linearised at a monocular depth prior 50 % off it
mis-states the landmark's correlation with the pose. Measured with the fixed anchor on the
simulated mono room drive (10 s, 800 landmarks): pose ANEES 660 over four seeds, 29 on seed 0
(96 otherwise) when the chart change alone was evaluated at the true depth; with the clone 11.5
over eight seeds. On EuRoC's 30 s: aligned ATE 0.038 -> 0.024 m, NEES 801 -> 282.

**Young landmarks** (``mature_ratio``, default 0.5). A landmark whose inverse depth is not yet
known to ``mature_ratio`` of itself (``sigma_rho >= 0.5 rho``: a monocular landmark until the
motion has given it its depth) updates only itself: Schmidt's consider update, the gain's rows
of every other state zero, so the landmark's rows and columns of ``P`` change as in the optimal
update and every other block stays (the Joseph form's covariance for that gain: consistent for
any gain). Its observations inform the pose once it is mature. Why: linearised at a depth still
far from the truth, a monocular observation tells the pose things its depth does not support.
Measured on the simulated mono room drive (8 seeds): pose ANEES 15.3 at 0.3, 11.5 at 0.5; 4
seeds: 28.8 at 0 (every landmark updates everything), 44 at 0.15, 26 at 0.7; EuRoC aligned ATE
0.0227 m at 0.3, 0.0239 at 0.5, 0.0245 at 0. Stereo landmarks are mature from their first
observation (their disparity gives the depth).

**Observability** (``linearisation="oc"``, not the default). The four directions the drive
cannot observe (a world translation, a turn about gravity; :func:`imu_nullspace` for the IMU
state and a clone, zero for a landmark, whose chart moves with its clone) are carried as the
covariance holds them: the IMU rows reset at every prior estimate with the least change of the
interval's transition that maps them there (OC-VINS, Hesch et al. 2014); each observation's
Jacobian is moved by the least change (Frobenius) that makes it blind to them in the columns it
touches. Measured: with anchor clones it changes nothing that matters (EuRoC NEES 279 -> 278,
mono room drive 19.5 either way over four seeds). With the fixed anchor (before the clones) it
halved EuRoC's NEES (801 -> 442) and diverged on two of four mono simulations: the spurious
information was the chart change's, which the clone removes.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import solve_triangular
from vislam.ekf import chi_square as chi2

from vislam.ekf import imu_landmarks as il
from vislam.ekf import inverse_depth as idp
from vislam.ekf.errors import InputError
from vislam.ekf.geometry import hat, so3_exp
from vislam.ekf.filter import FrameObservations, Landmarks, MotionInput, UpdateCounts
from vislam.ekf.imu_init import RestConfig, detect_rest, rest_initial_state
from vislam.ekf.imu_propagation import propagate
from vislam.ekf.inertial import ImuNoise, InertialDrive
from vislam.ekf.inertial_dead_reckoning import WORLD_GRAVITY_DIRECTION
from vislam.ekf.strapdown import N_ERROR, POS, ROT, VEL

#: Error-state rows of the pose, in the order ``[dth; dp]`` (the update's pose columns).
_POSE_ROWS = np.r_[np.arange(ROT.start, ROT.stop), np.arange(POS.start, POS.stop)]
_AR3 = np.arange(3)
#: What a 3-row slot of the state holds: a landmark, or the rotation or position rows of an
#: anchor clone (the IMU pose at a frame where landmarks started, their anchor).
LANDMARK, CLONE_ROT, CLONE_POS = 0, 1, 2


def imu_nullspace(x) -> np.ndarray:
    """The unobservable directions (15, 4) of the IMU state ``x``: a world translation
    (``dp = t``) and a turn ``a`` about gravity (``dth = R^T e_z a``, ``dv = e_z x v a``,
    ``dp = e_z x p a``)."""
    ez = np.array([0.0, 0.0, 1.0])
    N = np.zeros((N_ERROR, 4))
    N[POS, :3] = np.eye(3)
    N[ROT, 3] = x.R.T @ ez
    N[VEL, 3] = np.cross(ez, x.v)
    N[POS, 3] = np.cross(ez, x.p)
    return N


class ImuEkf:
    """The error-state EKF on the raw IMU (module docstring), a :class:`ekf.filter.Filter`
    run by :func:`ekf.driver.run_filter` on an :class:`ekf.inertial.InertialDrive`.

    ``noise`` overrides the drive's IMU noise (None: the calibration's data-sheet figures);
    ``depth_prior`` is the monocular inverse-depth prior; ``rest`` the rest detection;
    ``linearisation`` ``"standard"`` or ``"oc"`` and ``mature_ratio`` (0: every landmark
    updates everything) as the module docstring says."""

    name = "ekf-imu"
    drive_kind = "raw-imu"

    def __init__(self, noise: ImuNoise | None = None, depth_prior: il.DepthPrior = il.DepthPrior(),
                 rest: RestConfig = RestConfig(),
                 linearisation: str = "standard", mature_ratio: float = 0.5):
        if linearisation not in ("standard", "oc"):
            raise InputError(f"ekf-imu: linearisation must be 'standard' or 'oc', got {linearisation!r}")
        if not np.isfinite(mature_ratio) or mature_ratio < 0:
            raise InputError(f"ekf-imu: mature_ratio must be >= 0, got {mature_ratio!r}")
        self.mature_ratio = float(mature_ratio)
        self.linearisation = linearisation
        self.noise_override = noise
        self.depth_prior = depth_prior
        self.rest_config = rest

    # --- the protocol -------------------------------------------------------------------------
    def initialise(self, drive, config, guard) -> None:
        if not isinstance(drive, InertialDrive):
            raise InputError(f"ekf-imu runs on raw-IMU drives (IMU samples and camera tracks); "
                             f"{getattr(drive, 'name', 'this drive')!r} is a velocity drive")
        calib = drive.calibration
        if calib.distortion_model != "none":
            raise InputError(f"{drive.name}: tracks with lens distortion ({calib.distortion_model}) "
                             "are not supported by ekf-imu yet; give undistorted pixels")
        self.guard = guard
        self.g_world = calib.gravity * WORLD_GRAVITY_DIRECTION
        self.noise = self.noise_override or calib.noise
        t0 = float(drive.timestamps[0])
        rest = detect_rest(drive.imu, self.rest_config, t0)
        self.initial = rest_initial_state(drive.imu, t0, calib.gravity, calib.noise,
                                          self.rest_config, rest)
        self.x = self.initial.state
        self.P = np.array(self.initial.cov, dtype=float)
        # the unobservable directions (translation, turn about gravity) the covariance holds
        self.N = imu_nullspace(self.x)
        self.model = il.PixelModel(np.asarray(calib.K, dtype=float),
                                   np.asarray(calib.cam_T_imu, dtype=float), calib.baseline)
        self.imu_T_cam = calib.imu_T_cam
        self.Ad_cam = il.camera_from_imu_jacobian(self.model.cam_T_imu)
        self.pixel_var = float(config.pixel_sigma) ** 2
        m = self.model.rows
        self.gate = (np.inf if config.gate_probability is None
                     else float(chi2.ppf(config.gate_probability, m)))
        n_tracks = int(drive.n_tracks)
        self.wanted = np.bincount(drive.obs.track, minlength=n_tracks) >= 2
        self.slot = -np.ones(n_tracks, dtype=np.int64)
        self.lm_x = np.zeros((0, 3))
        self.lm_R = np.zeros((0, 3, 3))
        self.lm_p = np.zeros((0, 3))
        self.lm_track = np.zeros(0, dtype=np.int64)  # -1: a slot of an anchor clone
        self.lm_kind = np.zeros(0, dtype=np.int64)  # LANDMARK, CLONE_ROT or CLONE_POS
        self.lm_clone = np.zeros(0, dtype=np.int64)  # the anchor clone's id (its own, for a clone)
        self.next_clone = 0
        self.clone_frame, self.clone_now = -1, -1  # the frame of the newest clone, its id
        self.n_clones_max = 0
        self.map_mean = np.full((n_tracks, 3), np.nan)
        self.map_cov = np.full((n_tracks, 3, 3), np.nan)
        self.n_started = 0
        self.n_gated = 0

    def predict(self, motion: MotionInput) -> None:
        if motion.imu is None:
            raise self.guard.error(motion.frame, "ekf-imu needs raw IMU samples (a raw-IMU drive)")
        x, Pii, Phi = propagate(self.x, self.P[:N_ERROR, :N_ERROR], motion.imu, motion.start,
                                motion.end, self.g_world, self.noise)
        if not (np.all(np.isfinite(x.pose)) and np.all(np.isfinite(Pii))):
            raise self.guard.error(motion.frame, "state or covariance not finite after the IMU "
                                   "propagation")
        if self.linearisation == "oc":
            # OC-VINS (Hesch et al. 2014): the least change of Phi taking the unobservable
            # directions at the last prior estimate to those at this one; the interval's
            # noise kept as the per-sample propagation made it
            P0 = self.P[:N_ERROR, :N_ERROR]
            Qint = Pii - Phi @ P0 @ Phi.T
            u, w = self.N[:N_ERROR], imu_nullspace(x)
            Phi = Phi - (Phi @ u - w) @ np.linalg.solve(u.T @ u, u.T)
            Pii = Phi @ P0 @ Phi.T + Qint
            Pii = 0.5 * (Pii + Pii.T)
            self.N[:N_ERROR] = w
        else:
            self.N[:N_ERROR] = Phi @ self.N[:N_ERROR]
        self.x = x
        self.P[:N_ERROR, :N_ERROR] = Pii
        if self.P.shape[0] > N_ERROR:
            cross = Phi @ self.P[:N_ERROR, N_ERROR:]
            self.P[:N_ERROR, N_ERROR:] = cross
            self.P[N_ERROR:, :N_ERROR] = cross.T

    def update(self, frame: FrameObservations) -> UpdateCounts:
        tracks = np.asarray(frame.tracks, dtype=np.int64)
        z = np.asarray(frame.z, dtype=float)
        slots = self.slot[tracks]
        known = slots >= 0
        n_up = n_rej = 0
        if known.any():
            n_up, n_rej = self._update(slots[known], z[known], frame.frame)
        new = ~known & self.wanted[tracks]
        n_new = 0
        if new.any():
            n_new, n_bad = self._start(tracks[new], z[new], frame.frame)
            n_rej += n_bad
        return UpdateCounts(n_up, n_rej, n_new)

    def marginalise(self, tracks: np.ndarray) -> None:
        slots = self.slot[np.asarray(tracks, dtype=np.int64)]
        slots = slots[slots >= 0]
        if slots.size == 0:
            return
        mean, cov = self._world(slots)
        tr = self.lm_track[slots]
        self.map_mean[tr] = mean
        self.map_cov[tr] = cov
        keep = np.ones(self.lm_track.size, dtype=bool)
        keep[slots] = False
        # anchor clones no landmark refers to any more leave too
        used = np.unique(self.lm_clone[keep & (self.lm_kind == LANDMARK)])
        keep &= (self.lm_kind == LANDMARK) | np.isin(self.lm_clone, used)
        if self.clone_now not in used:
            self.clone_frame = -1
        rows = np.r_[np.arange(N_ERROR), (N_ERROR + 3 * np.flatnonzero(keep)[:, None] + _AR3).ravel()]
        self.P = self.P[np.ix_(rows, rows)]
        self.N = self.N[rows]
        self.slot[self.lm_track[self.lm_kind == LANDMARK]] = -1
        self.lm_x, self.lm_R, self.lm_p = self.lm_x[keep], self.lm_R[keep], self.lm_p[keep]
        self.lm_track = self.lm_track[keep]
        self.lm_kind, self.lm_clone = self.lm_kind[keep], self.lm_clone[keep]
        lm = np.flatnonzero(self.lm_kind == LANDMARK)
        self.slot[self.lm_track[lm]] = lm

    def pose(self) -> np.ndarray:
        return self.x.pose

    def pose_cov(self) -> np.ndarray:
        J = self._xi_of_error()
        return J @ self.P[:N_ERROR, :N_ERROR] @ J.T

    def active_landmarks(self) -> Landmarks:
        lm = np.flatnonzero(self.lm_kind == LANDMARK)
        if lm.size == 0:
            return Landmarks.none()
        mean, cov = self._world(lm)
        return Landmarks(self.lm_track[lm].copy(), mean, cov)

    def landmark_map(self) -> tuple[np.ndarray, np.ndarray]:
        return self.map_mean.copy(), self.map_cov.copy()

    def info(self) -> dict:
        return {
            **self.initial.info(self.x),
            "landmarks": "anchored inverse depth",
            "monocular_depth_prior": {"min_depth_m": self.depth_prior.min_depth,
                                      "rho": self.depth_prior.rho,
                                      "sigma_rho": self.depth_prior.sigma},
            "n_landmarks_started": int(self.n_started),
            "n_gated": int(self.n_gated),
            "most_anchor_clones": int(self.n_clones_max),
            "imu_noise": self.noise.as_array().tolist(),
        }

    # --- pieces --------------------------------------------------------------------------------
    def _xi_of_error(self) -> np.ndarray:
        """``d xi / d error`` (6, 15): ``xi = [R^T dp; dth]``."""
        J = np.zeros((6, N_ERROR))
        J[:3, POS] = self.x.R.T
        J[3:, ROT] = np.eye(3)
        return J

    def _world(self, slots: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World points (k, 3) and covariances (k, 3, 3) of landmark slots (NaN where the
        inverse depth is not positive)."""
        x = self.lm_x[slots]
        R_a, p_a, R_c, rows = self._anchors(slots)
        mean = idp.world_point(x, R_a, p_a)
        J = np.empty((slots.size, 3, 9))
        J[:, :, :3] = idp.world_jacobian(x, R_a)
        with np.errstate(divide="ignore", invalid="ignore"):
            q = idp.bearing(x) / x[:, 2:3]  # the point in the anchor camera
        G = np.concatenate([R_a, -R_a @ hat(q)], axis=2) @ self.Ad_cam  # d m / d xi_imu (clone)
        J[:, :, 3:6] = G[:, :, 3:]
        J[:, :, 6:] = G[:, :, :3] @ np.swapaxes(R_c, 1, 2)
        Pll = self.P[rows[:, :, None], rows[:, None, :]]
        cov = J @ Pll @ np.swapaxes(J, 1, 2)
        bad = ~(x[:, 2] > 0)
        mean[bad] = np.nan
        cov[bad] = np.nan
        return mean, cov

    def _linearise(self, x_state, lm_x, slots: np.ndarray, z: np.ndarray):
        """Residuals (k, m), pose Jacobians of ``[dth; dp]`` (k, m, 6), landmark Jacobians
        (k, m, 3) and whether each point is in front, at the state ``x_state`` and landmark
        coordinates ``lm_x``."""
        T = x_state.pose
        x = lm_x[slots]
        R_a, p_a, R_c, rows = self._anchors(slots)
        q_i = il.imu_points(x, R_a, p_a, T)
        zhat, dz_dq, depth = self.model.predict(q_i)
        front = (depth > 0) & (x[:, 2] > 0) & np.all(np.isfinite(zhat), axis=1)
        Hl = np.empty((slots.size, dz_dq.shape[1], 9))  # landmark, then its anchor clone
        Hl[:, :, :3] = dz_dq @ il.landmark_jacobian(x, R_a, p_a, T)
        Ha = dz_dq @ il.anchor_jacobian(x, R_a, T) @ self.Ad_cam  # of the clone's xi = [t; phi]
        Hl[:, :, 3:6] = Ha[:, :, 3:]
        Hl[:, :, 6:] = Ha[:, :, :3] @ np.swapaxes(R_c, 1, 2)
        Hxi = dz_dq @ il.pose_jacobian(q_i)  # (k, m, 6) of xi = [t; phi]
        Hp = np.empty_like(Hxi)  # of [dth; dp]
        Hp[:, :, :3] = Hxi[:, :, 3:]
        Hp[:, :, 3:] = Hxi[:, :, :3] @ x_state.R.T
        if self.linearisation == "oc":
            Hp, Hl = self._observability_constrained(rows, Hp, Hl)
        return z - zhat, Hp, Hl, front, rows

    def _anchors(self, slots: np.ndarray):
        """For landmark slots: the anchor cameras ``(R_a (k, 3, 3), p_a (k, 3))`` from their
        clones' means, the clones' rotations ``R_c`` (k, 3, 3), and each observation's state
        rows (k, 9): the landmark's three, then its clone's six ``[dth_c; dp_c]``."""
        cs = self._clone_slots(self.lm_clone[slots])
        R_c, p_c = self.lm_R[cs], self.lm_p[cs]
        R_ic, t_ic = self.imu_T_cam[:3, :3], self.imu_T_cam[:3, 3]
        R_a = R_c @ R_ic
        p_a = p_c + R_c @ t_ic
        rows = np.empty((slots.size, 9), dtype=np.int64)
        rows[:, :3] = N_ERROR + 3 * slots[:, None] + _AR3
        rows[:, 3:] = N_ERROR + 3 * cs[:, None] + np.arange(6)
        return R_a, p_a, R_c, rows

    def _clone_slots(self, ids: np.ndarray) -> np.ndarray:
        """The first slot (its rotation's) of each anchor clone ``ids``."""
        first = np.flatnonzero(self.lm_kind == CLONE_ROT)
        return first[np.searchsorted(self.lm_clone[first], ids)]

    def _observability_constrained(self, rows, Hp, Hl):
        """``[Hp, Hl]`` of each observation moved by the least change (Frobenius) that makes
        it blind to the four unobservable directions (a world translation and a turn about
        gravity: OC-VINS, Hesch et al. 2014), in the columns it touches ``[dth, dp, x_i]``.
        The directions are those the covariance holds (``self.N``: set at frame 0 and carried
        by every transition and landmark start since), not recomputed at the current estimate,
        whose own directions an update has moved."""
        k, q = rows.shape
        N = np.empty((k, 6 + q, 4))
        N[:, :3] = self.N[ROT]
        N[:, 3:6] = self.N[POS]
        N[:, 6:] = self.N[rows]
        H = np.concatenate([Hp, Hl], axis=2)  # (k, m, 6 + q)
        NtN = np.swapaxes(N, 1, 2) @ N
        H = H - (H @ N) @ np.linalg.solve(NtN, np.swapaxes(N, 1, 2))
        return H[:, :, :6], H[:, :, 6:]

    def _update(self, slots: np.ndarray, z: np.ndarray, t: int) -> tuple[int, int]:
        """Gate, then update with the observations of mature landmarks (every state moved),
        then with those of young ones (only the young landmarks moved: Schmidt's update)."""
        r, Hp, Hl, front, rows = self._linearise(self.x, self.lm_x, slots, z)
        P = self.P
        m = self.model.rows
        ok = front.copy()
        if ok.any():  # per-observation chi-square gate
            Ppp = P[np.ix_(_POSE_ROWS, _POSE_ROWS)]
            Ppl = P[_POSE_ROWS[None, :, None], rows[ok][:, None, :]]  # (k, 6, q)
            Pll = P[rows[ok][:, :, None], rows[ok][:, None, :]]  # (k, q, q)
            hp, hl = Hp[ok], Hl[ok]
            HpT, HlT = np.swapaxes(hp, 1, 2), np.swapaxes(hl, 1, 2)
            cross = hp @ Ppl @ HlT
            S = hp @ Ppp @ HpT + cross + np.swapaxes(cross, 1, 2) + hl @ Pll @ HlT
            S += self.pixel_var * np.eye(m)
            d2 = np.full(slots.size, np.inf)
            d2[ok] = np.einsum("ni,nij,nj->n", r[ok], np.linalg.inv(S), r[ok])
            self.n_gated += int((ok & ~(d2 <= self.gate)).sum())
            ok &= d2 <= self.gate
        n_rej = int(slots.size - ok.sum())
        young = self._young(slots)
        full = ok & ~young
        n_up = 0
        if full.any():
            n = self._stacked(Hp[full], Hl[full], r[full], rows[full], t, None)
            n_up += n
            n_rej += int(full.sum()) - n
        late = ok & young
        if late.any():
            r, Hp, Hl, front, rows = self._linearise(self.x, self.lm_x, slots[late], z[late])
            rows = rows[front]
            n = self._stacked(Hp[front], Hl[front], r[front], rows, t, rows[:, :3].ravel())
            n_up += n
            n_rej += int(late.sum()) - n
        return n_up, n_rej

    def _correct_clones(self) -> None:
        """Move the anchor clones' means by the corrections an update left in their rows of
        ``lm_x`` (rotation on the right, position added), and zero those rows."""
        rot = np.flatnonzero(self.lm_kind == CLONE_ROT)
        if rot.size == 0:
            return
        self.lm_R[rot] = self.lm_R[rot] @ so3_exp(self.lm_x[rot])
        self.lm_p[rot] += self.lm_x[rot + 1]
        self.lm_x[rot] = 0.0
        self.lm_x[rot + 1] = 0.0

    def _young(self, slots: np.ndarray) -> np.ndarray:
        """Landmarks whose inverse depth is not yet known to ``mature_ratio`` of itself."""
        if not self.mature_ratio:
            return np.zeros(slots.size, dtype=bool)
        i = N_ERROR + 3 * slots + 2
        var = self.P[i, i]
        rho = self.lm_x[slots, 2]
        return ~(var < (self.mature_ratio * rho) ** 2)

    def _stacked(self, Hp, Hl, r, rows, t: int, moved: np.ndarray | None) -> int:
        """One stacked update with ``k`` observations (Jacobians ``Hp`` (k, m, 6) of
        ``[dth; dp]``, ``Hl`` (k, m, 3) of the landmark rows ``rows`` (k, 3), residuals ``r``).
        ``moved`` None: the optimal update of every state. Else only the states of rows
        ``moved`` take the update (Schmidt's consider update): their rows and columns of
        ``P`` change as in the optimal update, every other block stays, which is the Joseph
        form's covariance for that gain (consistent for any gain). Returns the number used."""
        P = self.P
        k, m = r.shape
        if k == 0:
            return 0
        N = P.shape[0]
        flat = rows.ravel()
        # P H^T (N, k m), rows of H ordered (observation, pixel)
        PHt = P[:, _POSE_ROWS] @ Hp.reshape(-1, 6).T
        q = rows.shape[1]
        G = P[:, flat].reshape(N, k, q)
        PHt += np.einsum("nkj,kmj->nkm", G, Hl).reshape(N, k * m)
        S = Hp.reshape(-1, 6) @ PHt[_POSE_ROWS]
        B = PHt[flat].reshape(k, q, k * m)
        S += np.einsum("kmj,kjc->kmc", Hl, B).reshape(k * m, k * m)
        S = 0.5 * (S + S.T)
        S[np.diag_indices_from(S)] += self.pixel_var
        try:
            L = np.linalg.cholesky(S)
        except np.linalg.LinAlgError:
            self.guard.reject(t, "innovation covariance not positive definite", k)
            return 0
        if moved is None:
            Y = solve_triangular(L, PHt.T, lower=True, check_finite=False)  # (k m, N)
        else:
            Y = solve_triangular(L, PHt[moved].T, lower=True, check_finite=False)
        w = solve_triangular(L, r.ravel(), lower=True, check_finite=False)
        d = Y.T @ w
        if not np.all(np.isfinite(d)):
            self.guard.reject(t, "update not finite", k)
            return 0
        if moved is None:
            P -= Y.T @ Y
            self.P = 0.5 * (P + P.T)
            self.x = self.x.retract(d[:N_ERROR])
            self.lm_x = self.lm_x + d[N_ERROR:].reshape(-1, 3)
            self._correct_clones()
            return k
        Yall = solve_triangular(L, PHt.T, lower=True, check_finite=False)
        block = P[moved] - Y.T @ Yall  # the moved rows, every column
        P[moved] = block
        P[:, moved] = block.T
        sub = P[np.ix_(moved, moved)]
        P[np.ix_(moved, moved)] = 0.5 * (sub + sub.T)
        lm = self.lm_x.reshape(-1)
        lm[moved - N_ERROR] += d
        return k

    def _start(self, tracks: np.ndarray, z: np.ndarray, t: int) -> tuple[int, int]:
        """Start landmarks for ``tracks`` from their first pixels ``z`` at frame ``t``, anchored
        in this frame's camera: its IMU pose is cloned into the state once (the anchor clone,
        shared by the landmarks started here), so that a landmark's error is its pixels' and
        its prior's alone, uncorrelated with anything else, and its anchor's error is the
        clone's. Returns (started, rejected)."""
        if self.model.baseline is not None:
            ok = (z[:, 0] - z[:, 2]) > 0
            tracks, z = tracks[ok], z[ok]
            n_bad = int((~ok).sum())
        else:
            n_bad = 0
        k = tracks.size
        if k == 0:
            return 0, n_bad
        if self.clone_frame != t:
            self._clone(t)
        x, C = il.initial_landmarks(z, self.model.K, self.model.baseline, self.pixel_var,
                                    self.depth_prior)
        P = self.P
        N = P.shape[0]
        P_new = np.zeros((N + 3 * k, N + 3 * k))
        P_new[:N, :N] = P
        for i in range(k):
            P_new[N + 3 * i:N + 3 * i + 3, N + 3 * i:N + 3 * i + 3] = C[i]
        self.P = P_new
        self.N = np.concatenate([self.N, np.zeros((3 * k, self.N.shape[1]))])
        self._add_slots(x, np.zeros((k, 3, 3)), np.zeros((k, 3)), tracks,
                        np.full(k, LANDMARK), np.full(k, self.clone_now))
        self.slot[tracks] = self.lm_track.size - k + np.arange(k)
        self.n_started += k
        return k, n_bad

    def _clone(self, t: int) -> None:
        """Append a copy of the IMU pose ``[dth; dp]`` (mean and every covariance) as the anchor
        clone of frame ``t``."""
        P = self.P
        N = P.shape[0]
        P_new = np.empty((N + 6, N + 6))
        P_new[:N, :N] = P
        P_new[N:, :N] = P[_POSE_ROWS]
        P_new[:N, N:] = P[:, _POSE_ROWS]
        P_new[N:, N:] = P[np.ix_(_POSE_ROWS, _POSE_ROWS)]
        self.P = P_new
        self.N = np.concatenate([self.N, self.N[_POSE_ROWS]])
        cid = self.next_clone
        self.next_clone += 1
        self._add_slots(np.zeros((2, 3)), np.stack([self.x.R, np.zeros((3, 3))]),
                        np.stack([self.x.p, np.zeros(3)]), np.array([-1, -1]),
                        np.array([CLONE_ROT, CLONE_POS]), np.array([cid, cid]))
        self.clone_frame, self.clone_now = t, cid
        self.n_clones_max = max(self.n_clones_max, int((self.lm_kind == CLONE_ROT).sum()))

    def _add_slots(self, x, R, p, track, kind, clone) -> None:
        self.lm_x = np.concatenate([self.lm_x, x])
        self.lm_R = np.concatenate([self.lm_R, R])
        self.lm_p = np.concatenate([self.lm_p, p])
        self.lm_track = np.concatenate([self.lm_track, track])
        self.lm_kind = np.concatenate([self.lm_kind, kind])
        self.lm_clone = np.concatenate([self.lm_clone, clone])
