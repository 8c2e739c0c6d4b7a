"""Pixel errors correlated along a track: their integrated correlation time, from the smoother's
residuals.

Every estimator treats the stereo observations of a track as independent draws of the pixel
noise. A feature tracker does not make them so: where it places a feature drifts slowly along
the track, so the error of one frame is nearly that of the next (docs/findings.md: "Pixel errors
drift along a track"; the simulator's white noise shows only the landmark fit's own small
negative correlation, ``benchmarks/track_residuals.py``). Counted as independent, a track
of n such observations carries the information of n / tau of them, where

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
first non-positive value the estimates are noise).

Correction for the landmark fit (:func:`landmark_fit_correction`). Each track's landmark is
fitted to the same pixels, so the slow part of its error goes into the landmark, not the
residuals: the residuals' tau is about half the errors' (simulator, AR(1) a = 0.85, tau 12.3:
4.9-5.2), and their spread, from which EM takes the white sigma, is too small (0.77 of 1 px).
By indirect inference on the drive's own tracks: unit AR(1) errors of each trial tau on
:data:`CORRECTION_GRID` (standard normal draws from :data:`SIMULATION_SEED`, the same for every
trial) go through each track's least-squares landmark fit with the solution's own landmark
Jacobians (:func:`without_landmark_fit`), and the same estimator measures their residuals'
tau; the trial whose residuals show the data's (log-log interpolation) is the errors' tau,
and the residuals' variance per degree of freedom there (``variance_ratio``) rescales EM's
sigma (``sigma_factor``). The poses' share of the fit is left out (each pose is shared by many
tracks). Simulator: 11.6-11.7 for 12.3, 5.4-5.5 for 5.7, 2.9-3.0 for 3.0; sigma within 2 %.
Known limit: with few tracks a frame the premise fails: the poses' share of the fit is no
longer small, the figure then depends on the solution it is measured on, and errors common to
the tracks of a frame are outside this AR(1) model of independent tracks (docs/findings.md).

Decision: the correlation is kept when lag 1's is positive and its statistic ``N rho(1)^2``
(chi-square with 1 degree of freedom for white noise, N the lag-1 pairs) passes BIC (ln N), as
the model's other terms; otherwise tau = 1 (none).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from vislam.ekf.model import ar1_coefficient
from vislam.ekf.sequence import track_runs
from vislam.graph.factors import StereoRows

#: Longest lag summed (frames).
MAX_LAG = 30
#: Fewest pairs of observations a lag needs to be summed.
MIN_PAIRS = 100
#: Whitening of GTSAM's ``[uL, uR, v]`` residuals, up to the pixel sigma: v (the mean of vL
#: and vR) has half the variance of a pixel.
_WHITEN = np.array([1.0, 1.0, np.sqrt(2.0)])
#: Correlation times (frames) of the errors the landmark-fit correction simulates; past the
#: last the residuals' estimate barely moves (it sums at most MAX_LAG lags).
CORRECTION_GRID = np.array([1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0, 12.0, 16.0, 24.0, 32.0, 48.0,
                            64.0, 100.0, 150.0, 200.0])
#: Seed of the correction's simulated errors.
SIMULATION_SEED = 0
#: Rows the correction simulates at least (the drive's own, replicated up to 8 times).
SIMULATION_ROWS = 100_000


@dataclass(frozen=True)
class TrackCorrelation:
    """The pixel errors' correlation along tracks (module docstring)."""

    #: rho(m) of the residuals for lags 1, 2, ... (as long as each had MIN_PAIRS pairs, at
    #: most MAX_LAG)
    correlation: np.ndarray
    #: pairs of observations behind each rho(m)
    pairs: np.ndarray
    #: the residuals' 1 + 2 sum rho(m) over the initial positive sequence (>= 1)
    estimate: float
    #: lags summed
    lags_summed: int
    #: N rho(1)^2 and its BIC threshold ln N
    statistic: float
    threshold: float
    #: the errors' correlation time, the residuals' corrected for the landmark fit
    #: (:func:`landmark_fit_correction`); None when not corrected
    corrected: float | None = None
    #: expected residual variance / error variance at ``corrected`` (the landmark fit's share)
    variance_ratio: float = 1.0
    #: the correction's lookup (the errors' tau, the residuals' expected tau)
    lookup: tuple[tuple[float, float], ...] = ()

    @property
    def kept(self) -> bool:
        return bool(self.correlation.size and self.correlation[0] > 0
                    and self.statistic > self.threshold)

    @property
    def time(self) -> float | None:
        """The errors' integrated correlation time in the model (the corrected one where
        there is one): None when the data support none."""
        tau = self.estimate if self.corrected is None else self.corrected
        return float(tau) if self.kept and tau > 1.0 else None

    @property
    def sigma_factor(self) -> float:
        """The errors' sigma over the white sigma EM fitted to the residuals: the landmark fit
        keeps part of a slow error out of them (1 when the correlation is not kept)."""
        return float(1.0 / np.sqrt(self.variance_ratio)) if self.time is not None else 1.0

    def to_dict(self) -> dict:
        return {
            "estimate": float(self.estimate),
            "corrected": None if self.corrected is None else float(self.corrected),
            "variance_ratio": float(self.variance_ratio),
            "lag1": float(self.correlation[0]) if self.correlation.size else None,
            "correlation": [float(x) for x in self.correlation[:10]],
            "pairs_lag1": int(self.pairs[0]) if self.pairs.size else 0,
            "lags_summed": int(self.lags_summed),
            "statistic": float(self.statistic),
            "threshold": float(self.threshold),
            "criterion": "BIC (ln n, n = lag-1 pairs) on N rho(1)^2",
            "correction": "landmark fit (AR(1) errors through each track's least-squares "
                          "landmark fit, seed %d)" % SIMULATION_SEED,
            "decision": "correlated" if self.time is not None else "none",
        }


