"""A radial lens term of the pixels, identified by its likelihood around the smoother.

A file's pixels may carry a lens distortion that its pinhole ``K`` does not describe; with one
radial coefficient ``k1`` (:mod:`ekf.camera`: ``x_d = x (1 + k1 r^2)``) it scales the bearings
towards the edge of the image, so vision's turns come out too large or too small
(docs/findings.md: "A radial lens term"). Under a model with the term, the pixels lose it once
(:func:`ekf.model.without_radial`) and every estimator keeps the pinhole model. To identify it:

1. *The likelihood in the measured pixels.* The noise lives where the pixels were measured,
   in the lens image. The smoother solves the drive with ``k1`` removed (pinhole pixels
   ``undistort(z, k1)``; noise levels, extrinsic and stereo rows held at the identified
   model's, :func:`solve_at`); at its solution each stereo row's residual is taken again in
   the lens image, ``e = distort(p, k1) - z`` (``p`` the predicted pinhole pixels), whitened
   as the linearisation whitens the row (:func:`lens_rows`). A change of ``k1`` moves the
   predicted lens pixels by ``de/dk1 = distort(p, 1) - distort(p, 0)`` (the lens map is linear
   in ``k1``).
2. *Gauss-Newton on the profile.* With the poses and landmarks profiled out
   (:func:`graph.out_of_sample.profile_rows`: ``A~ = P A_k``, ``b~ = P b``), the step is
   ``dk1 = (A~^T A~)^-1 A~^T b~`` and ``sigma = (A~^T A~)^-1/2`` (:func:`lens_step`). The
   nuisance is profiled with the pinhole rows' information, which differs from the lens rows'
   by ``O(k1 r^2)``; so the step taken at ``c`` lands at ``a + s c`` with a small slope ``s``
   (0.15-0.2 on the simulator) instead of at one point. Solved once more where the first
   step lands, the secant through the two steps gives the fixed point, the maximum of the
   likelihood in the measured pixels (:func:`lens_estimate`): two solves, one where the first
   step is already within a quarter sigma. (The pinhole pixels' likelihood would reward a
   ``k1`` that shrinks every residual towards the edge: on pinhole drives it put the maximum
   at +0.007 to +0.009 at 1 px.)
3. *Bias.* On the simulator the maximum is within a sigma of the lens (the pinhole pixels'
   own likelihood put it 0.004-0.009 high at 1 px), but on a real drive's geometry it can be
   biased (the 2019 edition of 0027: +0.005, 3.6 sigma). A parametric bootstrap measures it:
   the drive made again from the solution, through the lens found, with the identified pixel
   noise (seed ``BOOTSTRAP_SEED``), estimated again from the lens found; the difference is the
   bias, subtracted once. The replicate's own scatter enters the correction, so the reported
   sigma is the step's times sqrt(2).
4. *Decision.* The term is kept when its Wald statistic ``(k1 / sigma)^2`` passes BIC
   (``ln n``, one parameter, n stereo observations), as the gyro bias and the extrinsic are, and
   when, fitted without each stretch of the drive, it predicts that stretch better than none
   (:func:`radial_fold_gain`, on the same lens rows).

(Until 2026-12-02 the likelihood was a parabola through three solves of the pinhole graph's
error with the lens residuals added at its solution, and the bootstrap profiled three more:
seven solves where this takes two to five; docs/findings.md, "The radial term in the
measured pixels".)
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass, field

import numpy as np

from vislam.ekf.camera import distort_pixels
from vislam.ekf.config import FilterConfig
from vislam.ekf.model import MAX_RADIAL_K1, without_radial
from vislam.ekf.sequence import Sequence
from vislam.graph.settings import SmootherSettings

log = logging.getLogger(__name__)

#: The largest move of one Gauss-Newton step (normalised coordinates): 4 % of bearing at the
#: image corner (r about 0.9), many sigmas of a typical drive's estimate.
RADIAL_STEP = 0.04
#: A first step within this many sigmas of where it was taken is the maximum (no second solve).
RADIAL_STEP_TOL = 0.25
#: Seed of the parametric bootstrap's pixel noise (the same data give the same model).
BOOTSTRAP_SEED = 0


@dataclass
class RadialFit:
    """The radial term's estimate, its standard deviation and the test against none."""

    k1: float | None  # None: the data support none
    estimate: float  # the bias-corrected estimate, kept or not
    std: float  # inf when the pixels carry no information on the term
    test: dict = field(default_factory=dict)
    solution: object = None  # the smoother's solution under ``k1`` (warm start for EM)


def solve_at(seq: Sequence, config: FilterConfig, settings: SmootherSettings, k1: float,
             warm_start):
    """The smoother's solution of ``seq`` with ``k1`` removed from its pixels: the same stereo
    rows as ``warm_start`` (no outlier round), the noise model of ``config``."""
    from vislam.graph.smoother import solve_smoother

    moved = without_radial(seq, k1) if k1 else seq
    return solve_smoother(moved, config, settings.replace(rejection_rounds=0), warm_start=warm_start)


