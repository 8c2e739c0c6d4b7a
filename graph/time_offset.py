"""The velocity streams' time offsets against the camera, by maximum likelihood around the
smoother (issue 39 item 1; the model keys ``velocity_time_offset``, ``gyro_time_offset``,
:mod:`ekf.model`).

A stream whose stamps are ``d`` late holds at stamp ``t`` the motion of ``t - d``; on the
camera's clock its value at ``t`` is its value at stamp ``t + d``, to first order
``v(t) + d a(t)``, ``a`` the stream's own time derivative (central differences over its
stamps, :func:`numpy.gradient`), paired as the velocities are (:func:`ekf.prediction.
paired_velocities`). So ``d`` enters each motion factor linearly: the twist noise of interval k
becomes ``w_k - d a_k`` (the linear part for the velocity stream's ``d``, the rotational part
for the gyro's). From a solved smoother (:func:`graph.identification.motion_residuals`) the
score of ``(d_v, d_g)`` is ``sum_k A_k^T W^-1 w_k`` and the information, the poses profiled
out, ``sum_k A_k^T W^-1 (W - C Sigma C^T) W^-1 A_k`` (``W`` the interval covariance, ``C
Sigma C^T`` the posterior's share of the interval's residual: where vision does not pin the
motion, the trajectory follows the stream and the residual says nothing about its timing).
:func:`offset_step` is the Gauss-Newton step; :func:`identify_time_offsets` applies it (the
streams resampled, :func:`ekf.model.time_shifted`), re-solves warm-started (EM continued) and
repeats with secant steps (the score's slope measured between solves, which also gives the
sigma), safeguarded: each solve's score narrows a bracket around the root, a secant step more
than twice the current Gauss-Newton step takes that step instead, and a step out of the bracket
bisects it; until the step is below ``STEP_TOL``, at most ``MAX_STEPS`` re-solves. The noise in
``a`` only slows the iteration: its fixed point is where the exact residuals are uncorrelated
with the stream's rate. The rate is a local quadratic's slope over ``RATE_WINDOW`` samples.

The decision (BIC, as the gyro bias's): a stream keeps an offset when the score statistic at
zero, ``score^2 / information``, exceeds ``ln n`` (one parameter, ``n`` intervals); otherwise
it stays zero and the model is what it is without this module. The sigma assumes white
interval noise: where the model carries a long-run ratio (correlated errors) it is optimistic.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vislam.ekf.conventions import estimate_cov_to_gtsam
from vislam.ekf.model import time_shifted
from vislam.ekf.prediction import paired_velocities

#: The streams, in the order of every array here.
STREAMS = ("velocity", "gyro")
#: The iteration stops when no offset moves by more than this (s).
STEP_TOL = 1e-3
#: Samples of the local quadratic whose slope is a stream's rate (Savitzky-Golay; about 1 s at
#: 10 Hz: the rate of a noisy stream from neighbouring samples is mostly their noise, which
#: weakens the test at zero; the stamps are taken as evenly spaced at their median interval).
RATE_WINDOW = 11
#: Largest offset the iteration moves to (s): beyond it the streams would lose their ends' share
#: of the drive (the model accepts up to ekf.model.MAX_TIME_OFFSET).
MAX_OFFSET = 0.5
#: Steps at most (each a warm-started re-solve).
MAX_STEPS = 4


@dataclass
class OffsetStep:
    """One Gauss-Newton step of the offsets (s) from a solved smoother."""

    step: np.ndarray  # (2,) velocity, gyro
    information: np.ndarray  # (2, 2)
    score: np.ndarray  # (2,)
    n_intervals: int

    @property
    def sigma(self) -> np.ndarray:
        """(2,) standard deviations (s) of each offset, the other one free."""
        return np.sqrt(np.diag(np.linalg.pinv(self.information)))

    @property
    def statistic(self) -> np.ndarray:
        """(2,) score statistic of each stream alone: score^2 / information."""
        d = np.diag(self.information)
        return np.where(d > 0, self.score ** 2 / np.where(d > 0, d, 1.0), 0.0)


def stream_rates(seq, pairing: str) -> np.ndarray:
    """``A`` (T-1, 6, 2), GTSAM order [rot; trans]: the derivative of each interval's twist
    with respect to the velocity stream's offset (column 0, the translation rows) and the
    gyro's (column 1, the rotation rows)."""
    from scipy.signal import savgol_filter

    t = np.asarray(seq.timestamps, dtype=float)
    u = np.asarray(seq.velocities, dtype=float)
    if t.size >= RATE_WINDOW:  # a local quadratic's slope: noisy samples' differences are mostly noise
        rate = savgol_filter(u, RATE_WINDOW, 2, deriv=1, delta=float(np.median(np.diff(t))),
                             axis=0, mode="interp")
    else:
        rate = np.gradient(u, t, axis=0)  # (T, 6) [v; w]
    paired = paired_velocities(rate, pairing)
    out = np.zeros((paired.shape[0], 6, 2))
    out[:, 3:, 0] = paired[:, :3]
    out[:, :3, 1] = paired[:, 3:]
    return out