def lag_pairs(frame: np.ndarray, track: np.ndarray, lags) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """``{m: (i, j)}``: the row indices of every pair of observations of the same ``track``
    exactly m ``frame``\\ s apart with every frame between observed too (pairs across a
    removed observation are left out), for each lag m in ``lags``."""
    frame, track = np.asarray(frame), np.asarray(track)
    order = track_runs(frame, track)[0]
    f, t = frame[order], track[order]
    out = {}
    for lag in lags:
        if lag >= f.size:
            break
        same = np.flatnonzero((t[lag:] == t[:-lag]) & (f[lag:] == f[:-lag] + lag))
        out[lag] = (order[same], order[same + lag])
    return out


def along_track_correlation(residuals: np.ndarray, frame: np.ndarray, track: np.ndarray,
                            max_lag: int = MAX_LAG, min_pairs: int = MIN_PAIRS, *,
                            pairs_by_lag: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(rho, pairs)``: the correlation of ``residuals`` (N, d) between the pairs of
    :func:`lag_pairs` m frames apart, for m = 1, 2, ... while a lag has at least ``min_pairs``
    pairs (at most ``max_lag``); pooled over the d components, about a zero mean (a residual's
    expectation). ``pairs_by_lag``: :func:`lag_pairs` of ``frame`` and ``track`` for lags
    1..max_lag, when the caller has them already."""
    r = np.asarray(residuals, dtype=float)
    variance = float(np.mean(r * r)) if r.size else 0.0
    if pairs_by_lag is None:
        pairs_by_lag = lag_pairs(frame, track, range(1, max_lag + 1))
    rho, pairs = [], []
    for i, j in pairs_by_lag.values():
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


def track_correlation(residuals: np.ndarray, rows: StereoRows,
                      jacobians: np.ndarray | None = None) -> TrackCorrelation:
    """The pixel errors' correlation along tracks from the smoother's residuals ``[uL, uR, v]``
    (N, 3) of ``rows`` (module docstring); a correlation, so the pixel sigma drops out. With
    the landmark ``jacobians`` (:func:`landmark_jacobians`) the estimate is corrected for the
    landmark fit (:func:`landmark_fit_correction`)."""
    white = np.asarray(residuals, dtype=float) * _WHITEN
    rho, pairs = along_track_correlation(white, rows.frame, rows.track)
    tau, lags = correlation_time(rho)
    n = int(pairs[0]) if pairs.size else 0
    statistic = n * float(rho[0]) ** 2 if n else 0.0
    threshold = float(np.log(max(n, 2)))
    out = TrackCorrelation(rho, pairs, tau, lags, statistic, threshold)
    if jacobians is None or not out.kept or tau <= 1.0:
        return out
    corrected, ratio, lookup = landmark_fit_correction(tau, rows, jacobians)
    return dataclasses.replace(out, corrected=corrected, variance_ratio=ratio, lookup=lookup)


# --- The landmark fit's share: indirect inference ------------------------------------------


def landmark_jacobians(poses: np.ndarray, landmarks: np.ndarray, calib, rows: StereoRows) -> np.ndarray:
    """Whitened Jacobians (N, 3, 3) of each row's ``[uL, uR, v]`` on its landmark's world
    position, ``M dpi/dq R_cw`` (paper eqs. 2-3) in GTSAM's rows (``v`` the mean of ``vL`` and
    ``vR``), up to the pixel sigma (:data:`_WHITEN`)."""
    from vislam.ekf.camera import dpi_dq
    from vislam.ekf.geometry import se3_inv
    from vislam.graph.factors import camera_points, stereo_measurement

    q = camera_points(poses, landmarks, calib, rows)
    H = calib.M @ dpi_dq(np.concatenate([q, np.ones((q.shape[0], 1))], axis=1))[:, :, :3]
    rows_3 = stereo_measurement(H)
    R = (calib.cam_T_imu @ se3_inv(poses[rows.frame]))[:, :3, :3]  # d q / d p
    return (rows_3 * _WHITEN[None, :, None]) @ R


def ar1_along_tracks(frame: np.ndarray, track: np.ndarray, a: float, white: np.ndarray) -> np.ndarray:
    """Unit-variance AR(1) errors of correlation ``a`` per frame along each track, built from
    the standard normal draws ``white`` (N, d) in the rows' order (``a ** gap`` across a gap)."""
    order, first, last = track_runs(frame, track)
    f = np.asarray(frame)[order]
    w = white[order]
    x = np.empty_like(w)
    start = np.zeros(f.size, dtype=bool)
    start[first] = True
    position = np.arange(f.size) - np.repeat(first, last - first)
    x[start] = w[start]
    by_position = np.argsort(position, kind="stable")
    counts = np.bincount(position)
    ends = np.cumsum(counts)
    for p in range(1, counts.size):
        i = by_position[ends[p - 1]:ends[p]]
        g = np.power(a, f[i] - f[i - 1])[:, None]
        x[i] = g * x[i - 1] + np.sqrt(1.0 - g * g) * w[i]
    out = np.empty_like(x)
    out[order] = x
    return out