def lens_rows(solution, k1: float) -> tuple[np.ndarray, np.ndarray]:
    """``(b, A_k)`` of a smoother solved with ``k1`` removed from its pixels: the right-hand
    side of its linearisation (all rows) with the stereo rows' ``[uL, uR, v]`` residuals taken
    in the measured (lens) pixels, and the term's whitened Jacobian (rows, 1), the lens
    pixels' change with ``k1`` at the predicted pinhole pixels (zero on the other rows)
    (module docstring, step 1). Each stereo row is whitened as the linearisation whitens it:
    ``sqrt(w) / sigma_c``, ``sigma_c`` the stereo noise's ``[sigma, sigma, sigma / sqrt(2)]``
    and ``w`` the robust kernel's weight, read off the linearised right-hand side of the row
    against its pinhole error."""
    from vislam.graph.extrinsic import stereo_rows
    from vislam.graph.factors import stereo_measurement, stereo_residuals

    rows = solution.problem.rows
    K = np.asarray(solution.calibration.K, dtype=float)
    r_pin, _ = stereo_residuals(solution.poses, solution.landmarks, solution.calibration, rows)
    z = rows.z  # the pinhole pixels the smoother was given: undistort(measured, k1)
    v = 0.5 * (z[:, 1] + z[:, 3]) - r_pin[:, 2]
    predicted = np.stack([z[:, 0] - r_pin[:, 0], v, z[:, 2] - r_pin[:, 1], v], axis=1)
    residual = distort_pixels(z, K, k1) - distort_pixels(predicted, K, k1)  # measured - predicted
    moves = distort_pixels(predicted, K, 1.0) - distort_pixels(predicted, K, 0.0)  # d/dk1, exact

    system = solution.linearised()[0]
    stereo = stereo_rows(solution)
    ratio = np.array([1.0, 1.0, np.sqrt(2.0)])  # 1 / sigma_c in units of 1 / sigma
    e = -r_pin * ratio  # GTSAM's error (predicted - measured) times sigma / sigma_c
    b_pin = system.b[stereo].reshape(-1, 3)
    ee = np.sum(e * e, axis=1)
    scale = np.where(ee > 1e-18, -np.sum(b_pin * e, axis=1) / np.where(ee > 1e-18, ee, 1.0), np.nan)
    scale = np.where(np.isfinite(scale), scale, np.nanmedian(scale) if np.isfinite(scale).any() else 0.0)
    whiten = scale[:, None] * ratio
    b = np.array(system.b, dtype=float)
    b[stereo] = (whiten * stereo_measurement(residual)).reshape(-1)  # GTSAM's b is minus the whitened error
    A_k = np.zeros((b.size, 1))
    A_k[stereo, 0] = (whiten * stereo_measurement(moves)).reshape(-1)
    return b, A_k


def lens_step(solution, k1: float) -> tuple[float, float]:
    """The Gauss-Newton step's landing point and sigma on the profile likelihood in the
    measured pixels (module docstring, step 2), from a smoother solved with ``k1`` removed;
    sigma inf (and the point ``k1``) where the pixels carry no information on the term."""
    from vislam.graph.out_of_sample import profile_rows

    system, posterior_of = solution.linearised()
    b, A_k = lens_rows(solution, k1)
    A_p, b_p = profile_rows(system.A, b, A_k, posterior_of.solve)
    information = float(A_p[:, 0] @ A_p[:, 0])
    if not (np.isfinite(information) and information > 0.0):
        return float(k1), float("inf")
    return float(k1 + (A_p[:, 0] @ b_p) / information), float(1.0 / np.sqrt(information))


def lens_estimate(seq: Sequence, config: FilterConfig, settings: SmootherSettings, solution,
                  step: float = RADIAL_STEP, centre: float = 0.0) -> tuple[float, float, dict, object]:
    """The maximum of the likelihood in the measured pixels over ``k1`` (module docstring,
    step 2), from the smoother's ``solution`` without a term: ``(k1, sigma, steps, solution)``,
    ``steps`` ``{k1 solved at: (landing point, sigma)}`` and the last solution solved (sigma
    inf when the pixels carry no information on the term). The first step is taken at
    ``centre``; a step moves ``k1`` by at most ``step``."""
    first = float(centre)
    sol = solve_at(seq, config, settings, first, solution)
    landing, sigma = lens_step(sol, first)
    steps = {first: (landing, sigma)}
    if not np.isfinite(sigma) or abs(landing - first) <= RADIAL_STEP_TOL * sigma:
        return landing, sigma, steps, sol
    second = float(np.clip(landing, first - step, first + step))
    second = float(np.clip(second, -MAX_RADIAL_K1, MAX_RADIAL_K1))
    sol = solve_at(seq, config, settings, second, sol)
    again, sigma_again = lens_step(sol, second)
    steps[second] = (again, sigma_again)
    if not np.isfinite(sigma_again):
        return landing, sigma, steps, sol
    # the landing point is a + slope * (where the step is taken): its fixed point
    slope = (again - landing) / (second - first)
    estimate = (landing - slope * first) / (1.0 - slope) if slope < 0.5 else again
    return float(np.clip(estimate, -MAX_RADIAL_K1, MAX_RADIAL_K1)), sigma_again, steps, sol


