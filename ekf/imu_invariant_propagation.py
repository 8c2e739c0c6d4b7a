"""Propagation of the right-invariant raw-IMU EKF (``ekf-imu-invariant``, :mod:`ekf.imu_invariant`).

**State.** The IMU's orientation, velocity and position and the K landmarks held as world points
form one element of SE_{2+K}(3) (Barrau and Bonnabel, "The invariant extended Kalman filter as a
stable observer", IEEE TAC 2017; "An EKF-SLAM algorithm with consistency properties", 2015)::

    X = [[R, v, p, l_1, ..., l_K],
         [0, I_{2+K}            ]]          R = world_R_imu; v, p, l_j in the world

and beside the group the gyro and accelerometer biases ``bg``, ``ba`` (vectors, additive error)
and any landmark that cannot join the group (anchored inverse depth, :mod:`ekf.imu_invariant`).
The mean's core ``(R, v, p, bg, ba)`` is an :class:`ekf.strapdown.NavState`.

**Error** (right-invariant): ``X_true = exp(xi) X``, with ``R_d = Exp(xi_R)``, ``J = J_l(xi_R)``::

    R <- R_d R,  v <- R_d v + J xi_v,  p <- R_d p + J xi_p,  l_j <- R_d l_j + J xi_lj    (RI-1)
    bg <- bg + dbg,  ba <- ba + dba

ordered ``[xi_R, xi_v, xi_p, dbg, dba]`` (the 15 of the core: :data:`ekf.strapdown.ERROR_STATE`'s
blocks, in invariant coordinates) then ``xi_lj`` (3 per landmark). To first order ``xi_R`` is the
world-frame rotation error, ``xi_v = dv + v^ xi_R``, ``xi_p = dp + p^ xi_R``, ``xi_l = dl + l^ xi_R``
(``dv``, ``dp``, ``dl`` world-frame differences, ``^`` the cross-product matrix).

**Mean** (RI-2): :func:`ekf.strapdown.step` per sample (the preintegration scheme, each sample
held until the next one). With ``dR = Exp(w dt)``, ``w = w_m - bg``, ``a = a_m - ba`` it is
``X' = Gamma Phi_dt(X) Upsilon``: ``Gamma = (I, g dt, g dt^2/2)`` (gravity, on the left),
``Phi_dt(R, v, p, l) = (R, v, p + v dt, l)`` (a group automorphism) and
``Upsilon = (dR, a dt, a dt^2/2)`` (the body increments, on the right); landmarks do not move.

**Error transition of one sample** (RI-3). Since ``Phi_dt`` is an automorphism and ``Gamma``
does not depend on the state, the error of the group part propagates *exactly* (log-linearly)
when the biases are known: ``xi' = Ad_Gamma Phi_dt xi``, i.e. ``xi_R' = xi_R``,
``xi_v' = xi_v + g^ dt xi_R``, ``xi_p' = xi_p + dt xi_v + g^ dt^2/2 xi_R``, ``xi_l' = xi_l``.
The bias errors enter through the body increments ``Upsilon``: with ``eps`` the right
perturbation of ``Upsilon`` that the input errors ``dw = -(dbg + n_g)``, ``da = -(dba + n_a)``
make, ``eps = [Jr dt dw; dR^T dt da; dR^T dt^2/2 da]`` (``Jr = Jr(w dt)``, SO(3)'s right
Jacobian), the error after the step is ``xi' = Ad_Gamma Phi_dt xi + Ad_{X'} eps`` to first
order, with ``X'`` the state *after* the step. This is the "imperfect IEKF" (Barrau's thesis,
2015; Hartley et al., "Contact-aided invariant EKF", 2020, its bias augmentation): the bias
columns of the transition depend on the estimate. So, with ``(R', v', p')`` after the step and
``R`` before it::

    F[R, bg] = -R' Jr dt
    F[v, R] = g^ dt,        F[v, bg] = -v'^ R' Jr dt,   F[v, ba] = -R dt
    F[p, R] = g^ dt^2/2,    F[p, v] = dt I,  F[p, bg] = -p'^ R' Jr dt,  F[p, ba] = -R dt^2/2
    F[l_j, bg] = -l_j^ R' Jr dt      (identity on the diagonal; every other block zero)

(:func:`sample_transition`; checked against finite differences of the step in
tests/test_imu_invariant_propagation.py.)

**Discrete noise** (RI-4). The white noise of a sample held over ``dt`` has covariance
``density^2 / dt`` (as in :mod:`ekf.strapdown`, Forster et al. 2017), so
``Cov(eps) = [[sg^2 dt Jr Jr^T, 0, 0], [0, sa^2 dt I, sa^2 dt^2/2 I], [0, sa^2 dt^2/2 I,
sa^2 dt^3/4 I]]`` and ``Q = Ad_{X'} Cov(eps) Ad_{X'}^T`` on ``[R, v, p]``, ``Ad_{X'}`` the
adjoint of SE_2(3) (rows ``[R', 0, 0]``, ``[v'^ R', R', 0]``, ``[p'^ R', 0, R']``); the bias
walks add ``wg^2 dt I`` and ``wa^2 dt I`` (GTSAM's ``CombinedImuFactor``). A landmark's rows of
``Ad_{X'}`` are ``[l^ R', 0, 0]`` (:func:`sample_noise`).

**One frame interval** (RI-5). The core's transition and noise are accumulated sample by sample,
``Phi <- F Phi``, ``Qc <- F Qc F^T + Q`` (:func:`propagate`). The landmark rows need no
per-sample work: from RI-3 and RI-4 a group landmark's error moves by ``l^`` times the rotation
error's change, ``xi_l' = xi_l + l^ (xi_R' - xi_R)``, exactly (``l - l^ xi_R``, the world-frame
error, is constant). So, with ``U`` the stacked ``l_j^`` (zero rows for landmarks outside the group)
and ``D = Phi[R, :] - [I, 0, 0, 0, 0]``, the whole state moves once per frame by
``[[Phi, 0], [U D, I]]`` with noise ``[w; U w_R]`` (:func:`frame_covariance`)::

    P_cc' = Phi P_cc Phi^T + Qc
    P_lc' = (P_lc + U D P_cc) Phi^T + U Qc[R, :]
    P_ll' = P_ll + U D P_cl + P_lc D^T U^T + U (D P_cc D^T + Qc[R, R]) U^T

**Conversions** (RI-6). From the strapdown error ``[dth (body), dv, dp, dbg, dba]``
(:mod:`ekf.strapdown`, the initial state of :mod:`ekf.imu_init`):
``xi_R = R dth``, ``xi_v = dv + v^ R dth``, ``xi_p = dp + p^ R dth`` (:func:`strapdown_to_invariant`).
To the Estimate convention (right perturbation of ``world_T_imu``, translation first,
``[rho; phi]``; :mod:`ekf.conventions`): ``[xi_p; xi_R]`` is a left, world-frame SE(3)
perturbation of ``T = (R, p)``, so ``[rho; phi] = Ad(T^-1) [xi_p; xi_R]``, i.e.
``rho = R^T (xi_p - p^ xi_R)``, ``phi = R^T xi_R`` (:func:`estimate_pose_jacobian`). Both are
exact to first order and checked both ways in the tests.
"""

