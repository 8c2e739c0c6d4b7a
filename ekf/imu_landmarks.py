"""Anchored inverse-depth landmarks of the raw-IMU filters: a landmark started from its first
monocular or stereo observation, and its measurement with the Jacobians a filter chains.

**Chart** (:mod:`ekf.inverse_depth`, Civera, Davison and Montiel 2008; its ID-1 and ID-2):
``x = [alpha, beta, rho]`` in the *anchor*, the camera ``world_T_cam_a = (R_a, p_a)`` at the
landmark's first observation, a constant of the chart (not a state): the world point is
``m = p_a + R_a b / rho`` with ``b = [alpha, beta, 1]``, and ``m_h = [R_a b + rho p_a; rho]`` its
homogeneous form scaled by ``rho`` (finite as ``rho -> 0``).

**Initialisation.** The anchor is the camera at the first observation, as the filter estimates it
then; ``x`` is that observation read in it. The anchor's own error (the filter's pose error at that
frame) enters through the chart change (IL-3), the filter adds its cross-covariances.

* *Stereo* ``z = [uL, vL, uR, vR]``: :func:`ekf.inverse_depth.from_stereo` (ID-3, exactly
  linear in the pixels).
* *Monocular* ``z = [u, v]``: ``alpha = (u - cu) / fu``, ``beta = (v - cv) / fv`` (exact,
  ``dx/dz = diag(1/fu, 1/fv)``) and the inverse depth from a prior (:class:`DepthPrior`),
  ``rho ~ N(1 / (2 d_min), (1 / (4 d_min))^2)``: its 95 % interval ``[0, 1 / d_min]`` holds every
  depth from ``d_min`` to infinity, Civera's rule (their section IV: the region of acceptance
  must hold infinity, the prior is what a single image says). ``d_min = 1 m`` by default: the
  room scenarios' and EuRoC's walls are at least a metre from the camera; a road's landmarks,
  3-60 m, lie inside it too. A prior that covers the truth (no more) is the honest one; the depth
  then comes from the motion, through the filter's updates.

**Measurement** of a landmark from the IMU pose ``world_T_imu = (R, p)`` (IL-1): the IMU-frame
point scaled by ``rho``, as a homogeneous 4-vector,

    q_i = [y; rho],   y = R^T (R_a b + rho (p_a - p)),

the camera point ``q_c = cam_T_imu q_i`` and the pixels ``z = [fu q1/q3 + cu, fv q2/q3 + cv]``
(monocular) or ``M pi(q_c)`` (stereo, :mod:`ekf.camera`), each ``q_c`` scale-invariant.

**Jacobians** (IL-2), each of ``q_i`` (so that any filter chains its own error onto them):

* landmark: ``dq_i/dx = [[R^T R_a e1, R^T R_a e2, R^T (p_a - p)], [0, 0, 1]]``;
* pose, as the right perturbation ``world_T_imu_true = world_T_imu Exp(xi)``, ``xi = [t; phi]``
  translation first (the Estimate convention): ``dq_i/dxi = [[-rho I, [y]x], [0, 0]]``. The
  error-state filter's ``[dth (body); dp (world)]`` is ``xi = [R^T dp; dth]``; an invariant
  filter's left perturbation ``xi_l`` is ``xi = Ad(T^-1) xi_l``;
* anchor, as the right perturbation of ``world_T_cam_a`` by ``xi_a = [t_a; phi_a]`` (were the
  anchor a state): ``dq_i/dxi_a = [[rho R^T R_a, -R^T R_a [b]x], [0, 0]]``;
* pixels of ``q_i``: ``dz/dq_i = dz/dq_c cam_T_imu``.

**Chart change** (IL-3). The landmark read in the true anchor, ``x_true``, sits in the estimated
anchor's chart at ``x = x_true + E [rho I, -[b]x] xi_a`` (first order) when the true anchor is the
estimated one moved by ``xi_a`` (right perturbation of ``world_T_cam_a``), with
``E = [[1, 0, -alpha], [0, 1, -beta], [0, 0, -rho]]``; the camera's ``xi_a`` is
``Ad(cam_T_imu) xi`` of the IMU's. A filter adds ``J P J^T`` and the cross-covariances with
``J = dx/dxi_a Ad(cam_T_imu) dxi/d(its error)``.

Every Jacobian is checked against finite differences in tests/test_imu_landmarks.py.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vislam.ekf import inverse_depth as idp
from vislam.ekf.camera import dpi_dq, stereo_matrix
from vislam.ekf.errors import InputError
from vislam.ekf.geometry import adjoint, hat


@dataclass(frozen=True)
class DepthPrior:
    """The inverse-depth prior of a monocular first observation (module docstring):
    ``rho ~ N(1 / (2 min_depth), (1 / (4 min_depth))^2)``, 95 % of it on depths from
    ``min_depth`` (m) to infinity."""

    min_depth: float = 1.0

    def __post_init__(self) -> None:
        if not np.isfinite(self.min_depth) or self.min_depth <= 0:
            raise InputError(f"depth prior: min_depth must be positive, got {self.min_depth!r}")

    @property
    def rho(self) -> float:
        return 0.5 / self.min_depth

    @property
    def sigma(self) -> float:
        return 0.25 / self.min_depth


def from_monocular(z: np.ndarray, K: np.ndarray, prior: DepthPrior
                   ) -> tuple[np.ndarray, np.ndarray]:
    """``x`` (n, 3) of first monocular pixels ``z`` (n, 2) with the prior's inverse depth, and the
    covariance factor ``dx/dz`` (3, 2) of the pixels (the prior's variance is on ``rho`` alone:
    :func:`initial_covariance`)."""
    z = np.atleast_2d(np.asarray(z, dtype=float))
    fu, fv, cu, cv = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    x = np.empty((z.shape[0], 3))
    x[:, 0] = (z[:, 0] - cu) / fu
    x[:, 1] = (z[:, 1] - cv) / fv
    x[:, 2] = prior.rho
    J = np.array([[1.0 / fu, 0.0], [0.0, 1.0 / fv], [0.0, 0.0]])
    return x, J


def initial_landmarks(z: np.ndarray, K: np.ndarray, baseline: float | None, pixel_var: float,
                      prior: DepthPrior) -> tuple[np.ndarray, np.ndarray]:
    """``x`` (n, 3) in the camera of their first observation and the covariance (n, 3, 3) its
    pixel noise (``pixel_var`` px^2 per coordinate) and, for a single camera, the depth prior
    give: monocular ``z`` (n, 2) when ``baseline`` is None, else stereo (n, 4) by
    :func:`ekf.inverse_depth.from_stereo`. The anchor's error is the filter's to add (IL-3)."""
    n = np.atleast_2d(z).shape[0]
    if baseline is None:
        x, J = from_monocular(z, K, prior)
        C = pixel_var * (J @ J.T)
        C[2, 2] = prior.sigma ** 2
    else:
        x, J = idp.from_stereo(z, K, baseline)
        C = pixel_var * (J @ J.T)
    return x, np.broadcast_to(C, (n, 3, 3)).copy()


def chart_change_jacobian(x: np.ndarray) -> np.ndarray:
    """(IL-3) ``dx/dxi_a`` (n, 3, 6): how a landmark's chart coordinates move when the true anchor
    camera is the estimated one moved by ``xi_a = [t_a; phi_a]`` (right perturbation of
    ``world_T_cam_a``, translation first)."""
    a, b, r = x[:, 0], x[:, 1], x[:, 2]
    n = x.shape[0]
    E = np.zeros((n, 3, 3))
    E[:, 0, 0] = E[:, 1, 1] = 1.0
    E[:, 0, 2] = -a
    E[:, 1, 2] = -b
    E[:, 2, 2] = -r
    A = np.empty((n, 3, 6))
    A[:, :, :3] = r[:, None, None] * np.eye(3)
    A[:, :, 3:] = -hat(idp.bearing(x))
    return E @ A


def camera_from_imu_jacobian(cam_T_imu: np.ndarray) -> np.ndarray:
    """``Ad(cam_T_imu)`` (6, 6), translation first: the right perturbation of
    ``world_T_cam = world_T_imu imu_T_cam`` of the IMU's right perturbation ``xi``."""
    return adjoint(cam_T_imu)


