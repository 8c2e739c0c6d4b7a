"""Pixel errors correlated along a track: their integrated correlation time, from the smoother's
residuals.

Every estimator treats the stereo observations of a track as independent draws of the pixel
noise. A feature tracker does not make them so: where it places a feature drifts slowly along
the track, so the error of one frame is nearly that of the next. On both editions of KITTI 0027
the residuals of neighbouring observations of a track correlate at about 0.7 (the simulator's
white noise: -0.09, the landmark fit's own small negative correlation;
``benchmarks/track_residuals.py``). Counted as independent, a track of n such observations
carries the information of n / tau of them, where

    tau = 1 + 2 sum_{m >= 1} rho(m)                                    (integrated correlation time)

is the integrated autocorrelation time of the error along the track (for AR(1) errors with
correlation a: (1 + a) / (1 - a)). What the estimators need is the error's long-run variance,
tau sigma^2: a drive's drift is built from the slow part of the error, which averaging along a
track does not remove. So the model carries tau (``pixel_correlation_time``), and every
estimator's pixel sigma is the white sigma EM fitted times sqrt(tau)
(:func:`ekf.model.model_config`): the classic long-run-variance (Newey-West) correction of a
white-noise fit to correlated errors, not a full model of them (which would take one state per
observation).

Estimate (:func:`track_correlation`). ``rho(m)`` is the correlation of the whitened residuals
``[uL, uR, v]`` of observations of the same track m frames apart, pooled over tracks and the
three components. The sum runs over lags 1, 2, ... while ``rho(m)`` stays positive and the lag
has at least ``MIN_PAIRS`` pairs, up to ``MAX_LAG`` (the initial positive sequence: past the
first non-positive value the estimates are noise). The landmark fit removes part of each track's
slow error, so the residuals' correlations, and tau, come out somewhat low: the correction is
conservative.

Decision: the correlation is kept when lag 1's is positive and its statistic ``N rho(1)^2``
(chi-square with 1 degree of freedom for white noise, N the lag-1 pairs) passes BIC (ln N), as
the model's other terms; otherwise tau = 1 (none).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vislam.graph.factors import StereoRows

#: Longest lag summed (frames).
MAX_LAG = 30
#: Fewest pairs of observations a lag needs to be summed.
MIN_PAIRS = 100
#: Whitening of GTSAM's ``[uL, uR, v]`` residuals, up to the pixel sigma: v (the mean of vL
#: and vR) has half the variance of a pixel.
_WHITEN = np.array([1.0, 1.0, np.sqrt(2.0)])


@dataclass(frozen=True)
class TrackCorrelation:
    """The pixel errors' correlation along tracks (module docstring)."""

    #: rho(m) for lags 1, 2, ... (as long as each had MIN_PAIRS pairs, at most MAX_LAG)
    correlation: np.ndarray
    #: pairs of observations behind each rho(m)
    pairs: np.ndarray
    #: the estimate 1 + 2 sum rho(m) over the initial positive sequence (>= 1)
    estimate: float
    #: lags summed
    lags_summed: int
    #: N rho(1)^2 and its BIC threshold ln N
    statistic: float
    threshold: float

    @property
    def kept(self) -> bool:
        return bool(self.correlation.size and self.correlation[0] > 0
                    and self.statistic > self.threshold)

    @property
    def time(self) -> float | None:
        """The integrated correlation time in the model: None when the data support none."""
        return float(self.estimate) if self.kept and self.estimate > 1.0 else None

    def to_dict(self) -> dict:
        return {
            "estimate": float(self.estimate),
            "lag1": float(self.correlation[0]) if self.correlation.size else None,
            "correlation": [float(x) for x in self.correlation[:10]],
            "pairs_lag1": int(self.pairs[0]) if self.pairs.size else 0,
            "lags_summed": int(self.lags_summed),
            "statistic": float(self.statistic),
            "threshold": float(self.threshold),
            "criterion": "BIC (ln n, n = lag-1 pairs) on N rho(1)^2",
            "decision": "correlated" if self.time is not None else "none",
        }


def lag_pairs(frame: np.ndarray, track: np.ndarray, lags) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """``{m: (i, j)}``: the row indices of every pair of observations of the same ``track``
    exactly m ``frame``\\ s apart with every frame between observed too (pairs across a
    removed observation are left out), for each lag m in ``lags``."""
    frame, track = np.asarray(frame), np.asarray(track)
    order = np.lexsort((frame, track))
    f, t = frame[order], track[order]
    out = {}
    for lag in lags:
        if lag >= f.size:
            break
        same = np.flatnonzero((t[lag:] == t[:-lag]) & (f[lag:] == f[:-lag] + lag))
        out[lag] = (order[same], order[same + lag])
    return out


def along_track_correlation(residuals: np.ndarray, frame: np.ndarray, track: np.ndarray,
                            max_lag: int = MAX_LAG, min_pairs: int = MIN_PAIRS
                            ) -> tuple[np.ndarray, np.ndarray]:
    """``(rho, pairs)``: the correlation of ``residuals`` (N, d) between the pairs of
    :func:`lag_pairs` m frames apart, for m = 1, 2, ... while a lag has at least ``min_pairs``
    pairs (at most ``max_lag``); pooled over the d components, about a zero mean (a residual's
    expectation)."""
    r = np.asarray(residuals, dtype=float)
    variance = float(np.mean(r * r)) if r.size else 0.0
    rho, pairs = [], []
    for i, j in lag_pairs(frame, track, range(1, max_lag + 1)).values():
        if i.size < min_pairs or variance <= 0.0:
            break
        rho.append(float(np.mean(r[i] * r[j])) / variance)
        pairs.append(i.size)
    return np.array(rho), np.array(pairs, dtype=np.int64)


def correlation_time(rho: np.ndarray) -> tuple[float, int]:
    """``(tau, lags)``: 1 + 2 sum rho(m) over the initial positive sequence of ``rho``."""
    positive = np.asarray(rho) > 0
    lags = int(np.argmin(positive)) if not positive.all() else int(positive.size)
    return 1.0 + 2.0 * float(np.sum(rho[:lags])), lags


def track_correlation(residuals: np.ndarray, rows: StereoRows) -> TrackCorrelation:
    """The pixel errors' correlation along tracks from the smoother's residuals ``[uL, uR, v]``
    (N, 3) of ``rows`` (module docstring); a correlation, so the pixel sigma drops out."""
    white = np.asarray(residuals, dtype=float) * _WHITEN
    rho, pairs = along_track_correlation(white, rows.frame, rows.track)
    tau, lags = correlation_time(rho)
    n = int(pairs[0]) if pairs.size else 0
    statistic = n * float(rho[0]) ** 2 if n else 0.0
    threshold = float(np.log(max(n, 2)))
    return TrackCorrelation(rho, pairs, tau, lags, statistic, threshold)


def solution_track_correlation(solution) -> TrackCorrelation:
    """:func:`track_correlation` of a solved batch smoother
    (:class:`graph.smoother.SmootherSolution`)."""
    from vislam.graph.factors import stereo_residuals

    rows = solution.problem.rows
    residuals, _ = stereo_residuals(solution.poses, solution.landmarks, solution.calibration, rows)
    return track_correlation(residuals, rows)


__all__ = ["TrackCorrelation", "lag_pairs", "along_track_correlation", "correlation_time", "track_correlation",
           "solution_track_correlation", "MAX_LAG", "MIN_PAIRS"]
