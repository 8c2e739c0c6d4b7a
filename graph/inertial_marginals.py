"""Marginal covariances of the raw-IMU smoother's solved graph in one pass (no per-key queries).

``gtsam.Marginals`` answers each query through the Bayes tree of a COLAMD ordering; on EuRoC
V1_01's 30 s (601 frames x 15 dof, 221 landmarks) one joint block per frame took 73 s. The graph
has a structure that makes the whole computation cheap:

- the frame states ``s_k = [X(k) (6), V(k) (3), B(k) (6)]`` (GTSAM's tangents) are linked only
  by the IMU factor between consecutive frames and by priors, so their information ``S`` is
  block tridiagonal with 15 x 15 blocks, and it is positive definite on its own (the priors at
  frame 0 and the IMU determine every state: dead reckoning);
- a landmark's factors (its projections and its weak prior) touch it and the poses that see it,
  so the landmarks' information ``D`` is block diagonal (3 x 3) and the coupling ``C`` is sparse.

With ``H = [[S, C], [C^T, D]]`` (``H = A^T A`` of the whitened Jacobian of
``graph.linearize(values)``, GTSAM's own linearisation at the solution), the landmarks are kept as
a dense border: ``Xs = S^-1 C`` (a sparse LU of ``S``, one solve with all the border's columns),
``Z = D - C^T Xs`` (the landmarks' marginal information, dense, small), and

- ``Sigma_ll = Z^-1`` (every landmark's block);
- ``Sigma_kk = (S^-1)_kk + Y_k Y_k^T`` with ``Y = Xs Lz^-T``, ``Z = Lz Lz^T``;
- ``(S^-1)_kk`` by the block-tridiagonal recursion: forward ``D_0 = S_00``,
  ``D_k = S_kk - S_{k-1,k}^T D_{k-1}^-1 S_{k-1,k}``; backward ``Sigma_T = D_T^-1``,
  ``Sigma_k = D_k^-1 + G_k Sigma_{k+1} G_k^T`` with ``G_k = D_k^-1 S_{k,k+1}``.

The cost is linear in the frames and quadratic in the landmarks (``T (15 nl) + nl^3``); the
result equals ``gtsam.Marginals``'s ``jointMarginalCovariance([X(k), V(k), B(k)])`` and
``marginalCovariance(L(j))`` to rounding (tests/test_inertial_smoother.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np
import scipy.linalg
import scipy.sparse as sp
import scipy.sparse.linalg

#: Tangent dimension of each variable kind (by its symbol's character).
_DIMS = {"x": 6, "v": 3, "b": 6, "l": 3}
FRAME_DIM = 15


def _symbol(key: int) -> tuple[str, int]:
    s = gtsam.Symbol(int(key))
    return chr(s.chr()), int(s.index())


@dataclass
class FrameMarginals:
    """The one-pass marginals and the linear system they come from."""

    P: np.ndarray  # (T, 15, 15) each frame's [X, V, B] block
    P_next: np.ndarray  # (T - 1, 15, 15) the cross block of frames k and k + 1
    Pl: np.ndarray  # (len(tracks), 3, 3)
    A: sp.csr_matrix  # whitened Jacobian, columns frame-major then landmarks
    b: np.ndarray  # minus the whitened error


def frame_and_landmark_covariances(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
                                   n_frames: int, tracks: np.ndarray
                                   ) -> tuple[np.ndarray, np.ndarray]:
    """``(P (T, 15, 15), Pl (len(tracks), 3, 3))``: each frame's joint marginal of
    ``[X(k), V(k), B(k)]`` in GTSAM's tangents and each landmark's (in ``tracks``' order),
    from ``graph`` linearised at ``values`` (module docstring). Raises RuntimeError (GTSAM's or
    numpy's LinAlgError) when the information is not positive definite."""
    m = frame_marginals(graph, values, n_frames, tracks)
    return m.P, m.Pl


def moment_traces(E: np.ndarray, L: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(chi2, leverage)`` (T - 1,) from the moments of :func:`imu_factor_moments`: the
    squared whitened residual at the solution ``tr(E - L) = |b|^2`` and ``tr(L) =
    tr(A_f Sigma_f A_f^T)``, the part of the factor's 15 dimensions the estimate's own
    uncertainty accounts for. EM's update of one scale ``c`` on every IMU factor's covariance
    is ``c' = c * sum(chi2 + leverage) / (15 (T - 1))``: 1 when the data sheet's noise
    explains the residuals."""
    lev = np.trace(L, axis1=1, axis2=2)
    return np.trace(E, axis1=1, axis2=2) - lev, lev


def imu_factor_moments(graph: gtsam.NonlinearFactorGraph, marginals: FrameMarginals,
                       first_imu_factor: int, n_frames: int) -> tuple[np.ndarray, np.ndarray]:
    """``(E, L)`` (T - 1, 15, 15) of the IMU factors ``graph.at(first_imu_factor + k - 1)``
    (interval ``[k - 1, k]``): the
    expected outer product of each factor's whitened residual under the Laplace posterior,
    ``E = b b^T + A_f Sigma_f A_f^T``, and its posterior part ``L = A_f Sigma_f A_f^T``, in the
    factor's own whitened coordinates (``r_w = R r``, ``R`` its noise model's ``R()``; the
    CombinedImuFactor's order: rotation, position, velocity, accelerometer bias, gyro bias).
    ``trace(E) = chi2 + leverage``. EM's M-step for the IMU noise works on them
    (:mod:`graph.inertial_identification`)."""
    dims = np.array([graph.at(i).dim() for i in range(graph.size())], dtype=np.int64)
    offsets = np.concatenate([[0], np.cumsum(dims)])
    E = np.empty((n_frames - 1, FRAME_DIM, FRAME_DIM))
    L = np.empty_like(E)
    A = marginals.A
    for k in range(1, n_frames):
        i = first_imu_factor + k - 1
        r0, r1 = int(offsets[i]), int(offsets[i + 1])
        if r1 - r0 != FRAME_DIM:
            raise RuntimeError(f"marginals: factor {i} has {r1 - r0} rows, an IMU factor {FRAME_DIM}")
        Af = A[r0:r1, FRAME_DIM * (k - 1):FRAME_DIM * (k + 1)].toarray()
        Sf = np.block([[marginals.P[k - 1], marginals.P_next[k - 1]],
                       [marginals.P_next[k - 1].T, marginals.P[k]]])
        b = marginals.b[r0:r1]
        L[k - 1] = Af @ Sf @ Af.T
        E[k - 1] = np.outer(b, b) + L[k - 1]
    return E, L


#: Landmark columns of the border solved at a time, and frames per block of its products: the
#: only dense array of the frames' size is ``Xs`` (then ``Y``, in place), 1.7 GB on a 5-minute
#: room flight (6,001 frames, 796 landmarks), where ``C``, ``Xs``, ``Y`` and their transposed
#: copies took four times that.
BORDER_COLUMNS = 384
FRAME_BLOCK = 512


def frame_marginals(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, n_frames: int,
                    tracks: np.ndarray, border_columns: int = BORDER_COLUMNS,
                    frame_block: int = FRAME_BLOCK) -> FrameMarginals:
    """:func:`frame_and_landmark_covariances` with the cross blocks of consecutive frames and
    the whitened system. ``border_columns`` and ``frame_block``: how the dense border is
    computed in pieces (:data:`BORDER_COLUMNS`; the result does not depend on them)."""
    linear = graph.linearize(values)
    keys = sorted(linear.keyVector())
    # GTSAM's sparse Jacobian: columns by sorted key, 1-based, the last column the rhs.
    src = np.empty(len(keys) + 1, dtype=np.int64)
    src[0] = 0
    kinds = []
    for i, key in enumerate(keys):
        kind, index = _symbol(key)
        kinds.append((kind, index))
        src[i + 1] = src[i] + _DIMS[kind]
    n = int(src[-1])
    track_slot = {int(j): i for i, j in enumerate(np.asarray(tracks).tolist())}
    n_f = FRAME_DIM * n_frames
    within = {"x": 0, "v": 6, "b": 9}
    dest = np.empty(n, dtype=np.int64)  # sorted-key column -> frame-major / landmark column
    for i, (kind, index) in enumerate(kinds):
        d = _DIMS[kind]
        if kind == "l":
            start = n_f + 3 * track_slot[index]
        else:
            start = FRAME_DIM * index + within[kind]
        dest[src[i]:src[i] + d] = np.arange(start, start + d)
    if n != n_f + 3 * len(track_slot):
        raise RuntimeError(f"marginals: {n} columns in the graph, expected {n_f + 3 * len(track_slot)}")
    rows, cols, vals = linear.sparseJacobian_()
    rows = rows.astype(np.int64) - 1
    cols = cols.astype(np.int64) - 1
    keep = cols < n
    n_rows = int(rows.max()) + 1
    A = sp.csr_matrix((vals[keep], (rows[keep], dest[cols[keep]])), shape=(n_rows, n))
    b = np.zeros(n_rows)
    b[rows[~keep]] = vals[~keep]
    H = (A.T @ A).tocsc()
    S = H[:n_f, :n_f].tocsc()
    C = H[:n_f, n_f:].tocsc()
    D = H[n_f:, n_f:].toarray()
    n_b = n - n_f
    Xs = np.empty((n_f, n_b), order="F")  # S^-1 C, then Y in place
    if n_b:
        lu = scipy.sparse.linalg.splu(S)
        for a in range(0, n_b, border_columns):
            b_ = min(a + border_columns, n_b)
            Xs[:, a:b_] = lu.solve(C[:, a:b_].toarray())
    Z = D - np.asarray(C.T @ Xs)
    try:
        Lz = scipy.linalg.cholesky(Z, lower=True) if Z.size else Z
    except np.linalg.LinAlgError as exc:
        raise RuntimeError(f"the landmarks' marginal information is not positive definite: {exc}") from None
    # Y = Xs Lz^-T (BLAS trsm from the right, overwriting Xs)
    Y = scipy.linalg.blas.dtrsm(1.0, Lz, Xs, side=1, lower=1, trans_a=1, overwrite_b=1) if n_b else Xs
    P, P_next = _tridiagonal_inverse_blocks(S, n_frames)
    for a in range(0, n_frames, frame_block):
        b_ = min(a + frame_block + 1, n_frames)  # one frame more for the cross block
        Yk = np.ascontiguousarray(Y[FRAME_DIM * a:FRAME_DIM * b_]).reshape(b_ - a, FRAME_DIM, -1)
        m_ = min(frame_block, b_ - a)
        P[a:a + m_] += np.einsum("kia,kja->kij", Yk[:m_], Yk[:m_])
        P_next[a:a + min(m_, b_ - a - 1)] += np.einsum("kia,kja->kij", Yk[:b_ - a - 1][:m_], Yk[1:][:m_])
    del Xs, Y
    if Z.size:
        Zinv = scipy.linalg.cho_solve((Lz, True), np.eye(Z.shape[0]))
        idx = np.arange(len(track_slot))[:, None] * 3 + np.arange(3)
        Pl = Zinv[idx[:, :, None], idx[:, None, :]]
    else:
        Pl = np.zeros((0, 3, 3))
    return FrameMarginals(P, P_next, Pl, A, b)


def _tridiagonal_inverse_blocks(S: sp.csc_matrix, n_frames: int) -> tuple[np.ndarray, np.ndarray]:
    """The diagonal 15 x 15 blocks of ``S^-1`` for a block-tridiagonal positive definite ``S``
    (module docstring's recursion) and the blocks ``(k, k + 1)``: ``-G_k Sigma_{k+1}``."""
    m = FRAME_DIM
    S = S.tocsr()
    diag = np.empty((n_frames, m, m))
    upper = np.zeros((max(n_frames - 1, 0), m, m))
    for k in range(n_frames):
        rows = S[k * m:(k + 1) * m]
        diag[k] = rows[:, k * m:(k + 1) * m].toarray()
        if k + 1 < n_frames:
            upper[k] = rows[:, (k + 1) * m:(k + 2) * m].toarray()
    Dinv = np.empty_like(diag)
    Dk = diag[0]
    for k in range(n_frames):
        if k > 0:
            Dk = diag[k] - upper[k - 1].T @ Dinv[k - 1] @ upper[k - 1]
        c = scipy.linalg.cho_factor(Dk, lower=True)
        Dinv[k] = scipy.linalg.cho_solve(c, np.eye(m))
    out = np.empty_like(diag)
    out[-1] = Dinv[-1]
    cross = np.empty_like(upper)
    for k in range(n_frames - 2, -1, -1):
        G = Dinv[k] @ upper[k]
        cross[k] = -G @ out[k + 1]
        out[k] = Dinv[k] + G @ out[k + 1] @ G.T
    return 0.5 * (out + out.transpose(0, 2, 1)), cross
