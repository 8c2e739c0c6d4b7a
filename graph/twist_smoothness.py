"""A smoothness prior on the body twist across intervals that vision does not span.

At a tracker's repeat events (after track cleaning) no track is observed at both ends of one
interval ``[k, k+1]``; only the velocity measurement spans it, with its gyro error, which
nothing else corrects. A car's motion is smooth at 10 Hz, though: the twist of an interval
differs from the mean of its two neighbours by much less than the velocity measurement's
noise (docs/findings.md: "Twist smoothness at the gaps"). The
neighbouring intervals are fixed well by vision, so the twist of the gap is predicted from
them. This module adds that prediction as a factor (a white-noise prior on the second
difference of the twist, i.e. on the angular and linear "jerk" over the gap):

    e_k = xi_k / tau_k - (xi_{k-1} / tau_{k-1} + xi_{k+1} / tau_{k+1}) / 2,
    xi_i = Log(x_i^-1 x_{i+1})   (GTSAM's rotation-first Pose3.Logmap),

on the four poses ``x_{k-1} .. x_{k+2}``, with a diagonal noise ``sigma`` (rad/s, m/s;
rotation first). Jacobians, with the right perturbation of each pose and ``B_i = x_i^-1 x_{i+1}``:

    d xi_i / d x_i     = -J_r^-1(xi_i) Ad(B_i^-1),
    d xi_i / d x_{i+1} =  J_r^-1(xi_i),

(tested against numerical derivatives in tests/test_graph_twist_smoothness.py).

The sigma is not a tuned constant: :func:`smoothness_sigma` measures it on the drive itself,
from the spread of the same residual over the intervals that vision does constrain in the
current estimate (a robust, MAD-based standard deviation per component). That spread contains
the estimate's own error as well as the true variation of the twist, so the prior is, if
anything, too weak rather than too strong.
"""

from __future__ import annotations

import gtsam
import numpy as np

from vislam.graph.pose_conversions import X, to_pose3

#: Floor on the measured sigma (rad/s for rotation, m/s for translation), so that a perfectly
#: smooth (e.g. simulated constant-velocity) drive does not produce a rigid constraint.
MIN_SIGMA = np.array([1e-3, 1e-3, 1e-3, 1e-2, 1e-2, 1e-2])
#: Consistency factor between the median absolute deviation and the standard deviation.
MAD_TO_SIGMA = 1.4826


def log_with_jacobians(x0: gtsam.Pose3, x1: gtsam.Pose3, H: list | None = None) -> np.ndarray:
    """``xi = Log(x0^-1 x1)`` (6,) rotation first; with ``H`` a list, appends d xi / d x0 and
    d xi / d x1 (6x6 each, right perturbation)."""
    between = x0.between(x1)
    xi = gtsam.Pose3.Logmap(between)
    if H is not None:
        J_log = gtsam.Pose3.LogmapDerivative(xi)
        H.append(-J_log @ between.inverse().AdjointMap())
        H.append(J_log)
    return xi


def smoothness_error(poses: list[gtsam.Pose3], tau: np.ndarray, H: list | None = None) -> np.ndarray:
    """The factor's error (6,) for four consecutive poses and the three interval lengths
    ``tau`` (s); with ``H`` a list, appends the four 6x6 Jacobians (module docstring)."""
    w = np.array([-0.5 / tau[0], 1.0 / tau[1], -0.5 / tau[2]])
    if H is None:
        return sum(w[i] * log_with_jacobians(poses[i], poses[i + 1]) for i in range(3))
    e = np.zeros(6)
    J = [np.zeros((6, 6)) for _ in range(4)]
    for i in range(3):
        Hi: list = []
        e += w[i] * log_with_jacobians(poses[i], poses[i + 1], Hi)
        J[i] += w[i] * Hi[0]
        J[i + 1] += w[i] * Hi[1]
    H.extend(J)
    return e


