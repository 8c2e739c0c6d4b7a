"""Identify the noise model from the data: expectation-maximisation around the batch smoother.

The model (issue 12) is what every estimator assumes about the measurements: the velocity
noise ``W = diag(sigma_v^2, sigma_g^2)`` per axis, the stereo pixel noise ``sigma_px``, a
constant gyro bias or none, and which velocity sample covers an interval. Ground truth is
never used. Each EM iteration

1. *E-step*: solves the smoother with the current model (:func:`graph.smoother.solve_smoother`,
   from the last E-step's solution: one round, its outlier test made there, its cameras kept
   where the extrinsic moves) and takes the Laplace approximation of the posterior: the MAP trajectory and landmarks, and
   the marginal covariances of each pose and of each pair of consecutive poses
   (:func:`graph.marginals.pose_chain_covariances`, the Takahashi recursion);
2. *M-step*: re-estimates each noise level from the expected squared residuals of its factors,
   ``E[w w^T] = w_hat w_hat^T + C Sigma C^T``. For a motion factor ``w`` is the twist noise of
   the interval, ``w = (tau J)^-1 Log(Delta^-1 X_k^-1 X_k+1)`` (``J`` the right Jacobian of the
   measured twist), and ``C`` its Jacobian on ``(X_k, X_k+1)``; the posterior term restores the
   degrees of freedom the smoother took from the residuals (on an interval that vision does not
   constrain the residual is zero, and all of the noise is in ``C Sigma C^T``). For the pixels
   the same correction is the stereo factors' share of the parameters (their leverage):
   ``sigma_px^2 = sum r^2 / (N - (n_params - leverage of the other factors))``;

until the sigmas change by less than ``rtol`` (SQUAREM-accelerated). The gyro bias is kept when
the data support it by the Bayesian information criterion: the likelihood ratio of the bias
against none must exceed ``3 ln n`` (3 parameters, n intervals; a chi-square test at a fixed
level, ``BIAS_TEST_LEVEL``, is reported beside it). BIC grows stricter with the drive's length:
on a long drive with clean velocities, small misfits of the model (an extrinsic the drive
barely determines, non-white velocity errors) pass a 99 % chi-square test as a "bias" of a
fraction of a mrad/s that, subtracted, makes dead reckoning worse (docs/findings.md). The
velocity pairing is the one under which the samples need the least noise (``sum log sigma^2``
over the six axes, per sample: the likelihood of white samples): a wrong pairing adds the
twist's change over an interval to the noise. The pairing the settings give is kept unless
another needs clearly less noise (``PAIRING_MARGIN``). The Laplace approximation
``-2 log p(z) ~ chi2 + sum log det Sigma_factor + log det H`` is reported too, but not used: it
credits "mean" with its halved variance and ignores the correlation of its intervals, so it
prefers "mean" on data made with any pairing.

The file's extrinsic is replaced only where the data refute it twice: in sample (its Wald
statistic under the identified one's covariance passes BIC) and out of sample (the extrinsic
fitted without each 10 s stretch predicts that stretch better, in sum, than the file's:
:func:`graph.extrinsic.extrinsic_fold_gain`, issue 34 item 2). The gyro bias likewise
(:func:`graph.gyro_bias.bias_fold_gain`). A term that only fits what is particular to the data
at hand (one stretch's slow error, a few tracks' correlated pixels) passes the first and fails
the second.

After EM, the pixel errors' correlation along tracks is measured on the final solution's
residuals (:mod:`graph.track_correlation`): where a tracker's errors drift along a track, the
model carries their correlation time tau and the estimators use the long-run pixel sigma
``sigma_px sqrt(tau)``. EM itself fits the white model to the residuals; the landmark fit keeps
part of a slow error out of them, so both tau and the sigma of one observation are corrected
for it (indirect inference on the drive's own tracks, :func:`graph.track_correlation.
landmark_fit_correction`).

With the "mean" pairing each interval's noise is the mean of two samples: its variance is half
a sample's. The identified model reports per-sample sigmas (the physical quantity the simulator
and the data's README speak of); :func:`ekf.model.interval_sigma_factor` converts, and
:func:`ekf.model.model_config` gives the estimators the interval sigmas EM fitted.

Known limits. With the "mean" pairing, adjacent intervals share a sample, so their noises are
correlated (0.5); the factors treat them as independent. Where vision constrains the motion
well the fit is the interval variance; where it does not (low-noise velocities, weakly
observed axes), EM partly fits the drift of the sum, whose variance is a sample's, and the
per-sample sigma comes out high (simulation, 0.05 m/s: vertical velocity and roll rate
20-30 % high; 0.5 m/s: within 7 %), and data made with "mean" at 0.05 m/s is identified as
"next". A velocity-noise state per sample would model it exactly. With clean velocities (0.05
m/s) and short drives, vision barely resolves the velocity noise (a 0.1 s interval moves 5 mm
from it): EM then creeps towards small sigmas for many steps without converging.

The streams' time offsets (issue 39, :mod:`graph.time_offset`; with ``time_offsets``, which
`vislam calibrate --time-offsets` sets and `vislam bench` does not). After the extrinsic's
decision, the score of each stream's offset against the camera is taken from the solution's
motion residuals (the offset enters each motion factor linearly through the stream's own
rate); a stream whose score statistic passes BIC (``ln n``) is moved onto the camera's clock
and EM continues there, warm-started, for a few safeguarded Gauss-Newton and secant steps
until the offsets move by less than a millisecond; everything after (the bias's value, correlations,
levels) works on the moved streams. The offsets are measured with the pairing chosen before
them, and the bias's decision is made before them too: a removed offset lowers the gyro's white
sigma, and with it BIC's bar for a "bias" that is a slow error rather than a constant. Where no
stream passes, nothing changes: the model is what it was without the test.

What the drive cannot determine (issue 34, :mod:`graph.parameter_uncertainty`). Each white
level's uncertainty is ``sd(log sigma) = 1 / sqrt(2 n (1 - r))``, ``r`` the share of the final
E-step's expected squared residuals that the posterior holds over the intervals vision spans
(``n`` of them; a gap between tracks informs nothing). Where it exceeds
``UNDETERMINED_LOG_SD`` the model takes the samples' own second-difference bound instead of
EM's estimate (never less), the level is named in ``noise_undetermined``, and the long-run
levels are measured from there (:mod:`graph.motion_correlation`, with the same rule and a
prior). The gyro bias's sigma is a sample's sigma over the square root of that information.

Tracks that return after a gap (a loop's, a room's) are identified as the per-frame filters
see them (:func:`ekf.driver.carry_tracks`): a landmark is carried through its gap while at
most ``ekf.driver.MAX_CARRIED`` are in gaps at once (a room's few dozen), and the rest return
as new landmarks. The noise levels are in the residuals next to each observation, not in the
loop a returning landmark closes, while such a landmark ties poses far apart and makes every
E-step's solve and marginals cost what the whole loop costs (``returning_tracks_split``
counts the returns identified as new landmarks; the estimators keep them as one).

A drive longer than ``MAX_FRAMES`` (1,500 frames, two and a half minutes at 10 Hz) is
identified on its central ``MAX_FRAMES`` frames (``ModelFit.frames``): that is 1,500 intervals
for each white level (``sd(log sigma)`` about ``1 / sqrt(2 n)``, 2 %, where vision constrains
every interval) and 30 blocks of 5 s for the slow errors, while each E-step costs what the
whole drive costs. The model holds for the whole drive as far as its noise is stationary;
``max_frames=None`` (``vislam calibrate --max-frames 0``) reads every frame.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import gtsam
import numpy as np
from vislam.ekf import chi_square as chi2

from vislam.ekf.config import VELOCITY_PAIRINGS, FilterConfig
from vislam.ekf.conventions import estimate_cov_to_gtsam
from vislam.ekf.driver import carry_tracks
from vislam.ekf.errors import EstimationError
from vislam.ekf.model import interval_sigma_factor, long_run_pixel_sigma, with_extrinsic, without_radial
from vislam.ekf.sequence import Sequence
from vislam.graph.parameter_uncertainty import (MAX_LOG_SD, conservative_level, log_sigma_sd,
                                                 missing_fraction, speed_scale_prior_sigma,
                                                 white_sigma_bound)
from vislam.graph.pose_conversions import interval_jacobians, to_pose3
from vislam.graph.settings import SmootherSettings

log = logging.getLogger(__name__)

#: Level of the chi-square test reported beside the BIC decision on a constant gyro bias.
BIAS_TEST_LEVEL = 0.99

#: The most frames identification reads (module docstring): the drive's central stretch of
#: this many frames; ``max_frames=None`` reads the whole drive.
MAX_FRAMES = 1500


def identification_frames(n_frames: int, max_frames: int | None = MAX_FRAMES) -> tuple[int, int]:
    """The frames ``[start, stop)`` identification reads: the whole drive, or its central
    ``max_frames``."""
    if max_frames is None or n_frames <= max_frames:
        return 0, n_frames
    start = (n_frames - max_frames) // 2
    return start, start + max_frames


@dataclass
class NoiseStatistics:
    """One E-step's expected sufficient statistics and likelihood terms."""

    motion_sq: np.ndarray  # (6,) sum over intervals of E[w_i^2], GTSAM order [rot; trans]
    n_intervals: int
    motion_leverage: float  # sum over motion factors of tr(Sigma_k^-1 C P C^T)
    pixel_sq: float  # sum of r_uL^2 + r_uR^2 + 2 r_v^2 (r_v carries half the variance)
    n_pixel_dims: int
    pixel_leverage: float
    chi2: float  # 2 x the graph's error at the solution
    log_det_noise: float  # sum of log det of every Gaussian factor's covariance
    log_det_information: float  # log det H (Laplace term)
    #: (6,) over the intervals vision spans (a track seen at both ends), the sum of E[w_i^2]
    #: and the posterior's part of it (diag C Sigma C^T): what vision leaves open there; their
    #: number. The other intervals (gaps) carry no information from the data on the noise
    #: (only the velocity, and the twist-smoothness prior, span them).
    spanned_sq: np.ndarray | None = None
    spanned_posterior: np.ndarray | None = None
    n_spanned: int = 0
    #: (T-1, 6) each interval's motion residual and (T-1, 6, 6) its posterior covariance
    #: (motion_residuals): what the time offsets are scored from (graph.time_offset)
    motion_w: np.ndarray | None = None
    motion_cw: np.ndarray | None = None

    @property
    def interval_sigma(self) -> np.ndarray:
        """(6,) per-interval twist noise sigma, GTSAM order [rot; trans]."""
        return np.sqrt(self.motion_sq / max(self.n_intervals, 1))

    @property
    def pixel_sigma(self) -> float:
        dof = max(self.n_pixel_dims - self.pixel_leverage, 1.0)
        return float(np.sqrt(self.pixel_sq / dof))

    @property
    def minus_two_log_likelihood(self) -> float:
        """Laplace approximation of -2 log p(z | model), up to a constant."""
        return self.chi2 + self.log_det_noise + self.log_det_information


