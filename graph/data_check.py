"""Do the velocities and the vision of a drive agree within their noise? (issue 12, item 4)

A wrong file (an extrinsic with the lever arm in the wrong frame, velocities noisier than the
settings say, a pairing off by a sample) shows up first as motion residuals of the batch
smoother larger than the noise model allows. :func:`velocity_check` measures them, stretch by
stretch along the drive, so that a user sees it before trusting a score.

For each motion interval ``k`` the smoother's twist-noise residual is, exactly as in the EM of
:func:`graph.identification.noise_statistics`,

    ``w_k = M (Log(Delta_k^-1 X_k^-1 X_k+1))``,  ``M = (tau_k J_k)^-1``,

with Jacobian ``C_k = M [-Ad(rel^-1), I]`` on ``(X_k, X_k+1)``. Under the model (linearised at
the solution) its covariance is ``R_k = W - C_k Sigma_k C_k^T``: ``W`` the interval twist
covariance the factors used (GTSAM order, rotation first) and ``Sigma_k`` the 12x12 joint
posterior of the two poses (:func:`graph.marginals.pose_chain_covariances`). The smoother took
``C Sigma C^T`` of the noise into the trajectory; what is left is ``R_k``. Then
``w_k^T R_k^-1 w_k`` is chi-square with 6 degrees of freedom when the data fit the model, and
the same holds for the linear-velocity part (``w_k[3:]``, the 3x3 block of ``R_k``) and the
angular part (``w_k[:3]``) with 3 each.

Intervals and directions vision does not see. Where no track spans an interval
(:func:`graph.factors.unconstrained_intervals`: a tracker's repeat events) nothing but
the velocity measures the motion: without the twist-smoothness prior the residual is forced to
zero and ``R_k ~ 0``, and with it the residual measures the velocity against that prior (whose
sigma comes from the drive itself), not against vision. Such intervals are left out whole.
Elsewhere, where vision sees the motion poorly, some directions of ``R_k`` are nearly zero:
they carry no evidence (the smoother simply followed the velocity there; what is left of
``R_k`` is mostly the landmarks' weak priors), and ``w^2 / R`` is noise over noise. Each test
is therefore taken in the eigenbasis of ``W^-1/2 R_k W^-1/2`` (the predicted residual variance
as a fraction of the noise's): directions whose fraction is below
:data:`MIN_VARIANCE_FRACTION` are left out and do not count as degrees of freedom. Intervals
left out whole are counted as "without vision" (:attr:`VelocityCheck.n_excluded_intervals`),
single directions of the other intervals in :attr:`VelocityCheck.n_excluded_dims`.

Stretches. Consecutive intervals are grouped by their start time into stretches of
``stretch_s`` seconds from the first frame (a last stretch shorter than half of that joins the
one before). Per stretch the chi-squares of its intervals are summed (total, linear, angular)
and each sum is compared with ``chi2.ppf(level, dof)`` of its degrees of freedom; a stretch is
flagged when any of the three exceeds its threshold (so the chance of a false alarm per stretch
is at most about ``3 (1 - level)``).

Correlated intervals. With the "mean" velocity pairing adjacent intervals share a velocity
sample: their noises are correlated (0.5 per axis), and the sum of the squares of such an MA(1)
sequence has the same mean as independent ones but 1.5 times the variance. The thresholds then
follow Satterthwaite: the sum over ``c`` is taken as chi-square with ``dof / c`` degrees of
freedom, ``c`` = :data:`PAIRING_VARIANCE_FACTOR` (1.5 for "mean", 1 otherwise). Measured on
simulated drives under their true model (300 frames, 8 seeds, "mean"): the spread of a
stretch's ratio is 1.3 times the independent chi-square's, close to ``sqrt(1.5)``.

Known limits. Otherwise the residuals of different intervals are treated as independent (they
share the posterior, a small effect). The linearisation is at the solution, with the robust
kernel's weights of the stereo factors; the residuals of a badly wrong model are not Gaussian
and the chi-square is only a yardstick then. On simulated drives under their true model the
ratio chi2/dof of a stretch averages 0.92-1.08 (linear part, by pairing; total within 5 %).
What the test can see depends on the velocity noise: a lever arm wrong by metres (the
simulator's ``--file-extrinsic-fault kitti``) adds ``|omega x dl|^2`` to the squared linear
residuals, which a 10 s stretch shows clearly at 0.1-0.2 m/s of noise per sample but hardly at
0.5 m/s, where :mod:`graph.extrinsic` (``vislam calibrate``) is the test to use.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from vislam.ekf import chi_square as chi2_dist

from vislam.ekf.config import FilterConfig
from vislam.ekf.conventions import estimate_cov_to_gtsam
from vislam.ekf.errors import InputError

log = logging.getLogger(__name__)

#: A direction of an interval's residual whose predicted variance (from the model and the
#: posterior) is below this fraction of the velocity noise's is left out of the test: vision
#: does not see it, and the residual there is forced to about zero. (A direction vision sees
#: with a sigma ten times the velocity's has 1 %; on simulated drives the least-seen
#: directions have 70 % at the true noise and 4.5 % with velocities ten times noisier than
#: the settings say, while the landmarks' weak priors leave under 1 % across a gap.)
MIN_VARIANCE_FRACTION = 0.01

#: Variance of a stretch's chi-square over that of independent intervals, by velocity pairing
#: (module docstring); pairings not listed: 1.
PAIRING_VARIANCE_FACTOR = {"mean": 1.5}

#: :meth:`VelocityCheck.lines` notes a part whose residuals over the whole drive are below this
#: fraction of their noise (sigma, not variance): the settings overstate the noise.
NOTE_BELOW = 0.8

#: Flagged stretches listed one per line in :meth:`VelocityCheck.lines`, at most.
MAX_STRETCHES_LISTED = 10

#: Index ranges of the parts of a GTSAM-order (rotation-first) twist.
_ANGULAR, _LINEAR = slice(0, 3), slice(3, 6)


@dataclass(frozen=True)
class _Ratios:
    """The total, linear and angular sums ``chi2*`` with their ``dof*``, and their chi2 / dof
    (1 on average when the data fit the model; 0 when nothing is tested)."""

    chi2: float
    dof: int
    chi2_linear: float
    dof_linear: int
    chi2_angular: float
    dof_angular: int

    @property
    def ratio(self) -> float:
        return _ratio(self.chi2, self.dof)

    @property
    def ratio_linear(self) -> float:
        return _ratio(self.chi2_linear, self.dof_linear)

    @property
    def ratio_angular(self) -> float:
        return _ratio(self.chi2_angular, self.dof_angular)


def _sums(chi2: np.ndarray, dof: np.ndarray) -> dict:
    """:class:`_Ratios`'s fields from the (total, linear, angular) sums ``chi2`` and ``dof``."""
    return {"chi2": float(chi2[0]), "dof": int(dof[0]), "chi2_linear": float(chi2[1]),
            "dof_linear": int(dof[1]), "chi2_angular": float(chi2[2]), "dof_angular": int(dof[2])}