def offset_step(residuals, seq, config) -> OffsetStep:
    """The Gauss-Newton step of both offsets from ``residuals`` ``(w, cw)``, the twist noise
    (n, 6) and its posterior covariance (n, 6, 6) of a solved smoother of ``seq`` (on the clock of
    the offsets it was solved with; graph.identification.noise_statistics: motion_w, motion_cw) under
    ``config`` (its interval sigmas and pairing): module docstring."""
    w, cw = residuals
    W = estimate_cov_to_gtsam(config.velocity_cov)
    W_inv = np.linalg.inv(W)
    A = stream_rates(seq, config.velocity_pairing)[:w.shape[0]]
    WA = W_inv @ A  # (n, 6, 2)
    score = np.einsum("nij,ni->j", WA, w)
    profiled = W[None] - cw
    info = np.einsum("nia,nij,njb->ab", WA, profiled, WA)
    info = 0.5 * (info + info.T)
    step = np.linalg.lstsq(info, score, rcond=1e-12)[0] if np.any(info) else np.zeros(2)
    return OffsetStep(step=step, information=info, score=score, n_intervals=int(w.shape[0]))


def shifted(seq, offsets) -> object:
    """``seq`` with its velocity and gyro streams moved onto the camera's clock by ``offsets``
    (s, velocity then gyro; zero leaves a stream as it is), as ekf.model.model_sequence does."""
    import dataclasses

    v_off, g_off = (float(x) for x in offsets)
    changes = {}
    if v_off:
        changes["linear_velocity"] = time_shifted(seq.timestamps, seq.linear_velocity, v_off)
    if g_off:
        changes["angular_velocity"] = time_shifted(seq.timestamps, seq.angular_velocity, g_off)
    return dataclasses.replace(seq, **changes) if changes else seq


@dataclass
class TimeOffsetFit:
    """What the identification found about the streams' offsets (s; velocity, gyro)."""

    estimate: np.ndarray  # (2,) the iterated estimate (zero for a stream not supported)
    sigma: np.ndarray  # (2,)
    first_estimate: np.ndarray  # (2,) the first Gauss-Newton step from zero, both streams
    first_sigma: np.ndarray
    statistic: np.ndarray  # (2,) score statistic at zero
    threshold: float  # ln n
    supported: np.ndarray  # (2,) bool
    steps: int
    converged: bool = True  # the last step below STEP_TOL (False: MAX_STEPS reached)

    def offset(self, stream: str) -> float | None:
        i = STREAMS.index(stream)
        return float(self.estimate[i]) if self.supported[i] else None

    def offset_sigma(self, stream: str) -> float | None:
        i = STREAMS.index(stream)
        return float(self.sigma[i]) if self.supported[i] else None

    def to_dict(self) -> dict:
        return {
            "criterion": "BIC (ln n per stream, score statistic at zero)",
            "threshold": self.threshold, "steps": self.steps, "converged": self.converged,
            **{s: {"estimate": float(self.estimate[i]) if self.supported[i]
                   else float(self.first_estimate[i]),
                   "sigma": float(self.sigma[i]) if self.supported[i] else float(self.first_sigma[i]),
                   "statistic": float(self.statistic[i]),
                   "decision": "offset" if self.supported[i] else "no offset"}
               for i, s in enumerate(STREAMS)},
        }