@dataclass
class ModelFit:
    """What :func:`identify_model` found (sigmas per sample, IMU body axes x, y, z)."""

    velocity_sigma: np.ndarray  # (3,) m/s
    gyro_sigma: np.ndarray  # (3,) rad/s
    pixel_sigma: float
    velocity_sigma_std: np.ndarray  # (3,) standard deviation of the estimate
    gyro_sigma_std: np.ndarray
    pixel_sigma_std: float
    pairing: str
    gyro_bias: np.ndarray | None  # (3,) rad/s, None when the data supports none
    gyro_bias_std: np.ndarray | None
    cam_T_imu: np.ndarray  # (4, 4) identified (or the file's when not estimated)
    file_cam_T_imu: np.ndarray  # (4, 4) the data file's
    #: (6, 6) covariance of theta = [dt; r] (graph.extrinsic), None when not estimated
    cam_T_imu_cov: np.ndarray | None = None
    cam_T_imu_undetermined: tuple[str, ...] = ()
    #: the file's extrinsic against the identified one: statistic, dof, threshold, decision
    extrinsic_test: dict = field(default_factory=dict)
    bias_test: dict = field(default_factory=dict)
    #: the pixels' radial lens term (graph.radial), None when the data support none
    radial_k1: float | None = None
    radial_k1_std: float | None = None
    #: the radial term against none: estimate, statistic, threshold, decision, profile
    radial_test: dict = field(default_factory=dict)
    #: the velocity and gyro streams' time offsets (s, stamps late against the camera's;
    #: graph.time_offset), None when the data support none, and their sigmas
    velocity_time_offset: float | None = None
    velocity_time_offset_std: float | None = None
    gyro_time_offset: float | None = None
    gyro_time_offset_std: float | None = None
    #: per stream: estimate, sigma, statistic, decision; the threshold (BIC) and steps
    time_offset_test: dict = field(default_factory=dict)
    #: the pixel errors' integrated correlation time along a track (graph.track_correlation),
    #: None when the data support none
    pixel_correlation_time: float | None = None
    #: its estimate, lag correlations, statistic, threshold, decision
    pixel_correlation_test: dict = field(default_factory=dict)
    #: long-run over white interval variance of the velocity and gyro noise per axis
    #: (graph.motion_correlation), None when the data support none
    velocity_correlation_time: tuple[float, float, float] | None = None
    gyro_correlation_time: tuple[float, float, float] | None = None
    #: its blocks, long-run sigmas, variance ratios, threshold, decision per axis
    motion_correlation_test: dict = field(default_factory=dict)
    #: pairing -> sum over the 6 axes of log(per-sample sigma^2) (lower is better: the decision)
    pairing_scores: dict = field(default_factory=dict)
    #: pairing -> Laplace -2 log L under independent intervals (reported; it favours "mean",
    #: whose halved variance it credits while ignoring the correlation of its intervals)
    pairing_laplace: dict = field(default_factory=dict)
    #: per white noise level (GTSAM order: gyro x y z, velocity x y z), how well the drive
    #: determines it and the value taken (graph.parameter_uncertainty.LevelUncertainty); the
    #: long-run levels are in motion_correlation_test["levels"]
    noise_levels: tuple = ()
    #: names (ekf.model.NOISE_LEVELS) of the noise levels the drive cannot determine, which
    #: take a conservative value
    noise_undetermined: tuple[str, ...] = ()
    iterations: int = 0
    converged: bool = False
    seconds: float = 0.0
    #: the frames ``[start, stop)`` of the drive the model was identified on, and its length
    frames: tuple[int, int] = (0, 0)
    n_frames: int = 0
    #: returns of tracks identified as new landmarks (module docstring; ekf.driver.carry_tracks)
    returning_tracks_split: int = 0
    #: the drift check of the final model (graph.drift_check.DriftCheck.to_dict, its widening
    #: and its report lines); empty when not run
    drift_test: dict = field(default_factory=dict)
    #: the factor every noise level of the model was widened by where the check failed
    noise_widening: float = 1.0
    solution: object = None  # graph.smoother.SmootherSolution under the identified model
    config: FilterConfig | None = None  # the identified interval sigmas and pairing

    @property
    def cam_T_imu_sigma(self) -> np.ndarray | None:
        """(6,) standard deviations of [dt; r] (inf where undetermined), None if not estimated."""
        if self.cam_T_imu_cov is None:
            return None
        return self.to_model("").extrinsic_sigmas()

    def to_model(self, source: str):
        """The :class:`ekf.model.Model` (per-sample sigmas; the file's extrinsic under [file])."""
        from vislam.ekf.model import EXTRINSIC_COMPONENTS, Model

        log_sd = None if not self.noise_levels else tuple(
            float(min(lv.log_sd, MAX_LOG_SD)) for lv in self.noise_levels)
        sigma = None if self.cam_T_imu_cov is None else tuple(
            float(x) for x in np.sqrt(np.diag(self.cam_T_imu_cov)))
        c = float(self.noise_widening)
        return Model(
            velocity_sigma=tuple(c * float(x) for x in self.velocity_sigma),
            gyro_sigma=tuple(c * float(x) for x in self.gyro_sigma),
            pixel_sigma=c * float(self.pixel_sigma),
            velocity_pairing=self.pairing,
            cam_T_imu=np.array(self.cam_T_imu),
            gyro_bias=None if self.gyro_bias is None else tuple(map(float, self.gyro_bias)),
            gyro_bias_sigma=None if self.gyro_bias_std is None else tuple(map(float, self.gyro_bias_std)),
            radial_k1=None if self.radial_k1 is None else float(self.radial_k1),
            radial_k1_sigma=None if self.radial_k1 is None else float(self.radial_k1_std),
            velocity_time_offset=self.velocity_time_offset,
            velocity_time_offset_sigma=self.velocity_time_offset_std,
            gyro_time_offset=self.gyro_time_offset,
            gyro_time_offset_sigma=self.gyro_time_offset_std,
            pixel_correlation_time=self.pixel_correlation_time,
            velocity_correlation_time=self.velocity_correlation_time,
            gyro_correlation_time=self.gyro_correlation_time,
            cam_T_imu_sigma=sigma,
            cam_T_imu_undetermined=tuple(n for n in EXTRINSIC_COMPONENTS
                                         if n in self.cam_T_imu_undetermined),
            velocity_sigma_log_sd=log_sd[3:] if log_sd is not None else None,
            gyro_sigma_log_sd=log_sd[:3] if log_sd is not None else None,
            noise_undetermined=self.noise_undetermined,
            source=source,
            file={"cam_T_imu": np.array(self.file_cam_T_imu)},
        )


