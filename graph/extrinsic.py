"""The camera-IMU extrinsic as a parameter of the stereo factors: a Gauss-Newton step on the
profile likelihood and its honest covariance (issue 12).

Parameter. ``theta = [dt; r]`` perturbs ``cam_T_imu = [R t]`` as ``t' = t + dt``,
``R' = so3_exp(r) R`` (:mod:`ekf.model`'s ``cam_T_imu_sigma`` convention: translation of the
translation column, then a rotation vector applied on the left, camera frame).

Jacobian. A stereo factor predicts the pixels of ``X_k E`` with ``E = imu_T_cam``. Since
``C' = Exp(eta) C`` (``eta = [w; v]``, GTSAM order) gives ``E' = E Exp(-eta)``, and
``X Exp(eps) E = X E Exp(Ad_E^-1 eps)``, a change ``eta`` of the extrinsic acts like the change
``eps = -Ad_E eta`` of the pose: ``d r / d eta = -(d r / d eps) Ad_E``. With
``eta = [r; dt + [t]x r]`` (first order of the update above),

    d r / d theta = -(d r / d eps) Ad_E N,   N = [[0, I], [I, [t]x]]            (EXTRINSIC_JACOBIAN)

so the whitened Jacobian on ``theta`` is read off GTSAM's own linearisation of the stereo
factors (robust weights included), with no new factor type; tests check it against finite
differences of the stereo residuals.

Profile step. At the smoother's solution ``x*(theta)`` (a minimum over the poses and landmarks
``x``), the Gauss-Newton step of the joint problem on ``theta`` is the Schur complement

    S = A_t^T A_t - A_t^T A_x (A_x^T A_x)^-1 A_x^T A_t,      S dtheta = A_t^T b - A_t^T A_x (A_x^T A_x)^-1 A_x^T b

and ``S^-1`` is the Laplace covariance of ``theta`` with ``x`` marginalised out: the
uncertainty the drive leaves on the extrinsic, from every factor (vision, motion, priors).
A component whose marginal standard deviation under a weak prior (``PRIOR_SIGMA``) stays
above ``UNDETERMINED_SIGMA`` is *undetermined*: the drive cannot say (the vertical lever arm of
a planar drive); its value is kept and only the others are stepped (conditionally on it).

Excitation. ``S`` is read at the estimate, and there it can hold information the drive does
not have. A lever arm ``l`` shows only through rotation: over an interval the camera moves by
``[w dt]x l`` more than the point whose velocity is measured, so ``l`` along an axis the drive
never turns away from is unobservable. On a planar drive the estimated roll and pitch still
wobble with the gyro's noise, and ``S`` takes that wobble for rotation: on simulated rooms it
gave the vertical lever arm a sigma of 0.2 m and EM walked it 2-4 m from the truth, a
"refuted" file extrinsic that was the true one. So the translation is also held to the
information the drive's own rotation can give at best, with vision taken as exact
(:func:`rotation_excitation_sigma`)::

    W   = sum_k w_k w_k^T - (n + 2 sqrt(2 n)) Sigma_g    (interval rates, noise removed)
    I_l = sum_m lambda_m [u_m]x^T Sigma_v^-1 [u_m]x        (W = sum_m lambda_m u_m u_m^T, lambda_m >= 0)

``Sigma_g`` and ``Sigma_v`` the intervals' gyro and velocity noise covariances; ``2 sqrt(2 n)``
is two standard deviations of the noise's own sum of squares, so that a drive whose rates
about an axis are noise gives no information there. A translation component whose standard deviation
under ``I_l`` (and the weak prior) is above ``UNDETERMINED_SIGMA`` is undetermined as well.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np
import scipy.sparse as sp

from vislam.ekf.geometry import hat, se3_inv, so3_exp
from vislam.ekf.model import EXTRINSIC_COMPONENTS
from vislam.ekf.errors import EstimationError
from vislam.graph.pose_conversions import X, to_pose3

#: Standard deviation of the weak prior around the current value, per component of theta
#: (m, m, m, rad, rad, rad): it only keeps an unobservable direction finite.
PRIOR_SIGMA = np.array([10.0, 10.0, 10.0, 1.0, 1.0, 1.0])
#: Above these marginal standard deviations a component is undetermined (m, then rad): a
#: lever arm the drive cannot place within 0.3 m, a rotation it cannot place within 3 degrees.
UNDETERMINED_SIGMA = np.array([0.3, 0.3, 0.3, 0.05, 0.05, 0.05])


def rotation_excitation_sigma(angular_velocity: np.ndarray, gyro_sigma, velocity_sigma,
                              cam_T_imu: np.ndarray, z: float = 2.0) -> np.ndarray:
    """(3,) the standard deviation of theta's translation (``dt``, camera frame) that the
    drive's rotation alone allows at best (module docstring, "Excitation"): from the angular
    rates ``angular_velocity`` (n, 3), rad/s, IMU frame, one per interval, with noise
    ``gyro_sigma`` (rad/s) and velocity noise ``velocity_sigma`` (m/s), one value or three each
    (per interval: the sigmas the smoother uses), under the weak prior ``PRIOR_SIGMA``. ``z``
    noise standard deviations of the gyro's sum of squares are taken off as well."""
    w = np.asarray(angular_velocity, dtype=float)
    w = w[np.all(np.isfinite(w), axis=1)]
    n = len(w)
    sg = np.broadcast_to(np.asarray(gyro_sigma, dtype=float), (3,))
    sv = np.broadcast_to(np.asarray(velocity_sigma, dtype=float), (3,))
    W = w.T @ w - (n + z * np.sqrt(2.0 * n)) * np.diag(sg ** 2)
    lam, U = np.linalg.eigh(0.5 * (W + W.T))
    D = np.diag(1.0 / sv ** 2)
    info = sum(max(float(lm), 0.0) * hat(u).T @ D @ hat(u) for lm, u in zip(lam, U.T))
    cov_l = np.linalg.inv(info + np.diag(1.0 / PRIOR_SIGMA[:3] ** 2))
    R = np.asarray(cam_T_imu, dtype=float)[:3, :3]  # dt = -R dl at a fixed rotation
    return np.sqrt(np.diag(R @ cov_l @ R.T))


