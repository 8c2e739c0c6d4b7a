"""A radial lens term of the pixels, identified by its profile likelihood around the smoother.

A file's pixels may carry a lens distortion that its pinhole ``K`` does not describe; with one
radial coefficient ``k1`` (:mod:`ekf.camera`: ``x_d = x (1 + k1 r^2)``) it scales the bearings
towards the edge of the image, so vision's turns come out too large or too small
(docs/findings.md: "A radial lens term"). Under a model with the term, the pixels lose it once
(:func:`ekf.model.without_radial`) and every estimator keeps the pinhole model. To identify it:

1. *Profile likelihood.* For a trial ``k1`` the smoother solves the drive with the term removed
   (noise levels, extrinsic and stereo rows held at the identified model's); ``-log L(k1)`` is
   its final graph error with the stereo rows' share evaluated in the *measured* (lens)
   pixels: the predicted pinhole pixels through the lens against the measured ones, the
   noise living where the pixels were measured (:func:`profile_point`). Three solves at
   ``c - h, c, c + h`` give a parabola, re-centred while its minimum lies beyond them; its
   curvature ``a`` gives the standard deviation ``1 / sqrt(2 a)``.
2. *Bias.* The minimum is biased by the pixel noise (the landmarks are fitted to the same
   noisy pixels): about -0.005 at 1 px on the simulator, growing with sigma^2 (-0.0005 at
   0.25 px). A parametric bootstrap measures it: the drive made again from the solution,
   through the lens found, with the identified pixel noise (seed ``BOOTSTRAP_SEED``), and
   profiled again; the difference is the bias, subtracted once. The replicate's own scatter
   enters the correction, so the reported sigma is the profile's times sqrt(2).
3. *Decision.* The term is kept when its Wald statistic ``(k1 / sigma)^2`` passes BIC
   (``ln n``, one parameter, n stereo observations), as the gyro bias and the extrinsic are.
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

#: Spacing of the profile's three points (normalised coordinates): a 1 % bearing change at
#: the image corner (r about 0.9), a few sigmas of a typical drive's estimate.
RADIAL_STEP = 0.01
#: Re-centrings of the parabola, at most.
RADIAL_ROUNDS = 4
#: Seed of the parametric bootstrap's pixel noise (the same data give the same model).
BOOTSTRAP_SEED = 0


@dataclass
class RadialFit:
    """The radial term's estimate, its standard deviation and the test against none."""

    k1: float | None  # None: the data support none
    estimate: float  # the bias-corrected estimate, kept or not
    std: float  # inf when the profile has no minimum
    test: dict = field(default_factory=dict)
    solution: object = None  # the smoother's solution under ``k1`` (warm start for EM)


def profile_point(seq: Sequence, config: FilterConfig, settings: SmootherSettings, k1: float,
                  warm_start) -> tuple[float, object]:
    """``-log p(z | k1)`` (up to a constant) and the smoother's solution under ``k1``: same
    stereo rows as ``warm_start`` (no outlier round), the noise model of ``config``."""
    from vislam.graph.factors import stereo_residuals
    from vislam.graph.smoother import solve_smoother

    moved = without_radial(seq, k1) if k1 else seq
    sol = solve_smoother(moved, config, settings.replace(rejection_rounds=0), warm_start=warm_start)
    error = float(sol.errors[-1][1])
    if not k1:
        return error, sol
    # The stereo rows' share of the error again, in the measured (lens) pixels: the predicted
    # pinhole pixels through the lens against the measured ones; Gaussian weights of the
    # smoother's stereo noise ([uL, uR, v]: sigma, sigma, sigma / sqrt(2)).
    rows = sol.problem.rows
    K = np.asarray(seq.calibration.K, dtype=float)
    r_pin, _ = stereo_residuals(sol.poses, sol.landmarks, sol.calibration, rows)
    z = rows.z
    v = 0.5 * (z[:, 1] + z[:, 3]) - r_pin[:, 2]
    predicted = np.stack([z[:, 0] - r_pin[:, 0], v, z[:, 2] - r_pin[:, 1], v], axis=1)
    z_lens, p_lens = distort_pixels(z, K, k1), distort_pixels(predicted, K, k1)
    d = z_lens - p_lens
    r_lens = np.stack([d[:, 0], d[:, 2], 0.5 * (d[:, 1] + d[:, 3])], axis=1)
    w = np.array([1.0, 1.0, 2.0]) / config.pixel_sigma ** 2
    return error + 0.5 * float(np.sum(w * (r_lens ** 2 - r_pin ** 2))), sol


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