@dataclass(frozen=True)
class StretchCheck(_Ratios):
    """The normalised velocity residuals of one stretch of the drive.

    ``start_s``/``end_s``: times (s) since the drive's first frame of the first interval's start
    and the last interval's end. ``chi2*``: sums of ``w^T R^-1 w`` over the stretch's intervals
    (total 6 dof per interval, linear and angular 3 each, less the directions left out);
    ``threshold*``: ``chi2.ppf(level, dof)``, scaled for correlated intervals (module
    docstring; 0 where the dof is 0: nothing to test)."""

    start_s: float
    end_s: float
    n_intervals: int
    threshold: float
    threshold_linear: float
    threshold_angular: float
    n_excluded_intervals: int  # intervals with every direction left out (no vision)

    @property
    def flagged_total(self) -> bool:
        return self.dof > 0 and self.chi2 > self.threshold

    @property
    def flagged_linear(self) -> bool:
        return self.dof_linear > 0 and self.chi2_linear > self.threshold_linear

    @property
    def flagged_angular(self) -> bool:
        return self.dof_angular > 0 and self.chi2_angular > self.threshold_angular

    @property
    def flagged(self) -> bool:
        """Any of the three sums beyond its threshold."""
        return self.flagged_total or self.flagged_linear or self.flagged_angular

    def describe(self) -> str:
        """``t 30-40 s: linear velocity residuals 2.05x their noise (chi2/dof 4.20), ...``."""
        parts = []
        if self.flagged_linear:
            parts.append(_part_text("linear velocity", self.ratio_linear))
        if self.flagged_angular:
            parts.append(_part_text("angular velocity", self.ratio_angular))
        if not parts and self.flagged_total:
            parts.append(_part_text("velocity", self.ratio))
        if not parts:
            parts.append(f"agree (chi2/dof {self.ratio:.2f})")
        return f"t {_time_text(self.start_s)}-{_time_text(self.end_s)} s: " + ", ".join(parts)