def determined_components(covariance: np.ndarray,
                          excitation_sigma: np.ndarray | None) -> np.ndarray:
    """(6,) bool: the components of theta the drive determines: marginal standard deviation
    at most ``UNDETERMINED_SIGMA``, and for the translation also under the drive's rotation
    alone (``excitation_sigma``, :func:`rotation_excitation_sigma`; None: not checked)."""
    determined = np.sqrt(np.diag(covariance)) <= UNDETERMINED_SIGMA
    if excitation_sigma is not None:
        determined[:3] &= np.asarray(excitation_sigma) <= UNDETERMINED_SIGMA[:3]
    return determined


def excitation_of(solution, cam_T_imu: np.ndarray, config) -> np.ndarray | None:
    """:func:`rotation_excitation_sigma` of a solved smoother's drive: its interval angular
    rates (``solution.twist``, the pairing applied, the gyro bias it removed taken off) under
    ``config``, the FilterConfig it was solved with (EM's: interval sigmas); None without a
    config."""
    if config is None:
        return None
    rates = solution.twist[:, 3:]
    if solution.gyro_bias is not None:
        rates = rates - np.asarray(solution.gyro_bias, dtype=float)
    return rotation_excitation_sigma(rates, config.gyro_sigmas, config.velocity_sigmas, cam_T_imu)


@dataclass
class ExtrinsicStep:
    """One Gauss-Newton step on the extrinsic at a solved smoother."""

    step: np.ndarray  # (6,) dtheta for the determined components (0 for the others)
    information: np.ndarray  # (6, 6) S: the profile information of theta
    covariance: np.ndarray  # (6, 6) marginal covariance of theta (weak prior included)
    determined: np.ndarray  # (6,) bool
    #: (3,) the translation's standard deviation from the drive's rotation alone (None: not
    #: checked; :func:`rotation_excitation_sigma`)
    excitation_sigma: np.ndarray | None = None

    @property
    def sigma(self) -> np.ndarray:
        return np.sqrt(np.diag(self.covariance))

    @property
    def undetermined(self) -> tuple[str, ...]:
        return tuple(n for n, ok in zip(EXTRINSIC_COMPONENTS, self.determined) if not ok)

    @property
    def step_in_sigmas(self) -> float:
        """The largest step of a determined component in its standard deviations."""
        if not self.determined.any():
            return 0.0
        return float(np.max(np.abs(self.step[self.determined]) / self.sigma[self.determined]))