from __future__ import annotations

import numpy as np
from vislam.ekf.filter import ImuSamples
from vislam.ekf.geometry import hat, so3_left_jacobian_inv, so3_log
from vislam.ekf.inertial import ImuNoise
from vislam.ekf.prediction import so3_exp_and_left_jacobian
from vislam.ekf.strapdown import (
    BA,
    BG,
    N_ERROR,
    POS,
    ROT,
    VEL,
    NavState,
    exp_and_right_jacobian,
    held_pieces,
    step,
)

#: The core error state's size and blocks (RI-1), in :mod:`ekf.strapdown`'s order.
N_CORE = N_ERROR
__all__ = [
    "BA",
    "BG",
    "N_CORE",
    "POS",
    "ROT",
    "VEL",
    "error_between",
    "estimate_pose_jacobian",
    "frame_covariance",
    "propagate",
    "retract",
    "sample_noise",
    "sample_transition",
    "strapdown_to_invariant",
]

_I3 = np.eye(3)


def _hat3(v: np.ndarray) -> np.ndarray:
    """The cross-product matrix of one 3-vector (the hot loop's; :func:`ekf.geometry.hat`
    takes stacks)."""
    x, y, z = float(v[0]), float(v[1]), float(v[2])
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def retract(state: NavState, xi: np.ndarray) -> NavState:
    """``exp(xi) X`` on the core (RI-1): ``xi`` (15,)."""
    xi = np.asarray(xi, dtype=float)
    Rd, J = so3_exp_and_left_jacobian(xi[ROT])
    return NavState(Rd @ state.R, Rd @ state.v + J @ xi[VEL], Rd @ state.p + J @ xi[POS],
                    state.bg + xi[BG], state.ba + xi[BA])