def identify_time_offsets(seq, em, refit):
    """``(fit, em, seq)``: the offsets of ``seq``'s streams around ``em`` (an
    graph.identification.EMResult on ``seq``) and, where the data support one, ``em`` refitted
    on the shifted streams (``refit(seq, em) -> EMResult``, warm-started) and the shifted
    sequence; where they support none, ``em`` and ``seq`` themselves, untouched.
    Each offset is scored from the motion residuals of ``em``'s final E-step (its statistics'
    ``motion_w`` and ``motion_cw``), at no further cost."""
    first = offset_step((em.stats.motion_w, em.stats.motion_cw), seq, em.config)
    n = max(first.n_intervals, 2)
    threshold = float(np.log(n))
    supported = first.statistic > threshold
    first_sigma = first.sigma
    if not supported.any():
        return TimeOffsetFit(estimate=np.zeros(2), sigma=first_sigma,
                             first_estimate=first.step, first_sigma=first_sigma,
                             statistic=first.statistic, threshold=threshold,
                             supported=supported, steps=0, converged=True), em, seq
    mask = supported.astype(float)

    def restricted(step: OffsetStep) -> np.ndarray:
        idx = np.nonzero(supported)[0]
        sub = step.information[np.ix_(idx, idx)]
        out = np.zeros(2)
        out[idx] = np.linalg.solve(sub, step.score[idx])
        return out

    # Gauss-Newton from zero, then secant steps per stream: the score's slope measured between
    # the solves (the profiled information above ignores the correlation of the posterior
    # across intervals, and overshoots where vision barely pins the motion).
    # Safeguarded: the score falls as the offset grows (a positive score: the root is later), so
    # each solve narrows a bracket [lo, hi] around the root; a secant step longer than twice the
    # Gauss-Newton step of the current solve (a slope measured between solves that barely moved
    # the motion) takes the Gauss-Newton step instead, and a step out of the bracket bisects it.
    lo, hi = np.full(2, -MAX_OFFSET), np.full(2, MAX_OFFSET)

    def narrow(at: np.ndarray, score: np.ndarray) -> None:
        np.copyto(lo, np.where(score > 0, np.maximum(lo, at), lo))
        np.copyto(hi, np.where(score < 0, np.minimum(hi, at), hi))

    narrow(np.zeros(2), first.score)
    d = np.clip(restricted(first), lo, hi)
    slope = np.diag(first.information).copy()
    d_prev, score_prev = np.zeros(2), first.score
    steps, last, converged = 0, first, False
    current_seq = seq
    for steps in range(1, MAX_STEPS + 1):
        current_seq = shifted(seq, d * mask)  # em is solved at these offsets from here on
        em = refit(current_seq, em)
        last = offset_step((em.stats.motion_w, em.stats.motion_cw), current_seq, em.config)
        narrow(d, last.score)
        moved = np.abs(d - d_prev) > 1e-4
        measured = np.where(moved, (score_prev - last.score) / np.where(moved, d - d_prev, 1.0), 0.0)
        slope = np.where(moved & (measured > 0), measured, slope)
        move = np.where(supported, last.score / slope, 0.0)
        gauss_newton = np.where(supported, last.score / np.diag(last.information), 0.0)
        move = np.where(np.abs(move) > 2.0 * np.abs(gauss_newton), gauss_newton, move)
        target = d + move
        move = np.where((target <= lo) | (target >= hi), 0.5 * (lo + hi) - d, move)
        if np.max(np.abs(move)) < STEP_TOL:
            converged = True
            break
        d_prev, score_prev = d, last.score
        d = d + move
    last.information = np.diag(slope)  # the measured slope: the information on each offset
    idx = np.nonzero(supported)[0]
    cov = np.zeros((2, 2))
    cov[np.ix_(idx, idx)] = np.linalg.inv(last.information[np.ix_(idx, idx)])
    sigma = np.where(supported, np.sqrt(np.abs(np.diag(cov))), first_sigma)
    return TimeOffsetFit(estimate=d * mask, sigma=sigma, first_estimate=first.step,
                         first_sigma=first_sigma, statistic=first.statistic,
                         threshold=threshold, supported=supported, steps=steps,
                         converged=converged), em, current_seq