def landmark_normal_matrices(jacobians: np.ndarray, track: np.ndarray) -> np.ndarray:
    """Each track's normal matrix ``sum J^T J`` (max track + 1, 3, 3) of its landmark's
    least-squares fit (``jacobians`` from :func:`landmark_jacobians`), with a ridge of 1e-12 of
    its trace so that a track never observed stays solvable."""
    n = int(track.max()) + 1 if track.size else 0
    JtJ = np.einsum("nki,nkj->nij", jacobians, jacobians)
    A = np.zeros((n, 9))
    for c in range(9):
        A[:, c] = np.bincount(track, JtJ.reshape(-1, 9)[:, c], minlength=n)
    A = A.reshape(n, 3, 3)
    A += np.eye(3) * (1e-12 * np.trace(A, axis1=1, axis2=2)[:, None, None] + 1e-300)
    return A


def without_landmark_fit(errors: np.ndarray, jacobians: np.ndarray, track: np.ndarray,
                         normal: np.ndarray | None = None) -> np.ndarray:
    """``errors`` (N, 3, whitened) less their least-squares fit by each track's landmark
    (``jacobians`` from :func:`landmark_jacobians`; ``normal`` their
    :func:`landmark_normal_matrices`, when the caller has them): the residuals they would
    leave."""
    if normal is None:
        normal = landmark_normal_matrices(jacobians, track)
    n = normal.shape[0]
    Jte = np.einsum("nki,nk->ni", jacobians, errors)
    b = np.zeros((n, 3))
    for c in range(3):
        b[:, c] = np.bincount(track, Jte[:, c], minlength=n)
    x = np.linalg.solve(normal, b[..., None])[..., 0]
    return errors - np.einsum("nki,ni->nk", jacobians, x[track])


