"""Velocity and gyro errors correlated in time: their long-run sigma, from whole blocks of the
drive.

Every estimator treats the twist noise of one interval as independent of the next. A vehicle's
velocity source does not make it so: its errors may correlate for seconds (docs/findings.md:
"Velocity errors are slow"), and a drive's drift is built from that slow part. EM fits the
white model to the interval residuals (:mod:`graph.identification`); where the motion is
smooth and vision weak it then finds the high-frequency spread, and every estimator is
overconfident about what the velocities integrate to.

What the estimators need is the twist noise's long-run variance, the white-equivalent that
gives the right variance of a sum over many intervals (the Newey-West correction the pixels'
model makes along tracks, :mod:`graph.track_correlation`). It is measured here the way the
batch-means method measures a long-run variance: on the drive cut into blocks of
``BLOCK_SECONDS``, longer than the errors' correlation. For block ``B = [s, e]``

    eps_B = Log(Delta_B^-1 X_s^-1 X_e),   Delta_B = Delta_s ... Delta_e-1     (the block residual)

and a white-equivalent interval covariance ``W = diag(sigma^2)`` (GTSAM order, rotation first)
predicts

    E[eps_B eps_B^T] = sum_k A_k W A_k^T,  A_k = Ad((Delta_k+1 ... Delta_e-1)^-1) tau_k J_r(tau_k u_k)

(interval k's right perturbation moved to the block's end). The expected squared residual of a
solved smoother is ``eps_B eps_B^T + C Sigma C^T`` with ``C = [-Ad(rel^-1), I]`` on
``(X_s, X_e)`` and ``Sigma`` the Laplace posterior (``H^-1`` of the whole graph, landmarks
included): the posterior term gives back what the smoother took into the trajectory, as in
EM's M-step. Matching the diagonals over all blocks is a non-negative least-squares problem in
``sigma^2``; the smoother is solved again with it, and so on to the fixed point (EM at the
scale of blocks; :func:`fixed_point` finds it by a secant search per axis). Each axis is kept
at least at its white per-sample sigma.

Decision, per axis: the long-run sigma replaces the white one when its variance exceeds the
per-sample variance of white samples by more than a chi-square with ``n_blocks`` degrees of
freedom allows (``LEVEL``, one-sided): under white samples the block estimate is a mean of
``n_blocks`` squares. The model then carries the ratio ``tau = sigma_long_run^2 /
sigma_interval^2`` (``velocity_correlation_time``, ``gyro_correlation_time``; frames, the
integrated correlation time of the interval noise) and the estimators use ``sigma sqrt(tau)``
(:func:`ekf.model.model_config`). With the "mean" pairing two intervals share a sample, so
white samples give ``tau = 2``; the test's null is the samples', so that alone is not
evidence (and :func:`ekf.model.model_config` gives every axis at least that ratio,
:func:`ekf.model.white_sample_ratio`, kept here or not). The simulator's white noise keeps none; what real drives keep is in docs/findings.md.

What the blocks cannot determine (issue 34). Each axis's long-run sigma has its own
uncertainty, ``sd(log sigma) = 1 / sqrt(2 n_blocks (1 - r))`` with ``r`` the posterior's share of
the blocks' expected squared residuals at the fixed point (:mod:`graph.parameter_uncertainty`:
a flat fixed point, where vision leaves the blocks to the posterior, has ``r`` near 1). An axis
it leaves undetermined takes a conservative value instead of "white": the upper end of what the
blocks allow, capped by a prior (a slow speed-scale error on the velocity axes; the gyro bias's
uncertainty on the gyro axes), never below the estimate. A long-run level is undetermined
above ``UNDETERMINED_LOG_SD`` (log 2 / 2: the blocks cannot place it within a factor of 2 at
two standard deviations; a white level's line is stricter, graph.parameter_uncertainty). A
drive of fewer than ``MIN_BLOCKS``
blocks measures nothing: every axis takes its prior. A 25 s drive has 5 blocks, so even with
``r = 0`` its sd is 0.32: short drives never determine their slow errors, and the prior speaks.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import gtsam
import numpy as np
from scipy.optimize import nnls
from vislam.ekf import chi_square as chi2

from vislam.graph.parameter_uncertainty import (MAX_LOG_SD, conservative_level, log_sigma_sd,
                                                 missing_fraction)
from vislam.graph.pose_conversions import interval_jacobians, to_pose3

log = logging.getLogger(__name__)

#: Block length in seconds: longer than the velocity errors' correlation (a few seconds on the
#: drives measured, docs/findings.md), short enough for MIN_BLOCKS blocks on a two-minute drive.
BLOCK_SECONDS = 5.0
#: Fewer blocks than this: nothing measured; every axis is undetermined and takes its prior.
#: From two blocks on the long-run sigma is measured, and its own uncertainty
#: (:mod:`graph.parameter_uncertainty`: ``1 / sqrt(2 n_blocks (1 - r))``) decides whether the
#: drive determines it; a short drive's few blocks rarely do.
MIN_BLOCKS = 2
#: Above this sd(log sigma) a long-run level is undetermined: the blocks cannot place it within a
#: factor of 2 at two standard deviations. (At graph.parameter_uncertainty's stricter line for
#: white levels, 0.15, a drive needs 23 blocks with vision pinning every one: the 110 s
#: 2019-edition drive of 0027 then took the prior on its forward axis, and its smoother's ATE
#: went from 0.62 m to 0.75 m.)
UNDETERMINED_LOG_SD = float(np.log(2.0) / 2.0)
#: What an undetermined axis is capped by, in reports (gyro first, as AXES).
PRIOR_WORDS = ("the gyro bias's uncertainty",) * 3 + (
    "the prior on slow speed errors",) * 3
#: One-sided level of the per-axis chi-square test against white samples: six axes are
#: tested at once, so 0.999 keeps the chance of a white drive keeping one near 0.6 % (at 0.99
#: a simulated white 80 s drive kept its vertical axis at a variance ratio of 2.9).
LEVEL = 0.999
#: Fixed point: stop when no log sigma moves by more than this.
RTOL = 0.01
#: Most smoother solves of the fixed point.
MAX_SOLVES = 20
#: Largest change of a log sigma in one secant step (a factor of 4).
MAX_LOG_STEP = float(np.log(4.0))
#: Axis names in GTSAM order (rotation first), for reports.
AXES = ("gyro x", "gyro y", "gyro z", "velocity x", "velocity y", "velocity z")


@dataclass
class BlockStatistics:
    """One solved smoother's block residuals: ``expected`` (6,) the sum over blocks of the
    expected squared residual, ``design`` (6, 6) how the interval variances move it (GTSAM
    order), ``n_blocks``."""

    expected: np.ndarray
    design: np.ndarray
    n_blocks: int
    #: (6,) the posterior's part of ``expected`` (what the data leave unresolved)
    posterior: np.ndarray | None = None

    @property
    def variance(self) -> np.ndarray:
        """(6,) the white-equivalent interval variances matching the blocks (non-negative
        least squares)."""
        s2, _ = nnls(self.design, self.expected)
        return s2


@dataclass
class MotionCorrelation:
    """The long-run twist noise (GTSAM order [rotation; translation], per interval) and the
    per-axis decision. ``time`` (6,) is ``sigma_long_run^2 / sigma_interval^2`` where kept, 1
    elsewhere (also when not tested: ``tested`` False and ``why``)."""

    time: np.ndarray
    long_run_sigma: np.ndarray | None = None
    ratio: np.ndarray | None = None  # long-run variance / white per-sample variance
    threshold: float | None = None
    n_blocks: int = 0
    block_frames: int = 0
    solves: int = 0
    converged: bool = False
    tested: bool = False
    why: str = ""
    kept: tuple[str, ...] = ()
    #: per axis, how well the drive determines its long-run sigma and the value taken
    #: (:class:`graph.parameter_uncertainty.LevelUncertainty`)
    levels: tuple = ()

    @property
    def undetermined(self) -> tuple[str, ...]:
        """The axes whose long-run sigma the drive cannot determine."""
        return tuple(lv.name.removesuffix(" long-run") for lv in self.levels if not lv.determined)

    @property
    def velocity_time(self) -> tuple[float, float, float] | None:
        return _times(self.time[3:])

    @property
    def gyro_time(self) -> tuple[float, float, float] | None:
        return _times(self.time[:3])

    def to_dict(self) -> dict:
        def lst(x):
            return None if x is None else [float(v) for v in np.ravel(x)]

        return {"tested": self.tested, "why": self.why, "n_blocks": self.n_blocks,
                "block_frames": self.block_frames, "level": LEVEL, "threshold": self.threshold,
                "long_run_interval_sigma": lst(self.long_run_sigma),
                "variance_ratio": lst(self.ratio), "correlation_time": lst(self.time),
                "axes": list(AXES), "kept": list(self.kept), "solves": self.solves,
                "converged": self.converged,
                "levels": [lv.to_dict() for lv in self.levels],
                "undetermined": list(self.undetermined),
                "criterion": f"chi-square {LEVEL:g} on n_blocks dof against white samples"}


def _times(t: np.ndarray) -> tuple[float, float, float] | None:
    return tuple(float(x) for x in t) if np.any(t > 1.0) else None


def block_bounds(tau: np.ndarray) -> list[tuple[int, int]]:
    """Blocks ``(s, e)`` of whole intervals of about ``BLOCK_SECONDS`` each (pose indices)."""
    dt = float(np.median(tau)) if len(tau) else 0.0
    if not np.isfinite(dt) or dt <= 0:
        return []
    length = max(int(round(BLOCK_SECONDS / dt)), 1)
    return [(s, s + length) for s in range(0, len(tau) - length + 1, length)]


def transport_jacobians(deltas: np.ndarray, twist: np.ndarray, tau: np.ndarray,
                        s: int, e: int) -> np.ndarray:
    """``A_k`` (e - s, 6, 6) for the intervals of block ``[s, e]`` (module docstring)."""
    out = interval_jacobians(twist[s:e], tau[s:e])
    after = gtsam.Pose3()  # Delta_k+1 ... Delta_e-1
    for k in range(e - 1, s - 1, -1):
        out[k - s] = after.inverse().AdjointMap() @ out[k - s]
        after = to_pose3(deltas[k]).compose(after)
    return out


def block_residual(poses: np.ndarray, deltas: np.ndarray, s: int, e: int) -> tuple[np.ndarray, np.ndarray]:
    """``eps_B`` (6,) of block ``[s, e]`` and its Jacobian blocks on ``X_s`` and ``X_e``."""
    rel = to_pose3(poses[s]).between(to_pose3(poses[e]))
    measured = gtsam.Pose3()
    for k in range(s, e):
        measured = measured.compose(to_pose3(deltas[k]))
    eps = gtsam.Pose3.Logmap(measured.between(rel))
    return eps, -rel.inverse().AdjointMap()


def block_statistics(solution, blocks: list[tuple[int, int]]) -> BlockStatistics:
    """:class:`BlockStatistics` of a solved smoother (:class:`graph.smoother.SmootherSolution`)."""
    _, posterior_of = solution.linearised()
    C = np.zeros((6 * len(blocks), 6 * solution.poses.shape[0]))  # on the poses (X(k): 6k..)
    eps = np.zeros((len(blocks), 6))
    design = np.zeros((6, 6))
    for b, (s, e) in enumerate(blocks):
        eps[b], Cs = block_residual(solution.poses, solution.deltas, s, e)
        rows = slice(6 * b, 6 * b + 6)
        C[rows, 6 * s:6 * s + 6] = Cs
        C[rows, 6 * e:6 * e + 6] = np.eye(6)
        A = transport_jacobians(solution.deltas, solution.twist, solution.tau, s, e)
        design += np.sum(A * A, axis=0)
    Y = posterior_of.pose_solve(C.T)  # (H^-1)_pp C^T
    posterior = np.einsum("ij,ji->i", C, Y)  # diag of C H^-1 C^T
    posterior = posterior.reshape(len(blocks), 6).sum(axis=0)
    return BlockStatistics(np.sum(eps * eps, axis=0) + posterior, design, len(blocks), posterior)


def fixed_point(step, theta: np.ndarray, floor: np.ndarray, rtol: float = RTOL,
                max_solves: int = MAX_SOLVES) -> tuple[np.ndarray, bool]:
    """The log sigmas where ``step`` (the blocks' log sigmas under the model ``theta``) gives
    back ``theta``, at least ``floor``: a secant search on ``h(theta) = step(theta) - theta``
    per axis (the axes barely interact), from one plain step. Plain iteration (EM) creeps
    where vision leaves much of the motion to the posterior (a few % per solve); the secant
    takes the slope of ``h`` into account.
    Steps are at most ``MAX_LOG_STEP``. Returns the last theta and whether it settled."""
    floor = np.asarray(floor, dtype=float)
    prev_theta, prev_h = None, None
    for _ in range(max_solves):
        h = step(theta) - theta
        settled = (np.abs(h) < rtol) | ((theta <= floor + 1e-12) & (h <= 0))
        if np.all(settled):
            return theta, True
        move = h.copy()  # plain step where no slope is known
        if prev_h is not None:
            dh, dt = h - prev_h, theta - prev_theta
            ok = (np.abs(dt) > 1e-12) & (dh * dt < 0)  # h decreasing through the root
            move[ok] = -h[ok] * dt[ok] / dh[ok]
        move = np.clip(move, -MAX_LOG_STEP, MAX_LOG_STEP)
        prev_theta, prev_h = theta, h
        theta = np.maximum(theta + np.where(settled, 0.0, move), floor)
    return theta, False


def motion_correlation(solve, solution, interval_sigma: np.ndarray, sample_sigma: np.ndarray,
                       prior_sigma: np.ndarray | None = None) -> MotionCorrelation:
    """The long-run twist noise of a drive (module docstring).

    ``solve(sigma, warm)`` solves the smoother with interval sigmas ``sigma`` (6,) (GTSAM
    order), warm-started from the solution ``warm``; ``solution`` is the smoother EM ended with
    (at ``interval_sigma``, the white fit), ``sample_sigma`` (6,) the white per-sample sigmas
    (the null and the floor); ``prior_sigma`` (6,) the long-run interval sigma an undetermined
    axis takes at most (:mod:`graph.parameter_uncertainty`: the speed-scale prior on the
    velocity axes; on the gyro axes, the uncertainty of the gyro bias as a slow error of the
    whole drive; 0 for none)."""
    interval_sigma = np.asarray(interval_sigma, dtype=float)
    sample_sigma = np.asarray(sample_sigma, dtype=float)
    prior = np.zeros(6) if prior_sigma is None else np.asarray(prior_sigma, dtype=float)
    floor = np.log(sample_sigma)
    blocks = block_bounds(solution.tau)
    frames = blocks[0][1] - blocks[0][0] if blocks else 0
    if len(blocks) < MIN_BLOCKS:
        # Nothing measured: every axis is undetermined and takes the prior (at least white).
        levels = tuple(conservative_level(f"{a} long-run", s, MAX_LOG_SD, 1.0, p, w, floor=s)
                       for a, s, p, w in zip(AXES, interval_sigma, prior, PRIOR_WORDS))
        value = np.array([lv.value for lv in levels])
        time = (value / interval_sigma) ** 2
        return MotionCorrelation(time, value, n_blocks=len(blocks), block_frames=frames,
                                 why=f"{len(blocks)} blocks of {BLOCK_SECONDS:g} s, fewer than "
                                     f"{MIN_BLOCKS}", levels=levels,
                                 kept=tuple(a for a, t in zip(AXES, time) if t > 1.0))
    state = {"solution": solution, "solves": 0, "stats": None, "theta": None}

    def step(theta: np.ndarray) -> np.ndarray:
        state["solution"] = solve(np.exp(theta), state["solution"])
        state["solves"] += 1
        state["stats"] = block_statistics(state["solution"], blocks)
        state["theta"] = np.array(theta)
        s2 = state["stats"].variance
        out = 0.5 * np.log(np.maximum(s2, 1e-30))
        log.info("motion correlation: interval sigma gyro %s, velocity %s -> blocks' gyro %s, "
                 "velocity %s", np.round(np.exp(theta[:3]), 5), np.round(np.exp(theta[3:]), 4),
                 np.round(np.exp(out[:3]), 5), np.round(np.exp(out[3:]), 4))
        return out

    theta, converged = fixed_point(step, np.maximum(np.log(interval_sigma), floor), floor)
    long_run = np.exp(theta)
    ratio = (long_run / sample_sigma) ** 2
    n = len(blocks)
    threshold = float(chi2.ppf(LEVEL, n) / n)
    if not np.allclose(state["theta"], theta, rtol=0.0, atol=RTOL):
        step(theta)  # the missing information is the EM map's slope at the fixed point itself
    stats = state["stats"]
    missing = missing_fraction(stats.posterior, stats.expected)
    log_sd = log_sigma_sd(n, missing)
    levels = []
    for i, a in enumerate(AXES):
        level = conservative_level(f"{a} long-run", long_run[i], log_sd[i], missing[i], prior[i],
                                   PRIOR_WORDS[i], floor=interval_sigma[i],
                                   undetermined_log_sd=UNDETERMINED_LOG_SD)
        if level.determined and not ratio[i] > threshold:
            # Determined and no larger than white samples allow: white (the test's null).
            level = replace(level, value=float(interval_sigma[i]),
                            why=f"{level.why}; not above white (variance ratio "
                                f"{ratio[i]:.3g} against {threshold:.3g}): white")
        levels.append(level)
    value = np.array([lv.value for lv in levels])
    time = np.maximum((value / interval_sigma) ** 2, 1.0)
    return MotionCorrelation(time, long_run, ratio, threshold, n, frames, state["solves"],
                             converged, True, "", tuple(a for a, t in zip(AXES, time) if t > 1.0),
                             tuple(levels))


__all__ = ["BlockStatistics", "MotionCorrelation", "block_bounds", "block_residual",
           "block_statistics", "motion_correlation", "transport_jacobians", "BLOCK_SECONDS",
           "MIN_BLOCKS", "LEVEL", "AXES", "UNDETERMINED_LOG_SD"]