def _profile_minimum(seq: Sequence, config: FilterConfig, settings: SmootherSettings, solution,
                     step: float, centre: float = 0.0) -> tuple[float, float, dict]:
    """The minimum of the profile ``-log L`` over ``k1`` (a parabola through three points,
    re-centred while its minimum lies beyond them), its standard deviation (inf when the
    profile has no minimum) and the points evaluated, ``{k1: (-log L, solution)}``."""
    points: dict[float, tuple[float, object]] = {}

    def at(k1: float) -> float:
        k1 = float(np.clip(k1, -MAX_RADIAL_K1, MAX_RADIAL_K1))
        if k1 not in points:
            points[k1] = profile_point(seq, config, settings, k1, solution)
        return points[k1][0]

    estimate, curvature = centre, 0.0
    for _ in range(RADIAL_ROUNDS):
        lo, mid, hi = at(centre - step), at(centre), at(centre + step)
        curvature = (lo + hi - 2.0 * mid) / (2.0 * step * step)  # -log L ~ a (k1 - k)^2
        if not curvature > 0:
            return centre, float("inf"), points
        estimate = centre + (lo - hi) / (4.0 * curvature * step)
        if abs(estimate - centre) <= 2.0 * step:
            break
        centre = float(np.clip(estimate, centre - 4.0 * step, centre + 4.0 * step))
    return float(estimate), float(1.0 / np.sqrt(2.0 * curvature)), points


#: Step of the central difference of the undistorted pixels in k1 (they are smooth in k1).
K1_DIFFERENCE = 1e-6


def radial_jacobian(solution, k1: float) -> np.ndarray:
    """The whitened Jacobian (3 N, 1) of a solved smoother's stereo rows ``[uL, uR, v]`` on a
    change of the radial term ``k1`` removed from the pixels (the solution solved with ``k1``
    removed). The measured pinhole pixels are ``undistort(z_lens, k1)``, ``z_lens =
    distort(z, k1)``; GTSAM's error is predicted minus measured, so its derivative is minus the
    measured pixels' (a central difference of :func:`ekf.camera.undistort_pixels`), whitened as
    the linearisation whitens each row: ``sqrt(w) / sigma_c``, ``sigma_c`` the stereo noise's
    ``[sigma, sigma, sigma / sqrt(2)]`` and ``w`` the robust kernel's weight, read off the
    linearised right-hand side of the row against its error."""
    from vislam.ekf.camera import undistort_pixels
    from vislam.graph.extrinsic import stereo_rows
    from vislam.graph.factors import stereo_residuals

    rows = solution.problem.rows
    K = np.asarray(solution.calibration.K, dtype=float)
    z_lens = distort_pixels(rows.z, K, k1)
    h = K1_DIFFERENCE
    dz = (undistort_pixels(z_lens, K, k1 + h) - undistort_pixels(z_lens, K, k1 - h)) / (2.0 * h)
    d_measured = np.stack([dz[:, 0], dz[:, 2], 0.5 * (dz[:, 1] + dz[:, 3])], axis=1)
    ratio = np.array([1.0, 1.0, np.sqrt(2.0)])  # 1 / sigma_c in units of 1 / sigma
    r, _ = stereo_residuals(solution.poses, solution.landmarks, solution.calibration, rows)
    e = -r * ratio  # GTSAM's error (predicted - measured) times sigma / sigma_c
    b = solution.linearised()[0].b[stereo_rows(solution)].reshape(-1, 3)
    ee = np.sum(e * e, axis=1)
    scale = np.where(ee > 1e-18, -np.sum(b * e, axis=1) / np.where(ee > 1e-18, ee, 1.0), np.nan)
    scale = np.where(np.isfinite(scale), scale, np.nanmedian(scale) if np.isfinite(scale).any() else 0.0)
    return (-(scale[:, None] * ratio) * d_measured).reshape(-1, 1)


