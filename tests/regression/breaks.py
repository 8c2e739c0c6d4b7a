"""Shared settings of the regression tests.

* ``VISLAM_REGRESSION_BREAK`` deliberately breaks the estimators, to show the tests can fail:
  ``pixel-noise`` doubles the pixel noise the estimators assume (``FilterConfig.pixel_sigma``
  x 2); ``half-pixel-noise`` halves it (the estimators overconfident); ``no-cross-cov`` runs
  the joint filter without its pose-landmark cross-covariance
  (``ekf-joint`` is replaced by ``ekf-decoupled``, the same filter with that block dropped);
  ``half-accel-noise`` makes the raw-IMU EKF assume half the accelerometer's noise density
  (:func:`broken_imu_noise`).
  Unset (the default and CI) nothing is broken.
* Real data: ``VISLAM_DATA`` or ``../shared/data/kitti-pr3`` beside the repository. Missing data
  skips the test with the reason, except with ``CI=true``, where it fails.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from vislam.ekf.config import FilterConfig

BREAKS = ("pixel-noise", "half-pixel-noise", "no-cross-cov", "half-accel-noise")
REPO = Path(__file__).resolve().parents[2]


def in_ci() -> bool:
    return os.environ.get("CI", "").lower() == "true"


def skip_or_fail(reason: str) -> None:
    """Skip the test with ``reason``; in CI (CI=true) fail instead."""
    if in_ci():
        pytest.fail(f"{reason} (CI=true: missing inputs fail)")
    pytest.skip(reason)


def regression_break() -> str | None:
    value = os.environ.get("VISLAM_REGRESSION_BREAK", "").strip() or None
    if value is not None and value not in BREAKS:
        raise pytest.UsageError(f"VISLAM_REGRESSION_BREAK={value!r}: expected one of {', '.join(BREAKS)}")
    return value


def broken_config(config: FilterConfig) -> FilterConfig:
    """``config`` with the deliberate break applied (if any)."""
    if regression_break() == "pixel-noise":
        return config.replace(pixel_sigma=2.0 * config.pixel_sigma)
    if regression_break() == "half-pixel-noise":
        return config.replace(pixel_sigma=0.5 * config.pixel_sigma)
    return config


def run_name(estimator: str) -> str:
    """The registry name actually run for ``estimator`` (the break may swap it)."""
    if regression_break() == "no-cross-cov" and estimator == "ekf-joint":
        return "ekf-decoupled"
    return estimator


def broken_imu_noise(noise):
    """The IMU noise (:class:`ekf.inertial.ImuNoise`) a raw-IMU filter is told to assume: ``noise``
    itself, or with half its accelerometer noise density under the ``half-accel-noise``
    break."""
    if regression_break() == "half-accel-noise":
        from dataclasses import replace

        return replace(noise, accel_noise_density=0.5 * noise.accel_noise_density)
    return noise
