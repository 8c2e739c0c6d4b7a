"""Pose-perturbation conventions and the conversions between them (one module, tested both ways).

Three conventions meet in vislam. For a pose ``T = world_T_imu`` and its inverse
``U = imu_T_world`` (the paper's state):

* **EKF** (the paper's): left perturbation of the inverse pose, translation first,
  ``U_true = exp(d^) U_est`` with ``d = [dp; dth]``.
* **Estimate** (what :class:`ekf.estimate.Estimate` stores): right perturbation of the pose,
  translation first, ``T_true = T_est exp(xi^)`` with ``xi = [rho; phi]``.
  Since ``T_true = U_true^-1 = U_est^-1 exp(-d^)``, ``xi = -d`` **exactly**: the pose
  covariances agree and only pose-landmark cross-covariances change sign.
* **GTSAM** (``gtsam.Pose3``): right perturbation of the pose, rotation first,
  ``T_true = T_est * Pose3.Expmap([w; v])`` so ``xi_gtsam = [phi; rho]``, a permutation.
* **Left-invariant world frame** (used by the invariant EKF): left perturbation of the pose,
  ``T_true = exp(xi_l^) T_est``; then ``xi = Ad(T_est^-1) xi_l``.

Each conversion is a linear map J on the tangent vector, and a covariance P maps to J P J^T.
For a joint covariance with the pose block first, :func:`convert_joint_pose_block` applies J
to the pose rows and columns only, which carries the cross-covariances correctly.
"""

from __future__ import annotations

import numpy as np

from vislam.ekf.geometry import adjoint, se3_inv

#: Permutation between translation-first ``[rho; phi]`` and rotation-first ``[phi; rho]``.
SWAP = np.block([[np.zeros((3, 3)), np.eye(3)], [np.eye(3), np.zeros((3, 3))]])

#: EKF tangent ``d`` -> Estimate tangent ``xi`` (and back: the map is its own inverse).
EKF_TO_ESTIMATE = -np.eye(6)

#: Estimate tangent ``[rho; phi]`` -> GTSAM tangent ``[phi; rho]`` (its own inverse).
ESTIMATE_TO_GTSAM = SWAP

#: EKF tangent ``d`` -> GTSAM tangent.
EKF_TO_GTSAM = ESTIMATE_TO_GTSAM @ EKF_TO_ESTIMATE


def _congruence(J: np.ndarray, P: np.ndarray) -> np.ndarray:
    return J @ P @ np.swapaxes(J, -1, -2)


def ekf_cov_to_estimate(P: np.ndarray) -> np.ndarray:
    """6x6 pose covariance (..., 6, 6): EKF convention -> Estimate convention."""
    return _congruence(EKF_TO_ESTIMATE, P)


def estimate_cov_to_ekf(P: np.ndarray) -> np.ndarray:
    """6x6 pose covariance: Estimate convention -> EKF convention."""
    return _congruence(EKF_TO_ESTIMATE, P)


def estimate_cov_to_gtsam(P: np.ndarray) -> np.ndarray:
    """6x6 pose covariance: Estimate convention -> GTSAM Pose3 (rotation first)."""
    return _congruence(ESTIMATE_TO_GTSAM, P)


def gtsam_cov_to_estimate(P: np.ndarray) -> np.ndarray:
    """6x6 pose covariance: GTSAM Pose3 (rotation first) -> Estimate convention."""
    return _congruence(ESTIMATE_TO_GTSAM, P)


def ekf_cov_to_gtsam(P: np.ndarray) -> np.ndarray:
    """6x6 covariance of the EKF's inverse-pose perturbation -> GTSAM Pose3 covariance."""
    return _congruence(EKF_TO_GTSAM, P)


def gtsam_cov_to_ekf(P: np.ndarray) -> np.ndarray:
    """GTSAM Pose3 covariance -> 6x6 covariance of the EKF's inverse-pose perturbation."""
    return _congruence(np.linalg.inv(EKF_TO_GTSAM), P)


def left_to_right_jacobian(T: np.ndarray) -> np.ndarray:
    """Map a left pose perturbation ``xi_l`` to the right one ``xi = Ad(T^-1) xi_l``."""
    return adjoint(se3_inv(T))


def left_cov_to_estimate(T: np.ndarray, P_left: np.ndarray) -> np.ndarray:
    """Covariance of a left perturbation of ``T`` (world frame) -> Estimate convention."""
    return _congruence(left_to_right_jacobian(T), P_left)


def estimate_cov_to_left(T: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Estimate-convention covariance -> covariance of a left perturbation of ``T``."""
    return _congruence(adjoint(T), P)


def convert_joint_pose_block(P: np.ndarray, J: np.ndarray) -> np.ndarray:
    """Apply the 6x6 tangent map ``J`` to the leading pose block of a joint covariance ``P``.

    ``P`` is (6 + n) x (6 + n) with the pose first; the result is ``G P G^T`` with
    ``G = blkdiag(J, I_n)``, so pose-landmark cross-covariances become ``J P_pm``.
    """
    P = np.asarray(P, dtype=float)
    out = P.copy()
    out[:6, :] = J @ P[:6, :]
    out[:, :6] = out[:, :6] @ J.T
    return out
