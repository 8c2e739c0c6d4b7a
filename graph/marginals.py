"""Marginal covariances of a solved graph, in the :class:`ekf.estimate.Estimate` convention.

``gtsam.Marginals`` answers one key at a time through the Bayes tree; on a drive-long pose chain
that costs milliseconds per key (about 10 s for a 300-frame simulated drive).
:func:`schur_marginals` computes the same numbers from GTSAM's own linearisation at the solution
(robust weights included):

1. the whitened sparse Jacobian ``A`` of ``graph.linearize(values)``, information ``H = A^T A``;
2. landmarks eliminated in closed form (their blocks are 3x3 and independent), leaving the
   reduced pose system ``S = H_pp - H_pl H_ll^-1 H_lp``; ``S`` is block-banded because a
   landmark only couples the poses of its track;
3. a banded Cholesky ``S = L L^T`` and the block Takahashi recursion for the entries of
   ``S^-1`` inside the band, from the last pose backwards:
   ``Sigma_sj = -Sigma_ss L_sj L_jj^-1``, ``Sigma_jj = L_jj^-T L_jj^-1 - Sigma_sj^T L_sj L_jj^-1``,
   ``s`` over the poses below ``j`` inside ``L``'s envelope (fill-in stays inside the envelope
   of ``S``: a pose's rows reach no further than the last pose that shares a landmark or a
   factor with a pose at or before it), so each step costs what its own stretch of the drive
   needs, not the drive's longest track;
4. each landmark's covariance ``A_l + B Sigma_pp B^T`` with ``A_l = H_ll^-1``,
   ``B = -H_ll^-1 H_lp``, over the poses of its track (all inside the band);
5. the border (an arrowhead): a landmark seen over a long stretch of the drive (a room's, a
   loop's seen at the start and at the end) would widen the band of every pose to its span,
   the whole drive at worst ((6T)^2 per step). Such landmarks, and any variable that is
   neither a pose nor a landmark (the gyro bias, speed scales), are not eliminated in step 2 but kept as a
   dense border ``[S C; C^T D]``: the band of ``S`` is then set by the short tracks,
   ``X = S^-1 C`` costs banded solves, ``Z = D - C^T X`` is small and dense, and the blocks
   asked for are ``S^-1``'s from step 3 plus a low-rank term: ``Sigma_pp = S^-1 + X Z^-1 X^T``
   on the band blocks only (as ``Y Y^T``, ``Y = X Lz^-T``, ``Z = Lz Lz^T``: 6 x nb a pose),
   ``Sigma_bb = Z^-1`` (the long landmarks' and the bias's covariances), ``Sigma_pb = -X Z^-1``,
   a short landmark's ``A_l + B S^-1 B^T + G Z^-1 G^T`` with ``G = B X`` (so ``(B Y)(B Y)^T``;
   plus ``A_l H_lb`` in ``G`` where it touches the border), ``log det H = log det H_ll +
   log det S + log det Z``. Which landmarks go to the border is a cost model's choice
   (:func:`border_landmarks`); it picks none unless that is clearly cheaper, so drives whose
   tracks are all short (KITTI's) keep steps 1-4 exactly. Cost: about ``T w^2`` for the band
   ``w`` of the short tracks plus ``T w nb + T nb^2`` for a border of ``nb`` columns; never a
   dense window of the whole drive (benchmarks/marginals_scaling.py, on a loaded 2-core
   machine: a room of 4,541 frames with 20 landmarks seen in every frame, all its blocks in
   about 5 s at 0.3 GB; a 4,541-frame loop with 126 landmarks seen again, about a minute).

GTSAM returns the ``Pose3`` marginal in its rotation-first right perturbation; the Estimate
stores the translation-first right perturbation, so each pose block goes through
:func:`ekf.conventions.gtsam_cov_to_estimate` (the one tested conversion). Landmark marginals are
world-frame ``Point3`` covariances in both.
"""

from __future__ import annotations

import re

from dataclasses import dataclass

import gtsam
import numpy as np
import scipy.linalg
import scipy.sparse as sp

from vislam.ekf.conventions import gtsam_cov_to_estimate
from vislam.ekf.errors import EstimationError
from vislam.ekf.runner import blas_threads
from vislam.graph.pose_conversions import L, X, estimation_error, key_name


@dataclass
class WhitenedSystem:
    """GTSAM's linearisation of a graph at some values, as sparse arrays: ``A x ~= b`` with
    ``A`` the whitened Jacobian (robust weights included) and ``b`` minus the whitened error."""

    A: sp.csr_matrix  # (rows, n)
    b: np.ndarray  # (rows,)
    keys: list  # the variables, sorted: the order of A's column blocks
    offsets: dict  # key -> its first column in A


def _key_chars(keys) -> np.ndarray:
    """Each key's symbol character (gtsam.Symbol's top 8 bits), as one-letter strings."""
    k = np.asarray([int(x) for x in keys], dtype=np.uint64)
    return (k >> np.uint64(56)).astype(np.uint8).view("S1").astype(str)