def motion_residuals(poses: np.ndarray, deltas: np.ndarray, twist: np.ndarray, tau: np.ndarray,
                     pose_cov: np.ndarray, pair_cov: np.ndarray):
    """Per interval k of a solved smoother, in GTSAM's rotation-first order: the twist noise
    ``w = (tau J)^-1 Log(Delta^-1 X_k^-1 X_k+1)`` (n, 6), its posterior covariance
    ``C Sigma C^T`` (n, 6, 6) with ``C`` its Jacobian on ``(X_k, X_k+1)`` and ``Sigma`` their
    joint marginal (``pose_cov``, ``pair_cov``: :func:`graph.marginals.pose_chain_covariances`),
    and ``tau J`` (n, 6, 6), ``J`` the right Jacobian of the measured twist ``Delta``."""
    n = max(poses.shape[0] - 1, 0)
    w = np.zeros((n, 6))
    cw = np.zeros((n, 6, 6))
    scale = interval_jacobians(twist[:n], tau[:n])
    if n == 0:
        return w, cw, scale
    # The same arithmetic as one interval at a time (numpy's stacked inv and matmul are the
    # per-matrix LAPACK/BLAS calls), without a Python round trip per small array.
    M = np.linalg.inv(scale)
    err = np.empty((n, 6))
    C = np.zeros((n, 6, 12))
    C[:, :, 6:] = np.eye(6)
    x1 = to_pose3(poses[0])
    for k in range(n):
        x0, x1 = x1, to_pose3(poses[k + 1])
        rel = x0.between(x1)
        err[k] = gtsam.Pose3.Logmap(to_pose3(deltas[k]).between(rel))
        C[k, :, :6] = -rel.inverse().AdjointMap()
    w[:] = (M @ err[:, :, None])[:, :, 0]
    C = M @ C
    block = np.empty((n, 12, 12))  # the joint marginal of (X_k, X_k+1)
    block[:, :6, :6] = pose_cov[:n]
    block[:, :6, 6:] = pair_cov[:n]
    block[:, 6:, :6] = np.swapaxes(pair_cov[:n], 1, 2)
    block[:, 6:, 6:] = pose_cov[1:n + 1]
    cw[:] = C @ block @ np.swapaxes(C, 1, 2)
    return w, cw, scale