@dataclass(frozen=True)
class LandmarkFit:
    """What every trial of :func:`landmark_fit_correction` shares: the rows, their landmark
    Jacobians, the tracks' normal matrices, the lag pairs and the number of tracks."""

    rows: StereoRows
    jacobians: np.ndarray
    normal: np.ndarray
    pairs_by_lag: dict
    n_tracks: int

    @classmethod
    def of(cls, rows: StereoRows, jacobians: np.ndarray) -> "LandmarkFit":
        return cls(rows, jacobians, landmark_normal_matrices(jacobians, rows.track),
                   lag_pairs(rows.frame, rows.track, range(1, MAX_LAG + 1)),
                   int(np.unique(rows.track).size))


def residual_correlation_time(tau: float, fit: LandmarkFit, white: np.ndarray) -> tuple[float, float]:
    """``(tau_r, ratio)``: what :func:`track_correlation` finds in the residuals of AR(1) errors
    with correlation time ``tau`` (built from the standard normal draws ``white``, N x 3) once
    each track's landmark (``fit``) is fitted to them, and the residuals' variance over the
    errors' (per degree of freedom the landmarks leave)."""
    a = ar1_coefficient(tau)
    rows = fit.rows
    r = without_landmark_fit(ar1_along_tracks(rows.frame, rows.track, a, white), fit.jacobians,
                             rows.track, fit.normal)
    rho, _ = along_track_correlation(r, rows.frame, rows.track, pairs_by_lag=fit.pairs_by_lag)
    ratio = float(np.sum(r * r)) / max(r.size - 3 * fit.n_tracks, 1)
    return correlation_time(rho)[0], ratio


def landmark_fit_correction(tau_r: float, rows: StereoRows, jacobians: np.ndarray):
    """``(tau, ratio, lookup)``: the errors' correlation time whose residuals would show
    ``tau_r`` after the landmark fit (indirect inference over :data:`CORRECTION_GRID`, the
    drive's own tracks and landmark Jacobians, AR(1) errors from seed :data:`SIMULATION_SEED`;
    module docstring), the residuals' variance over the errors' there, and the lookup."""
    finite = np.isfinite(jacobians).all(axis=(1, 2))
    if not finite.all():  # a row without a usable Jacobian (a point at infinity) is left out
        rows, jacobians = rows.subset(finite), jacobians[finite]
    fit = LandmarkFit.of(rows, jacobians)  # the same for every trial
    rng = np.random.default_rng(SIMULATION_SEED)
    replicates = int(np.clip(np.ceil(SIMULATION_ROWS / max(len(rows), 1)), 1, 8))
    draws = [rng.standard_normal((len(rows), 3)) for _ in range(replicates)]
    seen, ratios = [], []
    for tau in CORRECTION_GRID:
        runs = [residual_correlation_time(float(tau), fit, w) for w in draws]
        seen.append(np.mean([x[0] for x in runs]))
        ratios.append(np.mean([x[1] for x in runs]))
    seen = np.maximum.accumulate(np.asarray(seen))  # the residuals' tau rises with the errors'
    log_tau = np.interp(np.log(tau_r), np.log(seen), np.log(CORRECTION_GRID))
    ratio = float(np.interp(log_tau, np.log(CORRECTION_GRID), ratios))
    lookup = tuple((float(t), float(x)) for t, x in zip(CORRECTION_GRID, seen))
    return float(np.exp(log_tau)), ratio, lookup


def solution_track_correlation(solution) -> TrackCorrelation:
    """:func:`track_correlation` of a solved batch smoother
    (:class:`graph.smoother.SmootherSolution`), corrected for its landmark fit."""
    from vislam.graph.factors import stereo_residuals

    rows = solution.problem.rows
    residuals, _ = stereo_residuals(solution.poses, solution.landmarks, solution.calibration, rows)
    jacobians = landmark_jacobians(solution.poses, solution.landmarks, solution.calibration, rows)
    return track_correlation(residuals, rows, jacobians)


__all__ = ["TrackCorrelation", "lag_pairs", "along_track_correlation", "correlation_time",
           "track_correlation", "solution_track_correlation", "landmark_jacobians",
           "ar1_along_tracks", "landmark_normal_matrices", "without_landmark_fit",
           "LandmarkFit", "residual_correlation_time",
           "landmark_fit_correction", "CORRECTION_GRID", "MAX_LAG", "MIN_PAIRS"]