def _key_indices(keys) -> np.ndarray:
    """Each key's symbol index (gtsam.Symbol's low 56 bits)."""
    k = np.asarray([int(x) for x in keys], dtype=np.uint64)
    return (k & np.uint64((1 << 56) - 1)).astype(np.int64)


def _key_dims(keys) -> np.ndarray:
    """Each key's dimension: poses (``x``) 6, the speed scales (``s``, graph.speed_scale) 1,
    landmarks and the gyro bias 3."""
    if not len(keys):
        return np.zeros(0, dtype=np.int64)
    chars = _key_chars(keys)
    return np.where(chars == "x", 6, np.where(chars == "s", 1, 3))


def whitened_system(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
                    doing: str) -> WhitenedSystem:
    """``graph.linearize(values)`` through ``sparseJacobian_`` (columns by sorted key, the
    last one the right-hand side b); ``doing`` names the step in an EstimationError."""
    try:
        linear = graph.linearize(values)
    except RuntimeError as exc:
        raise estimation_error(exc, doing) from None
    keys = sorted(linear.keyVector())
    dims = _key_dims(keys)
    offsets = dict(zip(keys, (np.cumsum(dims) - dims).tolist()))
    n = int(dims.sum())
    triplets = linear.sparseJacobian_()
    rows = triplets[0].astype(np.int64) - 1
    cols = triplets[1].astype(np.int64) - 1
    n_rows = int(rows.max()) + 1
    is_b = cols == n
    b = np.zeros(n_rows)
    b[rows[is_b]] = triplets[2][is_b]
    A = sp.csr_matrix((triplets[2][~is_b], (rows[~is_b], cols[~is_b])), shape=(n_rows, n))
    return WhitenedSystem(A, b, keys, offsets)


#: The cost model of :func:`border_landmarks`, per pose, in seconds-like units measured on this
#: code (benchmarks/marginals_scaling.py): a band of width ``w`` columns costs ``BAND_COST w^2``
#: (banded Cholesky and Takahashi recursion), a border of ``nb`` columns ``SOLVE_COST w nb``
#: (the banded solves of ``X = S^-1 C``) plus ``CORRECTION_COST nb^2`` (the low-rank terms).
BAND_COST = 1.0
SOLVE_COST = 4.0
CORRECTION_COST = 2.0
#: A border is used only where the model says it costs at most a quarter of the band alone:
#: the model is rough, and on drives whose tracks are all short (KITTI's, where the best cut
#: saves less than that) the band alone keeps today's arithmetic, bit for bit.
BORDER_GAIN = 4.0


@dataclass
class Border:
    """The variables kept out of the banded pose system (the arrowhead's border, module
    docstring): long-lived landmarks and any variable that is neither a pose nor a landmark
    (the gyro bias), after the short landmarks' closed-form elimination. Columns: the long
    landmarks (3 each, in ``tracks`` order), then the other variables (``other_keys``)."""

    tracks: np.ndarray  # the long landmarks' tracks, sorted
    other_keys: list  # the other variables' keys, sorted (H's order)
    other_offsets: np.ndarray  # each other variable's first border column
    C: np.ndarray  # (6 T, nb) the reduced pose-border information
    H_bl: sp.csr_matrix  # (nb, 3 n_short) the border's information with the short landmarks
    X: np.ndarray  # (6 T, nb) S^-1 C
    Y: np.ndarray  # (6 T, nb) X Lz^-T (Z = Lz Lz^T): Y Y^T = X Sigma X^T
    Z_factor: tuple  # scipy.linalg.cho_factor of the border's Schur complement D - C^T X
    Sigma: np.ndarray  # (nb, nb) its inverse: the border's marginal covariance
    log_det_Z: float

    @property
    def size(self) -> int:
        return self.C.shape[1]