def noise_statistics(solution, config: FilterConfig) -> NoiseStatistics:
    """The E-step: expected squared residuals of the motion and stereo factors of a solved
    smoother (:class:`graph.smoother.SmootherSolution`) and the Laplace likelihood terms."""
    from vislam.graph.factors import stereo_residuals, unconstrained_intervals
    from vislam.graph.marginals import pose_chain_covariances

    problem, values = solution.problem, solution.values
    T = solution.poses.shape[0]
    pose_cov, pair_cov, log_det_h = pose_chain_covariances(solution.linearised()[1], T,
                                                           with_log_det=True)
    W_g = estimate_cov_to_gtsam(config.velocity_cov)  # what graph.factors.relative_motions uses
    W_inv = np.linalg.inv(W_g)
    w, cw, scale = motion_residuals(solution.poses, solution.deltas, solution.twist,
                                    solution.tau, pose_cov, pair_cov)
    # Summed interval by interval, in order (cumulative sums), as a loop over k would.
    motion_sq = np.zeros(6)
    spanned = ~unconstrained_intervals(problem.rows, T)
    spanned_sq = np.zeros(6)
    spanned_posterior = np.zeros(6)
    leverage = 0.0
    log_det_noise = 0.0
    if T > 1:
        terms = w * w + np.diagonal(cw, axis1=1, axis2=2)
        motion_sq = np.cumsum(terms, axis=0)[-1]
        # adding the zeros of the other intervals changes no sum: as the loop over k would
        spanned_sq = np.cumsum(np.where(spanned[:, None], terms, 0.0), axis=0)[-1]
        spanned_posterior = np.cumsum(np.where(spanned[:, None], np.diagonal(cw, axis1=1, axis2=2),
                                               0.0), axis=0)[-1]
        leverage = float(np.cumsum(np.trace(W_inv @ cw, axis1=1, axis2=2))[-1])
        log_det_noise = float(np.cumsum(
            np.linalg.slogdet(scale @ W_g @ np.swapaxes(scale, 1, 2))[1])[-1])
    res, _ = stereo_residuals(solution.poses, solution.landmarks, solution.calibration,
                              problem.rows)
    pixel_sq = float(np.sum(res[:, 0] ** 2 + res[:, 1] ** 2 + 2.0 * res[:, 2] ** 2))
    n_dims = 3 * len(problem.rows)
    n_params = 6 * T + 3 * len(problem.landmark_tracks)
    prior_leverage = float(np.trace(np.linalg.solve(solution.pose_prior_cov, pose_cov[0])))
    # The twist-smoothness factors (gap intervals only) take at most their dimension each.
    other = leverage + prior_leverage + 6.0 * solution.n_smoothness
    s2 = config.pixel_sigma ** 2
    log_det_noise += len(problem.rows) * float(np.log(s2 * s2 * s2 / 2.0))
    return NoiseStatistics(
        motion_sq=motion_sq, n_intervals=T - 1, motion_leverage=leverage,
        pixel_sq=pixel_sq, n_pixel_dims=n_dims,
        pixel_leverage=float(np.clip(n_params - other, 0.0, n_dims - 1.0)),
        chi2=2.0 * float(problem.graph.error(values)), log_det_noise=log_det_noise,
        log_det_information=float(log_det_h), spanned_sq=spanned_sq,
        spanned_posterior=spanned_posterior, n_spanned=int(np.count_nonzero(spanned)),
        motion_w=w, motion_cw=cw,
    )


def _sigmas(cfg: FilterConfig) -> np.ndarray:
    """The 7 noise levels EM moves, as logs: velocity (3), gyro (3), pixel."""
    return np.log(np.r_[cfg.velocity_sigmas, cfg.gyro_sigmas, cfg.pixel_sigma])


def _with_sigmas(cfg: FilterConfig, theta: np.ndarray) -> FilterConfig:
    s = np.exp(np.clip(theta, np.log(1e-9), np.log(1e2)))
    return cfg.replace(velocity_sigma=tuple(map(float, s[:3])), gyro_sigma=tuple(map(float, s[3:6])),
                       pixel_sigma=float(s[6]))


@dataclass
class EMResult:
    """What :func:`em_noise` converged to under one velocity pairing."""

    config: FilterConfig  # the interval sigmas the solution was solved with (within rtol of stats')
    stats: NoiseStatistics
    solution: object  # graph.smoother.SmootherSolution at the converged model
    steps: int
    converged: bool
    cam_T_imu: np.ndarray  # the extrinsic in use (identified, or the file's)
    extrinsic: object | None  # graph.extrinsic.ExtrinsicStep at the solution, None if not estimated


#: E-steps a pairing other than the first gets before the pairings are compared: one, the
#: M-step from the first pairing's converged model (noise and extrinsic), warm-started. The
#: pairing that wins by PAIRING_MARGIN is then iterated to convergence.
PAIRING_STEPS = 1
#: LM's relative error tolerance inside EM, at least: EM stops at 1 % changes of the sigmas,
#: far above what 1e-4 of the error moves them; fewer LM iterations per E-step.
EM_RELATIVE_ERROR_TOL = 1e-4

#: Another pairing replaces the one the settings give only if it explains the velocities
#: with clearly less noise: per-sample sigmas 5 % lower on average (in the score, the sum over
#: 6 axes of log sigma^2: 12 log 1.05). Below that the pairings are interchangeable for the
#: estimators, and a forward lever arm of about speed x interval / 2 mimics the half-interval
#: time shift between two pairings, so a small score difference is no evidence.
PAIRING_MARGIN = 12.0 * float(np.log(1.05))

