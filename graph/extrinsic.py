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


@dataclass
class ExtrinsicStep:
    """One Gauss-Newton step on the extrinsic at a solved smoother."""

    step: np.ndarray  # (6,) dtheta for the determined components (0 for the others)
    information: np.ndarray  # (6, 6) S: the profile information of theta
    covariance: np.ndarray  # (6, 6) marginal covariance of theta (weak prior included)
    determined: np.ndarray  # (6,) bool

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


def extrinsic_step(solution, cam_T_imu: np.ndarray) -> ExtrinsicStep:
    """The profile Gauss-Newton step and covariance of the extrinsic at a solved smoother
    (:class:`graph.smoother.SmootherSolution`, solved with ``cam_T_imu``); module docstring."""
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
    determined = np.sqrt(np.diag(cov)) <= UNDETERMINED_SIGMA
    step = np.zeros(6)
    if determined.any():
        d = np.flatnonzero(determined)
        step[d] = np.linalg.solve(S[np.ix_(d, d)] + prior[np.ix_(d, d)], g[d])
    return ExtrinsicStep(step=step, information=S, covariance=cov, determined=determined)


def extrinsic_fold_gain(solution, cam_T_imu: np.ndarray, other: np.ndarray,
                        stretch_s: float = 10.0):
    """The identified extrinsic's out-of-sample gain over ``other`` (the file's), by
    leave-one-stretch-out cross-validation of the profile likelihood at a smoother solved with
    ``cam_T_imu`` (:func:`graph.out_of_sample.fold_gain`; folds: ``stretch_s`` stretches of the
    drive, :func:`graph.stretches.stretch_labels`). The components fitted are those the drive
    determines (:func:`extrinsic_step`), under the weak prior ``PRIOR_SIGMA``."""
    from vislam.graph.out_of_sample import fold_gain, term_rows

    system = linear_system(solution, cam_T_imu)
    A_p, b_p, folds = term_rows(solution, system.stereo, system.A_t, stretch_s)
    prior = np.diag(1.0 / PRIOR_SIGMA ** 2)
    cov = np.linalg.inv(A_p.T @ A_p + prior)
    determined = np.sqrt(np.diag(cov)) <= UNDETERMINED_SIGMA
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


__all__ = ["ExtrinsicStep", "ExtrinsicSystem", "linear_system", "extrinsic_step", "extrinsic_fold_gain", "stereo_rows", "perturb_cam_T_imu", "theta_map", "lever_arm",
           "lever_arm_covariance", "theta_between", "mahalanobis", "PRIOR_SIGMA", "UNDETERMINED_SIGMA"]