def retract_landmarks(lm: np.ndarray, xi_R: np.ndarray, xi_l: np.ndarray) -> np.ndarray:
    """Group landmarks (k, 3) moved by their error rows ``xi_l`` (k, 3) and ``xi_R`` (RI-1)."""
    Rd, J = so3_exp_and_left_jacobian(np.asarray(xi_R, dtype=float))
    return lm @ Rd.T + xi_l @ J.T


def error_between(true: NavState, est: NavState) -> np.ndarray:
    """The exact error ``xi`` (15,) with ``true = exp(xi) est`` (the inverse of :func:`retract`)."""
    Rd = true.R @ est.R.T
    phi = so3_log(Rd)
    Jinv = so3_left_jacobian_inv(phi)
    return np.concatenate([phi, Jinv @ (true.v - Rd @ est.v), Jinv @ (true.p - Rd @ est.p),
                           true.bg - est.bg, true.ba - est.ba])


def landmark_errors(true_lm: np.ndarray, est_lm: np.ndarray, true_R: np.ndarray,
                    est_R: np.ndarray) -> np.ndarray:
    """The exact landmark errors ``xi_l`` (k, 3) of world points (RI-1)."""
    Rd = true_R @ est_R.T
    Jinv = so3_left_jacobian_inv(so3_log(Rd))
    return (np.asarray(true_lm) - np.asarray(est_lm) @ Rd.T) @ Jinv.T