#: Level of the chi-square test of the file's extrinsic against the identified one, reported
#: beside the BIC decision (``k ln n``, k determined components, n stereo observations): the
#: Wald statistic runs about twice its chi-square expectation on short simulated drives (mean
#: 10.5 for 3-5 dof over 12 drives of 80-300 frames, seeds 0-3), so the 99 % test refuted the
#: file's (true) extrinsic on 3 of them, and estimators run under an extrinsic moved by 3 sigma
#: were then off the truth by far more than their covariance (pose NEES about 6000 on an
#: 80-frame drive). The gyro bias is decided by BIC for the same kind of reason.
EXTRINSIC_TEST_LEVEL = 0.99

#: EM has converged when no log sigma moves by more than ``rtol`` and no determined extrinsic
#: component by more than this many of its standard deviations.
EXTRINSIC_STEP_TOL = 0.1


def em_noise(seq: Sequence, config: FilterConfig, settings: SmootherSettings, *,
             max_iterations: int = 12, rtol: float = 0.01,
             extrinsic: bool = True, cam_T_imu: np.ndarray | None = None,
             warm_start=None) -> EMResult:
    """EM for the noise levels with the pairing and bias treatment of ``config`` and
    ``settings`` fixed, accelerated by SQUAREM (Varadhan and Roland 2008: two EM steps give a
    direction, a step along it, then one EM step from there; on a drive where vision leaves
    much of the motion noise to the posterior, plain EM moves a few % per iteration).
    With ``extrinsic`` every E-step also takes the profile Gauss-Newton step of the camera-IMU
    extrinsic (:mod:`graph.extrinsic`) from the same solution (an ECM scheme: the extrinsic
    is maximised conditionally, the noise levels by their M-step). ``cam_T_imu`` the
    extrinsic to start from (default the file's); ``warm_start`` a solution of the same drive
    under a nearby model (:func:`graph.smoother.solve_smoother`)."""
    from vislam.graph.extrinsic import extrinsic_step, perturb_cam_T_imu
    from vislam.graph.smoother import solve_smoother

    start = seq.calibration.cam_T_imu if cam_T_imu is None else cam_T_imu
    state = {"solution": warm_start, "steps": 0, "cam_T_imu": np.array(start, dtype=float),
             "extrinsic": None}

    def solve(cfg: FilterConfig):
        previous = state["solution"]
        return solve_smoother(with_extrinsic(seq, state["cam_T_imu"]), cfg, settings,
                              warm_start=previous)

    def em_step(theta: np.ndarray) -> np.ndarray:
        cfg = _with_sigmas(config, theta)
        solution = solve(cfg)
        stats = noise_statistics(solution, cfg)
        state.update(solution=solution, steps=state["steps"] + 1, cfg=cfg, stats=stats,
                     theta_in=np.array(theta))
        if extrinsic:
            step = extrinsic_step(solution, state["cam_T_imu"], cfg)
            state["extrinsic"] = step
            state["cam_T_imu"] = perturb_cam_T_imu(state["cam_T_imu"], step.step)
        g = stats.interval_sigma  # [rot; trans]
        out = np.log(np.r_[g[3:], g[:3], stats.pixel_sigma])
        state["theta_out"] = out
        log.info("EM step %d (%s): velocity %s, gyro %s, pixel %.3f%s", state["steps"],
                 config.velocity_pairing, np.round(g[3:], 4), np.round(g[:3], 5),
                 stats.pixel_sigma, "" if not extrinsic else
                 f", extrinsic step {state['extrinsic'].step_in_sigmas:.2f} sigma")
        return out

    def settled(a: np.ndarray, b: np.ndarray) -> bool:
        ext = state["extrinsic"]
        return (np.max(np.abs(a - b)) < rtol
                and (ext is None or ext.step_in_sigmas < EXTRINSIC_STEP_TOL))

    theta = _sigmas(config)
    converged = False
    while state["steps"] + 3 <= max_iterations:
        t1 = em_step(theta)
        if settled(t1, theta):
            theta, converged = t1, True
            break
        t2 = em_step(t1)
        r, v = t1 - theta, (t2 - t1) - (t1 - theta)
        nv = float(np.linalg.norm(v))
        alpha = -float(np.linalg.norm(r)) / nv if nv > 0 else -1.0
        alpha = min(alpha, -1.0)  # -1 is plain EM (two steps); below it extrapolates
        extrapolated = theta - 2.0 * alpha * r + alpha * alpha * v
        t3 = em_step(extrapolated)
        if settled(t3, t2):
            theta, converged = t3, True
            break
        theta = t3
    if converged and settled(state["theta_out"], state["theta_in"]):
        # The last E-step was solved at (within rtol of) its own output: it is the final
        # solution (its config is the one solved with; its statistics give the sigmas).
        return EMResult(config=state["cfg"], stats=state["stats"], solution=state["solution"],
                        steps=state["steps"], converged=True, cam_T_imu=state["cam_T_imu"],
                        extrinsic=state["extrinsic"])
    cfg = _with_sigmas(config, theta)
    solution = solve(cfg)
    stats = noise_statistics(solution, cfg)
    final = extrinsic_step(solution, state["cam_T_imu"], cfg) if extrinsic else None
    return EMResult(config=cfg, stats=stats, solution=solution, steps=state["steps"] + 1,
                    converged=converged, cam_T_imu=state["cam_T_imu"], extrinsic=final)


