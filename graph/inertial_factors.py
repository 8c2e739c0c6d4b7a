"""The raw-IMU smoother's factors: IMU preintegration between camera frames, monocular
projections, and landmarks triangulated from them (all of it GTSAM's).

**IMU noise, continuous to discrete.** ``gtsam.PreintegrationCombinedParams`` takes
*continuous-time* covariances: ``setGyroscopeCovariance(gyro_noise_density^2 I)``
((rad/s)^2/Hz) and ``setAccelerometerCovariance(accel_noise_density^2 I)`` ((m/s^2)^2/Hz),
which GTSAM turns into the covariance of one sample held over ``dt`` by dividing by ``dt``
(``sigma_sample = density / sqrt(dt)``, i.e. ``density * sqrt(rate)``);
``setBiasOmegaCovariance(gyro_random_walk^2 I)`` and ``setBiasAccCovariance(accel_random_walk^2
I)`` (the random walks' spectral densities), which ``CombinedImuFactor`` multiplies by the time
integrated (the bias changes by ``walk * sqrt(dt)`` over ``dt``). These are exactly the units of
Kalibr's / the ASL ``sensor.yaml`` figures (:class:`ekf.inertial.ImuNoise`), so they go in
unchanged, each times ``inflation^2`` (one factor for every drive,
:attr:`InertialSmootherSettings.imu_noise_inflation`). ``setIntegrationCovariance`` (the error
of integrating velocity into position) is a tiny ``1e-8 I`` as in GTSAM's examples.

**The samples of an interval** (:func:`preintegrate`): each sample is held from its stamp
until the next one (GTSAM's ``integrateMeasurement`` holds one value over ``dt``), the piece
before the interval's first sample by the sample before it, clipped to the interval: the scheme
of :mod:`ekf.strapdown` (:func:`ekf.strapdown.held_pieces`), so that the smoother and the
filters integrate the same signal. A sample holding its interval's mean rate and specific force
(an integrating IMU's delta angle and delta velocity, the simulator's) is integrated exactly;
the trapezoid rule used before (the linear interpolation of point samples) put the smoother
half a sample (2.5 ms at 200 Hz) late against them, a rotation error of millirad per rad/s
that its covariance did not hold (pose NEES about 50 on the simulated room drive).

**Monocular tracks**: ``GenericProjectionFactorCal3_S2(pixel, noise, X(k), L(j), K,
body_P_sensor = imu_T_cam)`` under a Huber kernel; a landmark is triangulated
(``gtsam.triangulatePoint3`` with its nonlinear refinement) from all its observations in frames
whose poses are known, and kept only when it is in front of every one of those cameras, within
``max_landmark_distance`` of them and seen under ``min_parallax_deg`` at least; observations it
does not reproject within ``outlier_px`` of are dropped (and the point triangulated again without
them). A track that fails is left out (counted).
"""

from __future__ import annotations

import gtsam
import numpy as np

from vislam.ekf.filter import ImuSamples
from vislam.ekf.inertial import ImuNoise
from vislam.ekf.strapdown import held_pieces

INTEGRATION_COVARIANCE = 1e-8


def preintegration_params(noise: ImuNoise, gravity: float, inflation: float = 1.0
                          ) -> gtsam.PreintegrationCombinedParams:
    """GTSAM's parameters for ``noise`` (continuous time, module docstring), gravity ``gravity``
    m/s^2 along the world's -z, every figure times ``inflation``."""
    p = gtsam.PreintegrationCombinedParams.MakeSharedU(float(gravity))
    k2 = float(inflation) ** 2
    p.setGyroscopeCovariance(k2 * noise.gyro_noise_density ** 2 * np.eye(3))
    p.setAccelerometerCovariance(k2 * noise.accel_noise_density ** 2 * np.eye(3))
    p.setBiasOmegaCovariance(k2 * noise.gyro_random_walk ** 2 * np.eye(3))
    p.setBiasAccCovariance(k2 * noise.accel_random_walk ** 2 * np.eye(3))
    p.setIntegrationCovariance(INTEGRATION_COVARIANCE * np.eye(3))
    return p


def interval_pieces(imu: ImuSamples, t0: float, t1: float
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(accel (n, 3), gyro (n, 3), dt (n,))``: the pieces of ``[t0, t1]`` to integrate, each
    sample held until the next one (:func:`ekf.strapdown.held_pieces`, the rule of every raw-IMU
    estimator; module docstring). EstimationError when no sample is at or before ``t0``."""
    pieces = held_pieces(imu.time, t0, t1)
    index = np.array([j for j, _ in pieces], dtype=np.int64)
    dt = np.array([d for _, d in pieces], dtype=float)
    return imu.accel[index], imu.gyro[index], dt


def preintegrate(imu: ImuSamples, t0: float, t1: float, params: gtsam.PreintegrationCombinedParams,
                 bias: gtsam.imuBias.ConstantBias) -> gtsam.PreintegratedCombinedMeasurements:
    """The preintegrated measurement of ``[t0, t1]`` (:func:`interval_pieces`) about ``bias``."""
    pim = gtsam.PreintegratedCombinedMeasurements(params, bias)
    acc, gyr, dt = interval_pieces(imu, t0, t1)
    for a, w, d in zip(acc, gyr, dt.tolist()):
        pim.integrateMeasurement(a, w, d)
    return pim


def triangulate_track(world_T_cams: list[gtsam.Pose3], pixels: np.ndarray,
                      calibration: gtsam.Cal3_S2, noise: gtsam.noiseModel.Base,
                      min_parallax_deg: float, max_distance: float, outlier_px: float,
                      min_inliers: int = 2) -> tuple[np.ndarray, np.ndarray] | None:
    """A landmark (3,) in the world from its pixels (n, 2) in cameras ``world_T_cams`` and the
    mask (n,) of the observations it reprojects within ``outlier_px`` of (re-triangulated from
    those once), or None when fewer than ``min_inliers`` remain or a check of the module
    docstring fails (behind a camera, too far, too little parallax)."""
    pixels = np.asarray(pixels, dtype=float)
    keep = np.ones(len(world_T_cams), dtype=bool)
    for _ in range(2):
        cams = [c for c, k in zip(world_T_cams, keep) if k]
        try:
            point = np.asarray(gtsam.triangulatePoint3(cams, calibration, list(pixels[keep]),
                                                       1e-9, True, noise), dtype=float)
        except RuntimeError:
            return None
        if not np.all(np.isfinite(point)):
            return None
        err = np.full(len(world_T_cams), np.inf)
        for i, (pose, z) in enumerate(zip(world_T_cams, pixels)):
            q = pose.transformTo(point)
            if q[2] > 0.0:
                err[i] = np.hypot(*(calibration.uncalibrate(q[:2] / q[2]) - z))
        inliers = err <= outlier_px
        if inliers.sum() < min_inliers:
            return None
        if np.array_equal(inliers, keep):
            break
        keep = inliers
    centres = np.array([p.translation() for p, k in zip(world_T_cams, keep) if k])
    rays = point - centres
    dist = np.linalg.norm(rays, axis=1)
    if np.any(dist > max_distance) or np.any(dist == 0):
        return None
    unit = rays / dist[:, None]
    if np.degrees(np.arccos(np.clip(unit @ unit.T, -1.0, 1.0).min())) < min_parallax_deg:
        return None
    return point, keep