def perturb_cam_T_imu(cam_T_imu: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """``cam_T_imu`` moved by ``theta = [dt; r]`` (the module's convention)."""
    out = np.array(cam_T_imu, dtype=float)
    theta = np.asarray(theta, dtype=float)
    out[:3, 3] = out[:3, 3] + theta[:3]
    out[:3, :3] = so3_exp(theta[3:]) @ out[:3, :3]
    return out


def theta_map(cam_T_imu: np.ndarray) -> np.ndarray:
    """(6, 6) ``N @ ...``: the extrinsic's left perturbation ``eta = [w; v]`` (GTSAM order)
    per unit of ``theta = [dt; r]``, pre-multiplied by ``-Ad_E`` (``E = imu_T_cam``): the
    matrix that turns a stereo factor's pose Jacobian into its theta Jacobian."""
    t = np.asarray(cam_T_imu, dtype=float)[:3, 3]
    N = np.zeros((6, 6))
    N[:3, 3:] = np.eye(3)
    N[3:, :3] = np.eye(3)
    N[3:, 3:] = hat(t)
    Ad_E = np.asarray(to_pose3(se3_inv(np.asarray(cam_T_imu, dtype=float))).AdjointMap())
    return -Ad_E @ N


@dataclass
class ExtrinsicSystem:
    """The linearised batch problem at a solution, with the extrinsic's columns beside it."""

    A: sp.csr_matrix  # (rows, n) whitened Jacobian on the poses and landmarks (GTSAM's)
    b: np.ndarray  # (rows,) whitened right-hand side (minus the whitened error)
    stereo: slice  # the rows of the stereo factors, 3 per row of ``problem.rows``
    A_t: np.ndarray  # (3N, 6) whitened Jacobian of the stereo rows on theta (EXTRINSIC_JACOBIAN)


def stereo_rows(solution) -> slice:
    """The rows of a solved smoother's stereo factors in its linearisation, 3 per row of
    ``problem.rows`` (they follow the pose prior and the T-1 motion factors: graph.factors);
    EstimationError where the graph is not so built."""
    graph, T = solution.problem.graph, solution.poses.shape[0]
    start = sum(int(graph.at(i).dim()) for i in range(T))
    N = len(solution.problem.rows)
    stereo = slice(start, start + 3 * N)
    if N and not (isinstance(graph.at(T), gtsam.GenericStereoFactor3D)
                  and isinstance(graph.at(T + N - 1), gtsam.GenericStereoFactor3D)
                  and stereo.stop <= solution.linearised()[0].A.shape[0]):
        raise EstimationError("extrinsic: the graph's stereo factors are not where "
                              "graph.factors.build_graph puts them")
    return stereo


def linear_system(solution, cam_T_imu: np.ndarray) -> ExtrinsicSystem:
    """GTSAM's linearisation of a solved smoother and the extrinsic's whitened Jacobian."""
    rows = solution.problem.rows
    T = solution.poses.shape[0]
    system, _ = solution.linearised()
    A, b, offsets = system.A, system.b, system.offsets
    stereo = stereo_rows(solution)
    N = len(rows)
    pose_cols = np.array([offsets[X(int(k))] for k in range(T)])
    A_st = A[stereo].tocoo()
    local = A_st.col - pose_cols[np.repeat(rows.frame, 3)[A_st.row]]
    in_pose = (local >= 0) & (local < 6)
    J_pose = np.zeros((3 * N, 6))  # each stereo row's whitened Jacobian on its pose
    np.add.at(J_pose, (A_st.row[in_pose], local[in_pose]), A_st.data[in_pose])
    return ExtrinsicSystem(A=A, b=b, stereo=stereo, A_t=J_pose @ theta_map(cam_T_imu))


def extrinsic_step(solution, cam_T_imu: np.ndarray, config) -> ExtrinsicStep:
    """The profile Gauss-Newton step and covariance of the extrinsic at a solved smoother
    (:class:`graph.smoother.SmootherSolution`, solved with ``cam_T_imu`` under ``config``, the
    FilterConfig whose noise levels the excitation check reads; None skips that check);
    module docstring."""
    system = linear_system(solution, cam_T_imu)
    A, b, stereo, A_t = system.A, system.b, system.stereo, system.A_t
    B = np.asarray(A[stereo].T @ A_t)  # (n, 6) A_x^T A_t
    rhs_x = np.asarray(A.T @ b)
    _, posterior_of = solution.linearised()
    Y = posterior_of.solve(np.column_stack([B, rhs_x]))  # H^-1 [A_x^T A_t, A^T b]
    S = A_t.T @ A_t - B.T @ Y[:, :6]
    S = 0.5 * (S + S.T)
    g = A_t.T @ b[stereo] - B.T @ Y[:, 6]
    prior = np.diag(1.0 / PRIOR_SIGMA ** 2)
    cov = np.linalg.inv(S + prior)
    cov = 0.5 * (cov + cov.T)
    excitation = excitation_of(solution, cam_T_imu, config)
    determined = determined_components(cov, excitation)
    step = np.zeros(6)
    if determined.any():
        d = np.flatnonzero(determined)
        step[d] = np.linalg.solve(S[np.ix_(d, d)] + prior[np.ix_(d, d)], g[d])
    return ExtrinsicStep(step=step, information=S, covariance=cov, determined=determined,
                         excitation_sigma=excitation)


def extrinsic_fold_gain(solution, cam_T_imu: np.ndarray, other: np.ndarray, config,
                        stretch_s: float = 10.0):
    """The identified extrinsic's out-of-sample gain over ``other`` (the file's), by
    leave-one-stretch-out cross-validation of the profile likelihood at a smoother solved with
    ``cam_T_imu`` (:func:`graph.out_of_sample.fold_gain`; folds: ``stretch_s`` stretches of the
    drive, :func:`graph.stretches.stretch_labels`). The components fitted are those the drive
    determines (:func:`extrinsic_step`, ``config`` as there), under the weak prior
    ``PRIOR_SIGMA``."""
    from vislam.graph.out_of_sample import fold_gain, term_rows

    system = linear_system(solution, cam_T_imu)
    A_p, b_p, folds = term_rows(solution, system.stereo, system.A_t, stretch_s)
    prior = np.diag(1.0 / PRIOR_SIGMA ** 2)
    cov = np.linalg.inv(A_p.T @ A_p + prior)
    determined = determined_components(cov, excitation_of(solution, cam_T_imu, config))
    return fold_gain(A_p, b_p, folds, theta_between(cam_T_imu, other), determined, prior)


def theta_between(cam_T_imu: np.ndarray, other: np.ndarray) -> np.ndarray:
    """The ``theta`` that moves ``cam_T_imu`` to ``other`` (:func:`perturb_cam_T_imu`)."""
    from vislam.ekf.geometry import so3_log

    C, F = np.asarray(cam_T_imu, dtype=float), np.asarray(other, dtype=float)
    return np.r_[F[:3, 3] - C[:3, 3], so3_log(F[:3, :3] @ C[:3, :3].T)]


def mahalanobis(theta: np.ndarray, covariance: np.ndarray, components: np.ndarray) -> tuple[float, int]:
    """``theta^T C^-1 theta`` over ``components`` (indices or a mask) and their number."""
    idx = np.flatnonzero(components) if np.asarray(components).dtype == bool \
        else np.asarray(components, dtype=int)
    if idx.size == 0:
        return 0.0, 0
    d = np.asarray(theta, dtype=float)[idx]
    return float(d @ np.linalg.solve(np.asarray(covariance)[np.ix_(idx, idx)], d)), int(idx.size)


def lever_arm(cam_T_imu: np.ndarray) -> np.ndarray:
    """The camera's position in the IMU frame (the translation of ``imu_T_cam``)."""
    return se3_inv(np.asarray(cam_T_imu, dtype=float))[:3, 3]


def lever_arm_covariance(cam_T_imu: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """(3, 3) covariance of :func:`lever_arm` from a theta covariance: ``p = -R^T t``, so
    ``dp = -R^T dt - R^T [t]x r`` to first order (``R' = exp(r) R``: ``R'^T = R^T exp(-r)``)."""
    C = np.asarray(cam_T_imu, dtype=float)
    R, t = C[:3, :3], C[:3, 3]
    G = np.hstack([-R.T, -R.T @ hat(t)])
    return G @ cov @ G.T


__all__ = ["ExtrinsicStep", "ExtrinsicSystem", "linear_system", "extrinsic_step",
           "extrinsic_fold_gain", "rotation_excitation_sigma", "determined_components",
           "excitation_of", "stereo_rows", "perturb_cam_T_imu", "theta_map", "lever_arm",
           "lever_arm_covariance", "theta_between", "mahalanobis", "PRIOR_SIGMA",
           "UNDETERMINED_SIGMA"]