def imu_points(x: np.ndarray, R_a: np.ndarray, p_a: np.ndarray, world_T_imu: np.ndarray
               ) -> np.ndarray:
    """(IL-1) ``q_i = [R^T (R_a b + rho (p_a - p)); rho]`` (n, 4)."""
    R, p = world_T_imu[:3, :3], world_T_imu[:3, 3]
    q = np.empty((x.shape[0], 4))
    w = np.einsum("nij,nj->ni", R_a, idp.bearing(x)) + x[:, 2:3] * (p_a - p)
    q[:, :3] = w @ R
    q[:, 3] = x[:, 2]
    return q


def landmark_jacobian(x: np.ndarray, R_a: np.ndarray, p_a: np.ndarray, world_T_imu: np.ndarray
                      ) -> np.ndarray:
    """(IL-2) ``dq_i/dx`` (n, 4, 3)."""
    R, p = world_T_imu[:3, :3], world_T_imu[:3, 3]
    J = np.zeros((x.shape[0], 4, 3))
    J[:, :3, :2] = np.einsum("ji,njk->nik", R, R_a[:, :, :2])
    J[:, :3, 2] = (p_a - p) @ R
    J[:, 3, 2] = 1.0
    return J


def pose_jacobian(q_i: np.ndarray) -> np.ndarray:
    """(IL-2) ``dq_i/dxi`` (n, 4, 6) for the right perturbation ``xi = [t; phi]`` of
    ``world_T_imu``, at the points ``q_i`` (n, 4) of :func:`imu_points`."""
    J = np.zeros((q_i.shape[0], 4, 6))
    J[:, :3, :3] = -q_i[:, 3, None, None] * np.eye(3)
    J[:, :3, 3:] = hat(q_i[:, :3])
    return J


