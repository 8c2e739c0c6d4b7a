"""Does the model explain its drive? Dead reckoning against the smoother over stretches (issue 34).

A model can pass every per-interval test (:mod:`graph.data_check`) and still not explain the
drive: an error that is slow (a tracker's drift along its tracks, a lens or lever-arm error
that leans every track the same way, a speed-scale error of the velocities) is small in each
interval and large over a stretch. This test looks at the stretches, from the drive alone.

It is Hausman's specification test. Over a stretch of the drive from frame ``a`` to frame
``b``, two estimates of the relative motion ``X_a^-1 X_b`` are at hand:

* dead reckoning's, ``D = Delta_a ... Delta_b-1`` (the measured motions the smoother's motion
  factors use, bias removed), with covariance ``P_D`` from the model's twist noise ``W``,
  propagated in GTSAM's right perturbation: ``P_k+1 = Ad(Delta_k^-1) P_k Ad(Delta_k^-1)^T +
  G_k W G_k^T``, ``G_k = tau_k J_r(tau_k u_k)`` (:func:`graph.pose_conversions.interval_jacobians`);
* the smoother's, ``S = X_a^-1 X_b``, with covariance ``P_S = J Sigma_ab J^T``, ``Sigma_ab`` the
  joint marginal of the two poses (solved from the reduced pose system,
  :meth:`graph.marginals.LandmarksEliminated.pose_solve`) and ``J = [-Ad(S^-1), I]``.

When the model is right, the smoother is the efficient estimate and dead reckoning an unbiased
one that uses part of the same data, so their difference ``d = Log(D^-1 S)`` has covariance
``V = P_D - P_S`` (the efficient estimate is uncorrelated with its difference from any other
unbiased one). Then ``d^T V^+ d`` is chi-square with as many degrees of freedom as ``V`` has
directions. When the model claims more than the data hold (vision overconfident, velocities
overconfident, either biased over the stretch), the two disagree by more than ``V`` allows. The
test cannot say which of the two is wrong; it says that the model does not explain the drive.

Directions where vision adds almost nothing to dead reckoning (``V`` below
:data:`MIN_INFORMATION_FRACTION` of ``P_D`` in the eigenbasis of ``P_D^-1/2 V P_D^-1/2``) carry
no evidence and are left out, as in :mod:`graph.data_check`; a stretch without vision tests
nothing. The stretches are the velocity check's (:func:`graph.stretches.stretch_labels`),
each tested at ``level``; the drive as a whole by the sum of the stretches' statistics (they
do not overlap; they share the posterior, a small effect) against ``chi2.ppf(level, dof)``.

Known limits. The covariances are first-order at the solution, with the robust kernel's weights.
With a joint gyro bias the test is conditional on the estimated bias (as the marginals are,
:func:`graph.factors.fix_bias`). The twist-smoothness prior where no track spans an interval is
part of the model: it is information dead reckoning lacks, as vision is.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import gtsam
import numpy as np

from vislam.ekf import chi_square as chi2_dist
from vislam.ekf.config import FilterConfig
from vislam.ekf.conventions import estimate_cov_to_gtsam
from vislam.ekf.errors import InputError

log = logging.getLogger(__name__)

#: A direction of a stretch's difference whose variance ``V`` is below this fraction of dead
#: reckoning's own (``P_D``) is left out: vision barely improves on dead reckoning there, and
#: both estimates are nearly the same numbers.
MIN_INFORMATION_FRACTION = 0.01

#: The stretch length (s) and the level of the tests, as `vislam bench` runs them.
STRETCH_S = 10.0
LEVEL = 0.999


@dataclass(frozen=True)
class StretchDrift:
    """One stretch: frames ``first``..``last`` (times ``start_s``..``end_s`` from the drive's
    first frame), the statistic ``chi2`` with ``dof`` directions tested, its ``threshold``
    (``chi2.ppf(level, dof)``; 0 when nothing is tested), and the difference itself: ``d``
    (6,) in GTSAM's rotation-first order, and the two sides' sigmas along the translation
    (m) and rotation (rad), for the report."""

    first: int
    last: int
    start_s: float
    end_s: float
    chi2: float
    dof: int
    threshold: float
    d: tuple[float, ...]
    translation_m: float  # |d| translation
    rotation_rad: float  # |d| rotation
    dead_reckoning_sigma_m: float  # sqrt(trace P_D) translation
    smoother_sigma_m: float  # sqrt(trace P_S) translation

    @property
    def ratio(self) -> float:
        return float(self.chi2 / self.dof) if self.dof else 0.0

    @property
    def flagged(self) -> bool:
        return self.dof > 0 and self.chi2 > self.threshold


@dataclass(frozen=True)
class DriftCheck:
    """What :func:`drift_check` found: one :class:`StretchDrift` per stretch and the drive's
    sum (``chi2`` over ``dof``, against ``threshold`` at ``level``)."""

    stretches: tuple[StretchDrift, ...]
    chi2: float
    dof: int
    threshold: float
    level: float
    stretch_s: float

    @property
    def ratio(self) -> float:
        """chi2 / dof over the drive: 1 on average when the model explains it."""
        return float(self.chi2 / self.dof) if self.dof else 0.0

    @property
    def flagged(self) -> tuple[StretchDrift, ...]:
        return tuple(s for s in self.stretches if s.flagged)

    @property
    def explains(self) -> bool:
        """The model explains the drive: the sum is within its threshold (or nothing is
        tested)."""
        return self.dof == 0 or self.chi2 <= self.threshold

    def lines(self) -> list[str]:
        """Short report lines: the verdict in words and the worst stretch."""
        n = sum(1 for s in self.stretches if s.dof)
        level = f"{100.0 * self.level:g} %"
        if n == 0:
            return ["dead reckoning vs the smoother: nothing to test (vision adds nothing "
                    "over any stretch)"]
        head = (f"dead reckoning vs the smoother over {n} stretches of {self.stretch_s:g} s: "
                f"chi2/dof {self.ratio:.2f} ({self.dof} dof)")
        if self.explains:
            out = [head + f": they agree within what the model claims ({level})"]
        else:
            out = [head + f": the model does not explain the drive ({level}): the two "
                   f"disagree {np.sqrt(self.ratio):.1f}x beyond what it claims"]
        bad = self.flagged
        if bad:
            worst = max(bad, key=lambda s: s.ratio)
            out.append(f"  {len(bad)} of {n} stretches beyond their threshold; worst t "
                       f"{worst.start_s:.0f}-{worst.end_s:.0f} s: {worst.translation_m:.3f} m and "
                       f"{np.degrees(worst.rotation_rad):.2f} deg apart (chi2/dof "
                       f"{worst.ratio:.1f}; dead reckoning's sigma {worst.dead_reckoning_sigma_m:.3f}"
                       f" m, the smoother's {worst.smoother_sigma_m:.3f} m)")
        return out

    def to_dict(self) -> dict:
        return {"chi2": self.chi2, "dof": self.dof, "ratio": self.ratio,
                "threshold": self.threshold, "level": self.level, "stretch_s": self.stretch_s,
                "explains": self.explains, "n_stretches": len(self.stretches),
                "n_flagged": len(self.flagged),
                "worst_ratio": max((s.ratio for s in self.stretches), default=0.0)}


def dead_reckoning_relative(deltas: np.ndarray, scale: np.ndarray, W: np.ndarray,
                            first: int, last: int) -> tuple[gtsam.Pose3, np.ndarray]:
    """Dead reckoning's relative motion from frame ``first`` to ``last`` and its covariance
    (6, 6), GTSAM's right perturbation (module docstring): ``deltas`` (T-1, 4, 4) the measured
    motions, ``scale`` (T-1, 6, 6) their ``tau J_r``, ``W`` the twist noise (6, 6, GTSAM order)."""
    rel = gtsam.Pose3()
    P = np.zeros((6, 6))
    for k in range(first, last):
        step = gtsam.Pose3(deltas[k])
        A = step.inverse().AdjointMap()
        P = A @ P @ A.T + scale[k] @ W @ scale[k].T
        rel = rel.compose(step)
    return rel, P


def smoother_relative(poses: np.ndarray, joint: np.ndarray, first: int,
                      last: int) -> tuple[gtsam.Pose3, np.ndarray]:
    """The smoother's relative motion ``X_first^-1 X_last`` and its covariance from the joint
    marginal ``joint`` (12, 12) of the two poses (GTSAM's right perturbation)."""
    rel = gtsam.Pose3(poses[first]).between(gtsam.Pose3(poses[last]))
    J = np.hstack([-rel.inverse().AdjointMap(), np.eye(6)])
    return rel, J @ joint @ J.T


def hausman_statistic(d: np.ndarray, P_D: np.ndarray, P_S: np.ndarray,
                      fraction: float = MIN_INFORMATION_FRACTION) -> tuple[float, int]:
    """``d^T V^+ d`` over the directions of ``V = P_D - P_S`` holding at least ``fraction`` of
    ``P_D``'s variance (in the eigenbasis of ``P_D^-1/2 V P_D^-1/2``), and how many there are."""
    L = np.linalg.cholesky(0.5 * (P_D + P_D.T))
    Li = np.linalg.inv(L)
    Vn = Li @ (P_D - P_S) @ Li.T
    lam, U = np.linalg.eigh(0.5 * (Vn + Vn.T))
    keep = lam >= fraction
    proj = U.T @ (Li @ d)
    return float(np.sum(proj[keep] ** 2 / lam[keep])), int(keep.sum())


def posterior_system(solution):
    """``(deltas, reduced)`` of a solved smoother: the measured motions its motion factors use
    (T-1, 4, 4) and its information matrix at the solution with the landmarks eliminated
    (:class:`graph.marginals.LandmarksEliminated`). With a joint gyro bias both are given the
    estimated bias (:func:`graph.factors.fix_bias`): the motions with it removed, the graph
    without the bias variable."""
    from vislam.graph.factors import fix_bias
    from vislam.graph.gyro_bias import corrected_deltas
    from vislam.graph.marginals import linearise

    if solution.bias_model is None:  # the solution's own graph: its linearisation, computed once
        return solution.deltas, solution.linearised()[1]
    graph, values = fix_bias(solution.problem, solution.values, solution.deltas, solution.noise,
                             solution.bias_model)
    deltas = corrected_deltas(solution.deltas, solution.bias_model.D,
                              np.asarray(solution.gyro_bias, dtype=float))
    _, reduced = linearise(graph, values, solution.poses.shape[0],
                           "linearising given the estimated bias")
    return deltas, reduced


def joint_pose_marginals(reduced, n_frames: int, pairs: list[tuple[int, int]]) -> list[np.ndarray]:
    """The joint marginal (12, 12) of each pair of poses, from the reduced pose system."""
    if not pairs:
        return []
    cols = np.zeros((6 * n_frames, 12 * len(pairs)))
    for i, (a, b) in enumerate(pairs):
        cols[6 * a:6 * a + 6, 12 * i:12 * i + 6] = np.eye(6)
        cols[6 * b:6 * b + 6, 12 * i + 6:12 * i + 12] = np.eye(6)
    Y = reduced.pose_solve(cols)
    out = []
    for i, (a, b) in enumerate(pairs):
        rows = np.r_[6 * a:6 * a + 6, 6 * b:6 * b + 6]
        block = Y[rows, 12 * i:12 * i + 12]
        out.append(0.5 * (block + block.T))
    return out


def drift_check(solution, config: FilterConfig, *, stretch_s: float = STRETCH_S,
                level: float = LEVEL) -> DriftCheck:
    """Dead reckoning against the smoother per stretch of the drive (module docstring).
    ``solution`` a :class:`graph.smoother.SmootherSolution` solved with ``config``; ``stretch_s``
    the stretch length (s), ``level`` the tests' level.

    Raises InputError for a bad ``stretch_s`` or ``level``, EstimationError when the posterior
    cannot be computed."""
    if not (np.isfinite(stretch_s) and stretch_s > 0):
        raise InputError(f"drift check: stretch length must be a positive number of seconds, "
                         f"got {stretch_s!r}")
    if not (np.isfinite(level) and 0.0 < level < 1.0):
        raise InputError(f"drift check: level must be between 0 and 1, got {level!r}")
    from vislam.graph.pose_conversions import interval_jacobians
    from vislam.graph.stretches import stretch_labels

    deltas, reduced = posterior_system(solution)
    poses = solution.poses
    T = poses.shape[0]
    W = estimate_cov_to_gtsam(config.velocity_cov)
    times = np.asarray(solution.cleaned.timestamps, dtype=float)
    rel_t = times - times[0]
    stretches: list[StretchDrift] = []
    if T >= 2:
        scale = interval_jacobians(solution.twist[:T - 1], solution.tau[:T - 1])
        labels = stretch_labels(rel_t[:-1], stretch_s)
        starts = np.flatnonzero(np.r_[True, np.diff(labels) != 0])  # labels never decrease
        spans = [(int(a), int(b)) for a, b in zip(starts, np.r_[starts[1:], labels.size])]
        for (a, b), joint in zip(spans, joint_pose_marginals(reduced, T, spans)):
            D, P_D = dead_reckoning_relative(deltas, scale, W, a, b)
            S, P_S = smoother_relative(poses, joint, a, b)
            d = gtsam.Pose3.Logmap(D.between(S))
            c, k = hausman_statistic(d, P_D, P_S)
            stretches.append(StretchDrift(
                first=a, last=b, start_s=float(rel_t[a]), end_s=float(rel_t[b]), chi2=c, dof=k,
                threshold=float(chi2_dist.ppf(level, k)) if k else 0.0,
                d=tuple(float(x) for x in d), translation_m=float(np.linalg.norm(d[3:])),
                rotation_rad=float(np.linalg.norm(d[:3])),
                dead_reckoning_sigma_m=float(np.sqrt(np.trace(P_D[3:, 3:]))),
                smoother_sigma_m=float(np.sqrt(max(np.trace(P_S[3:, 3:]), 0.0)))))
    c = float(sum(s.chi2 for s in stretches))
    k = int(sum(s.dof for s in stretches))
    result = DriftCheck(stretches=tuple(stretches), chi2=c, dof=k,
                        threshold=float(chi2_dist.ppf(level, k)) if k else 0.0,
                        level=float(level), stretch_s=float(stretch_s))
    log.info("drift check: chi2/dof %.2f over %d stretches (%d dof), %d flagged", result.ratio,
             len(stretches), k, len(result.flagged))
    return result


def drift_widening(seq, config: FilterConfig, model, settings, *, warm_start=None,
                   stretch_s: float = STRETCH_S, level: float = LEVEL) -> tuple[DriftCheck, float]:
    """The check of ``model`` (an :class:`ekf.model.Model`) on ``seq`` as the estimators see
    them (:func:`ekf.model.model_sequence`, :func:`ekf.model.model_config` over ``config``),
    the smoother solved with ``settings`` (from ``warm_start``'s solution when given), and the
    factor by which every noise level of the model is to be widened: 1 where the model explains
    the drive, else ``sqrt(chi2 / dof)``. Widening the velocity, gyro and pixel sigmas together
    by one factor keeps what each estimator makes of the data (the same weights) and scales
    every covariance by its square, so the stretches' statistic then averages 1: the least
    widening under which the drive's own stretches agree with the model. The test cannot tell
    which source claims too much, so it does not pick one."""
    from vislam.ekf.model import model_config, model_sequence
    from vislam.graph.smoother import solve_smoother

    cfg = model_config(config, model)
    solution = solve_smoother(model_sequence(seq, model), cfg, settings, warm_start=warm_start)
    check = drift_check(solution, cfg, stretch_s=stretch_s, level=level)
    return check, 1.0 if check.explains else float(np.sqrt(check.ratio))


__all__ = ["DriftCheck", "LEVEL", "MIN_INFORMATION_FRACTION", "STRETCH_S", "StretchDrift",
           "dead_reckoning_relative", "drift_check", "drift_widening", "hausman_statistic", "joint_pose_marginals",
           "posterior_system", "smoother_relative"]
