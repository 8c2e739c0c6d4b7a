"""Does a model term predict data it was not fitted on? Leave-one-stretch-out cross-validation
of the profile likelihood (issue 34 item 2).

In-sample tests (BIC on a Wald or likelihood-ratio statistic) ask whether the data fitted are
better explained with the term. A term can pass them by fitting what is particular to the data
at hand: a slow error of one stretch, correlated pixel errors of a few tracks. The test here
fits the term without one stretch of the drive and scores it on that stretch, for every stretch
in turn.

The linearised problem. At a solved smoother, GTSAM's whitened linearisation is ``A x ~ b``
over the poses and landmarks ``x``, and ``A_t`` is the whitened Jacobian of the same rows on the
term's parameter ``theta`` (``p`` of them; zero on rows the term does not touch). The nuisance
``x`` is profiled out over the whole drive, ``x(theta) = argmin ||b - A_t theta - A x||``. What is
left per row is

    ``r(theta) = b~ - A~ theta``,   ``A~ = P A_t``,   ``b~ = P b``,   ``P = I - A H^-1 A^T``

(``H = A^T A``, solved by :meth:`graph.marginals.LandmarksEliminated.solve`). Summed over the
rows of a fold ``F`` (a stretch of the drive), the fold's log-likelihood is, up to a constant,

    ``l_F(theta) = g_F^T theta - theta^T S_F theta / 2``,   ``S_F = A~_F^T A~_F``,   ``g_F = A~_F^T b~_F``.

The term fitted without ``F`` is ``theta_-F = (S - S_F + Pi)^-1 (g - g_F)`` over the components
the drive determines (``Pi`` the term's own weak prior), and its out-of-sample gain over the null
``theta_0`` (the value without the term: the file's extrinsic, no bias, no lens term) is

    ``G = sum_F [l_F(theta_-F) - l_F(theta_0)]``.

``G > 0``: the term fitted elsewhere predicts every stretch better, in sum, than the null does.
Beside it, the in-sample gain ``(theta_0 - theta^)^T S (theta_0 - theta^) / 2`` (half the Wald
statistic). Under a null that is true, ``G`` is negative on average, about ``-p/2``, because each
fold pays for the noise of a fit made without it. With a real effect, ``G`` approaches the
in-sample gain.

Known limits. The nuisance is profiled on the whole drive, held-out stretch included. The poses'
information from the held-out stretch's vision thus reaches the fit through ``P``, a small leak
next to the term's own rows, which are left out exactly. The quadratic is taken at the solution,
not refitted per fold. A row belongs to the fold of the earliest pose it touches, and rows
touching no pose (landmark priors) are in every fit and no fold. A stretch of 10 s holds most of
its tracks whole, so the fold is over tracks as well as over time.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp


@dataclass(frozen=True)
class FoldGain:
    """The out-of-sample gain ``gain`` of a term (module docstring: sum over the folds of the
    held-out log-likelihood of the term fitted without the fold, less the null's), per fold in
    ``fold_gains``, and the in-sample gain (half the Wald statistic) beside it."""

    gain: float
    in_sample: float
    fold_gains: tuple[float, ...]
    n_components: int  # the components fitted (those the drive determines)

    @property
    def n_folds(self) -> int:
        return len(self.fold_gains)

    @property
    def improves(self) -> bool:
        """The term predicts held-out stretches better than the null (``gain > 0``)."""
        return self.gain > 0.0

    def to_dict(self) -> dict:
        return {"gain": self.gain, "in_sample": self.in_sample, "folds": self.n_folds,
                "components": self.n_components,
                "folds_better": int(sum(g > 0 for g in self.fold_gains)),
                "criterion": "leave-one-stretch-out gain of the profile log-likelihood"}


def profile_rows(A: sp.spmatrix, b: np.ndarray, A_t: np.ndarray, solve) -> tuple[np.ndarray, np.ndarray]:
    """``(A~, b~)``: the term's Jacobian ``A_t`` (rows, p) and the right-hand side ``b`` (rows,)
    with the nuisance ``x`` profiled out, ``P A_t`` and ``P b`` (module docstring); ``A`` the
    whitened Jacobian on ``x`` (rows, n), ``solve(B)`` gives ``H^-1 B`` for ``B`` (n, m)."""
    A = sp.csr_matrix(A)
    A_t = np.asarray(A_t, dtype=float).reshape(A.shape[0], -1)
    rhs = np.column_stack([np.asarray(A.T @ A_t), np.asarray(A.T @ b)])
    Y = np.asarray(solve(rhs)).reshape(A.shape[1], -1)
    projected = np.column_stack([A_t, b]) - np.asarray(A @ Y)
    return projected[:, :-1], projected[:, -1]


def row_frames(A: sp.spmatrix, pose_columns: np.ndarray) -> np.ndarray:
    """Per row of ``A``, the earliest frame whose pose it touches (-1 where it touches none);
    ``pose_columns`` (T,) the first of each pose's six columns."""
    A = sp.csr_matrix(A)
    owner = np.full(A.shape[1], np.iinfo(np.int64).max, dtype=np.int64)
    for k, c in enumerate(np.asarray(pose_columns, dtype=np.int64)):
        owner[c:c + 6] = k
    out = np.full(A.shape[0], -1, dtype=np.int64)
    nnz = np.diff(A.indptr)
    rows = np.flatnonzero(nnz)
    if rows.size:
        first = np.minimum.reduceat(owner[A.indices], A.indptr[rows])
        out[rows] = np.where(first == np.iinfo(np.int64).max, -1, first)
    return out


def term_rows(solution, rows, A_rows: np.ndarray, stretch_s: float = 10.0,
              b: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(A~, b~, folds)`` of a term at a solved smoother (:class:`graph.smoother.SmootherSolution`):
    its whitened Jacobian ``A_rows`` on the linearisation's rows ``rows`` (a slice or indices;
    zero elsewhere) with the nuisance profiled out (:func:`profile_rows`), and each row's fold,
    the ``stretch_s`` stretch of the earliest pose it touches (-1: none;
    :func:`graph.stretches.stretch_labels`). ``b`` replaces the linearisation's right-hand
    side (all rows), for a term whose likelihood takes some rows elsewhere (the radial term's
    lens pixels, :func:`graph.radial.lens_rows`)."""
    from vislam.graph.pose_conversions import X
    from vislam.graph.stretches import stretch_labels

    system, posterior_of = solution.linearised()
    A_rows = np.asarray(A_rows, dtype=float)
    A_t = np.zeros((system.A.shape[0], A_rows.shape[1]))
    A_t[rows] = A_rows
    A_p, b_p = profile_rows(system.A, system.b if b is None else b, A_t, posterior_of.solve)
    T = solution.poses.shape[0]
    frames = row_frames(system.A, np.array([system.offsets[X(k)] for k in range(T)]))
    times = np.asarray(solution.cleaned.timestamps, dtype=float)
    labels = stretch_labels(times - times[0], stretch_s)
    return A_p, b_p, np.where(frames >= 0, labels[np.clip(frames, 0, T - 1)], -1)


def fold_gain(A_p: np.ndarray, b_p: np.ndarray, folds: np.ndarray, null: np.ndarray,
              components: np.ndarray, prior: np.ndarray | None = None) -> FoldGain:
    """The out-of-sample gain (module docstring) from the profiled rows ``A_p`` (rows, p) and
    ``b_p`` (rows,) at the fitted term (``theta^ = 0`` there), ``folds`` (rows,) each row's fold
    (-1: in no fold), ``null`` (p,) the null value relative to the fitted one (every component, the
    undetermined ones too: the null is the value without the term), ``components``
    (p,) bool the components fitted (the others are held at the fitted value), ``prior`` (p, p)
    the term's weak prior information (default none)."""
    A_p = np.asarray(A_p, dtype=float)
    b_p = np.asarray(b_p, dtype=float)
    p = A_p.shape[1]
    d = np.flatnonzero(np.asarray(components, dtype=bool))
    null = np.asarray(null, dtype=float)
    prior = np.zeros((p, p)) if prior is None else np.asarray(prior, dtype=float)
    S = A_p.T @ A_p
    g = A_p.T @ b_p
    in_sample = 0.5 * float(null @ S @ null)
    gains = []
    for f in np.unique(folds[folds >= 0]):
        m = folds == f
        S_f = A_p[m].T @ A_p[m]
        g_f = A_p[m].T @ b_p[m]
        theta = np.zeros(p)
        if d.size:
            theta[d] = np.linalg.solve((S - S_f + prior)[np.ix_(d, d)], (g - g_f)[d])
        gains.append(float(g_f @ theta - 0.5 * theta @ S_f @ theta
                           - (g_f @ null - 0.5 * null @ S_f @ null)))
    return FoldGain(gain=float(sum(gains)), in_sample=in_sample, fold_gains=tuple(gains),
                    n_components=int(d.size))


__all__ = ["FoldGain", "fold_gain", "profile_rows", "row_frames", "term_rows"]