def anchor_jacobian(x: np.ndarray, R_a: np.ndarray, world_T_imu: np.ndarray) -> np.ndarray:
    """(IL-2) ``dq_i/dxi_a`` (n, 4, 6) for the right perturbation ``xi_a = [t_a; phi_a]`` of the
    anchor ``world_T_cam_a``."""
    RtRa = np.einsum("ji,njk->nik", world_T_imu[:3, :3], R_a)
    J = np.zeros((x.shape[0], 4, 6))
    J[:, :3, :3] = x[:, 2, None, None] * RtRa
    J[:, :3, 3:] = -RtRa @ hat(idp.bearing(x))
    return J


@dataclass(frozen=True)
class PixelModel:
    """The camera of a raw-IMU drive: intrinsics ``K``, ``baseline`` (None: one camera) and
    ``cam_T_imu``; :meth:`predict` gives pixels and ``dz/dq_i`` of IMU-frame points."""

    K: np.ndarray
    cam_T_imu: np.ndarray
    baseline: float | None = None

    @property
    def rows(self) -> int:
        """Pixel coordinates per observation: 2 (monocular) or 4 (stereo)."""
        return 2 if self.baseline is None else 4

    def camera_points(self, q_i: np.ndarray) -> np.ndarray:
        """``q_c = cam_T_imu q_i`` (n, 4)."""
        return q_i @ self.cam_T_imu.T

    def predict(self, q_i: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(z (n, rows), dz/dq_i (n, rows, 4), depth (n,))`` of IMU-frame points ``q_i``
        (IL-1); ``depth`` is the camera's ``q3 / q4`` sign-carrying part ``q3`` (its sign says
        whether the point is in front; divide by ``rho`` for metres)."""
        q = self.camera_points(q_i)
        if self.baseline is None:
            K = self.K
            inv = 1.0 / q[:, 2]
            z = np.stack([K[0, 0] * q[:, 0] * inv + K[0, 2], K[1, 1] * q[:, 1] * inv + K[1, 2]],
                         axis=1)
            dz_dq = np.zeros((q.shape[0], 2, 4))
            dz_dq[:, 0, 0] = K[0, 0] * inv
            dz_dq[:, 0, 2] = -K[0, 0] * q[:, 0] * inv * inv
            dz_dq[:, 1, 1] = K[1, 1] * inv
            dz_dq[:, 1, 2] = -K[1, 1] * q[:, 1] * inv * inv
        else:
            M = stereo_matrix(self.K, self.baseline)
            z = (q / q[:, 2:3]) @ M.T
            dz_dq = M @ dpi_dq(q)
        return z, dz_dq @ self.cam_T_imu, q[:, 2]
