"""A constant gyro bias shared by every motion factor of the batch smoother.

A drive's angular velocities may carry constant offsets per axis (docs/findings.md names
the ones measured). Where vision constrains consecutive poses that hardly matters, but at a
tracker's "repeat events" one interval has no visual constraint and only the velocity spans it; the
offsets then add up to a systematic heading drift. The smoother therefore estimates one bias
``b`` (rad/s, body frame) jointly with the poses.

Model (paper eq. 11 with the bias removed from the measured twist): the interval ``[k, k+1]``
moves by ``exp(tau (u - [0; b]))`` (translation-first twist). To first order in ``b``

    exp(tau u - tau [0; b]) ~= exp(tau u) Exp(-D_k b),   D_k = tau J_r(tau u)[:, rotation]

in GTSAM's rotation-first right perturbation (``J_r`` = ``Pose3.ExpmapDerivative``), exactly as
IMU preintegration corrects for a bias change. The factor's error is

    e = Log(P_k^-1 x_k^-1 x_{k+1}),   P_k = Delta_k Exp(-D_k b),

with the covariance of the plain between-factor, and analytic Jacobians (tested against
numerical derivatives in tests/test_graph_gyro_bias.py):

    de/dx_k     = -J_r^-1(e) Ad(B^-1),        B = x_k^-1 x_{k+1}
    de/dx_{k+1} =  J_r^-1(e)
    de/db       =  J_r^-1(e) Ad(R^-1) J_r(-D_k b) D_k,   R = P_k^-1 B.

The factor is a ``gtsam.CustomFactor`` (a Python callback, about 0.1 ms per evaluation; one
per interval, so well under the cost of a linear solve).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B

from vislam.graph.pose_conversions import interval_jacobians, to_pose3

log = logging.getLogger(__name__)

#: The one bias variable (a ``Point3``: rad/s, body frame).
BIAS_KEY = B(0)


def bias_jacobians(twists: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """``D_k`` (T-1, 6, 3): how a gyro bias moves each interval's relative pose (module docstring).

    ``twists`` (T-1, 6) translation first, ``tau`` (T-1,) seconds."""
    return interval_jacobians(twists, tau)[:, :, :3]


def corrected_delta(delta: gtsam.Pose3, D: np.ndarray, bias: np.ndarray) -> gtsam.Pose3:
    """``P = Delta Exp(-D b)``: the relative motion with the bias removed."""
    return delta.compose(gtsam.Pose3.Expmap(-D @ np.asarray(bias, dtype=float)))


def bias_corrections(D: np.ndarray, bias: np.ndarray) -> np.ndarray:
    """``Exp(-D_k b)`` (T-1, 4, 4): what removes the bias ``b`` from each interval's motion."""
    b = np.asarray(bias, dtype=float)
    return np.stack([gtsam.Pose3.Expmap(-Dk @ b).matrix() for Dk in D]) if len(D) \
        else np.zeros((0, 4, 4))


def corrected_deltas(deltas: np.ndarray, D: np.ndarray, bias: np.ndarray) -> np.ndarray:
    """All relative motions (T-1, 4, 4) with the bias ``b`` removed."""
    return np.stack([corrected_delta(to_pose3(d), Dk, bias).matrix() for d, Dk in zip(deltas, D)]) \
        if len(deltas) else np.zeros((0, 4, 4))


def relative_motion_error(P: gtsam.Pose3, x0: gtsam.Pose3, x1: gtsam.Pose3,
                          H: list | None = None) -> tuple[np.ndarray, gtsam.Pose3, np.ndarray | None]:
    """``e = Log(P^-1 x0^-1 x1)`` of a motion factor whose measured relative motion is ``P``;
    ``(e, R, J_log)`` with ``R = P^-1 x0^-1 x1`` and, when ``H`` is a list, ``J_log`` the Log's
    derivative at ``e`` and the Jacobians wrt ``x0`` and ``x1`` appended to ``H`` (module
    docstring)."""
    between = x0.between(x1)
    R = P.between(between)
    e = gtsam.Pose3.Logmap(R)
    if H is None:
        return e, R, None
    J_log = gtsam.Pose3.LogmapDerivative(e)
    H.append(-J_log @ between.inverse().AdjointMap())
    H.append(J_log)
    return e, R, J_log


