"""Identify a raw-IMU drive's IMU noise from the data: EM around the raw-IMU smoother (issue 39
item 2). Ground truth is never used.

**The model.** The smoother's IMU factor of interval ``f`` (GTSAM's ``CombinedImuFactor``,
:mod:`graph.inertial_factors`) has a 15-dim residual ``r_f`` (rotation, position, velocity,
accelerometer bias, gyro bias) with the covariance ``Sigma_f`` that GTSAM's preintegration
propagates from the four continuous-time figures of :class:`ekf.inertial.ImuNoise`. That
propagation (``Sigma <- F Sigma F^T + G Q G^T`` per sample, ``F`` and ``G`` made of the
measurements and the bias, not of the noise) is *linear* in the four squared figures, so with
``theta = (g^2, gw^2, a^2, aw^2) / sheet^2`` (each the ratio of a variance to the data sheet's)::

    Sigma_f(theta) = Sigma_f0 + sum_i theta_i B_fi

exactly, where ``B_fi`` is GTSAM's own covariance of the interval preintegrated with figure
``i`` at the sheet's value and the other three at zero, less ``Sigma_f0`` (all four at zero:
the integration covariance alone; by linearity, from the sheet's figures and each variance
doubled, since the factor takes positive definite covariances only), each read from the noise model of the factor GTSAM makes of
it (:func:`factor_covariance`). Nothing of GTSAM is re-implemented: the bases are five
preintegrations per interval (:func:`noise_bases`; checked against GTSAM's covariance at other
figures in tests/test_inertial_identification.py). The blocks are *not* separable: the gyro
noise enters the velocity and position blocks through the rotation of the specific force, the
accelerometer walk enters velocity and position within the interval, and the bias blocks are
cross-coupled with the navigation blocks; the fit below takes all of it, with no block assigned
to one figure.

**EM.** Each iteration

1. *E-step*: solves the smoother under the current figures (:mod:`graph.inertial_smoother`: the
   first time from its incremental pass, then from the last solution; the pixel sigma identified
   inside the batch solve, :func:`graph.inertial_smoother.identify_pixel_sigma`, starting from
   the last step's) and takes the Laplace posterior: the marginals' whitened Jacobian ``A`` and
   joint covariance of each interval's two frames give every IMU factor's expected outer
   product ``E_f = E[r_w r_w^T] = b b^T + A_f Sigma A_f^T`` in its whitened coordinates
   ``r_w = R_f r`` (:func:`graph.inertial_marginals.imu_factor_moments`; ``R_f`` the factor's
   noise model's square-root information, so ``R_f Sigma_f(theta_old) R_f^T = I``);
2. *M-step*: maximises the expected log-likelihood of the IMU factors over ``theta``,
   ``Q(theta) = -1/2 sum_f [log det S_f(theta) + tr(S_f(theta)^-1 E_f)]`` with
   ``S_f = R_f Sigma_f(theta) R_f^T`` (the same model in whitened coordinates, where it is well
   conditioned). Its fixed point is the variance-component update (an MM step that keeps
   every ``theta_i`` positive and never lowers ``Q``)::

       theta_i' = theta_i * sum_f tr(W_f E_f W_f B~_fi) / sum_f tr(W_f B~_fi),
       W_f = S_f(theta)^-1,  B~_fi = R_f B_fi R_f^T

   iterated to convergence (:func:`m_step`). With one scale on all four figures this is the
   smoother's ``imu_noise_em_scale`` (``sum tr E_f / 15 (T - 1)``).

until every figure moves by less than ``rtol`` (relative, on the density) or ``max_iterations``.
Plain EM moves each figure by the share of its information the data hold, ``1 - m_i`` below:
on a 5 s simulated flight 0.1 (gyro noise) to 0.03 (accelerometer), 4 % a step where the sheet
is 3x off. So by default (``accelerate``) each step is a scoring step instead,
``theta' = theta + I_obs^-1 dQ/dtheta`` (:func:`scoring_step`: ``dQ/dtheta`` at the E-step's
``theta`` is the marginal likelihood's score by Fisher's identity, so its fixed points are EM's),
each variance moved by at most 4x. A figure whose share ``m_i`` at the start is
``UNDETERMINED_SHARE`` (0.99) or more is held at the sheet's and named (``undetermined``).

**Uncertainty.** The complete-data Fisher information of ``theta`` is
``F_ij = 1/2 sum_f tr(W_f B~_fi W_f B~_fj)``; the posterior holds a share
``m_i = sum_f tr(W L_f W B~_fi) / sum_f tr(W E_f W B~_fi)`` of the expected squared residuals
that figure ``i`` explains (``L_f = A_f Sigma A_f^T``: where the smoother absorbed a residual,
it carries no information on the noise), and the observed information is taken as
``D F D`` with ``D = diag(sqrt(1 - m_i))`` (the scalar case is exact: ``n`` residuals of which
``k`` degrees of freedom were fitted give ``(n - k) / (2 theta^2)``); ``sd(density) = density
sd(theta) / (2 theta)``. The bias random walks have ``m`` near 1 on drives of seconds (the
smoother fits the bias per frame and what is left is the prior's): their sigmas say so.
The pixel sigma's sd is ``sigma / sqrt(2 dof)`` (``dof = d N - 3 M - 6 T``, the rule of
:func:`graph.inertial_smoother.identify_pixel_sigma`).

**What is safe to use** (``ImuNoiseFit.usable``; measured on EuRoC V1_01, docs/findings.md).
EM can stop short of its fixed point (``max_iterations``), and a figure still moving by more than
``rtol`` in the last step is not identified: it keeps the sheet's value in ``usable`` and is named
in ``unconverged``. On EuRoC's 30 s EM does not converge at all: the gyro random walk grew 1.3x
a step (48x the sheet's at 12 steps, 179x at 40) while the gyro noise density, 5.3x at step 5,
fell to 0.05x, its posterior share 0.84 -> 0.999: the two trade along a ridge (the rotation
residuals are correlated across intervals, which a bias walk explains better than white rate
noise). A figure free at the start whose share reaches ``UNDETERMINED_SHARE`` at the model EM
returns is withheld too (``undetermined_at_end``). The identified model is also only worth writing if the
smoother finds its solution from its *own* initial values, as every later run of it will
(EM's E-steps start from the last step's solution, never from scratch): after EM the smoother
solves the usable model twice, from EM's last solution and from its own incremental pass, and
``cold_start_nees`` is the mean over frames of the 6-dof squared Mahalanobis distance between the
two solutions' poses under the first one's covariances. Above ``COLD_START_NEES`` the two are
different minima (EuRoC, all four figures identified: the cold solve's ATE 0.265 m against 0.027 m
from EM's solution), and ``usable`` is the sheet's figures with every figure named in
``withheld``; ``trusted`` says whether every determined figure is in ``usable`` as identified.

**The camera-IMU extrinsic is not checked here.** The velocity drives' check
(:mod:`graph.extrinsic`) makes the extrinsic a variable of the stereo factors; GTSAM's Python
wrapper has no projection factor with the extrinsic as a variable (``ProjectionFactorPPP`` is
not wrapped), and a Jacobian of ours for it is not written yet: the extrinsic stays the file's.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import gtsam
import numpy as np

from vislam.ekf.errors import EstimationError, InputError
from vislam.ekf.geometry import se3_inv, se3_log
from vislam.ekf.inertial import ImuNoise, InertialDrive
from vislam.graph.inertial_factors import preintegrate, preintegration_params
from vislam.graph.inertial_smoother import (InertialProblem, InertialSmootherResult,
                                            InertialSmootherSettings, batch_solve, build_problem,
                                            robust_initial_solve, to_result)

#: The four figures, in ``theta``'s order (:meth:`ekf.inertial.ImuNoise.as_array`'s).
FIGURES = ("gyro_noise_density", "gyro_random_walk", "accel_noise_density", "accel_random_walk")
#: Inner iterations of the M-step's fixed point at most, and its relative tolerance.
M_STEP_ITERATIONS = 2000
M_STEP_RTOL = 1e-7
#: No figure goes below this fraction of the sheet's variance (a floor for the fixed point).
THETA_FLOOR = 1e-8
#: A figure whose expected squared residuals the posterior holds this share of (or more) is not
#: determined by the drive: it keeps its start value (the sheet's) and is named in
#: ``ImuNoiseFit.undetermined`` (on a few seconds of simulated room flight, the gyro random walk:
#: share 0.9999; left free, EM drives it towards zero with nothing in the data to stop it).
UNDETERMINED_SHARE = 0.99
#: An accelerated step moves each variance by at most this factor (in log): exp(1.4) = 4x.
MAX_LOG_STEP = 1.4
#: The usable model's solve from the smoother's own initial values must come within this mean
#: squared Mahalanobis distance (6-dof, per frame) of its solve from EM's last solution
#: (module docstring): two solves of one model that agree differ by far less than their own
#: sigmas; on EuRoC the cold solve under all four identified figures was about 1e5 away.
COLD_START_NEES = 1.0


@dataclass
class ImuNoiseFit:
    """What EM identified (module docstring), beside the data sheet's figures.

    ``noise`` the identified :class:`ImuNoise` and ``noise_std`` each figure's standard
    deviation (same units, ``ImuNoise.as_array`` order); ``sheet`` the drive's own figures;
    ``pixel_sigma`` (px) with ``pixel_sigma_std`` and the start's ``pixel_sigma_start``;
    ``missing_share`` per figure the share of its expected squared residuals the posterior
    holds; ``history`` the figures (T, 4) and pixel sigma of each E-step's model;
    ``result`` the smoother's result under the identified model (from EM's last solution);
    ``unconverged`` the free figures still moving by more than ``rtol`` at the last step;
    ``undetermined_at_end`` those free at the start whose posterior share reached
    ``UNDETERMINED_SHARE`` at the model returned (both withheld);
    ``usable`` the figures to use: the identified ones, the sheet's for the ``undetermined``, the
    ``unconverged`` and (all four) when the cold-start check fails, each of those named in
    ``withheld`` (undetermined ones not repeated); ``cold_start_nees`` that check's statistic
    (module docstring; NaN when ``usable`` is the sheet's and there was nothing to check)."""

    noise: ImuNoise
    noise_std: np.ndarray
    sheet: ImuNoise
    pixel_sigma: float
    pixel_sigma_std: float
    pixel_sigma_start: float
    iterations: int
    converged: bool
    seconds: float
    missing_share: np.ndarray
    history: np.ndarray
    pixel_history: np.ndarray
    n_intervals: int
    undetermined: tuple[str, ...] = ()
    result: InertialSmootherResult | None = None
    unconverged: tuple[str, ...] = ()
    usable: ImuNoise | None = None
    withheld: tuple[str, ...] = ()
    cold_start_nees: float = float("nan")
    undetermined_at_end: tuple[str, ...] = ()

    @property
    def trusted(self) -> bool:
        """Whether every determined figure is identified in ``usable`` (converged, and the
        smoother finds the model's solution from its own initial values; module docstring);
        the ``undetermined`` keep the sheet's either way."""
        return not self.withheld

    @property
    def ratio(self) -> np.ndarray:
        """Identified over the sheet's, per figure (``ImuNoise.as_array`` order)."""
        return self.noise.as_array() / self.sheet.as_array()

    def rows(self) -> list[tuple[str, float, float, float, float]]:
        """``(name, sheet, identified, sigma, ratio)`` per figure, then the pixel sigma."""
        out = [(name, s, v, sd, v / s) for name, s, v, sd in
               zip(FIGURES, self.sheet.as_array(), self.noise.as_array(), self.noise_std)]
        out.append(("pixel_sigma", self.pixel_sigma_start, self.pixel_sigma, self.pixel_sigma_std,
                    self.pixel_sigma / self.pixel_sigma_start))
        return out


def with_noise(drive: InertialDrive, noise: ImuNoise) -> InertialDrive:
    """``drive`` with its calibration's IMU noise replaced by ``noise``."""
    return dataclasses.replace(drive, calibration=dataclasses.replace(drive.calibration, noise=noise))


def factor_covariance(pim: gtsam.PreintegratedCombinedMeasurements) -> np.ndarray:
    """The covariance (15, 15) of the ``CombinedImuFactor`` made of ``pim``: its noise model's,
    which is not ``pim.preintMeasCov()`` (GTSAM 4.3's factor has the opposite sign on the
    velocity-accelerometer-bias cross block, about 5 % of the entries' scale)."""
    keys = [gtsam.symbol(c, 0) for c in "xvXVbB"]
    return np.asarray(gtsam.CombinedImuFactor(*keys, pim).noiseModel().covariance())


def noise_bases(problem: InertialProblem, sheet: ImuNoise) -> tuple[np.ndarray, np.ndarray]:
    """``(Sigma0 (T-1, 15, 15), B (4, T-1, 15, 15))``: per interval of ``problem``, GTSAM's
    preintegrated covariance with every figure zero, and with figure ``i`` (:data:`FIGURES`) at
    ``sheet``'s value and the others zero, less ``Sigma0`` (module docstring); about the
    problem's bias (the rest's, as its factors)."""
    drive = problem.drive
    t = drive.timestamps
    g = drive.calibration.gravity
    values = sheet.as_array()

    def covs(figures: np.ndarray) -> np.ndarray:
        params = preintegration_params(ImuNoise.from_array(figures), g)
        return np.stack([factor_covariance(preintegrate(drive.imu, float(t[k - 1]), float(t[k]),
                                                        params, problem.bias0))
                         for k in range(1, drive.n_frames)])

    # The factor's noise model needs a positive definite covariance, so the bases are the
    # differences of figure i at sqrt(2) x the sheet's (its variance doubled) and the sheet's.
    at_sheet = covs(values)
    B = np.stack([covs(values * np.where(np.arange(4) == i, np.sqrt(2.0), 1.0)) - at_sheet
                  for i in range(4)])
    return at_sheet - B.sum(axis=0), B


def whitened_bases(problem: InertialProblem, S0: np.ndarray, B: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray]:
    """``S0`` and ``B`` in each IMU factor's whitened coordinates (``R S R^T``, ``R`` the
    factor's noise model's ``R()``: the coordinates of
    :func:`graph.inertial_marginals.imu_factor_moments`)."""
    R = np.stack([np.asarray(problem.imu_factor(k).noiseModel().R())
                  for k in range(1, problem.n_frames)])
    S0w = np.einsum("fab,fbc,fdc->fad", R, S0, R)
    Bw = np.einsum("fab,ifbc,fdc->ifad", R, B, R)
    return S0w, Bw


def m_step(E: np.ndarray, S0w: np.ndarray, Bw: np.ndarray, theta: np.ndarray,
           iterations: int = M_STEP_ITERATIONS, rtol: float = M_STEP_RTOL) -> np.ndarray:
    """The ``theta`` (4,) that maximises ``Q`` (module docstring) for the expected outer products
    ``E`` (T-1, 15, 15), by the variance-component fixed point from ``theta``."""
    theta = np.maximum(np.asarray(theta, dtype=float), THETA_FLOOR)
    for _ in range(int(iterations)):
        W = np.linalg.inv(S0w + np.einsum("i,ifab->fab", theta, Bw))
        WEW = W @ E @ W
        num = np.einsum("fab,ifba->i", WEW, Bw)
        den = np.einsum("fab,ifba->i", W, Bw)
        new = np.maximum(theta * num / den, THETA_FLOOR)
        done = np.all(np.abs(new - theta) <= rtol * new)
        theta = new
        if done:
            break
    return theta


def expected_log_likelihood(E: np.ndarray, S0w: np.ndarray, Bw: np.ndarray, theta: np.ndarray) -> float:
    """``Q(theta)`` of the module docstring (up to a constant)."""
    S = S0w + np.einsum("i,ifab->fab", np.asarray(theta, dtype=float), Bw)
    _, logdet = np.linalg.slogdet(S)
    return float(-0.5 * (logdet.sum() + np.einsum("fab,fba->", np.linalg.inv(S), E)))


def theta_information(E: np.ndarray, L: np.ndarray, S0w: np.ndarray, Bw: np.ndarray,
                      theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(information (4, 4), missing share (4,))`` of ``theta`` (module docstring)."""
    W = np.linalg.inv(S0w + np.einsum("i,ifab->fab", theta, Bw))
    WB = np.einsum("fab,ifbc->ifac", W, Bw)
    F = 0.5 * np.einsum("ifab,jfba->ij", WB, WB)
    WEW = W @ E @ W
    WLW = W @ L @ W
    total = np.einsum("fab,ifba->i", WEW, Bw)
    missing = np.clip(np.einsum("fab,ifba->i", WLW, Bw) / total, 0.0, 1.0 - 1e-12)
    d = np.sqrt(1.0 - missing)
    return d[:, None] * F * d[None, :], missing


def score(E: np.ndarray, S0w: np.ndarray, Bw: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """``dQ / dtheta`` (4,) at ``theta``: ``1/2 sum_f [tr(W E W B~_i) - tr(W B~_i)]``; at the
    E-step's own ``theta`` it is the score of the marginal likelihood (Fisher's identity)."""
    W = np.linalg.inv(S0w + np.einsum("i,ifab->fab", np.asarray(theta, dtype=float), Bw))
    return 0.5 * (np.einsum("fab,ifba->i", W @ E @ W, Bw) - np.einsum("fab,ifba->i", W, Bw))


def scoring_step(E: np.ndarray, L: np.ndarray, S0w: np.ndarray, Bw: np.ndarray, theta: np.ndarray,
                 free: np.ndarray | None = None, max_log_step: float = MAX_LOG_STEP) -> np.ndarray:
    """EM accelerated (module docstring): ``theta + I^-1 score`` over the ``free`` figures (mask;
    default all) with ``I`` the observed information :func:`theta_information`, each
    ``log theta_i`` moved by at most ``max_log_step``; the others kept."""
    theta = np.asarray(theta, dtype=float)
    free = np.ones(theta.size, dtype=bool) if free is None else np.asarray(free, dtype=bool)
    info, _ = theta_information(E, L, S0w, Bw, theta)
    out = theta.copy()
    if free.any():
        step = np.linalg.solve(info[np.ix_(free, free)], score(E, S0w, Bw, theta)[free])
        out[free] = theta[free] * np.exp(np.clip(step / theta[free], -max_log_step, max_log_step))
    return out


def _solve(problem: InertialProblem, previous):
    """One E-step's smoother solve: the batch from ``previous`` (a Solution) or, the first time,
    from the incremental pass (QR when Cholesky finds the system indeterminate, as
    :func:`graph.inertial_smoother.smooth` does). A batch from ``previous`` that fails (on
    EuRoC V1_01 with its IMU 2.5 ms earlier, one step's solve from the last solution under a
    gyro walk 50x the sheet's kept 15 of 216 landmarks, too few for the pixel sigma) is solved
    again from the incremental pass under the new figures."""
    sol = None
    if previous is not None:
        try:
            sol = batch_solve(problem, previous)
        except EstimationError:
            pass
    if sol is None:
        problem, initial = robust_initial_solve(problem)
        sol = batch_solve(problem, initial)
    return sol, to_result(problem, sol)


def identify_imu_noise(drive: InertialDrive,
                       settings: InertialSmootherSettings = InertialSmootherSettings(),
                       max_iterations: int = 15, rtol: float = 0.01,
                       start: ImuNoise | None = None, accelerate: bool = True,
                       check_cold_start: bool = True) -> ImuNoiseFit:
    """EM for the four IMU figures and the pixel sigma of ``drive`` (module docstring), from
    ``start`` (default the drive's data sheet, ``drive.calibration.noise``). ``settings``: the
    smoother's (its ``imu_noise_inflation`` is taken as 1 and ``compute_marginals`` as true:
    EM needs the posterior; a given ``pixel_sigma`` stays fixed). ``check_cold_start``: solve
    the usable model from the smoother's own initial values and withhold it when that lands
    elsewhere (module docstring; two more solves)."""
    if not isinstance(max_iterations, (int, np.integer)) or not 1 <= max_iterations <= 1000:
        raise InputError(f"identify_imu_noise: max_iterations must be an integer in 1..1000, "
                         f"got {max_iterations!r}")
    if not 0 < rtol < 1:
        raise InputError(f"identify_imu_noise: rtol must be in (0, 1), got {rtol!r}")
    begin = time.perf_counter()
    sheet = drive.calibration.noise
    values = sheet.as_array()
    if np.any(values <= 0) or not np.all(np.isfinite(values)):
        raise InputError(f"{drive.source or drive.name}: key 'imu_noise' "
                         f"{dict(zip(FIGURES, values.tolist()))}: every figure must be positive to "
                         "be identified (EM scales the sheet's figures)")
    theta = np.ones(4) if start is None else (start.as_array() / values) ** 2
    settings = dataclasses.replace(settings, imu_noise_inflation=1.0, compute_marginals=True)
    problem = build_problem(with_noise(drive, ImuNoise.from_array(values * np.sqrt(theta))), settings)
    S0, B = noise_bases(problem, sheet)
    pixel0 = settings.pixel_sigma if settings.pixel_sigma is not None else settings.pixel_sigma_start
    history, pixels = [], []
    previous, converged, pixel = None, False, pixel0
    for it in range(int(max_iterations)):
        noise = ImuNoise.from_array(values * np.sqrt(theta))
        step_settings = (settings if settings.pixel_sigma is not None
                         else dataclasses.replace(settings, pixel_sigma_start=pixel))
        problem = build_problem(with_noise(drive, noise), step_settings)
        previous, result = _solve(problem, previous)
        pixel = float(result.info["pixel_sigma"])
        history.append(noise.as_array())
        pixels.append(pixel)
        S0w, Bw = whitened_bases(problem, S0, B)
        _, share = theta_information(result.imu_moments, result.imu_leverage, S0w, Bw, theta)
        if it == 0:  # decided at the start's model, then kept (module docstring)
            free = share < UNDETERMINED_SHARE
        if accelerate:
            new = scoring_step(result.imu_moments, result.imu_leverage, S0w, Bw, theta, free)
        else:
            new = np.where(free, m_step(result.imu_moments, S0w, Bw, theta), theta)
        moved = np.abs(np.sqrt(new / theta) - 1.0)
        if np.all(moved <= rtol):
            converged = True  # the model of this E-step is EM's fixed point (to rtol)
            break
        theta = new
    final_settings = (settings if settings.pixel_sigma is not None
                      else dataclasses.replace(settings, pixel_sigma_start=pixel))
    if not converged:  # the result and the statistics under the figures returned, not the last E-step's
        problem = build_problem(with_noise(drive, ImuNoise.from_array(values * np.sqrt(theta))),
                                final_settings)
        previous, result = _solve(problem, previous)
        pixel = float(result.info["pixel_sigma"])
        S0w, Bw = whitened_bases(problem, S0, B)
    unconverged = tuple(n for n, f, m in zip(FIGURES, free, moved) if f and m > rtol)
    info, missing = theta_information(result.imu_moments, result.imu_leverage, S0w, Bw, theta)
    # free at the start but left to the posterior at the model reached (module docstring)
    lost = tuple(n for n, f, m in zip(FIGURES, free, missing)
                 if f and m >= UNDETERMINED_SHARE and n not in unconverged)
    sd_theta = np.full(4, np.inf)
    if free.any():
        try:
            cov = np.linalg.inv(info[np.ix_(free, free)])
            sd_theta[free] = np.sqrt(np.maximum(np.diag(cov), 0.0))
        except np.linalg.LinAlgError:
            pass
    noise = ImuNoise.from_array(values * np.sqrt(theta))
    noise_std = noise.as_array() * sd_theta / (2.0 * theta)
    noise_std[~free] = np.inf  # the drive does not determine them
    dims = 2 if problem.stereo is None else 3
    dof = (dims * result.info["n_observations_used"] - 3 * result.info["n_landmarks"]
           - 6 * drive.n_frames)
    undetermined = tuple(n for n, f in zip(FIGURES, free) if not f)
    withheld = unconverged + lost
    keep = np.array([n not in undetermined and n not in withheld for n in FIGURES])
    usable = ImuNoise.from_array(np.where(keep, noise.as_array(), values))
    cold = float("nan")
    if check_cold_start and keep.any():
        cold = cold_start_nees(drive, usable, final_settings, previous,
                               result if np.all(keep) else None)
        if not cold <= COLD_START_NEES:
            usable, withheld = sheet, tuple(n for n in FIGURES if n not in undetermined)
    return ImuNoiseFit(noise=noise, noise_std=noise_std, sheet=sheet, pixel_sigma=pixel,
                       pixel_sigma_std=pixel / np.sqrt(2.0 * max(dof, 1)), pixel_sigma_start=pixel0,
                       iterations=len(history), converged=converged,
                       seconds=time.perf_counter() - begin, missing_share=missing,
                       history=np.array(history), pixel_history=np.array(pixels),
                       n_intervals=drive.n_frames - 1,
                       undetermined=undetermined, result=result, unconverged=unconverged,
                       usable=usable, withheld=withheld, cold_start_nees=cold,
                       undetermined_at_end=lost)


def pose_mahalanobis(reference: InertialSmootherResult, other: InertialSmootherResult) -> np.ndarray:
    """Per frame, ``xi^T P^-1 xi`` (T,) of ``other``'s pose against ``reference``'s, ``xi`` the
    right perturbation (translation first) and ``P`` the reference's pose covariance."""
    ref, oth = reference.estimate, other.estimate
    xi = se3_log(se3_inv(ref.poses) @ oth.poses)
    return np.einsum("fa,fa->f", xi, np.linalg.solve(ref.pose_cov, xi[..., None])[..., 0])


def cold_start_nees(drive: InertialDrive, noise: ImuNoise, settings: InertialSmootherSettings,
                    previous=None, warm: InertialSmootherResult | None = None) -> float:
    """The cold-start check's statistic (module docstring): ``drive`` under ``noise`` solved from
    ``previous`` (EM's last Solution; its result ``warm`` when already solved under ``noise``)
    and from the smoother's own initial values; the mean of :func:`pose_mahalanobis` over the
    frames after the first (inf when the cold solve fails)."""
    problem = build_problem(with_noise(drive, noise), settings)
    if warm is None:
        if previous is None:
            raise InputError("cold_start_nees: give EM's last solution or its result")
        _, warm = _solve(problem, previous)
    try:
        _, cold = _solve(problem, None)
    except EstimationError:
        return float("inf")
    d = pose_mahalanobis(warm, cold)[1:]
    return float(np.mean(d)) if np.all(np.isfinite(d)) else float("inf")
