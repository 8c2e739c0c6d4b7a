"""GTSAM's navigation state and IMU bias <-> vislam's convention (each way tested).

vislam (:class:`ekf.estimate.Estimate` and :class:`graph.inertial_smoother.InertialStates`):

* pose ``world_T_imu`` (4, 4), covariance of ``xi = [rho; phi]`` (translation first) in the
  right perturbation ``T_true = T_est exp(xi^)``;
* velocity ``v`` (3,) of the IMU in the **world** frame, m/s, covariance of the additive error
  ``v_true = v_est + dv``;
* bias ``[b_gyro; b_accel]`` (6,) (gyro first, as :class:`ekf.inertial.ImuNoise` and the ASL /
  OpenVINS ground truth order them), additive, so that the true rate is ``gyro - b_gyro``.

GTSAM:

* ``Pose3`` (the ``X`` keys): right perturbation, rotation first ``[phi; rho]``;
* ``Vector3`` velocity (the ``V`` keys of ``CombinedImuFactor``): world ("navigation") frame,
  additive, so the same as vislam's;
* ``NavState(R, p, v)`` (``PreintegratedCombinedMeasurements.predict``): tangent
  ``[dphi; dp; dv]`` with ``R_true = R Exp(dphi)``, ``p_true = p + R dp``, ``v_true = v + R dv``
  (body-frame increments), so ``dv_world = R dv`` and, to first order, ``rho = dp``;
* ``imuBias.ConstantBias(accel, gyro)``: vector and tangent ``[b_accel; b_gyro]``, additive, the
  swap of vislam's order.
"""

from __future__ import annotations

import gtsam
import numpy as np

from vislam.ekf.conventions import SWAP

#: vislam bias order ``[gyro; accel]`` <-> GTSAM's ``[accel; gyro]`` (its own inverse).
BIAS_TO_GTSAM = SWAP


def nav_state(pose: np.ndarray, velocity: np.ndarray) -> gtsam.NavState:
    """``world_T_imu`` (4, 4) and the world-frame velocity (3,) as a ``gtsam.NavState``."""
    pose = np.asarray(pose, dtype=float)
    return gtsam.NavState(gtsam.Rot3(pose[:3, :3]), pose[:3, 3].copy(),
                          np.asarray(velocity, dtype=float).copy())


def from_nav_state(state: gtsam.NavState) -> tuple[np.ndarray, np.ndarray]:
    """``(world_T_imu (4, 4), world velocity (3,))`` of a ``gtsam.NavState``."""
    return np.asarray(state.pose().matrix(), dtype=float), np.asarray(state.velocity(), dtype=float)


def nav_tangent_to_vislam(pose: np.ndarray) -> np.ndarray:
    """The 9x9 linear map from GTSAM's NavState tangent ``[dphi; dp; dv]`` at ``pose`` to
    vislam's ``[rho; phi; dv_world]`` (module docstring), first order."""
    R = np.asarray(pose, dtype=float)[:3, :3]
    J = np.zeros((9, 9))
    J[0:3, 3:6] = np.eye(3)
    J[3:6, 0:3] = np.eye(3)
    J[6:9, 6:9] = R
    return J


def nav_cov_to_vislam(pose: np.ndarray, P: np.ndarray) -> np.ndarray:
    """A 9x9 NavState covariance at ``pose`` -> the covariance of ``[rho; phi; dv_world]``."""
    J = nav_tangent_to_vislam(pose)
    return J @ np.asarray(P, dtype=float) @ J.T


def vislam_cov_to_nav(pose: np.ndarray, P: np.ndarray) -> np.ndarray:
    """The inverse of :func:`nav_cov_to_vislam`."""
    J = np.linalg.inv(nav_tangent_to_vislam(pose))
    return J @ np.asarray(P, dtype=float) @ J.T


def to_gtsam_bias(bias: np.ndarray) -> gtsam.imuBias.ConstantBias:
    """vislam's ``[b_gyro; b_accel]`` (6,) as GTSAM's ``ConstantBias(accel, gyro)``."""
    b = np.asarray(bias, dtype=float).reshape(6)
    return gtsam.imuBias.ConstantBias(b[3:6].copy(), b[0:3].copy())


def from_gtsam_bias(bias: gtsam.imuBias.ConstantBias) -> np.ndarray:
    """GTSAM's ``ConstantBias`` as vislam's ``[b_gyro; b_accel]`` (6,)."""
    return np.concatenate([np.asarray(bias.gyroscope(), dtype=float),
                           np.asarray(bias.accelerometer(), dtype=float)])


def gtsam_bias_cov_to_vislam(P: np.ndarray) -> np.ndarray:
    """6x6 covariance of a ``ConstantBias`` (accel first) -> vislam's order (gyro first)."""
    return BIAS_TO_GTSAM @ np.asarray(P, dtype=float) @ BIAS_TO_GTSAM.T


def vislam_bias_cov_to_gtsam(P: np.ndarray) -> np.ndarray:
    """6x6 bias covariance, vislam's order (gyro first) -> GTSAM's (accel first)."""
    return BIAS_TO_GTSAM @ np.asarray(P, dtype=float) @ BIAS_TO_GTSAM.T