def radial_fold_gain(solution, k1: float, stretch_s: float = 10.0):
    """The radial term's out-of-sample gain over none (:func:`graph.out_of_sample.fold_gain`,
    folds of ``stretch_s`` seconds) at a smoother solved with ``k1`` removed from its pixels:
    the term fitted without each stretch against the null ``k1 = 0`` (a change of ``-k1``)."""
    from vislam.graph.extrinsic import stereo_rows
    from vislam.graph.out_of_sample import fold_gain, term_rows

    A_p, b_p, folds = term_rows(solution, stereo_rows(solution), radial_jacobian(solution, k1),
                                stretch_s)
    return fold_gain(A_p, b_p, folds, np.array([-float(k1)]), np.ones(1, dtype=bool))


def radial_profile(seq: Sequence, config: FilterConfig, settings: SmootherSettings, solution,
                   step: float = RADIAL_STEP) -> RadialFit:
    """The radial term of ``seq``'s pixels (module docstring) at the model of ``config``
    (``seq`` with the extrinsic in use), starting from the smoother's ``solution`` there."""
    n_obs = max(len(solution.problem.rows), 2)
    threshold = float(np.log(n_obs))  # BIC: k ln n, one parameter
    criterion = f"BIC (ln n, n = {n_obs} stereo observations)"
    estimate, std, points = _profile_minimum(seq, config, settings, solution, step)
    if not np.isfinite(std):
        log.info("radial term: the profile likelihood has no minimum near %g", estimate)
        return RadialFit(None, estimate, std, {
            "statistic": 0.0, "threshold": threshold, "criterion": criterion,
            "decision": "none (the likelihood has no minimum)"})
    # The profile's minimum is biased by the pixel noise (about -0.005 at 1 px on the
    # simulator, growing with sigma^2: the landmarks are fitted to the same noisy pixels).
    # A parametric bootstrap measures it: the same drive made from the solution through the
    # lens found, with the identified pixel noise, identified again.
    replicate, replicate_config = _replicate(solution, config, estimate,
                                             np.random.default_rng(BOOTSTRAP_SEED))
    again, _, _ = _profile_minimum(replicate, replicate_config, settings, solution, step,
                                   centre=float(np.clip(estimate, -MAX_RADIAL_K1, MAX_RADIAL_K1)))
    bias = again - estimate
    k1 = float(np.clip(estimate - bias, -MAX_RADIAL_K1, MAX_RADIAL_K1))
    std = std * float(np.sqrt(2.0))  # the replicate's own scatter enters the correction
    statistic = (k1 / std) ** 2  # Wald, against none
    keep = statistic > threshold
    # the solution under the term, where EM goes on from (only when it is kept); the term must
    # also predict held-out stretches better than none (issue 34 item 2, graph.out_of_sample)
    sol = held_out = None
    if keep:
        sol = profile_point(seq, config, settings, k1, solution)[1]
        held_out = radial_fold_gain(sol, k1)
        keep = held_out.improves
        if not keep:
            sol = None
    log.info("radial term: k1 %.5f +- %.5f (profile %.5f, bootstrap bias %.5f), Wald %.1f "
             "against BIC %.1f: %s", k1, std, estimate, bias, statistic, threshold,
             "kept" if keep else "none")
    return RadialFit(
        k1=k1 if keep else None, estimate=k1, std=std,
        test={"statistic": statistic, "threshold": threshold, "criterion": criterion,
              "decision": ("radial term" if keep else "none (the data support none)"
                           if held_out is None else "none (passes BIC in sample, but fitted "
                           "without a stretch it predicts that stretch no better)"),
              "out_of_sample": None if held_out is None else held_out.to_dict(),
              "profile_minimum": estimate, "bootstrap_bias": bias,
              "profile": {f"{k:.6g}": v for k, (v, _) in sorted(points.items())}},
        solution=sol)
