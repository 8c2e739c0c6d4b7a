"""How well a drive determines each identified noise level, and the conservative value taken
where it does not (issue 34, items 1 and 3).

EM (:mod:`graph.identification`) and the block fixed point of :mod:`graph.motion_correlation`
return point estimates. Where vision barely constrains the motion, their fixed point is flat:
the data cannot tell a sigma from one several times larger, EM creeps towards small values,
and an estimator given the point estimate is overconfident (docs/findings.md, "Doing no
harm"). This module gives each noise level its uncertainty from the data and, where the drive
cannot determine it, the value the model takes instead.

The uncertainty: the fraction of missing information
----------------------------------------------------
Meng and Rubin's SEM (1991): the observed information of a parameter is the complete-data
information times ``1 - r``, ``r`` the slope of the EM map at its fixed point. For the log
sigma of a noise level fitted to the expected squared residuals of ``n`` factors, the complete
information is ``2 n``, so

    sd(log sigma) = 1 / sqrt(2 n (1 - r)).

The slope is taken along the direction that scales every noise level of the model by the same
factor: there the smoother's MAP is unchanged (only the fixed priors of the first pose and the
gap smoothness weigh otherwise) and the posterior covariance scales by the factor squared, so
the perturbed E-step needs no new solve: the M-step of axis ``i`` is ``log sigma_i = 1/2 log
(S_i / n)`` with ``S_i = sum w_i^2 + P_i`` (residual squares plus the posterior term), and its
slope along the scaling is ``r_i = P_i / S_i``, the share of the expected squared residual that
the data leave to the posterior. An interval vision pins down has ``r`` near 0; one it does not
constrain at all has ``r = 1`` (its residual is zero and all of its noise is in the posterior).
Along the scaling, every other level's posterior moves with it, so this ``r`` is at least the
diagonal of the EM map's Jacobian: the uncertainty it gives errs on the large side.

Undetermined means conservative
-------------------------------
A level whose ``sd(log sigma)`` exceeds :data:`UNDETERMINED_LOG_SD` (the data cannot place it
within 35 % at two standard deviations) is *undetermined*. The model then takes the
upper end of what the data allow: the upper bound the data give without vision, where there is
one, else ``sigma exp(UPPER_Z sd)`` capped by a physical prior:

* the white (per-sample) velocity and gyro sigma: the measured samples' own second
  differences (EM's estimate of an undetermined level is biased low by more than its sd says:
  on the campaign's sparse drives, levels with sd 0.2-0.35 came out 1.5-3x low, while this
  bound was within 5 % of the truth). ``v_k+1 - 2 v_k + v_k-1`` carries ``6 sigma^2`` of white noise plus the motion's
  jerk over two intervals, so ``rms / sqrt(6)`` bounds the white sigma from above
  (:func:`white_sigma_bound`);
* the long-run (slow) velocity error, which blocks of a few seconds cannot resolve on a short
  drive or a sparse one: a physical prior on the slow errors of a vehicle's speed source
  (:func:`speed_scale_prior_sigma`): a relative speed error of :data:`SPEED_SCALE_PRIOR`
  (0.5 %, one standard deviation), constant over :data:`SPEED_SCALE_TIME_S` (20 s). Source: on
  the 2019-edition drive of KITTI 06 the file's speed is off the ground truth's path length by
  up to 1.6 % over tenths of the drive (docs/findings.md), the largest of ten stretches, so
  about three standard deviations; wheel odometry's scale moves by a similar amount with tyre
  pressure, load and wear. (1 % was measured too: on the campaign's sparse drives it left
  dead reckoning's NEES below the band and every SLAM estimator further from it, 1.6-2.8x dead
  reckoning's ATE where 0.5 % gave 1.2-1.9x; docs/findings.md.) A relative error ``a`` of the
  velocity ``v`` constant over ``L`` intervals adds ``a^2 v^2 L^2`` to the variance of their
  sum; the white-equivalent interval variance that matches it is ``a^2 v^2 L`` (``v^2`` the
  drive's mean square on that axis, ``L`` the prior's intervals or the drive's, whichever is
  fewer);
* the long-run (slow) gyro error: the gyro bias's own uncertainty, whether BIC keeps the bias
  or not: a constant error of the whole drive, white-equivalent ``sd_b sqrt(n)`` per interval. The bias's uncertainty is a sample's gyro
  sigma over the square root of the information vision gives on it: with the gyro level's
  ``sd(log sigma) = 1 / sqrt(2 n_eff)``, ``sigma_g sqrt(2) sd`` (given the trajectory, as
  before, ``sigma_g / sqrt(n)``: 25x too small on a sparse drive, docs/findings.md).

A level that is determined keeps its point estimate; the estimators widen it by its own
uncertainty (:func:`ekf.model.model_config`): a Gaussian whose log sigma is uncertain by ``sd``
has, averaged over that uncertainty, the variance ``sigma^2 exp(2 sd^2)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: Above this standard deviation of log sigma a noise level is undetermined: the data cannot
#: place it within 35 % (exp(2 sd)) at two standard deviations. EM's own bias where vision is
#: sparse is larger than its statistical sd suggests (on the campaign's sparse noisy drives,
#: levels with sd 0.2-0.35 came out 2x low), so the line is drawn well below a factor of 2.
UNDETERMINED_LOG_SD = 0.15
#: The upper end of what the data allow: the estimate times exp(UPPER_Z sd(log sigma)) (about
#: the 98th percentile).
UPPER_Z = 2.0
#: Largest sd(log sigma) reported (r = 1: nothing determined; a finite stand-in for infinity).
MAX_LOG_SD = 10.0
#: The physical prior on a vehicle's slow speed error (module docstring): a relative error of
#: the speed of this size (0.5 %, one standard deviation) ...
SPEED_SCALE_PRIOR = 0.005
#: ... constant over this long (s).
SPEED_SCALE_TIME_S = 20.0


def log_sigma_sd(n: float, missing_fraction) -> np.ndarray:
    """``sd(log sigma) = 1 / sqrt(2 n (1 - r))`` per level (module docstring), at most
    :data:`MAX_LOG_SD`."""
    r = np.clip(np.asarray(missing_fraction, dtype=float), 0.0, 1.0)
    info = 2.0 * max(float(n), 0.0) * (1.0 - r)
    with np.errstate(divide="ignore"):
        sd = np.where(info > 0, 1.0 / np.sqrt(np.maximum(info, 1e-300)), np.inf)
    return np.minimum(sd, MAX_LOG_SD)


def missing_fraction(posterior: np.ndarray, expected: np.ndarray) -> np.ndarray:
    """``r = P / S`` per level: the posterior's share of the expected squared residuals
    (module docstring); 1 where nothing was expected."""
    posterior = np.asarray(posterior, dtype=float)
    expected = np.asarray(expected, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(expected > 0, posterior / expected, 1.0)
    return np.clip(r, 0.0, 1.0)


def white_sigma_bound(samples: np.ndarray) -> np.ndarray:
    """(k,) upper bound of the white noise sigma of each column of ``samples`` (T, k) from
    their second differences: ``rms(x_k+1 - 2 x_k + x_k-1) / sqrt(6)`` (module docstring); inf
    for fewer than 3 samples."""
    x = np.asarray(samples, dtype=float)
    if x.shape[0] < 3:
        return np.full(x.shape[1], np.inf)
    d2 = x[2:] - 2.0 * x[1:-1] + x[:-2]
    return np.sqrt(np.mean(d2 * d2, axis=0) / 6.0)


def speed_scale_prior_sigma(velocity: np.ndarray, interval_s: float, n_intervals: int) -> np.ndarray:
    """(3,) the long-run interval sigma per axis of a relative speed error of
    :data:`SPEED_SCALE_PRIOR` constant over :data:`SPEED_SCALE_TIME_S` (module docstring):
    ``a rms(v_i) sqrt(L)``, ``L`` the prior's intervals or ``n_intervals``, whichever is fewer.
    ``velocity`` (T, 3) m/s, ``interval_s`` the drive's interval."""
    v = np.asarray(velocity, dtype=float)
    if v.size == 0 or not interval_s > 0:
        return np.zeros(v.shape[1] if v.ndim == 2 else 3)
    length = max(min(SPEED_SCALE_TIME_S / interval_s, float(n_intervals)), 1.0)
    return SPEED_SCALE_PRIOR * np.sqrt(np.mean(v * v, axis=0) * length)