@dataclass(frozen=True)
class VelocityCheck(_Ratios):
    """What :func:`velocity_check` found: one :class:`StretchCheck` per stretch and the drive's
    totals (same definitions, over every interval)."""

    stretches: tuple[StretchCheck, ...]
    level: float
    stretch_s: float
    min_variance_fraction: float
    variance_factor: float  # PAIRING_VARIANCE_FACTOR of the config's pairing
    n_intervals: int
    n_excluded_intervals: int  # intervals with every direction left out (no vision)
    n_excluded_dims: int  # directions left out of the 6-dof test, over all intervals

    @property
    def flagged(self) -> tuple[StretchCheck, ...]:
        """The stretches whose residuals exceed their noise (at ``level``)."""
        return tuple(s for s in self.stretches if s.flagged)

    @property
    def agrees(self) -> bool:
        return not self.flagged

    def lines(self) -> list[str]:
        """Short report lines: the verdict (with the worst stretch), one line per flagged
        stretch when there are several (up to MAX_STRETCHES_LISTED), the drive's totals, and a
        note where the residuals over the drive are clearly smaller than the settings' noise
        (below NOTE_BELOW of it and beyond the lower ``1 - level`` quantile)."""
        level = f"{100.0 * self.level:g} %"
        n = sum(1 for s in self.stretches if s.dof > 0)  # the stretches with something to test
        bad = self.flagged
        if n == 0:
            out = ["velocity vs vision: nothing to test: vision sees none of the "
                   + f"{self.n_intervals} intervals"]
        elif bad:
            worst = max(bad, key=lambda s: max(s.ratio_linear, s.ratio_angular, s.ratio))
            out = [f"velocity vs vision: {len(bad)} of {_stretches(n)} disagree beyond the noise "
                   f"({level})" + (f", worst {worst.describe()}" if len(bad) > 1
                                   else f": {worst.describe()}")]
            if len(bad) > 1:
                out += [f"  {s.describe()}" for s in bad[:MAX_STRETCHES_LISTED]]
            if len(bad) > MAX_STRETCHES_LISTED:
                out.append(f"  ... ({len(bad) - MAX_STRETCHES_LISTED} more)")
        else:
            where = f"all {n} stretches" if n > 1 else "the one stretch"
            out = [f"velocity vs vision: agree within the noise in {where} ({level})"]
        out.append(
            f"  overall chi2/dof {self.ratio:.2f} (linear {self.ratio_linear:.2f}, angular "
            f"{self.ratio_angular:.2f}) over {self.n_intervals} intervals in stretches of "
            f"{self.stretch_s:g} s; {self.n_excluded_intervals} intervals without vision and "
            f"{self.n_excluded_dims} more directions vision does not see left out"
        )
        for name, sigma, c, dof in (("linear", "velocity", self.chi2_linear, self.dof_linear),
                                    ("angular", "gyro", self.chi2_angular, self.dof_angular)):
            if (dof > 0 and c < NOTE_BELOW ** 2 * dof
                    and c < _threshold(dof, 1.0 - self.level, self.variance_factor)):
                out.append(f"  note: {name} velocity residuals are {np.sqrt(c / dof):.2f}x "
                           f"their noise over the drive: the settings' {sigma} sigma is larger "
                           "than the data's")
        return out


