"""What a filter author needs: the per-frame protocol, its driver, and the math vislam's EKFs use.

A filter is a class with the :class:`Filter` methods (``initialise``, ``predict``, ``update``,
``marginalise``, and read-outs of the pose, its covariance and the landmarks); :func:`run_filter`
drives it over a :class:`Sequence` and returns an :class:`Estimate`, exactly as it drives
vislam's own EKFs. The order of the calls, the conventions of every read-out and the motion input
(:class:`MotionInput`, with room for raw IMU samples :class:`ImuSamples`) are documented in
:mod:`vislam.ekf.filter`. On the command line a filter class is an estimator like any other:
``vislam bench --estimators my_module:MyFilter`` (and ``vislam nees``, ``vislam run``).

Building blocks (numpy arrays throughout; translation first in every twist ``[v; w]``):

- settings: :class:`FilterConfig` (noise model, gates, options; ``config.velocity_cov``,
  ``config.pixel_cov``, ``config.initial_pose_cov``);
- SE(3) and SO(3): :func:`hat`, :func:`se3_exp`, :func:`se3_log`, :func:`se3_inv`,
  :func:`so3_exp`, :func:`so3_log`, :func:`adjoint`, :func:`so3_left_jacobian`;
- the stereo camera: :class:`StereoModel` (projection ``z = M pi(cam_T_imu U m)``, paper eq. 1-3,
  its Jacobians in the pose and the landmark, the reduced 3-row update, triangulation with its
  covariance, the chi-square gate); the functions :func:`project`, :func:`dpi_dq`,
  :func:`triangulate`, :func:`triangulate_with_jacobian`;
- numerical guards: :class:`NumericalGuard`, :class:`UpdateRejected` (:mod:`vislam.ekf.numerics`);
- pose-covariance conventions: :func:`ekf_cov_to_estimate`, :func:`left_cov_to_estimate`.
"""

from __future__ import annotations

from vislam.ekf.camera import dpi_dq, project, stereo_matrix, triangulate, triangulate_with_jacobian
from vislam.ekf.config import FilterConfig
from vislam.ekf.conventions import ekf_cov_to_estimate, left_cov_to_estimate
from vislam.ekf.driver import motion_inputs, run_filter
from vislam.ekf.estimate import Estimate
from vislam.ekf.filter import (
    Filter,
    FrameObservations,
    ImuSamples,
    Landmarks,
    MotionInput,
    UpdateCounts,
    is_filter_class,
)
from vislam.ekf.geometry import (
    adjoint,
    hat,
    se3_exp,
    se3_inv,
    se3_log,
    so3_exp,
    so3_left_jacobian,
    so3_log,
)
from vislam.ekf.numerics import NumericalGuard, UpdateRejected
from vislam.ekf.sequence import Calibration, Sequence
from vislam.ekf.stereo_update import StereoModel

__all__ = [
    "Calibration",
    "Estimate",
    "Filter",
    "FilterConfig",
    "FrameObservations",
    "ImuSamples",
    "Landmarks",
    "MotionInput",
    "NumericalGuard",
    "Sequence",
    "StereoModel",
    "UpdateCounts",
    "UpdateRejected",
    "adjoint",
    "dpi_dq",
    "ekf_cov_to_estimate",
    "hat",
    "is_filter_class",
    "left_cov_to_estimate",
    "motion_inputs",
    "project",
    "run_filter",
    "se3_exp",
    "se3_inv",
    "se3_log",
    "so3_exp",
    "so3_left_jacobian",
    "so3_log",
    "stereo_matrix",
    "triangulate",
    "triangulate_with_jacobian",
]