@dataclass
class LandmarksEliminated:
    """An information matrix ``H`` ordered [landmarks, poses(, other variables)] with its
    short-lived landmarks eliminated in closed form (steps 2-3 of the module docstring):
    ``A_l = H_ll^-1`` per such landmark, ``H_lp`` and the banded Cholesky factor ``Lb`` of the
    reduced pose system ``S`` (``ab`` its lower band, ``w`` the band's width); the long-lived
    landmarks and the other variables, when any, in :attr:`border`. :meth:`solve` gives
    ``H^-1 B`` exactly, at the cost of banded triangular solves instead of a sparse LU of the
    whole ``H``."""

    H_ll: np.ndarray  # (n_short, 3, 3)
    A_l: np.ndarray  # (n_short, 3, 3)
    A_blocks: sp.csr_matrix  # block-diagonal A_l (3 n_short, 3 n_short)
    H_lp: sp.csr_matrix  # (3 n_short, 6 T)
    ab: np.ndarray  # S's lower band (w + 1, 6 T)
    Lb: np.ndarray  # its Cholesky factor, same layout
    w: int
    tracks: np.ndarray  # every landmark's track, sorted (H's landmark blocks, in order)
    short_tracks: np.ndarray | None = None  # the eliminated landmarks' tracks (None: all)
    border: Border | None = None  # long landmarks and other variables (None: there are none)
    #: H's rows in the order [short landmarks, poses, border] (None: H is already so ordered)
    order: np.ndarray | None = None

    def __post_init__(self):
        if self.short_tracks is None:
            self.short_tracks = self.tracks

    @property
    def n_l(self) -> int:
        """Rows of the eliminated (short) landmarks."""
        return self.H_lp.shape[0]

    def other_covariance(self, key: int) -> np.ndarray:
        """The marginal covariance (d, d) of a variable of ``H`` that is neither a pose nor a
        landmark (the gyro bias: 3, a speed scale: 1), from the border (step 5 of the module
        docstring)."""
        keys = [] if self.border is None else self.border.other_keys
        if int(key) not in keys:
            raise EstimationError(f"marginals: {key_name(int(key))} is not a variable of the graph")
        o = int(self.border.other_offsets[keys.index(int(key))])
        d = int(_key_dims([int(key)])[0])
        return self.border.Sigma[o:o + d, o:o + d].copy()

    def others_covariance(self, keys: list) -> np.ndarray:
        """The joint marginal covariance of several such variables (their dimensions summed,
        in ``keys`` order)."""
        where = {} if self.border is None else dict(zip(self.border.other_keys, self.border.other_offsets))
        cols = []
        for key, d in zip(keys, _key_dims([int(k) for k in keys])):
            if int(key) not in where:
                raise EstimationError(f"marginals: {key_name(int(key))} is not a variable of the graph")
            cols.append(np.arange(where[int(key)], where[int(key)] + d))
        if not cols:
            return np.zeros((0, 0))
        idx = np.concatenate(cols)
        return self.border.Sigma[np.ix_(idx, idx)].copy()

    def _arrow_solve(self, r_p: np.ndarray, r_b: np.ndarray | None) -> tuple:
        """``[S C; C^T D]^-1 [r_p; r_b]`` (``r_b`` None: zero) by the arrowhead's Schur
        complement: ``y = S^-1 r_p``, ``z = Z^-1 (r_b - C^T y)``, ``x_p = y - X z``."""
        y = scipy.linalg.cho_solve_banded((self.Lb, True), r_p, check_finite=False)
        if self.border is None:
            return y, None
        bd = self.border
        rhs = -(bd.C.T @ y) if r_b is None else r_b - bd.C.T @ y
        z = scipy.linalg.cho_solve(bd.Z_factor, rhs, check_finite=False)
        return y - bd.X @ z, z

    def pose_solve(self, B_p: np.ndarray) -> np.ndarray:
        """``S^-1 B_p``: ``H^-1 B`` for a ``B`` that is zero on the landmark rows, read on the
        pose rows only (the pose block of ``H^-1`` is ``S^-1``); ``B_p`` (6 T,) or (6 T, m)."""
        return self._arrow_solve(np.asarray(B_p, dtype=float), None)[0]

    def solve(self, B: np.ndarray) -> np.ndarray:
        """``H^-1 B`` for ``B`` (n,) or (n, m), rows ordered as ``H``'s columns."""
        B = np.asarray(B, dtype=float)
        if self.order is not None:
            B = B[self.order]
        n_p = self.Lb.shape[1]
        b_l, b_p, b_b = B[:self.n_l], B[self.n_l:self.n_l + n_p], B[self.n_l + n_p:]
        t = self.A_blocks @ b_l
        if self.border is None:
            y_p = self.pose_solve(b_p - self.H_lp.T @ t)
            return np.concatenate([t - self.A_blocks @ (self.H_lp @ y_p), y_p])
        H_bl = self.border.H_bl
        y_p, y_b = self._arrow_solve(b_p - self.H_lp.T @ t, b_b - H_bl @ t)
        y_l = t - self.A_blocks @ (self.H_lp @ y_p + H_bl.T @ y_b)
        out = np.concatenate([y_l, y_p, y_b])
        if self.order is not None:
            out[self.order] = out.copy()
        return out


def border_landmarks(first: np.ndarray, last: np.ndarray, pose_band: int,
                     n_frames: int) -> np.ndarray:
    """Which landmarks go to the border (a boolean mask): those whose track spans more poses
    than the cut that makes the estimated cost smallest. A landmark kept in the band widens
    the band of every pose to its span ``s`` (a banded Cholesky and a Takahashi recursion cost
    about ``T (6 s)^2`` each); in the border it costs three columns of ``X = S^-1 C`` (banded
    solves, ``T 6 w`` each) and its share of the low-rank correction (``T nb^2``).
    ``first``/``last`` are each landmark's first and last pose, ``pose_band`` the band (in
    poses) of the factors between poses. The cut is at most the widest span: a drive whose
    tracks are all short keeps every landmark in the band."""
    span = np.asarray(last, dtype=np.int64) - np.asarray(first, dtype=np.int64)  # band in poses
    if span.size == 0:
        return np.zeros(0, dtype=bool)
    cuts = np.unique(np.r_[span, pose_band])
    cuts = cuts[cuts >= pose_band]
    sorted_span = np.sort(span)
    n_out = span.size - np.searchsorted(sorted_span, cuts, side="right")  # landmarks above it
    w = 6.0 * cuts + 6.0
    nb = 3.0 * n_out
    cost = BAND_COST * w * w + SOLVE_COST * w * nb + CORRECTION_COST * nb * nb
    best = int(np.argmin(cost))
    if cost[best] * BORDER_GAIN > cost[-1]:  # not clearly cheaper: everything in the band
        return np.zeros(span.size, dtype=bool)
    return span > cuts[best]