def biased_motion_error(delta: gtsam.Pose3, D: np.ndarray, x0: gtsam.Pose3, x1: gtsam.Pose3,
                        bias: np.ndarray, H: list | None = None) -> np.ndarray:
    """The factor's error (6,) and, when ``H`` is a list, its three Jacobians appended to it
    (wrt ``x0``, ``x1`` and ``bias``; 6x6, 6x6, 6x3)."""
    Db = D @ bias
    P = delta.compose(gtsam.Pose3.Expmap(-Db))
    e, R, J_log = relative_motion_error(P, x0, x1, H)
    if H is not None:
        H.append(J_log @ R.inverse().AdjointMap() @ gtsam.Pose3.ExpmapDerivative(-Db) @ D)
    return e


def _bias_error(delta: gtsam.Pose3, D: np.ndarray, between: gtsam.Pose3,
                bias: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`biased_motion_error`'s error and bias Jacobian (the same arithmetic) for the
    relative motion ``between`` = ``x0.between(x1)`` of fixed poses."""
    Db = D @ bias
    P = delta.compose(gtsam.Pose3.Expmap(-Db))
    R = P.between(between)
    e = gtsam.Pose3.Logmap(R)
    J_log = gtsam.Pose3.LogmapDerivative(e)
    return e, J_log @ R.inverse().AdjointMap() @ gtsam.Pose3.ExpmapDerivative(-Db) @ D


def biased_motion_factor(k0: int, k1: int, bias_key: int, delta: np.ndarray, D: np.ndarray,
                         noise: gtsam.noiseModel.Base) -> gtsam.CustomFactor:
    """A ``CustomFactor`` on (``k0``, ``k1``, ``bias_key``) for the relative motion ``delta``
    (4x4) with bias Jacobian ``D`` (6x3)."""
    measured = to_pose3(delta)
    D = np.ascontiguousarray(D, dtype=float)

    def error(this: gtsam.CustomFactor, values: gtsam.Values, jacobians) -> np.ndarray:
        keys = this.keys()
        x0 = values.atPose3(keys[0])
        x1 = values.atPose3(keys[1])
        b = values.atPoint3(keys[2])
        if jacobians is None:
            return biased_motion_error(measured, D, x0, x1, b)
        H: list = []
        e = biased_motion_error(measured, D, x0, x1, b, H)
        jacobians[0], jacobians[1], jacobians[2] = H
        return e

    return gtsam.CustomFactor(noise, [int(k0), int(k1), int(bias_key)], error)


@dataclass
class GyroBiasModel:
    """What the graph needs to estimate the bias: ``D`` (T-1, 6, 3) per interval, the bias
    prior (zero mean) and the initial value."""

    D: np.ndarray
    prior: gtsam.noiseModel.Base
    initial: np.ndarray

    @classmethod
    def create(cls, twists: np.ndarray, tau: np.ndarray, prior_sigma: float,
               initial: np.ndarray | None = None) -> "GyroBiasModel":
        return cls(bias_jacobians(twists, tau), gtsam.noiseModel.Isotropic.Sigma(3, float(prior_sigma)),
                   np.zeros(3) if initial is None else np.asarray(initial, dtype=float))


def estimate_bias(poses: np.ndarray, deltas: np.ndarray, D: np.ndarray, covs: np.ndarray,
                  prior_sigma: float, initial: np.ndarray | None = None, iterations: int = 3) -> np.ndarray:
    """The bias (3,) that best explains the relative poses of a fixed trajectory ``poses``
    (T, 4, 4): Gauss-Newton on ``sum_k |e_k(b)|^2_{covs_k} + |b / prior_sigma|^2`` with the
    factor's error and bias Jacobian (the poses held fixed).

    This is the bias step of the smoother's alternating scheme (``gyro_bias="alternate"``):
    the bias is determined by the intervals vision constrains, so the poses and the bias are
    only weakly coupled and two rounds (solve, re-estimate, solve) suffice.

    On degenerate input (non-finite poses or motions, a singular covariance or normal matrix,
    a non-finite step) the bias cannot be estimated: the last sound value (``initial``, or
    zero) is returned with a logged warning."""
    b0 = np.zeros(3) if initial is None else np.asarray(initial, dtype=float).copy()
    if not np.all(np.isfinite(b0)):
        b0 = np.zeros(3)
    b = b0

    def give_up(why: str) -> np.ndarray:
        log.warning("smoother: gyro bias not estimated (%s); keeping %s rad/s", why,
                    np.array2string(b0, precision=4))
        return b0

    if len(deltas) == 0:
        return b
    if not (np.isfinite(poses).all() and np.isfinite(deltas).all() and np.isfinite(D).all()
            and np.isfinite(covs).all()):
        return give_up("the trajectory or the motions are not finite")
    try:
        info = np.linalg.inv(covs)
    except np.linalg.LinAlgError:
        return give_up("a motion covariance is singular")
    x = [to_pose3(T) for T in poses]
    measured = [to_pose3(d) for d in deltas]
    # What biased_motion_error computes for the bias (the poses are fixed: their relative
    # motions once), the normal equations' terms for all intervals at once and summed in
    # interval order (cumulative sums from the prior's term), as a loop over k would.
    between = [x[k].between(x[k + 1]) for k in range(len(deltas))]
    n = len(deltas)
    e = np.empty((n, 6))
    Hb = np.empty((n, 6, 3))
    with np.errstate(all="ignore"):
        for _ in range(int(iterations)):
            for k in range(n):
                e[k], Hb[k] = _bias_error(measured[k], D[k], between[k], b)
            Ht_info = np.swapaxes(Hb, 1, 2) @ info
            A = np.cumsum(np.concatenate([(np.eye(3) / prior_sigma**2)[None], Ht_info @ Hb]),
                          axis=0)[-1]
            g = np.cumsum(np.concatenate([(b / prior_sigma**2)[None],
                                          (Ht_info @ e[:, :, None])[:, :, 0]]), axis=0)[-1]
            if not (np.isfinite(A).all() and np.isfinite(g).all()):
                return give_up("the normal equations are not finite")
            try:
                step = np.linalg.solve(A, -g)
            except np.linalg.LinAlgError:
                return give_up("the normal equations are singular")
            if not np.isfinite(step).all():
                return give_up("the step is not finite")
            b = b + step
            if np.max(np.abs(step)) < 1e-9:
                break
    return b


def motion_bias_jacobian(solution) -> tuple[np.ndarray, np.ndarray]:
    """``(rows, A_b)``: the whitened Jacobian (6 (T-1), 3) of a solved smoother's motion
    factors on a change ``db`` of the gyro bias removed from its motions, and the factors' rows
    in GTSAM's linearisation (:meth:`graph.smoother.SmootherSolution.linearised`; the motion
    factors follow the pose prior, graph.factors). At the solution's bias (``db = 0``) the module
    docstring's ``de/db = J_r^-1(e) Ad(R^-1) D_k``, ``R = Exp(e)``; its whitening is read off the
    linearisation's own block on ``x_k+1`` (``L J_r^-1(e)``), so

        ``A_b = (L J_r^-1(e)) Ad(Exp(-e)) D_k``.

    For a solution without a bias variable (``gyro_bias`` "alternate" or "off")."""
    from vislam.graph.pose_conversions import X

    system, _ = solution.linearised()
    T = solution.poses.shape[0]
    n = T - 1
    D = bias_jacobians(solution.twist[:n], solution.tau[:n])
    start = int(solution.problem.graph.at(0).dim())
    rows = np.arange(start, start + 6 * n)
    A = system.A.tocsr()
    A_b = np.zeros((6 * n, 3))
    for k in range(n):
        r0 = start + 6 * k
        c = system.offsets[X(k + 1)]
        block = A[r0:r0 + 6, c:c + 6].toarray()
        rel = to_pose3(solution.poses[k]).between(to_pose3(solution.poses[k + 1]))
        e = gtsam.Pose3.Logmap(to_pose3(solution.deltas[k]).between(rel))
        A_b[6 * k:6 * k + 6] = block @ gtsam.Pose3.Expmap(-e).AdjointMap() @ D[k]
    return rows, A_b


def bias_fold_gain(solution, stretch_s: float = 10.0):
    """The gyro bias's out-of-sample gain over none (:func:`graph.out_of_sample.fold_gain`,
    folds of ``stretch_s`` seconds) at a smoother solved with the bias removed
    (``solution.gyro_bias``, "alternate"): the bias fitted without each stretch against the
    null ``b = 0``, i.e. ``db = -b``."""
    from vislam.graph.out_of_sample import fold_gain, term_rows

    rows, A_b = motion_bias_jacobian(solution)
    A_p, b_p, folds = term_rows(solution, rows, A_b, stretch_s)
    bias = np.zeros(3) if solution.gyro_bias is None else np.asarray(solution.gyro_bias, dtype=float)
    return fold_gain(A_p, b_p, folds, -bias, np.ones(3, dtype=bool))