def sample_transition(after: NavState, R_before: np.ndarray, Jr: np.ndarray, dt: float,
                      g_world: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """``F`` (15, 15) of one sample (RI-3) on the core. ``out``: a (15, 15) array to fill (its
    constant blocks are rewritten too)."""
    F = np.eye(N_CORE) if out is None else out
    if out is not None:
        F[...] = 0.0
        np.fill_diagonal(F, 1.0)
    G = _hat3(g_world)
    RJ = after.R @ Jr * dt
    F[ROT, BG] = -RJ
    F[VEL, ROT] = G * dt
    F[VEL, BG] = -_hat3(after.v) @ RJ
    F[VEL, BA] = -R_before * dt
    F[POS, ROT] = G * (0.5 * dt * dt)
    F[POS, VEL] = _I3 * dt
    F[POS, BG] = -_hat3(after.p) @ RJ
    F[POS, BA] = -R_before * (0.5 * dt * dt)
    return F


def sample_noise(after: NavState, Jr: np.ndarray, dt: float, noise: ImuNoise) -> np.ndarray:
    """``Q`` (15, 15) of one sample (RI-4) on the core: ``Ad_{X'} Cov(eps) Ad_{X'}^T`` written
    out by blocks (``A_v = v'^``, ``A_p = p'^``; ``R' Cov R'^T`` is ``sa^2 ... I`` for the
    accelerometer's isotropic blocks)."""
    sg2, sa2 = noise.gyro_noise_density ** 2, noise.accel_noise_density ** 2
    RJ = after.R @ Jr
    Qr = sg2 * dt * (RJ @ RJ.T)  # Q_RR
    Av, Ap = _hat3(after.v), _hat3(after.p)
    AvQ, ApQ = Av @ Qr, Ap @ Qr
    a1, a2, a3 = sa2 * dt, 0.5 * sa2 * dt * dt, 0.25 * sa2 * dt ** 3
    Q = np.zeros((N_CORE, N_CORE))
    Q[ROT, ROT] = Qr
    Q[VEL, ROT] = AvQ
    Q[ROT, VEL] = AvQ.T
    Q[POS, ROT] = ApQ
    Q[ROT, POS] = ApQ.T
    Q[VEL, VEL] = AvQ @ Av.T + a1 * _I3
    Q[POS, VEL] = ApQ @ Av.T + a2 * _I3
    Q[VEL, POS] = Q[POS, VEL].T
    Q[POS, POS] = ApQ @ Ap.T + a3 * _I3
    Q[BG, BG] = noise.gyro_random_walk ** 2 * dt * _I3
    Q[BA, BA] = noise.accel_random_walk ** 2 * dt * _I3
    return Q


def propagate(state: NavState, imu: ImuSamples, t0: float, t1: float, g_world: np.ndarray,
              noise: ImuNoise) -> tuple[NavState, np.ndarray, np.ndarray]:
    """The core carried from ``t0`` to ``t1`` over ``imu`` (the samples as
    :func:`ekf.strapdown.integrate` takes them: the first at or before ``t0``, each held until
    the next one or ``t1``): ``(state, Phi, Qc)``, the accumulated transition and noise (RI-5).
    EstimationError when no sample is at or before ``t0``."""
    Phi = np.eye(N_CORE)
    Qc = np.zeros((N_CORE, N_CORE))
    F = np.eye(N_CORE)
    for j, dt in held_pieces(imu.time, t0, t1):
        Jr = exp_and_right_jacobian((imu.gyro[j] - state.bg) * dt)[1]
        R_before = state.R
        state = step(state, imu.gyro[j], imu.accel[j], dt, g_world)
        sample_transition(state, R_before, Jr, dt, g_world, out=F)
        Phi = F @ Phi
        Qc = F @ Qc @ F.T + sample_noise(state, Jr, dt, noise)
    return state, Phi, Qc


def frame_covariance(P: np.ndarray, Phi: np.ndarray, Qc: np.ndarray, landmarks: np.ndarray,
                     in_group: np.ndarray) -> np.ndarray:
    """The covariance ``P`` (15 + 3K, 15 + 3K), core first, carried over one frame interval
    (RI-5) by the core's ``Phi`` and ``Qc``; ``landmarks`` (K, 3) the slots' means, ``in_group``
    (K,) bool whether each is a group landmark (a world point; others do not move). Returns a
    new array."""
    c = N_CORE
    out = np.empty_like(P)
    Pcc = P[:c, :c]
    out[:c, :c] = Phi @ Pcc @ Phi.T + Qc
    if P.shape[0] == c:
        return out
    K = landmarks.shape[0]
    U = hat(landmarks)  # (K, 3, 3)
    U[~np.asarray(in_group, dtype=bool)] = 0.0
    U = U.reshape(3 * K, 3)
    D = Phi[ROT].copy()
    D[:, ROT] -= _I3
    Plc = P[c:, :c]
    DPcc = D @ Pcc  # (3, 15)
    out[c:, :c] = (Plc + U @ DPcc) @ Phi.T + U @ Qc[ROT, :]
    out[:c, c:] = out[c:, :c].T
    Y = D @ Plc.T  # D P_cl (3, 3K)
    C = DPcc @ D.T + Qc[ROT, ROT]
    W = Y + 0.5 * C @ U.T
    UW = U @ W
    out[c:, c:] = P[c:, c:] + UW + UW.T
    return out


def strapdown_to_invariant(state: NavState) -> np.ndarray:
    """``S`` (15, 15) with ``xi = S dx`` for the strapdown error ``dx`` (RI-6)."""
    S = np.eye(N_CORE)
    S[ROT, ROT] = state.R
    S[VEL, ROT] = hat(state.v) @ state.R
    S[POS, ROT] = hat(state.p) @ state.R
    return S


def estimate_pose_jacobian(state: NavState) -> np.ndarray:
    """``E`` (6, 15) with ``[rho; phi] = E xi`` (RI-6: the Estimate convention)."""
    Rt = state.R.T
    E = np.zeros((6, N_CORE))
    E[:3, POS] = Rt
    E[:3, ROT] = -Rt @ hat(state.p)
    E[3:, ROT] = Rt
    return E