def eliminate_landmarks(H: sp.spmatrix, n_l: int, n_frames: int, tracks: np.ndarray,
                        other_keys: list | None = None,
                        long_tracks: np.ndarray | None = None) -> LandmarksEliminated:
    """:class:`LandmarksEliminated` of ``H`` (columns [landmarks of ``tracks``, sorted, 3 each;
    ``n_frames`` poses, 6 each; the ``other_keys``, 3 each or 1 for a speed scale], ``n_l`` the
    landmark columns).
    The landmarks whose tracks are in ``long_tracks`` (default: :func:`border_landmarks`) and
    the other variables form the border. Raises :class:`ekf.errors.EstimationError` naming the
    variable where ``H`` is not positive definite."""
    H = sp.csr_matrix(H)
    tracks = np.sort(np.asarray(tracks, dtype=np.int64))
    other_keys = list(other_keys or [])
    other_dims = _key_dims(other_keys).astype(np.int64)
    n_lm = n_l // 3
    n_p = 6 * n_frames
    if long_tracks is None:
        long_mask = _long_landmarks(H, n_l, n_frames)
    else:
        long_mask = np.isin(tracks, np.asarray(long_tracks, dtype=np.int64))
    if not long_mask.any() and not other_keys:
        return _eliminate(H, n_l, n_frames, tracks)
    # reorder to [short landmarks, poses, border: long landmarks, others]
    lm_cols = (3 * np.arange(n_lm)[:, None] + np.arange(3)).reshape(n_lm, 3)
    order = np.concatenate([lm_cols[~long_mask].ravel(), n_l + np.arange(n_p),
                            lm_cols[long_mask].ravel(), np.arange(n_l + n_p, H.shape[0])])
    Hr = H[order][:, order].tocsr()
    n_s = 3 * int(np.count_nonzero(~long_mask))
    inner = _eliminate(Hr[:n_s + n_p, :n_s + n_p], n_s, n_frames, tracks[~long_mask])
    # --- the border: its reduced information, X = S^-1 C, Schur complement ------------------
    H_bl = Hr[n_s + n_p:, :n_s].tocsr()
    H_bp = Hr[n_s + n_p:, n_s:n_s + n_p].tocsr()
    H_bb = Hr[n_s + n_p:, n_s + n_p:].toarray()
    C = (H_bp - H_bl @ (inner.A_blocks @ inner.H_lp)).T.toarray()
    D = H_bb - (H_bl @ (inner.A_blocks @ H_bl.T)).toarray()
    X_ = scipy.linalg.cho_solve_banded((inner.Lb, True), C, check_finite=False)
    Z = D - C.T @ X_
    Z = 0.5 * (Z + Z.T)
    n_long = int(np.count_nonzero(long_mask))
    try:
        Z_factor = scipy.linalg.cho_factor(Z, lower=True, check_finite=True)
    except (np.linalg.LinAlgError, ValueError) as exc:
        # LAPACK's order of the failing leading minor: the border variable it falls in
        found = re.search(r"(\d+)", str(exc)) if isinstance(exc, np.linalg.LinAlgError) else None
        col = int(found.group(1)) - 1 if found else None
        other_starts = 3 * n_long + np.cumsum(other_dims) - other_dims
        where = "" if col is None else " near " + key_name(
            L(int(tracks[long_mask][col // 3])) if col < 3 * n_long
            else other_keys[max(int(np.searchsorted(other_starts, col, side="right")) - 1, 0)])
        raise EstimationError(f"marginals: the information matrix of the long-lived landmarks "
                              f"and other variables is not positive definite{where} (an "
                              f"under-constrained variable)") from None
    Sigma = scipy.linalg.cho_solve(Z_factor, np.eye(Z.shape[0]), check_finite=False)
    Sigma = 0.5 * (Sigma + Sigma.T)
    Y = scipy.linalg.solve_triangular(Z_factor[0], X_.T, lower=True, check_finite=False).T
    border = Border(
        tracks=tracks[long_mask], other_keys=other_keys,
        other_offsets=3 * n_long + np.cumsum(other_dims) - other_dims, C=C, H_bl=H_bl, X=X_, Y=Y,
        Z_factor=Z_factor, Sigma=Sigma,
        log_det_Z=2.0 * float(np.sum(np.log(np.diag(Z_factor[0])))))
    inner.tracks, inner.border, inner.order = tracks, border, order
    return inner


def _long_landmarks(H: sp.csr_matrix, n_l: int, n_frames: int) -> np.ndarray:
    """:func:`border_landmarks` of ``H``'s landmarks (their spans read off their rows of
    ``H``, the band of the factors between poses off ``H_pp``, only where a border could pay
    even with no such factors: a bound that spares the pose rows on short-track drives)."""
    n_lm = n_l // 3
    n_p = 6 * n_frames
    mask = np.zeros(n_lm, dtype=bool)
    if n_lm == 0:
        return mask
    ptr = H.indptr[:n_l + 1]
    cols = H.indices[:ptr[-1]]
    pose = np.where(cols >= n_l, (cols - n_l) // 6, -1)
    filled = np.flatnonzero(np.diff(ptr))
    last_row = np.full(n_l, -1, dtype=np.int64)
    first_row = np.full(n_l, n_frames, dtype=np.int64)
    if filled.size:
        last_row[filled] = np.maximum.reduceat(pose, ptr[filled])
        first_row[filled] = np.minimum.reduceat(np.where(pose >= 0, pose, n_frames), ptr[filled])
    first, last = first_row.reshape(n_lm, 3).min(axis=1), last_row.reshape(n_lm, 3).max(axis=1)
    seen = last >= 0
    if not border_landmarks(first[seen], last[seen], 0, n_frames).any():
        return mask  # no border even if nothing but the landmarks widened the band
    H_pp = H[n_l:n_l + n_p, n_l:n_l + n_p].tocoo()
    pose_band = int(np.max(np.abs(H_pp.row // 6 - H_pp.col // 6))) if H_pp.nnz else 0
    mask[seen] = border_landmarks(first[seen], last[seen], pose_band, n_frames)
    return mask


def _eliminate(H: sp.csr_matrix, n_l: int, n_frames: int,
               tracks: np.ndarray) -> LandmarksEliminated:
    """Closed-form elimination of every landmark of ``H`` ([landmarks, poses]) and the banded
    Cholesky of the reduced pose system (steps 2-3 of the module docstring)."""
    n_lm = n_l // 3
    # --- landmark blocks, inverted in closed form ------------------------------------------
    b = np.arange(n_lm)
    r = (3 * b[:, None, None] + np.arange(3)[None, :, None]).repeat(3, axis=2)
    c = np.swapaxes(r, 1, 2)
    H_ll = np.asarray(H[r.ravel(), c.ravel()]).reshape(n_lm, 3, 3) if n_lm else np.zeros((0, 3, 3))
    eig_min = np.linalg.eigvalsh(H_ll)[:, 0] if n_lm else np.zeros(0)
    bad = np.flatnonzero(~(eig_min > 1e-12 * np.maximum(1.0, np.abs(H_ll).max(axis=(1, 2)))))
    if bad.size:
        raise EstimationError(
            f"marginals: {key_name(L(int(tracks[bad[0]])))} is not determined by its factors "
            f"(information matrix singular)")
    A_l = np.linalg.inv(H_ll)
    H_lp = H[:n_l, n_l:].tocsr()
    H_pp = H[n_l:, n_l:]
    # block-diagonal H_ll^-1 straight into CSR: row 3b+i holds A_l[b, i] in columns 3b..3b+2
    block_cols = (3 * (np.arange(3 * n_lm) // 3))[:, None] + np.arange(3)
    A_blocks = sp.csr_matrix((A_l.ravel(), block_cols.ravel(), 3 * np.arange(3 * n_lm + 1)),
                             shape=(3 * n_lm, 3 * n_lm))
    S = (H_pp - H_lp.T @ (A_blocks @ H_lp)).tocoo() if n_lm else H_pp.tocoo()
    # --- banded Cholesky of the reduced pose system ---------------------------------------
    n = 6 * n_frames
    wp = int(np.max(np.abs(S.row // 6 - S.col // 6))) if S.nnz else 0  # band in poses
    w = 6 * wp + 5
    lower = S.row >= S.col
    ab = np.zeros((w + 1, n))
    ab[S.row[lower] - S.col[lower], S.col[lower]] += S.data[lower]
    try:
        Lb = scipy.linalg.cholesky_banded(ab, lower=True, check_finite=True)
    except (np.linalg.LinAlgError, ValueError) as exc:
        # LAPACK's order of the failing leading minor ("12-th leading minor not positive
        # definite"); none when the matrix is not finite: then its first non-finite pose row
        order = re.search(r"(\d+)", str(exc)) if isinstance(exc, np.linalg.LinAlgError) else None
        bad = np.flatnonzero(~np.isfinite(S.data))
        row = int(order.group(1)) - 1 if order else (int(S.row[bad[0]]) if bad.size else None)
        where = f" near {key_name(X(row // 6))}" if row is not None else ""
        raise EstimationError(
            f"marginals: the pose information matrix is not positive definite{where} "
            f"(an under-constrained pose)") from None
    return LandmarksEliminated(H_ll, A_l, A_blocks, H_lp, ab, Lb, w, tracks)


def information_solver(A: sp.spmatrix, keys: list, n_frames: int) -> LandmarksEliminated:
    """``H = A^T A`` of a whitened Jacobian ``A`` (:class:`WhitenedSystem`) whose columns are
    the variables ``keys``, sorted: the poses ``0..n_frames-1``, landmarks and any other
    variables (the gyro bias: 3-dimensional, speed scales: 1), which join the border; with its landmarks
    eliminated. ``.solve(B)`` is ``H^-1 B`` (the Laplace posterior covariance times ``B``)."""
    kinds = _key_chars(keys)
    is_pose, is_lm = kinds == "x", kinds == "l"
    pose_keys = np.asarray([int(k) for k in keys], dtype=np.uint64)[is_pose]
    if not np.array_equal(pose_keys, np.uint64(X(0)) + np.arange(n_frames, dtype=np.uint64)):
        raise EstimationError("marginals: the graph's variables are not the expected poses and "
                              "landmarks")
    lm_keys = [k for k, l in zip(keys, is_lm) if l]
    tracks = _key_indices(lm_keys) if lm_keys else np.zeros(0, dtype=np.int64)
    H = (A.T @ A).tocsr()
    other = ~(is_pose | is_lm)
    if not other.any():  # sorted keys: the landmarks ("l") come before the poses ("x")
        return eliminate_landmarks(H, 3 * len(lm_keys), n_frames, tracks)
    # columns reordered to [landmarks, poses, others] (sorted keys put "b" before "l")
    dims = _key_dims(keys)
    starts = np.r_[0, np.cumsum(dims)[:-1]]
    cols = [np.arange(s, s + d) for s, d in zip(starts, dims)]
    outer = np.concatenate([cols[i] for i in np.flatnonzero(is_lm)]
                           + [cols[i] for i in np.flatnonzero(is_pose)]
                           + [cols[i] for i in np.flatnonzero(other)])
    reduced = eliminate_landmarks(H[outer][:, outer], 3 * len(lm_keys), n_frames, tracks,
                                  other_keys=[int(k) for k, o in zip(keys, other) if o])
    reduced.order = outer if reduced.order is None else outer[reduced.order]
    return reduced


def schur_marginals(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, n_frames: int,
                    tracks: np.ndarray, n_tracks: int, others: list | None = None) -> tuple:
    """Pose covariances (T, 6, 6) in the Estimate convention and landmark covariances
    (n_tracks, 3, 3) (NaN for tracks not in ``tracks``); see the module docstring. With
    ``others`` (keys of variables that are neither poses nor landmarks: the speed scales) also
    their joint marginal covariance (:meth:`LandmarksEliminated.others_covariance`), third.

    Raises :class:`ekf.errors.EstimationError` naming the variable when the information
    matrix is not positive definite there. BLAS is pinned to one thread: the recursion works
    on small blocks, where multi-threaded OpenBLAS is many times slower (DESIGN.md)."""
    _, reduced = linearise(graph, values, n_frames, "linearising for marginal covariances")
    if not np.array_equal(reduced.tracks, np.sort(np.asarray(tracks, dtype=np.int64))):
        raise EstimationError("marginals: the graph's variables are not the expected poses and "
                              "landmarks")
    with blas_threads(1):
        pose_cov, landmark_cov = _schur_marginals(reduced, n_frames, n_tracks)
    if others is not None:
        return gtsam_cov_to_estimate(pose_cov), landmark_cov, reduced.others_covariance(others)
    return gtsam_cov_to_estimate(pose_cov), landmark_cov


def pose_chain_covariances(reduced: LandmarksEliminated, n_frames: int,
                           with_log_det: bool = False):
    """The marginal covariances of the poses (T, 6, 6) and of consecutive poses' cross terms
    ``Cov(x_k, x_{k+1})`` (T-1, 6, 6) of an information matrix with its landmarks eliminated
    (:func:`linearise`), both in GTSAM's rotation-first right perturbation (the entries of the
    Takahashi recursion next to the diagonal; what EM needs for the expected motion residuals,
    :mod:`graph.identification`). ``with_log_det``: also ``log det H`` of the whole information
    matrix (the Laplace term of the likelihood)."""
    with blas_threads(1):
        pose_cov, _, pair_cov, log_det = _schur_marginals(
            reduced, n_frames, int(np.max(reduced.tracks, initial=-1)) + 1, pairs=True,
            landmarks=False)
    return (pose_cov, pair_cov, log_det) if with_log_det else (pose_cov, pair_cov)


def linearise(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, n_frames: int,
              doing: str) -> tuple[WhitenedSystem, LandmarksEliminated]:
    """GTSAM's linearisation of a graph on landmarks and poses ``0..n_frames-1`` at ``values``
    and its information matrix with the landmarks eliminated (:func:`information_solver`);
    ``doing`` names the step in GTSAM's errors. BLAS is pinned to one thread, as for the
    marginals (:func:`schur_marginals`)."""
    system = whitened_system(graph, values, doing)
    with blas_threads(1):
        return system, information_solver(system.A, system.keys, n_frames)


def _schur_marginals(reduced: LandmarksEliminated, n_frames: int, n_tracks: int,
                     pairs: bool = False, landmarks: bool = True):
    """Pose (GTSAM convention unless converted by the caller) and landmark marginals (steps 3-4
    of the module docstring) of an information matrix with its landmarks eliminated; with
    ``pairs`` also the cross-covariances of consecutive poses (GTSAM convention). Without
    ``landmarks`` the landmark covariances are left NaN (not computed). With a border
    (:class:`Border`) the recursion runs on ``S`` and each block gets its low-rank correction
    (step 5 of the module docstring)."""
    tracks = reduced.short_tracks
    border = reduced.border
    if border is not None:  # Y per pose (T, 6, nb): X_p Sigma_bb X_q^T = Y_p Y_q^T
        Y_pose = border.Y.reshape(n_frames, 6, border.size)
        H_lb = border.H_bl.T.tocsr() if border.H_bl.nnz else None
    n_lm = len(tracks)
    H_ll, A_l, H_lp, ab, Lb, w = reduced.H_ll, reduced.A_l, reduced.H_lp, reduced.ab, reduced.Lb, reduced.w
    n = 6 * n_frames

    # L's envelope, in poses: the last pose whose rows reach pose p (have a nonzero of S in a
    # column at or before p); the Takahashi step at p needs Sigma over poses p+1..reach[p] only.
    last_nonzero = w - np.argmax(ab[::-1] != 0, axis=0)  # per column of S, below the diagonal
    reach = np.maximum.accumulate(((np.arange(n) + last_nonzero) // 6).reshape(n_frames, 6).max(axis=1))

    def L_block(first: int, m: int, j0: int) -> np.ndarray:
        """Dense ``L[first:first + m, j0:j0 + 6]`` from the banded factor (``first >= j0``,
        inside the band): column ``j0 + c`` of ``L`` holds ``Lb[i - j0 - c, j0 + c]`` at row ``i``."""
        out = np.zeros((m, 6))
        for c in range(6):
            top = max(first, j0 + c)  # the diagonal and below
            out[top - first:, c] = Lb[top - j0 - c:first + m - j0 - c, j0 + c]
        return out

    # each landmark's entries of H_lp, columns relative to the first pose it touches; the
    # landmarks grouped by that pose (their covariances are computed together, below)
    H_lp_csr = H_lp
    nnz_rows = np.repeat(np.arange(3 * n_lm), np.diff(H_lp_csr.indptr))
    entry_lm, entry_row = nnz_rows // 3, nnz_rows % 3
    # the first pose of each landmark: the smallest column of its three rows (none: n_frames)
    row_first = np.full(3 * n_lm, 6 * n_frames, dtype=np.int64)
    filled = np.flatnonzero(np.diff(H_lp_csr.indptr))
    if filled.size:
        row_first[filled] = np.minimum.reduceat(H_lp_csr.indices, H_lp_csr.indptr[filled])
    first_pose = row_first.reshape(n_lm, 3).min(axis=1) // 6
    entry_col = H_lp_csr.indices - 6 * first_pose[entry_lm]
    lm_order = np.argsort(first_pose, kind="stable")
    group_start = np.searchsorted(first_pose[lm_order], np.arange(n_frames + 2))
    slot = np.empty(n_lm, dtype=np.int64)  # a landmark's place in its group
    slot[lm_order] = np.arange(n_lm) - group_start[first_pose[lm_order]]
    entry_order = np.argsort(first_pose[entry_lm], kind="stable")
    entry_start = np.searchsorted(first_pose[entry_lm][entry_order], np.arange(n_frames + 1))

    window = np.zeros((6, 6))  # Sigma over the poses p+1..reach[p+1]
    pose_cov = np.empty((n_frames, 6, 6))
    pair_cov = np.zeros((max(n_frames - 1, 0), 6, 6))
    landmark_cov = np.full((n_tracks, 3, 3), np.nan)
    unobserved = lm_order[group_start[n_frames]:group_start[n_frames + 1]]  # no pose factor
    landmark_cov[tracks[unobserved]] = A_l[unobserved]
    for p in range(n_frames - 1, -1, -1):
        j0 = 6 * p
        m = 6 * (int(reach[p]) - p)  # rows of L's envelope below this block
        L_jj = L_block(j0, 6, j0)
        L_jj_inv = np.linalg.inv(L_jj)
        new = np.empty((6 + m, 6 + m))  # Sigma over the poses p..reach[p]
        if m > 0:
            L_sj = L_block(j0 + 6, m, j0)
            S_ss = window[:m, :m]
            S_sj = -(S_ss @ L_sj) @ L_jj_inv
            S_jj = L_jj_inv.T @ L_jj_inv - S_sj.T @ L_sj @ L_jj_inv
            new[6:6 + m, 6:6 + m] = S_ss
            new[6:6 + m, :6] = S_sj
            new[:6, 6:6 + m] = S_sj.T
        else:
            S_jj = L_jj_inv.T @ L_jj_inv
        new[:6, :6] = 0.5 * (S_jj + S_jj.T)
        window = new
        pose_cov[p] = new[:6, :6]
        if pairs and p < n_frames - 1:
            pair_cov[p] = new[:6, 6:12]
        group = lm_order[group_start[p]:group_start[p + 1]]
        if landmarks and group.size:
            landmark_cov[tracks[group]] = _landmark_covariances(
                A_l[group], new, slot, entry_order[entry_start[p]:entry_start[p + 1]],
                entry_lm, entry_row, entry_col, H_lp_csr.data, tracks,
                border=None if border is None else (border, p, group, H_lb))
    if border is not None:  # Sigma_pp = S^-1 + X Sigma_bb X^T on the blocks asked for
        pose_cov += Y_pose @ np.swapaxes(Y_pose, 1, 2)
        pose_cov = 0.5 * (pose_cov + np.swapaxes(pose_cov, 1, 2))
        if pairs and n_frames > 1:
            pair_cov += Y_pose[:-1] @ np.swapaxes(Y_pose[1:], 1, 2)
        n_long = len(border.tracks)
        if landmarks and n_long:
            blocks = border.Sigma[:3 * n_long, :3 * n_long].reshape(n_long, 3, n_long, 3)
            landmark_cov[border.tracks] = blocks[np.arange(n_long), :, np.arange(n_long), :]
    if pairs:  # log det H = log det H_ll + log det S (the Schur complement's Cholesky)
        log_det = float(np.sum(np.linalg.slogdet(H_ll)[1])) if n_lm else 0.0
        log_det += 2.0 * float(np.sum(np.log(Lb[0])))
        if border is not None:  # ... + log det of the border's Schur complement
            log_det += border.log_det_Z
        return pose_cov, landmark_cov, pair_cov, log_det
    return pose_cov, landmark_cov


def _landmark_covariances(A_g: np.ndarray, window: np.ndarray, slot: np.ndarray,
                          entries: np.ndarray, entry_lm: np.ndarray, entry_row: np.ndarray,
                          entry_col: np.ndarray, data: np.ndarray,
                          tracks: np.ndarray, border: tuple | None = None) -> np.ndarray:
    """Step 4 of the module docstring for the landmarks whose first pose is the window's:
    ``A_l + B Sigma_pp B^T`` with ``B = -A_l H_lp`` over the poses their tracks span (``A_g``
    their ``H_ll^-1``, ``entries`` their nonzeros of ``H_lp``, columns from the first pose).
    ``border`` (:class:`Border`, the first pose, the landmarks, their ``H_lb`` or None when
    zero): the window is ``S^-1``'s and the correction ``G Sigma_bb G^T`` is added, with
    ``G = B X + A_l H_lb`` (step 5)."""
    span = int(entry_col[entries].max()) + 1
    if span > window.shape[0]:
        raise EstimationError("marginals: internal band error at "
                              f"{key_name(L(int(tracks[entry_lm[entries][np.argmax(entry_col[entries])]])))}")
    H_rows = np.zeros((len(A_g), 3, span))
    # one CSR entry per (landmark, row, column): an assignment, no accumulation
    H_rows[slot[entry_lm[entries]], entry_row[entries], entry_col[entries]] = data[entries]
    B = -A_g @ H_rows
    cov = A_g + (B @ window[:span, :span]) @ np.swapaxes(B, 1, 2)
    if border is not None:
        bd, p, group, H_lb = border
        if H_lb is None:  # G Sigma_bb G^T = (B Y)(B Y)^T
            BY = B @ bd.Y[6 * p:6 * p + span]  # (g, 3, nb)
            cov = cov + BY @ np.swapaxes(BY, 1, 2)
        else:
            rows = (3 * group[:, None] + np.arange(3)).ravel()
            G = B @ bd.X[6 * p:6 * p + span] + A_g @ H_lb[rows].toarray().reshape(len(group), 3, bd.size)
            cov = cov + (G @ bd.Sigma) @ np.swapaxes(G, 1, 2)
    return 0.5 * (cov + np.swapaxes(cov, 1, 2))


def batch_marginals(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, n_frames: int,
                    tracks: np.ndarray, n_tracks: int, others: list | None = None) -> tuple:
    """Pose (Estimate convention) and landmark marginal covariances of a solved graph (and,
    with ``others``, those variables' joint covariance: :func:`schur_marginals`)."""
    return schur_marginals(graph, values, n_frames, tracks, n_tracks, others)


def gtsam_marginals(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, n_frames: int,
                    tracks: np.ndarray, n_tracks: int) -> tuple[np.ndarray, np.ndarray]:
    """The same figures from ``gtsam.Marginals`` key by key (slow; the reference in tests)."""
    try:
        marginals = gtsam.Marginals(graph, values)
        pose_cov = np.stack([marginals.marginalCovariance(X(k)) for k in range(n_frames)])
        landmark_cov = np.full((n_tracks, 3, 3), np.nan)
        for j in tracks:
            landmark_cov[j] = marginals.marginalCovariance(L(int(j)))
    except RuntimeError as exc:
        raise estimation_error(exc, "computing marginal covariances") from None
    return gtsam_cov_to_estimate(pose_cov), landmark_cov

