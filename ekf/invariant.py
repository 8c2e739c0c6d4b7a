"""``ekf-invariant``: a right-invariant EKF on SE_{1+K}(3) (Barrau & Bonnabel's invariant EKF SLAM).

State. The IMU pose in the world and the K active landmarks form one group element

    X = [[R, p, l_1, ..., l_K],
         [0, I_{1+K}        ]]          (world = IMU at frame 0; T = [[R, p], [0, 1]] = world_T_imu)

and, when ``config.gyro_bias`` is set, a constant gyro bias ``b`` (a vector, outside the group);
when ``config.speed_scale`` is set, a slow speed-scale error ``s`` of the linear velocities (a
scalar, outside the group: the true body twist is ``[(1 + s) v; w - b]``).

Error. Right-invariant: ``X_true = exp(xi) X_est`` with the tangent ordered

    xi = [xi_p (3), xi_R (3), (xi_b (3) with gyro bias), (xi_s (1) with speed scale),
          xi_l1 (3), ..., xi_lK (3)]

so the leading pose block ``[xi_p; xi_R]`` is an SE(3) twist, translation first, in the
conventions of :mod:`ekf.geometry`: ``T_true = se3_exp([xi_p; xi_R]) T_est`` (a left, world-frame
perturbation of T). The exponential of SE_{1+K}(3) is, with ``R_d = exp(xi_R^)``, ``J = J_l(xi_R)``,

    R <- R_d R,   p <- R_d p + J xi_p,   l_j <- R_d l_j + J xi_lj,   (b <- b + xi_b),   (s <- s + xi_s).

Propagation (the group form of paper eq. 4, body twist ``u = [v; w]``): ``T <- T se3_exp(tau u)``,
landmarks constant. The dynamics are group-affine with body inputs, so the error propagates with
the identity; body twist noise ``n`` enters as ``xi <- xi + tau Ad_X[:, pose] J_l(tau u) n`` where
the landmark rows of the SE_{1+K}(3) adjoint are ``[0, l_j^ R]`` (a rotation error also moves the
landmark error coordinates ``xi_lj ~ l_true - l_est + l_est^ xi_R``): see
:func:`noise_jacobian`. A gyro bias makes the error dynamics depend on the estimate
("imperfect IEKF"): ``xi <- xi - tau B_R xi_b`` to first order (:func:`twist_error_coupling`).
A speed scale does the same through the linear velocity: the true twist minus the estimate's
is ``[(s - s_est) v; -(b - b_est)] = [v xi_s; -xi_b]`` (``v`` the measured linear velocity), so
``xi_s`` acts as linear-velocity noise ``v xi_s`` and ``xi <- xi + tau B_p v xi_s`` (``B_p`` the
linear-velocity columns of the noise Jacobian). Both at once: the error transition is
``I + F S_e`` with ``F = -tau B E(u)`` and ``E(u) = [[0, -v], [I, 0]]`` the twist-error matrix of
:func:`ekf.prediction.twist_error_matrix` (its columns where configured), ``S_e`` selecting
``[xi_b; xi_s]``. Bias and scale are random walks: ``P[e, e] += walk^2 tau`` per step.

Observation (paper eq. 1-3): ``z = M pi(cam_T_imu T^-1 l_j)``. Under the right-invariant error,
``T_true^-1 l_true = R^T (l - p) + R^T J_r(xi_R) (xi_lj - xi_p)`` exactly, so the Jacobian is
``H_j = A_j [-I, 0, (0), I at l_j]`` with ``A_j = M dpi/dq(q) C R^T`` (C the rotation of
cam_T_imu): it does not depend on the landmark or position estimates, only on R and q
(:func:`observation_jacobian`).

New landmarks (stereo triangulation ``p_c`` of ``z``): ``l = T imu_T_cam p_c`` and
``xi_l = xi_p + R R_ic dp_c`` to first order (:func:`augmentation_jacobians`): the new landmark
inherits the position error of the pose and none of its rotation error.

Inverse-depth landmarks (``config.landmark_parameterisation = "inverse-depth"``,
:mod:`ekf.inverse_depth`). An anchored inverse-depth landmark ``x = [alpha, beta, rho]`` is not a
point of the group: its anchor is a fixed frame, so ``x`` is a vector state with an additive
error (like the bias), outside SE_{1+K}(3). There the invariant structure is lost: its rows get
no process noise, but its observation Jacobian depends on the estimate,
``H = [A_h (-C R^T [rho I, -s^]), 0, A_h C R^T G]`` with ``m_h = [s; rho]`` (ID-2,
:func:`inverse_depth_jacobians`), and a world change moves it by the estimate-dependent
``N_j = D R_a^T [I, -m^]`` (ID-7). The filter keeps those directions unobservable as ekf-joint's
"oc" does: after each update ``P <- T P T^T`` with ``T`` adding ``N_j(x+) - N_j(x-)`` times
the pose rows (the pose rows of the nullspace are the identity here). Once the linearity index
allows (ID-5), the landmark joins the group: ``xi_l = J dx + l^ xi_R`` (ID-6 with the
right-invariant coordinates, :func:`_to_group`), after which it is exactly as above.

Output. ``Estimate.pose_cov`` converts the pose block with
:func:`ekf.conventions.left_cov_to_estimate`; a landmark's world covariance is ``G P G^T`` with
``dl = xi_lj - l^ xi_R`` (:func:`landmark_world_jacobian`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from scipy.linalg.blas import dtrsm
from scipy.linalg.lapack import dpotrf
from vislam.ekf import chi_square as chi2

from vislam.ekf import inverse_depth as idp
from vislam.ekf.camera import dpi_dq, project, triangulate_unscented, triangulate_with_jacobian
from vislam.ekf.config import FilterConfig
from vislam.ekf.conventions import left_cov_to_estimate
from vislam.ekf.estimate import Estimate
from vislam.ekf.numerics import (
    NumericalGuard,
    Scratch,
    UpdateRejected,
    add_outer,
    add_pose_rows,
    all_finite,
    batched_inv,
    batched_solve,
    finite_norm2,
    finite_rows,
)
from vislam.ekf.geometry import (
    adjoint,
    hat,
    homogeneous,
    so3_left_jacobian_inv,
    so3_log,
)
from vislam.ekf.prediction import (se3_exp_single, se3_left_jacobian, so3_exp_and_left_jacobian,
                                  twist_error_coupling)
from vislam.ekf.kept_landmarks_invariant import InvariantKeptLandmarks
from vislam.ekf.kept_landmarks import map_with_kept
from vislam.ekf.driver import run_filter
from vislam.ekf.filter import FrameObservations, Landmarks, MotionInput, UpdateCounts
from vislam.ekf.sequence import Sequence


ESTIMATOR_NAME = "ekf-invariant"

#: Index blocks of the error state.
P_IDX = slice(0, 3)
R_IDX = slice(3, 6)
B_IDX = slice(6, 9)


def landmark_offset(gyro_bias: bool, speed_scale: bool = False) -> int:
    """Index of the first landmark coordinate in the error state."""
    return (9 if gyro_bias else 6) + (1 if speed_scale else 0)


def scale_index(gyro_bias: bool) -> int:
    """Index of the speed-scale error ``xi_s`` in the error state (with ``config.speed_scale``)."""
    return 9 if gyro_bias else 6


# --------------------------------------------------------------------------------------
# Group math of SE_{1+K}(3)
# --------------------------------------------------------------------------------------
def retract(
    T: np.ndarray,
    landmarks: np.ndarray,
    delta: np.ndarray,
    gyro_bias: np.ndarray | None = None,
    speed_scale: float | None = None,
):
    """``exp(delta) X``: apply a right-invariant correction to pose, landmarks (and bias and
    speed scale, each None where the state has none).

    ``delta`` is ordered as the error state. Returns ``(T, landmarks, gyro_bias, speed_scale)``.
    """
    delta = np.asarray(delta, dtype=float)
    Rd, J = so3_exp_and_left_jacobian(delta[R_IDX])
    off = landmark_offset(gyro_bias is not None, speed_scale is not None)
    T_new = np.eye(4)
    T_new[:3, :3] = Rd @ T[:3, :3]
    T_new[:3, 3] = Rd @ T[:3, 3] + J @ delta[P_IDX]
    dl = delta[off:].reshape(-1, 3)
    lm_new = landmarks @ Rd.T + dl @ J.T
    b_new = None if gyro_bias is None else gyro_bias + delta[B_IDX]
    s_new = None if speed_scale is None else speed_scale + delta[scale_index(gyro_bias is not None)]
    return T_new, lm_new, b_new, s_new


def error_between(
    T_true: np.ndarray,
    lm_true: np.ndarray,
    T_est: np.ndarray,
    lm_est: np.ndarray,
    b_true: np.ndarray | None = None,
    b_est: np.ndarray | None = None,
    s_true: float | None = None,
    s_est: float | None = None,
) -> np.ndarray:
    """The exact error ``xi = log(X_true X_est^-1)`` (the inverse of :func:`retract`)."""
    Rd = T_true[:3, :3] @ T_est[:3, :3].T
    phi = so3_log(Rd)
    Jinv = so3_left_jacobian_inv(phi)
    xp = Jinv @ (T_true[:3, 3] - Rd @ T_est[:3, 3])
    xl = (np.asarray(lm_true) - np.asarray(lm_est) @ Rd.T) @ Jinv.T
    parts = [xp, phi]
    if b_true is not None:
        parts.append(np.asarray(b_true) - np.asarray(b_est))
    if s_true is not None:
        parts.append([s_true - s_est])
    parts.append(xl.ravel())
    return np.concatenate(parts)


def noise_jacobian(
    T: np.ndarray, landmarks: np.ndarray, twist: np.ndarray, gyro_bias: bool = False,
    speed_scale: bool = False,
):
    """``B`` (n x 6): one step's error change is ``tau B n`` for body twist noise ``n``.

    ``T`` is the pose at the start of the step and ``twist = tau u`` the step's twist.
    ``B = Ad_X[:, pose] J_l(tau u)`` with the landmark rows of the SE_{1+K}(3) adjoint
    ``[0, l_j^ R]``; bias and speed-scale rows are zero.
    """
    off = landmark_offset(gyro_bias, speed_scale)
    K = landmarks.shape[0]
    R = T[:3, :3]
    B = np.zeros((off + 3 * K, 6))
    B[:6] = adjoint(T)
    B[off:, 3:] = (hat(landmarks) @ R).reshape(3 * K, 3)
    return B @ se3_left_jacobian(twist)


def observation_jacobian(T: np.ndarray, q_cam: np.ndarray, cam_T_imu: np.ndarray, M: np.ndarray):
    """``A`` (N, 4, 3) with ``H_j = A_j [-I at p, 0 at R, I at l_j]`` (right-invariant error).

    ``q_cam`` (N, 3) the predicted points in the left camera frame. ``A_j = M dpi/dq C R^T``.
    """
    qh = homogeneous(q_cam)
    CRt = cam_T_imu[:3, :3] @ T[:3, :3].T
    return M @ dpi_dq(qh)[:, :, :3] @ CRt


def augmentation_jacobians(T: np.ndarray, J_tri: np.ndarray, imu_T_cam: np.ndarray):
    """New landmark error ``xi_l = xi_p + G_z dz``: returns ``G_z`` (N, 3, 4).

    ``J_tri`` (N, 3, 4) is ``dp_cam/dz`` of the triangulation; ``G_z = R R_ic J_tri``. The
    Jacobian with respect to the existing error is ``I`` at ``xi_p`` and zero elsewhere.
    """
    return (T[:3, :3] @ imu_T_cam[:3, :3]) @ J_tri


def inverse_depth_jacobians(T: np.ndarray, m_h: np.ndarray, G: np.ndarray, cam_T_imu, M):
    """Observation Jacobians of inverse-depth landmarks (homogeneous world points ``m_h``
    (N, 4), ``dm_h/dx = G`` (N, 4, 3)) under the right-invariant pose error:
    ``(q_h (N, 4), H_pose (N, 4, 6), H_x (N, 4, 3))`` with ``q_h = cam_T_imu T^-1 m_h``,
    ``H_pose = -A_h C R^T [rho I, -s^]`` (``m_h = [s; rho]``, ``T_true^-1 = T^-1 exp(-xi)``) and
    ``H_x = A_h cam_T_imu T^-1 G``, ``A_h = M dpi/dq(q_h)``."""
    Ti = np.linalg.inv(T)
    CTi = cam_T_imu @ Ti
    q_h = m_h @ CTi.T
    A = M @ dpi_dq(q_h)  # (N, 4, 4)
    ACRt = A[:, :, :3] @ CTi[:3, :3]
    Hp = np.empty((m_h.shape[0], 4, 6))
    Hp[:, :, :3] = -ACRt * m_h[:, 3, None, None]
    Hp[:, :, 3:] = ACRt @ hat(m_h[:, :3])
    return q_h, Hp, A @ CTi @ G


def landmark_world_jacobian(landmarks: np.ndarray) -> np.ndarray:
    """``G`` (N, 3, 6) on ``[xi_R; xi_l]``: ``l_true - l_est ~ -l^ xi_R + xi_l``."""
    landmarks = np.atleast_2d(landmarks)
    G = np.zeros((landmarks.shape[0], 3, 6))
    G[:, :, :3] = -hat(landmarks)
    G[:, :, 3:] = np.eye(3)
    return G


def landmark_world_cov(P: np.ndarray, landmarks: np.ndarray, slots: np.ndarray, off: int):
    """World-frame covariances (N, 3, 3) of the landmarks in state ``slots``."""
    if slots.size == 0:
        return np.zeros((0, 3, 3))
    li = off + 3 * slots[:, None] + np.arange(3)
    ri = np.broadcast_to(np.arange(3, 6), li.shape)
    idx = np.concatenate([ri, li], axis=1)  # (N, 6)
    sub = P[idx[:, :, None], idx[:, None, :]]
    G = landmark_world_jacobian(landmarks)
    return G @ sub @ np.swapaxes(G, -1, -2)


# --------------------------------------------------------------------------------------
# The filter
# --------------------------------------------------------------------------------------
@dataclass
class InvariantState:
    """Mean of the group element, bias, speed scale and inverse-depth slots, and the
    covariance ``P``."""

    T: np.ndarray
    landmarks: np.ndarray  # (K, 3), slot order: world l, or x = [alpha, beta, rho]
    tracks: np.ndarray  # (K,) track id of each slot
    P: np.ndarray
    bias: np.ndarray | None
    #: The speed scale ``s`` (``v_true = (1 + s) v``), None without ``config.speed_scale``.
    scale: float | None = None
    # Inverse-depth slots and their anchors (world_T_camera at the first observation).
    lm_id: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    anchor_R: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 3)))
    anchor_p: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    # keep_landmarks: ended tracks' landmarks, as regressions on this state (ekf.kept_landmarks)
    retired: InvariantKeptLandmarks | None = None
    scratch: Scratch = field(default_factory=Scratch)

    def world_landmarks(self, slots: np.ndarray, off: int) -> tuple[np.ndarray, np.ndarray]:
        """World means (k, 3) and covariances (k, 3, 3) of ``slots``."""
        mean = self.landmarks[slots].copy()
        cov = landmark_world_cov(self.P, self.landmarks[slots], slots, off)
        i = self.lm_id[slots]
        if i.any():
            s = slots[i]
            x, R_a = self.landmarks[s], self.anchor_R[s]
            J = idp.world_jacobian(x, R_a)
            rows = off + 3 * s[:, None] + np.arange(3)
            mean[i] = idp.world_point(x, R_a, self.anchor_p[s])
            cov[i] = J @ self.P[rows[:, :, None], rows[:, None, :]] @ np.swapaxes(J, 1, 2)
        return mean, cov


class InvariantEKF:
    """The right-invariant EKF (see the module docstring for the model): the per-frame protocol
    (:mod:`ekf.filter`) around an :class:`InvariantState` and this module's steps.

    With ``config.keep_landmarks`` the landmarks of ended tracks stay refined through
    :class:`ekf.kept_landmarks_invariant.InvariantKeptLandmarks`, or in one dense covariance with
    ``textbook`` (the same numbers at ``O(n^2)`` per frame: the reference of its test)."""

    name = ESTIMATOR_NAME

    def __init__(self, textbook: bool = False):
        self.textbook = bool(textbook)

    def initialise(self, seq: Sequence, config: FilterConfig, guard: NumericalGuard) -> None:
        self.config = config
        self.guard = guard
        self.cal = cal = seq.calibration
        self.M = cal.M
        self.cam_T_imu = np.asarray(cal.cam_T_imu, dtype=float)
        self.imu_T_cam = cal.imu_T_cam
        self.V = config.pixel_cov
        self.Vinv = np.linalg.inv(self.V)
        self.W_chol = np.linalg.cholesky(config.velocity_cov)
        use_bias = bool(config.gyro_bias)
        use_scale = bool(config.speed_scale)
        self.off = off = landmark_offset(use_bias, use_scale)
        self.gate = None if config.gate_probability is None else chi2.ppf(config.gate_probability, 4)
        P0 = np.zeros((off, off))
        P0[:6, :6] = config.initial_pose_cov
        if use_bias:
            P0[B_IDX, B_IDX] = config.gyro_bias_sigma**2 * np.eye(3)
        if use_scale:
            i = scale_index(use_bias)
            P0[i, i] = config.speed_scale_sigma**2
        self.state = InvariantState(
            T=np.eye(4),
            landmarks=np.zeros((0, 3)),
            tracks=np.zeros(0, dtype=np.int64),
            P=P0,
            bias=np.zeros(3) if use_bias else None,
            scale=0.0 if use_scale else None,
            retired=InvariantKeptLandmarks(off) if config.keep_landmarks and not self.textbook else None,
        )
        self.slot_of = -np.ones(seq.n_tracks, dtype=np.int64)
        self.done = np.zeros(seq.n_tracks, dtype=bool)
        self.ended = np.zeros(seq.n_tracks, dtype=bool)  # scratch mask for marginalise
        self.map_mean = np.full((seq.n_tracks, 3), np.nan)
        self.map_cov = np.full((seq.n_tracks, 3, 3), np.nan)
        self.n_converted = 0

    def predict(self, motion: MotionInput) -> None:
        st, t = self.state, motion.frame
        if not _propagate(st, motion.twist, motion.dt, self.W_chol, self.config, self.off):
            raise self.guard.error(t, "state covariance not finite after prediction")
        self.guard.check_state(t, st.T, st.P[:self.off, :self.off])

    def update(self, frame: FrameObservations) -> UpdateCounts:
        st, guard, config, off = self.state, self.guard, self.config, self.off
        t, tracks, z = frame.frame, frame.tracks, frame.z
        slots = self.slot_of[tracks]
        old = slots >= 0
        try:
            n_used, n_rej, n_num = _update(
                st, slots[old], z[old], self.M, self.cam_T_imu, self.V, self.Vinv, self.gate,
                config, off
            )
        except UpdateRejected as exc:
            guard.reject(t, str(exc), int(old.sum()))
            n_used, n_rej, n_num = 0, int(old.sum()), 0
        fresh = (~old) & (~self.done[tracks])
        n_init, n_rej_new, n_num_new = _augment(
            st, tracks[fresh], z[fresh], self.cal, self.imu_T_cam, self.V, config, off, self.slot_of
        )
        self.n_converted += _convert_linear(st, config, self.imu_T_cam, off)
        if n_num + n_num_new:
            guard.reject(t, "innovation covariance or triangulation not finite", n_num + n_num_new)
        return UpdateCounts(n_used, n_rej + n_rej_new, n_init)

    def marginalise(self, tracks: np.ndarray) -> None:
        if not self.config.keep_landmarks or self.state.retired is not None:
            self.ended[tracks] = True
            _marginalise(self.state, self.ended, self.off, self.slot_of, self.done,
                         self.map_mean, self.map_cov)
            self.ended[tracks] = False

    def pose(self) -> np.ndarray:
        return self.state.T

    def pose_cov(self) -> np.ndarray:
        cov = left_cov_to_estimate(self.state.T, self.state.P[:6, :6].copy())
        return 0.5 * (cov + np.swapaxes(cov, -1, -2))

    def active_landmarks(self) -> Landmarks:
        st = self.state
        if not st.tracks.size:
            return Landmarks.none()
        return Landmarks(st.tracks.copy(), *st.world_landmarks(np.arange(st.tracks.size), self.off))

    def landmark_map(self) -> tuple[np.ndarray, np.ndarray]:
        st = self.state
        return map_with_kept(self.map_mean, self.map_cov, st.retired, st.P)

    def info(self) -> dict:
        info = {}
        if self.config.landmark_parameterisation == "inverse-depth":
            info["inverse_depth_converted"] = self.n_converted
        if self.state.bias is not None:
            info["gyro_bias"] = self.state.bias.tolist()
            info["gyro_bias_sigma_final"] = np.sqrt(np.diag(self.state.P[B_IDX, B_IDX])).tolist()
        if self.state.scale is not None:
            i = scale_index(self.state.bias is not None)
            info["speed_scale"] = float(self.state.scale)
            info["speed_scale_sigma_final"] = float(np.sqrt(self.state.P[i, i]))
        info["estimator"] = ESTIMATOR_NAME
        info["error_state"] = ("right-invariant SE_{1+K}(3): [xi_p, xi_R, (xi_b), (xi_s), xi_l...]"
                               if self.state.scale is not None else
                               "right-invariant SE_{1+K}(3): [xi_p, xi_R, (xi_b), xi_l...]")
        return info


def run_invariant(
    seq: Sequence,
    config: FilterConfig = FilterConfig(),
    progress: Callable[[int], None] | None = None,
    textbook: bool = False,
) -> Estimate:
    """:class:`InvariantEKF` over ``seq`` (:func:`ekf.driver.run_filter`)."""
    return run_filter(InvariantEKF(textbook), seq, config, progress)


def _propagate(st: InvariantState, u: np.ndarray, tau: float, W_chol, config: FilterConfig, off: int) -> bool:
    """Paper eq. 11 in group form: ``T <- T exp(tau u)``; ``P <- P + tau^2 B W B^T`` (the error
    transition is the identity), plus the coupling of a gyro-bias and a speed-scale state.
    Inverse-depth slots get no noise and no coupling: their rows of ``B`` are zero.

    Returns False when the noise term is not finite (an absurd but finite twist or time step;
    the caller raises)."""
    u = np.array(u, dtype=float)
    v_measured = u[:3].copy()
    if st.bias is not None:
        u[3:] -= st.bias
    if st.scale is not None:
        u[:3] *= 1.0 + st.scale
    twist = tau * u
    use_bias, use_scale = st.bias is not None, st.scale is not None
    B = noise_jacobian(st.T, st.landmarks, twist, use_bias, use_scale)
    if st.lm_id.any():
        B[off:].reshape(-1, 3, 6)[st.lm_id] = 0.0
    BL = tau * (B @ W_chol)
    if not finite_norm2(BL):
        return False
    P = st.P
    F = twist_error_coupling(B, tau, v_measured, use_bias, use_scale)
    if F is not None:
        # Imperfect IEKF: the bias error acts as angular-velocity noise -xi_b, the scale error
        # as linear-velocity noise v xi_s, so with the columns Pe of e = [xi_b; xi_s] the step
        # adds F Pe^T + Pe F^T + F Pee F^T (F = twist_error_coupling): one product of inner
        # size 2m, [F, Pe + F Pee] [Pe, F]^T; then the random walks.
        E = slice(6, off)
        Pb = P[:, E].copy()
        add_outer(P, np.hstack([F, Pb + F @ Pb[E]]), np.hstack([Pb, F]))
        if use_bias:
            P[B_IDX, B_IDX] += config.gyro_bias_walk**2 * tau * np.eye(3)
        if use_scale:
            i = scale_index(use_bias)
            P[i, i] += config.speed_scale_walk**2 * tau
    add_outer(P, BL, BL)
    _predict_retired(st, twist, tau, W_chol, config, BL, F, v_measured)
    st.T = st.T @ se3_exp_single(twist)
    return True


def _predict_retired(st: InvariantState, twist, tau, W_chol, config, BL, F, v_measured) -> None:
    """The retired landmarks' share of a prediction (RI-1): ``BL`` (dim A, 6) the twist noise
    rows of the active state, ``F`` (dim A, m) its bias and speed-scale coupling (None with
    neither), ``v_measured`` the step's measured linear velocity; called before ``st.T`` moves
    (the retired rows take the pose at the start of the step)."""
    if st.retired is None or not st.retired.n:
        return
    N_A = BL
    use_bias, use_scale = st.bias is not None, st.scale is not None
    if use_bias or use_scale:
        walk = np.zeros((BL.shape[0], landmark_offset(use_bias, use_scale) - 6))
        if use_bias:
            walk[B_IDX, :3] = np.sqrt(config.gyro_bias_walk**2 * tau) * np.eye(3)
        if use_scale:
            walk[scale_index(use_bias), -1] = np.sqrt(config.speed_scale_walk**2 * tau)
        N_A = np.concatenate([BL, walk], axis=1)
    st.retired.predict(st.T, twist, tau, W_chol, N_A, F, st.P,
                       v_measured if use_scale else None)


def _update(st: InvariantState, slots, z, M, cam_T_imu, V, Vinv, gate, config: FilterConfig, off: int):
    """Stacked update (paper eq. 14 in group form: ``X <- exp(K r) X``) with the frame's
    observations of landmarks already in the state; returns (used, rejected, numerical), the
    last the observations rejected (and counted in ``rejected``) because their own innovation
    covariance or information could not be used (singular, not finite).

    Raises :class:`~ekf.numerics.UpdateRejected`, with the state unchanged, when the stacked
    update cannot be computed (innovation covariance not positive definite, a non-finite
    gain or correction, a pose variance that would not stay positive)."""
    k = slots.size
    if k == 0:
        return 0, 0, 0
    R, p = st.T[:3, :3], st.T[:3, 3]
    C, c_t = cam_T_imu[:3, :3], cam_T_imu[:3, 3]
    lm = st.landmarks[slots]
    q = ((lm - p) @ R) @ C.T + c_t  # cam_T_imu T^-1 l
    idm = st.lm_id[slots] if st.lm_id.size else np.zeros(k, dtype=bool)
    has_id = bool(idm.any())
    if has_id:  # inverse-depth rows: their camera points and full Jacobians (4 rows)
        s_id = slots[idm]
        R_a, p_a = st.anchor_R[s_id], st.anchor_p[s_id]
        q_h, Hp_id, Hx_id = inverse_depth_jacobians(
            st.T, idp.homogeneous_point(lm[idm], R_a, p_a), idp.homogeneous_jacobian(R_a, p_a),
            cam_T_imu, M,
        )
        with np.errstate(divide="ignore", invalid="ignore"):
            q[idm] = np.where(q_h[:, 3:] > 0, q_h[:, :3] / q_h[:, 3:], np.nan)
        Hp_all = np.zeros((k, 4, 6))
        Hx_all = np.zeros((k, 4, 3))
        Hp_all[idm], Hx_all[idm] = Hp_id, Hx_id
    disp = z[:, 0] - z[:, 2]
    valid = (
        (q[:, 2] > 1e-6)
        & (q[:, 2] <= config.max_depth)
        & (disp > 0)
        & (disp >= config.min_disparity)
    )
    n_rej = int(k - valid.sum())
    n_num = 0
    if not valid.any():
        return 0, n_rej, 0
    slots, z, q = slots[valid], z[valid], q[valid]
    k = slots.size
    r = z - project(M, homogeneous(q))
    A = observation_jacobian(st.T, q, cam_T_imu, M)
    P = st.P
    li = off + 3 * slots[:, None] + np.arange(3)  # (k, 3)
    if has_id:
        # An inverse-depth row is z = Hx (Px xi_pose + xi_x) + v with Px = Hx^+ H_pose, exactly
        # (H_pose's columns lie in Hx's range), so below it is handled as a Euclidean one with
        # A = Hx and [Px, I] in place of [-I at p, 0 at R, I at l].
        idm = idm[valid]
        has_id = bool(idm.any())
    if has_id:
        Hx, Hp = Hx_all[valid][idm], Hp_all[valid][idm]
        A[idm] = Hx
        HtVi = np.swapaxes(Hx, 1, 2) @ Vinv
        Px_all = np.zeros((k, 3, 6))
        Px_all[:, :, :3] = -np.eye(3)  # a group landmark's [-I at p, 0 at R]
        Px_all[idm] = batched_solve(HtVi @ Hx, HtVi @ Hp)
    if gate is not None:
        Pll = P[li[:, :, None], li[:, None, :]]
        if has_id:  # E_j P E_j^T with E_j = [Px_j at the pose, I at l_j]
            PxPpl = Px_all @ P[:6][:, li].transpose(1, 0, 2)  # (k, 3, 3)
            Pe = Pll + PxPpl + np.swapaxes(PxPpl, 1, 2) + Px_all @ P[:6, :6] @ np.swapaxes(Px_all, 1, 2)
        else:
            Plp = P[li, :3]  # (k, 3, 3): rows l, cols p
            Pe = Pll - Plp - np.swapaxes(Plp, 1, 2) + P[:3, :3]
        S4 = A @ Pe @ np.swapaxes(A, 1, 2) + V
        m2 = np.einsum("ki,ki->k", r, batched_solve(S4, r[:, :, None])[:, :, 0])
        ok = m2 <= gate  # NaN (singular S4, overflow) is rejected
        if not np.isfinite(m2.sum()):
            n_num += int(k - np.isfinite(m2).sum())
        n_rej += int(k - ok.sum())
        if not ok.any():
            return 0, n_rej, n_num
        slots, r, A, li = slots[ok], r[ok], A[ok], li[ok]
        if has_id:
            idm, Px_all = idm[ok], Px_all[ok]
            has_id = bool(idm.any())
        k = slots.size
    # Compress each 4-d stereo observation to an equivalent 3-d one on xi_l - xi_p (exact
    # for the linear-Gaussian update: A has full column rank).
    AtVi = np.swapaxes(A, 1, 2) @ Vinv  # (k, 3, 4)
    Lam = AtVi @ A  # information (k, 3, 3)
    Lam_inv = batched_inv(Lam)
    y3 = (Lam_inv @ (AtVi @ r[:, :, None]))[:, :, 0]  # (k, 3)
    if not all_finite(Lam_inv, y3):
        fin = finite_rows(Lam_inv) & finite_rows(y3)
        n_bad = int(k - fin.sum())
        n_num += n_bad
        n_rej += n_bad
        if not fin.any():
            return 0, n_rej, n_num
        slots, li, Lam_inv, y3 = slots[fin], li[fin], Lam_inv[fin], y3[fin]
        if has_id:
            idm, Px_all = idm[fin], Px_all[fin]
            has_id = bool(idm.any())
        k = slots.size
    y = y3.ravel()  # (3k,)
    lflat = li.ravel()
    n = P.shape[0]
    # P E^T (n, 3k) and S = E P E^T + Lam^-1 (3k, 3k) in reused memory (Scratch); the
    # triangular solve below overwrites P E^T with L^-1 E P.
    PHt = st.scratch.array("PHt", (n, 3 * k))
    S = st.scratch.array("S", (3 * k, 3 * k))
    np.take(P, lflat, axis=1, out=PHt, mode="clip")
    if has_id:  # E's rows [Px_j, I at l_j]
        Px = Px_all.reshape(3 * k, 6)
        add_outer(PHt, P[:, :6], Px)
        np.take(PHt, lflat, axis=0, out=S, mode="clip")
        add_outer(S, Px, PHt[:6].T)
    else:  # E's rows [-I at p, 0 at R, I at l_j]
        PHt.reshape(n, k, 3)[...] -= P[:, None, :3]
        np.take(PHt, lflat, axis=0, out=S, mode="clip")
        S.reshape(k, 3, 3 * k)[...] -= PHt[None, :3, :]
    S.reshape(k, 3, k, 3)[np.arange(k), :, np.arange(k), :] += Lam_inv
    L, info = dpotrf(S, lower=1, clean=0, overwrite_a=1)  # reads S's lower triangle
    if info != 0:
        raise UpdateRejected(f"innovation covariance of {k} observations not positive definite")
    Wt = dtrsm(1.0, L, PHt.T, lower=1, overwrite_b=1)  # L^-1 E P, (3k, n)
    delta = Wt.T @ dtrsm(1.0, L, y[:, None], lower=1)[:, 0]
    # P - K S K^T = P - (L^-1 E P)^T (L^-1 E P); a^T a is computed symmetric (syrk).
    KSKt = np.matmul(Wt.T, Wt, out=st.scratch.array("KSKt", (n, n)))
    # Every posterior variance finite and positive (a NaN or inf anywhere in the gain shows on
    # the diagonal, and bounds the off-diagonal terms), and a finite correction.
    if not ((P.diagonal() - KSKt.diagonal()).min() > 0 and np.isfinite(delta).all()):
        raise UpdateRejected(
            f"gain of {k} observations not finite or a variance not positive after it"
        )
    P -= KSKt
    x_prior = st.landmarks
    st.T, st.landmarks, st.bias, st.scale = retract(st.T, st.landmarks, delta, st.bias, st.scale)
    C_active = None
    if st.lm_id.any():
        ids = np.flatnonzero(st.lm_id)
        st.landmarks[ids] = x_prior[ids] + delta[off:].reshape(-1, 3)[ids]  # additive error
        C_active = _transport_inverse_depth(st, ids, x_prior[ids], off)
    if st.retired is not None and st.retired.n:
        st.retired.update(delta, C_active)
    return k, n_rej, n_num


def _transport_inverse_depth(st: InvariantState, ids: np.ndarray, x_prior: np.ndarray, off: int) -> np.ndarray:
    """Keep the world-change directions unobservable for inverse-depth slots ``ids`` after an
    update (module docstring): ``P <- T P T^T``, ``T`` adding ``N_j(x+) - N_j(x-)`` (ID-7)
    times the pose rows to the rows of slot j. Returns those rows ``C`` (3K, 6)."""
    R_a, p_a = st.anchor_R[ids], st.anchor_p[ids]
    C = np.zeros((st.lm_id.size, 3, 6))
    C[ids] = idp.gauge_rows_change(x_prior, st.landmarks[ids], R_a, p_a)
    C = C.reshape(-1, 6)  # every landmark row (zero for group ones): contiguous slices
    add_pose_rows(st.P, off, C)
    return C


def _augment(st: InvariantState, tracks, z, cal, imu_T_cam, V, config: FilterConfig, off, slot_of):
    """Add triangulated landmarks of tracks seen for the first time (or never accepted yet).

    Returns ``(initialised, rejected, numerical)``, the last the tracks (counted in
    ``rejected``) whose landmark or covariance is not finite (an absurd but finite pixel)."""
    k = tracks.size
    if k == 0:
        return 0, 0, 0
    disp = z[:, 0] - z[:, 2]
    ok = (disp > 0) & (disp >= config.min_disparity)
    pc, Jt = triangulate_with_jacobian(np.where(ok[:, None], z, [1.0, 0.0, 0.0, 0.0]), cal.K, cal.baseline)
    ok &= np.isfinite(pc).all(axis=1) & (pc[:, 2] > 0) & (pc[:, 2] <= config.max_depth)
    n_rej = int(k - ok.sum())
    if not ok.any():
        return 0, n_rej, 0
    tracks, pc, Jt = tracks[ok], pc[ok], Jt[ok]
    k = tracks.size
    R, p = st.T[:3, :3], st.T[:3, 3]
    inverse_depth = config.landmark_parameterisation == "inverse-depth"
    if inverse_depth:  # x (ID-3) with dx = N_j [xi_p; xi_R] + Jz dz (N_j: ID-7 at the anchor)
        lm_new, R_a, p_a, Cn = idp.new_landmarks(z[ok], cal.K, cal.baseline, V, st.T @ imu_T_cam)
        Jd = idp.gauge_rows(lm_new, R_a, p_a)
    else:
        if config.triangulation == "unscented":
            # Mean and pixel-noise covariance to higher order; the pose part stays xi_l = xi_p.
            pc, cov_c = triangulate_unscented(z[ok], cal.K, cal.baseline, V)
            Rw = R @ imu_T_cam[:3, :3]
            Cn = Rw @ cov_c @ Rw.T
        else:
            Gz = augmentation_jacobians(st.T, Jt, imu_T_cam)
            Cn = Gz @ V @ np.swapaxes(Gz, 1, 2)
        c = pc @ imu_T_cam[:3, :3].T + imu_T_cam[:3, 3]
        lm_new = c @ R.T + p
    n_num = 0
    if not all_finite(lm_new, Cn):
        fin = finite_rows(lm_new) & finite_rows(Cn)
        n_num = int(k - fin.sum())
        n_rej += n_num
        if n_num == k:
            return 0, n_rej, n_num
        tracks, lm_new, Cn = tracks[fin], lm_new[fin], Cn[fin]
        if inverse_depth:
            Jd, R_a, p_a = Jd[fin], R_a[fin], p_a[fin]
        k = tracks.size
    P = st.P
    n = P.shape[0]
    Pn = st.scratch.covariance(P, n + 3 * k)
    Pn[:n, :n] = P
    if inverse_depth:
        Jd = Jd.reshape(3 * k, 6)
        cross = P[:, :6] @ Jd.T
        Pn[n:, n:] = Jd @ cross[:6]
    else:
        cross = np.tile(P[:, :3], (1, k))  # xi_l = xi_p + noise
        Pn[n:, n:] = np.tile(P[:3, :3], (k, k))
    Pn[:n, n:] = cross
    Pn[n:, :n] = cross.T
    bi = n + 3 * np.arange(k)[:, None, None] + np.arange(3)[None, :, None]
    bj = n + 3 * np.arange(k)[:, None, None] + np.arange(3)[None, None, :]
    Pn[bi, bj] += Cn
    K0 = st.tracks.size
    st.P = Pn
    if st.retired is not None:
        st.retired.augment(3 * k)
    st.landmarks = np.vstack([st.landmarks, lm_new])
    st.tracks = np.concatenate([st.tracks, tracks])
    slot_of[tracks] = K0 + np.arange(k)
    st.lm_id = np.concatenate([st.lm_id, np.full(k, inverse_depth)])
    if inverse_depth:
        st.anchor_R = np.concatenate([st.anchor_R, R_a])
        st.anchor_p = np.concatenate([st.anchor_p, p_a])
    else:
        st.anchor_R = np.concatenate([st.anchor_R, np.zeros((k, 3, 3))])
        st.anchor_p = np.concatenate([st.anchor_p, np.zeros((k, 3))])
    return k, n_rej, n_num


def _convert_linear(st: InvariantState, config: FilterConfig, imu_T_cam: np.ndarray, off: int) -> int:
    """Inverse-depth slots whose linearity index (ID-5) seen from the current camera is below
    ``inverse_depth_linearity`` join the group (:func:`_to_group`); returns how many."""
    if config.inverse_depth_linearity <= 0:
        return 0
    centre = st.T[:3, :3] @ imu_T_cam[:3, 3] + st.T[:3, 3]
    if st.retired is not None:
        st.retired.convert_linear(st.P, centre, config.inverse_depth_linearity)
    if not st.lm_id.any():
        return 0
    ids = np.flatnonzero(st.lm_id)
    rho_rows = off + 3 * ids + 2
    L = idp.linearity_index(
        st.landmarks[ids], st.P[rho_rows, rho_rows], st.anchor_R[ids], st.anchor_p[ids], centre
    )
    ids = ids[L < config.inverse_depth_linearity]
    if ids.size:
        _to_group(st, ids, off)
    return int(ids.size)


def _to_group(st: InvariantState, ids: np.ndarray, off: int) -> None:
    """Inverse-depth slots ``ids`` to group landmarks ``l = m(x)`` (ID-6): their error becomes
    ``xi_l = J dx + l^ xi_R`` (``l_true - l ~ -l^ xi_R + xi_l``), ``P <- T P T^T``."""
    x, R_a = st.landmarks[ids], st.anchor_R[ids]
    J = idp.world_jacobian(x, R_a)
    m = idp.world_point(x, R_a, st.anchor_p[ids])
    L = hat(m)
    rows = off + 3 * ids[:, None] + np.arange(3)  # (k, 3)
    P = st.P
    P[rows] = J @ P[rows] + L @ P[R_IDX]
    P[:, rows] = np.einsum("nkj,kij->nki", P[:, rows], J) + np.einsum("nj,kij->nki", P[:, R_IDX], L)
    if st.retired is not None:
        st.retired.active_to_group(rows, J, L)
    st.landmarks[ids] = m
    st.lm_id[ids] = False


def _marginalise(st: InvariantState, ended_tracks: np.ndarray, off, slot_of, done,
                 map_mean: np.ndarray, map_cov: np.ndarray) -> None:
    """Drop the landmarks of the tracks marked in ``ended_tracks`` (n_tracks,) bool; keep their
    mean and world covariance in ``map_mean``, ``map_cov``."""
    if st.tracks.size == 0:
        return
    ended = ended_tracks[st.tracks]
    if not ended.any():
        return
    gone = np.flatnonzero(ended)
    keep = np.flatnonzero(~ended)
    tr = st.tracks[gone]
    done[tr] = True
    slot_of[tr] = -1
    idx = np.concatenate([np.arange(off), (off + 3 * keep[:, None] + np.arange(3)).ravel()])
    if st.retired is None:
        map_mean[tr], map_cov[tr] = st.world_landmarks(gone, off)
    else:  # keep_landmarks: they stay refined as regressions on what remains
        rows = off + 3 * gone[:, None] + np.arange(3)
        st.retired.retire(st.P, idx, rows, st.landmarks[gone], st.landmarks[gone], tr,
                          st.lm_id[gone], st.anchor_R[gone], st.anchor_p[gone])
    st.P = st.scratch.submatrix(st.P, idx)
    st.landmarks = st.landmarks[keep]
    st.tracks = st.tracks[keep]
    st.lm_id, st.anchor_R, st.anchor_p = st.lm_id[keep], st.anchor_R[keep], st.anchor_p[keep]
    slot_of[st.tracks] = np.arange(keep.size)