def _replicate(solution, config: FilterConfig, k1: float, rng: np.random.Generator):
    """A drive like the solved one, made from the solution (parametric bootstrap): its
    landmarks seen from its poses, through a lens ``k1``, plus ``config``'s pixel noise, on
    the solution's stereo rows; its velocities the data's (the bias is the pixels')."""
    from vislam.ekf.camera import project
    from vislam.ekf.geometry import homogeneous
    from vislam.ekf.sequence import Observations
    from vislam.graph.factors import camera_points

    seq = solution.cleaned
    rows = solution.problem.rows
    calib = seq.calibration
    z = project(calib.M, homogeneous(camera_points(solution.poses, solution.landmarks, calib, rows)))
    z = distort_pixels(z, np.asarray(calib.K, dtype=float), k1)
    z = z + config.pixel_sigma * rng.standard_normal(z.shape)
    obs = Observations.from_rows(rows.frame, rows.track, z, seq.n_frames)
    return dataclasses.replace(seq, obs=obs), config.replace(clean_tracks=False)


def radial_fold_gain(solution, k1: float, stretch_s: float = 10.0):
    """The radial term's out-of-sample gain over none (:func:`graph.out_of_sample.fold_gain`,
    folds of ``stretch_s`` seconds) at a smoother solved with ``k1`` removed from its pixels,
    on its stereo rows in the measured pixels (:func:`lens_rows`): the term fitted without
    each stretch against the null ``k1 = 0`` (a change of ``-k1``)."""
    from vislam.graph.extrinsic import stereo_rows
    from vislam.graph.out_of_sample import fold_gain, term_rows

    b, A_k = lens_rows(solution, k1)
    stereo = stereo_rows(solution)
    A_p, b_p, folds = term_rows(solution, stereo, A_k[stereo], stretch_s, b=b)
    return fold_gain(A_p, b_p, folds, np.array([-float(k1)]), np.ones(1, dtype=bool))


def radial_profile(seq: Sequence, config: FilterConfig, settings: SmootherSettings, solution,
                   step: float = RADIAL_STEP) -> RadialFit:
    """The radial term of ``seq``'s pixels (module docstring) at the model of ``config``
    (``seq`` with the extrinsic in use), starting from the smoother's ``solution`` there."""
    n_obs = max(len(solution.problem.rows), 2)
    threshold = float(np.log(n_obs))  # BIC: k ln n, one parameter
    criterion = f"BIC (ln n, n = {n_obs} stereo observations)"
    k1, std, steps, last = lens_estimate(seq, config, settings, solution, step)
    if not np.isfinite(std):
        log.info("radial term: the pixels carry no information on it")
        return RadialFit(None, k1, std, {
            "statistic": 0.0, "threshold": threshold, "criterion": criterion,
            "decision": "none (the likelihood has no maximum)"})
    # The estimate's own bias on this drive (parametric bootstrap, module docstring step 3):
    # the drive made again from the solution through the lens found, with the identified
    # pixel noise, estimated again from there; the difference is subtracted once, and the
    # replicate's own scatter enters the sigma.
    replicate, replicate_config = _replicate(solution, config, k1, np.random.default_rng(BOOTSTRAP_SEED))
    again, _, again_steps, _ = lens_estimate(replicate, replicate_config, settings, solution, step,
                                             centre=k1)
    maximum, bias = k1, again - k1
    k1 = float(np.clip(k1 - bias, -MAX_RADIAL_K1, MAX_RADIAL_K1))
    std = std * float(np.sqrt(2.0))
    statistic = (k1 / std) ** 2  # Wald, against none
    keep = statistic > threshold
    # the solution under the term, where EM goes on from (only when it is kept); the term must
    # also predict held-out stretches better than none (issue 34 item 2, graph.out_of_sample)
    sol = held_out = None
    if keep:
        sol = solve_at(seq, config, settings, k1, last)
        held_out = radial_fold_gain(sol, k1)
        keep = held_out.improves
        if not keep:
            sol = None
    log.info("radial term: k1 %.5f +- %.5f (maximum %.5f, bootstrap bias %.5f; %d solves), Wald "
             "%.1f against BIC %.1f: %s", k1, std, maximum, bias, len(steps) + len(again_steps),
             statistic, threshold, "kept" if keep else "none")
    return RadialFit(
        k1=k1 if keep else None, estimate=k1, std=std,
        test={"statistic": statistic, "threshold": threshold, "criterion": criterion,
              "decision": ("radial term" if keep else "none (the data support none)"
                           if held_out is None else "none (passes BIC in sample, but fitted "
                           "without a stretch it predicts that stretch no better)"),
              "out_of_sample": None if held_out is None else held_out.to_dict(),
              "likelihood_maximum": maximum, "bootstrap_bias": bias,
              "steps": {f"{k:.6g}": {"landing": v, "std": s if np.isfinite(s) else None}
                        for k, (v, s) in sorted(steps.items())}},
        solution=sol)