def _stretches(n: int) -> str:
    return f"{n} stretch" + ("" if n == 1 else "es")


def _ratio(c: float, dof: int) -> float:
    return float(c / dof) if dof > 0 else 0.0


def _part_text(name: str, ratio: float) -> str:
    return f"{name} residuals {np.sqrt(ratio):.2f}x their noise (chi2/dof {ratio:.2f})"


def _time_text(t: float) -> str:
    return f"{t:.0f}" if abs(t - round(t)) < 0.05 else f"{t:.1f}"


@dataclass
class _IntervalTerms:
    """Per interval: the chi-square and dof of the total, linear and angular tests."""

    chi2: np.ndarray  # (n, 3): total, linear, angular
    dof: np.ndarray  # (n, 3) int


def interval_residuals(solution, config: FilterConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(w, R, W)``: the smoother's twist-noise residual of each interval (n, 6), its
    covariance under the model ``W - C Sigma C^T`` (n, 6, 6) and ``W`` (6, 6), all in GTSAM's
    rotation-first order; ``solution`` a :class:`graph.smoother.SmootherSolution` solved with
    ``config`` (:func:`graph.identification.motion_residuals`, as EM's E-step)."""
    from vislam.graph.identification import motion_residuals
    from vislam.graph.marginals import pose_chain_covariances

    T = solution.poses.shape[0]
    W = estimate_cov_to_gtsam(config.velocity_cov)  # what graph.factors.relative_motions uses
    n = max(T - 1, 0)
    w = np.zeros((n, 6))
    R = np.zeros((n, 6, 6))
    if n == 0:
        return w, R, W
    from vislam.graph.drift_check import posterior_system

    deltas, reduced = posterior_system(solution)
    pose_cov, pair_cov = pose_chain_covariances(reduced, T)
    w, cw, _ = motion_residuals(solution.poses, deltas, solution.twist, solution.tau,
                                pose_cov, pair_cov)
    R = W - cw
    R = 0.5 * (R + np.swapaxes(R, 1, 2))
    return w, R, W


def _normalised(w: np.ndarray, R: np.ndarray, W: np.ndarray,
                fraction: float) -> tuple[np.ndarray, np.ndarray]:
    """Per interval ``w^T R^+ w`` over the directions whose predicted variance is at least
    ``fraction`` of the noise's (eigenbasis of ``W^-1/2 R W^-1/2``), and how many there are."""
    L = np.linalg.cholesky(W)
    Li = np.linalg.inv(L)
    wn = w @ Li.T  # L^-1 w
    Rn = Li @ R @ Li.T
    lam, U = np.linalg.eigh(0.5 * (Rn + np.swapaxes(Rn, 1, 2)))
    keep = lam >= fraction
    proj = np.einsum("nij,ni->nj", U, wn)  # U^T wn
    terms = np.where(keep, proj ** 2 / np.where(keep, lam, 1.0), 0.0)
    return terms.sum(axis=1), keep.sum(axis=1)


def _interval_terms(w: np.ndarray, R: np.ndarray, W: np.ndarray, fraction: float) -> _IntervalTerms:
    c_all, d_all = _normalised(w, R, W, fraction)
    c_lin, d_lin = _normalised(w[:, _LINEAR], R[:, _LINEAR, _LINEAR], W[_LINEAR, _LINEAR], fraction)
    c_ang, d_ang = _normalised(w[:, _ANGULAR], R[:, _ANGULAR, _ANGULAR], W[_ANGULAR, _ANGULAR],
                               fraction)
    return _IntervalTerms(np.c_[c_all, c_lin, c_ang], np.c_[d_all, d_lin, d_ang].astype(np.int64))


def _threshold(dof: int, level: float, factor: float = 1.0) -> float:
    """The ``level`` quantile of a sum with ``dof`` degrees of freedom whose variance is
    ``factor`` times a chi-square's (Satterthwaite: ``factor * chi2(dof / factor)``)."""
    return float(factor * chi2_dist.ppf(level, dof / factor)) if dof > 0 else 0.0


def velocity_check(solution, config: FilterConfig, *, stretch_s: float = 10.0,
                   level: float = 0.999) -> VelocityCheck:
    """Normalised velocity residuals of a solved smoother per stretch of the drive (module
    docstring). ``solution`` a :class:`graph.smoother.SmootherSolution` from
    :func:`graph.smoother.solve_smoother` (marginals need not be computed: the ones needed are
    computed here), ``config`` the :class:`ekf.config.FilterConfig` it was solved with,
    ``stretch_s`` the length of a stretch (s), ``level`` the test level per stretch.

    Raises InputError for a bad ``stretch_s`` or ``level``, EstimationError when the posterior
    cannot be computed (an under-constrained pose)."""
    if not (np.isfinite(stretch_s) and stretch_s > 0):
        raise InputError(f"velocity check: stretch length must be a positive number of "
                         f"seconds, got {stretch_s!r}")
    if not (np.isfinite(level) and 0.0 < level < 1.0):
        raise InputError(f"velocity check: level must be between 0 and 1, got {level!r}")
    from vislam.graph.stretches import stretch_labels
    from vislam.graph.factors import unconstrained_intervals

    w, R, W = interval_residuals(solution, config)
    terms = _interval_terms(w, R, W, MIN_VARIANCE_FRACTION)
    gaps = unconstrained_intervals(solution.problem.rows, solution.poses.shape[0])
    terms.chi2[gaps] = 0.0
    terms.dof[gaps] = 0
    times = np.asarray(solution.cleaned.timestamps, dtype=float)
    rel = times - times[0]
    n = w.shape[0]
    labels = stretch_labels(rel[:-1], stretch_s)
    no_vision = terms.dof[:, 0] == 0
    factor = PAIRING_VARIANCE_FACTOR.get(config.velocity_pairing, 1.0)
    stretches = []
    for s in range(int(labels.max()) + 1 if n else 0):
        idx = np.flatnonzero(labels == s)
        c = terms.chi2[idx].sum(axis=0)
        d = terms.dof[idx].sum(axis=0)
        stretches.append(StretchCheck(
            start_s=float(rel[idx[0]]), end_s=float(rel[idx[-1] + 1]), n_intervals=int(idx.size),
            **_sums(c, d),
            threshold=_threshold(int(d[0]), level, factor),
            threshold_linear=_threshold(int(d[1]), level, factor),
            threshold_angular=_threshold(int(d[2]), level, factor),
            n_excluded_intervals=int(no_vision[idx].sum()),
        ))
    c = terms.chi2.sum(axis=0)
    d = terms.dof.sum(axis=0)
    result = VelocityCheck(
        stretches=tuple(stretches), level=float(level), stretch_s=float(stretch_s),
        min_variance_fraction=MIN_VARIANCE_FRACTION, variance_factor=float(factor),
        n_intervals=n,
        n_excluded_intervals=int(no_vision.sum()),
        n_excluded_dims=int(np.sum(6 - terms.dof[~no_vision, 0])),
        **_sums(c, d),
    )
    log.info("velocity check: %d of %d stretches flagged, chi2/dof %.3f (linear %.3f, "
             "angular %.3f), %d intervals without vision, %d directions left out",
             len(result.flagged), len(stretches), result.ratio, result.ratio_linear,
             result.ratio_angular, result.n_excluded_intervals, result.n_excluded_dims)
    return result


__all__ = ["MIN_VARIANCE_FRACTION", "NOTE_BELOW", "PAIRING_VARIANCE_FACTOR", "StretchCheck",
           "VelocityCheck", "interval_residuals", "velocity_check"]