def smoothness_factor(k: int, tau: np.ndarray, noise: gtsam.noiseModel.Base) -> gtsam.CustomFactor:
    """A ``CustomFactor`` on ``X(k-1) .. X(k+2)`` predicting the twist of interval ``[k, k+1]``
    from its neighbours; ``tau`` the lengths of intervals ``k-1, k, k+1``."""
    tau = np.asarray(tau, dtype=float).copy()

    def error(this: gtsam.CustomFactor, values: gtsam.Values, jacobians) -> np.ndarray:
        poses = [values.atPose3(key) for key in this.keys()]
        if jacobians is None:
            return smoothness_error(poses, tau)
        H: list = []
        e = smoothness_error(poses, tau, H)
        for i in range(4):
            jacobians[i] = H[i]
        return e

    keys = [int(X(i)) for i in range(k - 1, k + 3)]
    return gtsam.CustomFactor(noise, keys, error)


def prior_intervals(gaps: np.ndarray) -> np.ndarray:
    """Indices k of the gap intervals that have a neighbour interval on both sides (the first
    and last intervals of a drive cannot be predicted this way)."""
    k = np.flatnonzero(np.asarray(gaps, dtype=bool))
    return k[(k >= 1) & (k <= len(gaps) - 2)]


def twist_residuals(poses: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """The factor's error (T-3, 6) at every interior interval ``k = 1 .. T-3`` of a trajectory
    ``poses`` (T, 4, 4); row ``i`` belongs to interval ``k = i + 1``."""
    x = [to_pose3(T) for T in poses]
    rates = np.stack([log_with_jacobians(x[i], x[i + 1]) / tau[i] for i in range(len(x) - 1)])
    return rates[1:-1] - 0.5 * (rates[:-2] + rates[2:])


def smoothness_sigma(poses: np.ndarray, tau: np.ndarray, gaps: np.ndarray) -> np.ndarray:
    """Per-component sigma (6,) rotation first, of the twist's second difference measured on
    the trajectory ``poses`` over the interior intervals whose neighbours and themselves are
    all spanned by vision (robust: MAD); at least :data:`MIN_SIGMA`. Returns None when fewer
    than 10 such intervals exist."""
    gaps = np.asarray(gaps, dtype=bool)
    if len(poses) < 4:
        return None
    r = twist_residuals(poses, tau)
    k = np.arange(1, len(gaps) - 1)
    seen = ~(gaps[k - 1] | gaps[k] | gaps[k + 1])
    if seen.sum() < 10:
        return None
    r = r[seen]
    mad = np.median(np.abs(r - np.median(r, axis=0)), axis=0)
    return np.maximum(MAD_TO_SIGMA * mad, MIN_SIGMA)


def linearised(factor: gtsam.NonlinearFactor, values: gtsam.Values) -> gtsam.LinearContainerFactor:
    """``factor`` linearised at ``values`` (only its own keys are kept), as a C++ factor."""
    point = gtsam.Values()
    for key in factor.keys():
        point.insert(key, values.atPose3(key))
    return gtsam.LinearContainerFactor(factor.linearize(point), point)


def gap_prior(k: int, tau: np.ndarray, sigma: np.ndarray,
              values: gtsam.Values | None = None) -> gtsam.NonlinearFactor:
    """The smoothness factor of gap interval ``k`` (``tau`` all interval lengths, ``sigma``
    (6,) rotation first).

    With ``values`` it is linearised there and returned as a ``LinearContainerFactor``
    instead of the Python ``CustomFactor``: any Python factor in the graph halves the speed of
    GTSAM's Levenberg-Marquardt (docs/findings.md), the C++ container
    costs nothing. The linearisation is exact for a change of the global frame (the
    error depends on relative poses only, and a left change ``G x_i`` is the right perturbation
    ``Ad(x_i^-1) log G`` of every pose); the smoothers relinearise it each solve round (batch)
    or linearise it at the latest estimates (iSAM2)."""
    noise = gtsam.noiseModel.Diagonal.Sigmas(np.asarray(sigma, dtype=float))
    factor = smoothness_factor(int(k), tau[k - 1:k + 2], noise)
    return factor if values is None else linearised(factor, values)


def add_smoothness_factors(graph: gtsam.NonlinearFactorGraph, gaps: np.ndarray, tau: np.ndarray,
                           sigma: np.ndarray, values: gtsam.Values | None = None) -> int:
    """Add :func:`gap_prior` for each gap interval with neighbours on both sides to ``graph``
    (linearised at ``values`` if given); returns how many."""
    ks = prior_intervals(gaps)
    for k in ks:
        graph.add(gap_prior(int(k), tau, sigma, values))
    return int(ks.size)