@dataclass(frozen=True)
class LevelUncertainty:
    """One noise level: ``estimate`` the data's point estimate, ``log_sd`` its sd(log sigma),
    ``upper`` the upper end of what the data allow, ``cap`` the bound it is capped by (inf for
    none), ``value`` what the model takes, ``determined`` and ``why`` (words, for reports)."""

    name: str
    estimate: float
    log_sd: float
    missing_fraction: float
    value: float
    determined: bool
    why: str
    cap: float = math.inf

    def to_dict(self) -> dict:
        def num(x):
            return float(x) if math.isfinite(x) else None

        return {"name": self.name, "estimate": float(self.estimate), "log_sd": num(self.log_sd),
                "missing_fraction": float(self.missing_fraction), "value": float(self.value),
                "determined": bool(self.determined), "cap": num(self.cap), "why": self.why}


def conservative_level(name: str, estimate: float, log_sd: float, missing: float, cap: float,
                       cap_words: str, floor: float = 0.0, bound: bool = False,
                       undetermined_log_sd: float = UNDETERMINED_LOG_SD) -> LevelUncertainty:
    """The value the model takes for one level (module docstring): the estimate where it is
    determined; else ``estimate exp(UPPER_Z log_sd)`` capped by ``cap`` (``cap_words`` says
    what it is), never below the estimate or ``floor``. With ``bound``, ``cap`` is an upper
    bound the data themselves give, and an undetermined level takes it (EM's estimate of an
    undetermined level is biased low by more than its sd says: module docstring).
    ``undetermined_log_sd`` is where the line is drawn (default :data:`UNDETERMINED_LOG_SD`)."""
    estimate = float(estimate)
    if log_sd <= undetermined_log_sd:
        value = max(estimate, floor)
        return LevelUncertainty(name, estimate, log_sd, missing, value, True,
                                f"determined (sd of log sigma {log_sd:.2f})", cap)
    upper = cap if bound and math.isfinite(cap) else estimate * math.exp(min(UPPER_Z * log_sd, 50.0))
    value = max(min(upper, cap), estimate, floor)
    if value == min(upper, cap) and upper < cap:
        took = f"the upper end of what the data allow (x exp({UPPER_Z:g} sd) = {upper:.3g})"
    elif value == cap:
        took = (f"{cap_words} ({cap:.3g})" if bound else
                f"{cap_words} ({cap:.3g}; the data allow up to {upper:.3g})")
    elif value == floor and floor > estimate:
        took = f"its floor {floor:.3g}"
    else:
        took = f"the estimate ({cap_words} allows no more)"
    why = (f"undetermined: sd of log sigma {log_sd:.2f} (the data leave {100 * missing:.0f} % "
           f"of it to the posterior); takes {took}")
    return LevelUncertainty(name, estimate, log_sd, missing, value, False, why, cap)


__all__ = ["LevelUncertainty", "conservative_level", "log_sigma_sd", "missing_fraction",
           "speed_scale_prior_sigma", "white_sigma_bound", "MAX_LOG_SD",
           "SPEED_SCALE_PRIOR", "SPEED_SCALE_TIME_S", "UNDETERMINED_LOG_SD", "UPPER_Z"]