def identify_model(seq: Sequence, config: FilterConfig = FilterConfig(),
                   settings: SmootherSettings = SmootherSettings(), *,
                   pairings: tuple[str, ...] = VELOCITY_PAIRINGS,
                   max_iterations: int = 12, rtol: float = 0.01,
                   extrinsic: bool = True, radial: bool = True,
                   time_offsets: bool = False, max_frames: int | None = MAX_FRAMES,
                   drift: bool = True) -> ModelFit:
    """The model of ``seq`` by EM (module docstring): per-axis velocity and gyro sigma, pixel
    sigma, the velocity pairing with the largest likelihood, a gyro bias when a
    likelihood-ratio supports it (BIC), (``extrinsic``) the camera-IMU extrinsic with its
    covariance and (``radial``) a radial lens term of the pixels when its Wald statistic
    passes BIC (:mod:`graph.radial`), and (``time_offsets``) the velocity and gyro streams'
    time offsets against the camera where the data support them (BIC, :mod:`graph.time_offset`).
    On a drive longer than ``max_frames``, its central ``max_frames`` frames only
    (:func:`identification_frames`). ``drift``: the drift check of the final model, which
    widens every noise level where the drive's stretches disagree with it
    (:mod:`graph.drift_check`). ``config`` gives the starting point and every other filter setting; ``settings`` the
    smoother's."""
    from vislam.graph.radial import radial_profile
    from vislam.graph.smoother import solve_smoother
    from vislam.graph.track_correlation import solution_track_correlation

    t0 = time.perf_counter()
    if seq.n_frames < 3:
        raise EstimationError("calibrate: needs at least 3 frames")
    if max_frames is not None and max_frames < 3:
        raise EstimationError(f"calibrate: max_frames must be at least 3, got {max_frames}")
    n_frames = seq.n_frames
    frames = identification_frames(n_frames, max_frames)
    if frames != (0, n_frames):
        seq = seq.window(*frames)
    seq, n_split = carry_tracks(seq)  # returning tracks as the filters see them (docstring)
    given_seq = seq  # before the model's radial term and offsets: what the estimators are given
    # Every round to the same tolerance: the bias and pairing decisions compare likelihoods
    # of nearby solves, and a looser rejection round moved them across the BIC threshold
    # (docs/findings.md).
    em_tol = max(settings.relative_error_tol, EM_RELATIVE_ERROR_TOL)
    with_bias = settings.replace(gyro_bias="alternate", relative_error_tol=em_tol,
                                 rejection_relative_error_tol=em_tol)
    # EM to convergence under the pairing given; the others from there, PAIRING_STEPS warm
    # E-steps each, and one that wins by PAIRING_MARGIN continued to convergence.
    fits: dict[str, EMResult] = {}
    given = config.velocity_pairing
    first = given if given in pairings else pairings[0]
    pairings = (first, *[p for p in pairings if p != first])
    fits[first] = em_noise(seq, config.replace(velocity_pairing=first), with_bias,
                           max_iterations=max_iterations, rtol=rtol, extrinsic=extrinsic)
    base = fits[first]
    for pairing in pairings[1:]:
        f = interval_sigma_factor(pairing) / interval_sigma_factor(first)
        start = base.config.replace(
            velocity_pairing=pairing,
            velocity_sigma=tuple(f * x for x in base.config.velocity_sigmas),
            gyro_sigma=tuple(f * x for x in base.config.gyro_sigmas))
        fits[pairing] = em_noise(seq, start, with_bias, max_iterations=PAIRING_STEPS, rtol=rtol,
                                 extrinsic=extrinsic, cam_T_imu=base.cam_T_imu,
                                 warm_start=base.solution)
    laplace = {p: f.stats.minus_two_log_likelihood for p, f in fits.items()}
    # Per-sample noise under each pairing: the one the data was sampled with explains the
    # velocities with the least noise (a wrong one adds the twist's change over an interval).
    per_sample = {p: np.r_[f.stats.interval_sigma[3:], f.stats.interval_sigma[:3]]
                  / interval_sigma_factor(p) for p, f in fits.items()}
    scores = {p: float(2.0 * np.sum(np.log(s))) for p, s in per_sample.items()}
    best = min(scores, key=scores.get)
    if first in scores and scores[first] - scores[best] <= PAIRING_MARGIN:
        best = first  # the data cannot tell them apart: keep the pairing given
    em = fits[best]
    total_steps = sum(f.steps for f in fits.values())
    if best != first and not em.converged:
        em = em_noise(seq, em.config, with_bias, max_iterations=max_iterations, rtol=rtol,
                      extrinsic=extrinsic, cam_T_imu=em.cam_T_imu, warm_start=em.solution)
        total_steps += em.steps
        fits[best] = em

    # The radial lens term, at the identified noise levels and extrinsic. When the data
    # support one, the pixels lose it and EM continues from the solution under it (the pixel
    # sigma and the extrinsic move with it); everything after works on those pixels.
    radial_fit = None
    if radial:
        radial_fit = radial_profile(with_extrinsic(seq, em.cam_T_imu), em.config, with_bias,
                                    em.solution)
        if radial_fit.k1 is not None:
            seq = without_radial(seq, radial_fit.k1)
            em = em_noise(seq, em.config, with_bias, max_iterations=max_iterations, rtol=rtol,
                          extrinsic=extrinsic, cam_T_imu=em.cam_T_imu,
                          warm_start=radial_fit.solution)
            total_steps += em.steps

    # The file's extrinsic is kept unless the data refute it (BIC; see EXTRINSIC_TEST_LEVEL): a
    # poorly determined component moved by a sigma or two costs accuracy and buys nothing.
    extrinsic_test: dict = {}
    if em.extrinsic is not None:
        from vislam.graph.extrinsic import mahalanobis, theta_between

        file_T = np.array(seq.calibration.cam_T_imu)
        d2, k = mahalanobis(theta_between(em.cam_T_imu, file_T), em.extrinsic.covariance,
                            em.extrinsic.determined)
        n_obs = max(em.stats.n_pixel_dims // 3, 2)  # uL, uR, v per stereo observation
        threshold = k * float(np.log(n_obs))  # BIC: k ln n
        # Out of sample (issue 34 item 2): the extrinsic fitted without each 10 s stretch must
        # predict that stretch better, in sum, than the file's does (graph.out_of_sample).
        from vislam.graph.extrinsic import extrinsic_fold_gain

        oos = extrinsic_fold_gain(em.solution, em.cam_T_imu, file_T, em.config)
        keep_file = d2 <= threshold or not oos.improves
        excitation = em.extrinsic.excitation_sigma
        extrinsic_test = {"statistic": d2, "dof": k, "threshold": threshold,
                          "out_of_sample": oos.to_dict(),
                          # dt's sigmas from the drive's rotation alone (graph.extrinsic)
                          "translation_sigma_from_rotation": None if excitation is None
                          else [float(x) for x in excitation],
                          "criterion": f"BIC ({k} ln n, n = {n_obs} stereo observations)",
                          "chi2_threshold": float(chi2.ppf(EXTRINSIC_TEST_LEVEL, k)) if k else 0.0,
                          "level": EXTRINSIC_TEST_LEVEL,
                          "p_value": float(chi2.sf(d2, k)) if k else 1.0,
                          "decision": ("identified (the data refute the file's)" if not keep_file
                                       else "file's kept (the data agree)" if d2 <= threshold
                                       else "file's kept (refuted in sample, but the identified "
                                            "one predicts held-out stretches no better)")}
        if keep_file:
            data_extrinsic = em.extrinsic
            em = em_noise(seq, em.config, with_bias, max_iterations=max_iterations, rtol=rtol,
                          extrinsic=False, warm_start=em.solution)
            total_steps += em.steps
            em.extrinsic = data_extrinsic  # the data's uncertainty about the extrinsic

    # Gyro bias: likelihood ratio of the bias against none, at the identified noise levels.
    # Same stereo rows as the solution (no new outlier round), so that the two chi-squares
    # differ by the bias alone.
    def without_bias(seq: Sequence, em: EMResult):
        return solve_smoother(with_extrinsic(seq, em.cam_T_imu), em.config,
                              settings.replace(gyro_bias="off", rejection_rounds=0),
                              warm_start=em.solution)

    no_bias = without_bias(seq, em)
    chi2_without = 2.0 * float(no_bias.problem.graph.error(no_bias.values))
    chi2_with = em.stats.chi2
    # With the "mean" pairing the interval noises telescope: the mean of n of them has a
    # sample's variance over n, twice what independent intervals would have (f^2 = 1/2), so
    # the ratio statistic is scaled back by f^2 and the bias's sigma is a sample's / sqrt(n).
    f = interval_sigma_factor(best)
    statistic = max(chi2_without - chi2_with, 0.0) * f * f
    chi2_threshold = float(chi2.ppf(BIAS_TEST_LEVEL, 3))
    threshold = 3.0 * float(np.log(max(em.stats.n_intervals, 2)))  # BIC: k ln n
    # Out of sample (issue 34 item 2): the bias fitted without each 10 s stretch must predict
    # that stretch better, in sum, than no bias (graph.gyro_bias.bias_fold_gain); reported in
    # the same units as the statistic (f^2).
    bias_oos = None
    if em.solution.gyro_bias is not None and em.solution.bias_model is None:
        from vislam.graph.gyro_bias import bias_fold_gain

        bias_oos = bias_fold_gain(em.solution)
    in_sample_bias = statistic > threshold and em.solution.gyro_bias is not None
    has_bias = in_sample_bias and (bias_oos is None or bias_oos.improves)

    # The streams' time offsets against the camera (graph.time_offset), with the bias decided
    # above: where the data support one, the streams are moved onto the camera's clock and EM
    # continues from the solution there; everything after works on the moved streams. Where
    # they support none, nothing changes. The bias is decided before them: an offset removed
    # lowers the gyro's white sigma and with it BIC's bar for a "bias" that is a slow error,
    # not a constant (the 2019 edition of 0027: docs/findings.md, "Time offsets").
    offset_fit = None
    if time_offsets:
        from vislam.graph.time_offset import identify_time_offsets

        def refit(shifted_seq: Sequence, previous: EMResult) -> EMResult:
            nonlocal total_steps
            out = em_noise(shifted_seq, previous.config, with_bias, max_iterations=max_iterations,
                           rtol=rtol, extrinsic=False, cam_T_imu=previous.cam_T_imu,
                           warm_start=previous.solution)
            out.extrinsic = previous.extrinsic  # the data's uncertainty about the extrinsic
            total_steps += out.steps
            return out

        offset_fit, em, seq = identify_time_offsets(seq, em, refit)
        if offset_fit.supported.any() and not has_bias:
            no_bias = without_bias(seq, em)  # on the moved streams
    cfg, stats, solution = em.config, em.stats, em.solution
    bias = np.asarray(solution.gyro_bias, dtype=float) if has_bias else None
    bias_std = None

    # The pixel errors' correlation along tracks, from the residuals of the final solution:
    # the estimators then use the long-run pixel sigma (graph.track_correlation).
    # The landmark fit keeps part of a slow error out of the residuals, so the errors' own
    # sigma is EM's white one times the correlation's sigma_factor.
    correlation = solution_track_correlation(solution)
    pixel_sigma = stats.pixel_sigma * correlation.sigma_factor

    # The velocity and gyro errors' slow part, on blocks of the drive under the model the
    # estimators will use (bias as decided, long-run pixel sigma): where it is significant the
    # estimators use the long-run interval sigma (graph.motion_correlation).
    # Where the drive cannot determine a white level, the model takes the upper end of what
    # the data allow (graph.parameter_uncertainty); the long-run levels are measured from there
    # and, where undetermined, take the prior on slow speed errors.
    levels = white_noise_levels(seq, stats, f)
    sample = np.array([lv.value for lv in levels])
    interval = f * sample
    # The bias's uncertainty: a sample's gyro sigma over the square root of the intervals'
    # information on it, which vision gives only where it pins the rotation (the gyro levels'
    # sd(log sigma) = 1 / sqrt(2 n_eff)): sigma_g sqrt(2) sd. Given the trajectory (n_eff = n)
    # it was 25x too small on a sparse drive. The uncertainty of the bias, kept or not (BIC), is
    # a slow error of the whole drive: the gyro's prior, white-equivalent per interval, is its
    # size times sqrt(n).
    n = max(stats.n_intervals, 1)
    bias_sd = sample[:3] * np.sqrt(2.0) * np.array([lv.log_sd for lv in levels[:3]])
    if has_bias:
        bias_std = bias_sd
    prior = np.r_[bias_sd * np.sqrt(n), speed_scale_prior_sigma(
        seq.linear_velocity, float(np.median(np.diff(seq.timestamps))), stats.n_intervals)]
    motion = _motion_correlation(seq, em.cam_T_imu, cfg, settings, em_tol,
                                 solution if has_bias else no_bias, interval, f,
                                 long_run_pixel_sigma(pixel_sigma, correlation.time), has_bias,
                                 prior)
    undetermined = noise_undetermined(levels, motion.levels)

    dof_px = max(stats.n_pixel_dims - stats.pixel_leverage, 1.0)
    sample_std = np.array([lv.estimate * lv.log_sd for lv in levels])
    ext = em.extrinsic
    fit = ModelFit(
        velocity_sigma=sample[3:],
        gyro_sigma=sample[:3],
        pixel_sigma=pixel_sigma,
        velocity_sigma_std=sample_std[3:],
        gyro_sigma_std=sample_std[:3],
        pixel_sigma_std=pixel_sigma / float(np.sqrt(2.0 * dof_px)),
        pairing=best,
        gyro_bias=bias,
        gyro_bias_std=bias_std,
        cam_T_imu=np.array(em.cam_T_imu),
        file_cam_T_imu=np.array(seq.calibration.cam_T_imu),
        cam_T_imu_cov=None if ext is None else ext.covariance,
        cam_T_imu_undetermined=() if ext is None else ext.undetermined,
        extrinsic_test=extrinsic_test,
        bias_test={
            "statistic": statistic, "threshold": threshold, "criterion": "BIC (3 ln n)",
            "chi2_threshold": chi2_threshold, "level": BIAS_TEST_LEVEL,
            "p_value": float(chi2.sf(statistic, 3)),
            "decision": ("bias" if has_bias else "no bias" if not in_sample_bias else
                         "no bias (passes BIC in sample, but fitted without a stretch it predicts "
                         "that stretch no better)"),
            "out_of_sample": None if bias_oos is None else {
                **bias_oos.to_dict(), "gain": bias_oos.gain * f * f,
                "in_sample": bias_oos.in_sample * f * f},
            "estimate": None if solution.gyro_bias is None else list(map(float, solution.gyro_bias)),
        },
        radial_k1=None if radial_fit is None else radial_fit.k1,
        radial_k1_std=None if radial_fit is None else radial_fit.std,
        radial_test={} if radial_fit is None else {
            "estimate": radial_fit.estimate,
            "std": radial_fit.std if np.isfinite(radial_fit.std) else None, **radial_fit.test},
        velocity_time_offset=None if offset_fit is None else offset_fit.offset("velocity"),
        velocity_time_offset_std=None if offset_fit is None else offset_fit.offset_sigma("velocity"),
        gyro_time_offset=None if offset_fit is None else offset_fit.offset("gyro"),
        gyro_time_offset_std=None if offset_fit is None else offset_fit.offset_sigma("gyro"),
        time_offset_test={} if offset_fit is None else offset_fit.to_dict(),
        pixel_correlation_time=correlation.time,
        pixel_correlation_test={**correlation.to_dict(), "white_sigma": stats.pixel_sigma},
        velocity_correlation_time=motion.velocity_time,
        gyro_correlation_time=motion.gyro_time,
        motion_correlation_test=motion.to_dict(),
        pairing_scores=scores,
        pairing_laplace=laplace,
        noise_levels=tuple(levels),
        noise_undetermined=undetermined,
        iterations=total_steps,
        converged=em.converged,
        seconds=time.perf_counter() - t0,
        returning_tracks_split=n_split,
        frames=frames,
        n_frames=n_frames,
        solution=solution,
        config=cfg,
    )
    # Does the model explain its drive? Dead reckoning against the smoother over stretches,
    # under the model as the estimators will use it (graph.drift_check); where the two disagree
    # beyond what it claims, every noise level is widened by one factor until they agree.
    if drift:
        from vislam.graph.drift_check import drift_widening

        check, widening = drift_widening(given_seq, config, fit.to_model(""), settings,
                                         warm_start=solution)
        fit.drift_test = {**check.to_dict(), "widening": widening, "lines": check.lines()}
        fit.noise_widening = widening
    fit.seconds = time.perf_counter() - t0
    return fit


#: The white noise levels' names in GTSAM order (ekf.model.NOISE_LEVELS' first six, reordered).
_WHITE_NAMES = ("gyro_sigma_x", "gyro_sigma_y", "gyro_sigma_z",
                "velocity_sigma_x", "velocity_sigma_y", "velocity_sigma_z")
_LONG_RUN_NAMES = ("gyro_correlation_time_x", "gyro_correlation_time_y", "gyro_correlation_time_z",
                   "velocity_correlation_time_x", "velocity_correlation_time_y",
                   "velocity_correlation_time_z")


def white_noise_levels(seq: Sequence, stats: NoiseStatistics, f: float) -> list:
    """Per white noise level (GTSAM order), :func:`graph.parameter_uncertainty.
    conservative_level` of EM's per-sample sigma: its uncertainty from the posterior's share of
    the final E-step over the intervals vision spans (a gap's noise is known to the data only
    through the velocity itself and the smoothness prior: no information), capped where
    undetermined by the second differences of the measured samples (``f`` the pairing's
    :func:`ekf.model.interval_sigma_factor`)."""
    estimate = stats.interval_sigma / f
    if stats.spanned_sq is None:
        missing, n = np.zeros(6), stats.n_intervals
    else:
        missing, n = missing_fraction(stats.spanned_posterior, stats.spanned_sq), stats.n_spanned
    log_sd = log_sigma_sd(n, missing)
    bound = np.r_[white_sigma_bound(seq.angular_velocity), white_sigma_bound(seq.linear_velocity)]
    return [conservative_level(name, estimate[i], log_sd[i], missing[i], bound[i],
                               "the samples' own second differences", bound=True)
            for i, name in enumerate(_WHITE_NAMES)]


def noise_undetermined(white: list, long_run: tuple) -> tuple[str, ...]:
    """The names (ekf.model.NOISE_LEVELS order) of the undetermined levels."""
    from vislam.ekf.model import NOISE_LEVELS

    names = {n for n, lv in zip(_WHITE_NAMES, white) if not lv.determined}
    names |= {n for n, lv in zip(_LONG_RUN_NAMES, long_run) if not lv.determined}
    return tuple(n for n in NOISE_LEVELS if n in names)


def _motion_correlation(seq: Sequence, cam_T_imu: np.ndarray, cfg: FilterConfig,
                        settings: SmootherSettings, tol: float, solution, interval: np.ndarray,
                        f: float, pixel_sigma: float, has_bias: bool,
                        prior: np.ndarray | None = None):
    """:func:`graph.motion_correlation.motion_correlation` of the identified model: the
    smoother solved with the rows of ``solution``, the long-run ``pixel_sigma`` and the gyro
    bias estimated only where the model has one."""
    from vislam.graph.motion_correlation import motion_correlation
    from vislam.graph.smoother import solve_smoother

    seq = with_extrinsic(seq, cam_T_imu)
    smoother = settings.replace(gyro_bias="alternate" if has_bias else "off", rejection_rounds=0,
                                relative_error_tol=tol, rejection_relative_error_tol=tol)
    base = cfg.replace(pixel_sigma=float(pixel_sigma))

    def solve(sigma: np.ndarray, warm):
        return solve_smoother(seq, base.replace(gyro_sigma=tuple(map(float, sigma[:3])),
                                                velocity_sigma=tuple(map(float, sigma[3:]))),
                              smoother, warm_start=warm)

    return motion_correlation(solve, solution, interval, interval / f, prior)


__all__ = ["ModelFit", "EMResult", "NoiseStatistics", "identify_model", "em_noise",
           "motion_residuals",
           "noise_statistics", "with_extrinsic", "EXTRINSIC_STEP_TOL",
           "BIAS_TEST_LEVEL"]
