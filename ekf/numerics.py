"""Numerical guards shared by the estimators: what to do when an update cannot be computed.

On odd but finite input (a corrupt gyro sample, pixels shifted by 1e5 px, a 100 s time step)
an innovation covariance can be singular or indefinite in floating point, or a gain can
overflow. The filters then *reject that frame's update*: the state and covariance stay as
they were before the update, the observations count in ``Estimate.n_rejected``, and the frame
counts in ``Estimate.info["numerical_rejections"]`` (with the first
:data:`MAX_RECORDED_FRAMES` frame indices in ``info["numerical_rejection_frames"]``) and is
logged as a warning. A failure that cannot be rejected (the pose or its covariance not finite
after a prediction) is an :class:`~ekf.errors.EstimationError` naming the estimator, the frame
(index and time) and the quantity.

The checks are cheap by construction (Cholesky factorisations that report failure instead of
raising, ``isfinite`` on small blocks, one dot product for the size of a gain, the minimum of a
posterior diagonal), so the hot loops stay as fast as before; the fallbacks (per-row loops)
only run when the fast path fails.
"""

from __future__ import annotations

import logging
import math

import numpy as np
from scipy.linalg.blas import dgemm

from vislam.ekf.errors import EstimationError, time_text

log = logging.getLogger(__name__)

#: How many rejected frames are listed in ``info["numerical_rejection_frames"]`` (and logged).
MAX_RECORDED_FRAMES = 20


class UpdateRejected(Exception):
    """Raised inside an update when it cannot be computed; the caller keeps its prior state.

    Never escapes an estimator (the loop catches it and calls :meth:`NumericalGuard.reject`).
    """


class NumericalGuard:
    """Counts the frames whose update was rejected for numerical reasons; raises the
    estimator's :class:`EstimationError` for failures that cannot be rejected."""

    def __init__(self, estimator: str, timestamps: np.ndarray):
        self.estimator = estimator
        self.timestamps = np.asarray(timestamps, dtype=float)
        self.n_frames = 0
        self.frames: list[int] = []
        self._last = -1

    def where(self, t: int) -> str:
        time = self.timestamps[t] if 0 <= t < self.timestamps.size else float("nan")
        return f"frame {int(t)} (t={time_text(time)} s)"

    def reject(self, t: int, what: str, n_obs: int | None = None) -> None:
        """Record that (part of) frame ``t``'s update was rejected because of ``what``."""
        if t == self._last:
            return
        self._last = int(t)
        self.n_frames += 1
        if len(self.frames) < MAX_RECORDED_FRAMES:
            self.frames.append(int(t))
            obs = "" if n_obs is None else f" ({n_obs} observations)"
            log.warning("%s: %s: update rejected%s: %s", self.estimator, self.where(t), obs, what)
        elif self.n_frames == MAX_RECORDED_FRAMES + 1:
            log.warning("%s: more updates rejected for numerical reasons (not logged)", self.estimator)

    def error(self, t: int, what: str) -> EstimationError:
        """The one-line error for a failure at frame ``t``: ``"<estimator>: frame t (t=.. s): what"``."""
        return EstimationError(f"{self.estimator}: {self.where(t)}: {what}")

    def check_state(self, t: int, pose: np.ndarray, cov: np.ndarray,
                    stage: str = "after prediction") -> None:
        """Raise :meth:`error` if the pose or its covariance (small arrays) is not finite."""
        if np.isfinite(pose).all() and np.isfinite(cov).all():
            return
        if not np.isfinite(pose).all():
            raise self.error(t, f"pose not finite {stage}")
        raise self.error(t, f"pose covariance not finite {stage}")

    def info(self) -> dict:
        return {"numerical_rejections": int(self.n_frames), "numerical_rejection_frames": list(self.frames)}


def check_finite_trajectory(guard: NumericalGuard, poses: np.ndarray, pose_cov: np.ndarray,
                            quantity: str = "") -> None:
    """EstimationError naming the first frame whose pose or pose covariance is not finite."""
    T = poses.shape[0]
    bad_pose = ~np.isfinite(poses.reshape(T, -1)).all(axis=1)
    bad_cov = ~np.isfinite(pose_cov.reshape(T, -1)).all(axis=1)
    bad = bad_pose | bad_cov
    if bad.any():
        t = int(np.flatnonzero(bad)[0])
        what = "pose" if bad_pose[t] else "pose covariance"
        raise guard.error(t, f"{what} not finite{quantity}")


def batched_solve(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``np.linalg.solve(A, B)`` over a batch; rows whose system is singular come back NaN
    instead of the whole batch raising (the per-row fallback only runs when one is singular)."""
    try:
        return np.linalg.solve(A, B)
    except np.linalg.LinAlgError:
        pass
    out = np.full(np.broadcast_shapes(A.shape[:-2], B.shape[:-2]) + B.shape[-2:], np.nan)
    A = np.broadcast_to(A, out.shape[:-2] + A.shape[-2:])
    B = np.broadcast_to(B, out.shape)
    for i in np.ndindex(out.shape[:-2]):
        try:
            out[i] = np.linalg.solve(A[i], B[i])
        except np.linalg.LinAlgError:
            pass
    return out


def batched_inv(A: np.ndarray) -> np.ndarray:
    """``np.linalg.inv`` over a batch; singular matrices come back NaN (see :func:`batched_solve`)."""
    try:
        return np.linalg.inv(A)
    except np.linalg.LinAlgError:
        pass
    out = np.full(A.shape, np.nan)
    for i in np.ndindex(A.shape[:-2]):
        try:
            out[i] = np.linalg.inv(A[i])
        except np.linalg.LinAlgError:
            pass
    return out


def finite_rows(x: np.ndarray) -> np.ndarray:
    """Boolean (n,): every entry of ``x[i]`` is finite."""
    return np.isfinite(x.reshape(x.shape[0], -1)).all(axis=1)


def finite_norm2(x: np.ndarray) -> bool:
    """``|x|^2`` is finite (so neither ``x`` nor ``x^T x`` holds NaN or overflows): one dot
    product, the cheapest complete check (a False may also mean huge but finite entries)."""
    v = x.ravel(order="K")
    return math.isfinite(np.dot(v, v))


def all_finite(*arrays: np.ndarray) -> bool:
    """Every entry of every array is finite (fast path: :func:`finite_norm2` of each, so a
    False may also mean entries beyond 1e154; callers then take the per-row path)."""
    return all(finite_norm2(a) for a in arrays)


def add_pose_rows(P: np.ndarray, core: int, C: np.ndarray) -> None:
    """``P <- T P T^T`` in place for a symmetric ``P`` (its columns stand in for its rows
    below), ``T = [[I, 0], [C_z, I]]``: ``C`` (m, 6) adds the first six (pose) rows to the last
    ``m = P.shape[0] - core`` rows (the landmarks' gauge transports).

    ``T P T^T = P + C_z W^T + V C_z^T`` with ``W = P[:, :6]``, ``C_z`` the rows of ``C`` at
    ``core:`` and ``V = W + C_z P_pp`` (the new pose columns): one GEMM of inner size 12 over
    the whole matrix, in place, instead of a row-block and then a column-block update (about
    half the time). The terms are grouped as in those two steps,
    ``P_ll + C P_pl + (P_lp + C P_pp) C^T``: where the transport cancels a large correlation
    (a landmark far from where it was, pixels 1e5 px off) the symmetric split
    ``C W'^T + W' C^T`` with ``W' = W + C P_pp / 2`` lost the result to rounding."""
    N = P.shape[0]
    if C.shape != (N - core, 6):
        raise ValueError(f"add_pose_rows: C must have shape ({N - core}, 6), got {C.shape}")
    if N == core:
        return
    W = P[:, :6].copy()
    Cz = np.zeros((N, 6))
    Cz[core:] = C
    V = W + Cz @ W[:6]
    # P += W Cz^T + Cz V^T (the terms above, transposed: the same products, rows for columns).
    add_outer(P, np.hstack([W, Cz]), np.hstack([Cz, V]))


class Scratch:
    """Reusable memory for the filter's per-frame arrays of the state's size (``n x n``,
    ``n x 3k``). A fresh array that large is handed back to the operating system when freed,
    so the next frame's one page-faults on every 4 KiB page it touches: about 0.1 ms per
    ``n x n`` array at ``n ~ 220``, as long as the arithmetic on it. ``array(name, shape)`` is
    a C-contiguous view of the start of buffer ``name`` (grown, with headroom, only when too
    small); its content is undefined, and it is valid until the next call with that name."""

    def __init__(self):
        self._buffers: dict[str, np.ndarray] = {}

    def array(self, name: str, shape: tuple[int, ...]) -> np.ndarray:
        size = int(np.prod(shape))
        buf = self._buffers.get(name)
        if buf is None or buf.size < size:
            buf = self._buffers[name] = np.empty(size + size // 2)
        return buf[:size].reshape(shape)

    def covariance(self, P: np.ndarray, n: int) -> np.ndarray:
        """An ``n x n`` array for the next state covariance, in whichever of two buffers does
        not hold ``P`` (the current one, read while the next is filled)."""
        name = "P1" if P.base is not None and P.base is self._buffers.get("P0") else "P0"
        return self.array(name, (n, n))

    def submatrix(self, P: np.ndarray, idx: np.ndarray) -> np.ndarray:
        """``P[idx][:, idx]`` as the next state covariance (:meth:`covariance`), through a
        reused buffer for the rows."""
        rows = np.take(P, idx, axis=0, out=self.array("rows", (idx.size, P.shape[1])), mode="clip")
        return np.take(rows, idx, axis=1, out=self.covariance(P, idx.size), mode="clip")


def add_outer(P: np.ndarray, U: np.ndarray, W: np.ndarray) -> None:
    """``P += U W^T`` in place (``U``, ``W`` (n, r), small ``r``): one GEMM on ``P``'s memory
    instead of ``n x n`` temporaries (dgemm on the Fortran view ``P.T`` adds ``W U^T`` to it)."""
    out = dgemm(1.0, W, U, beta=1.0, c=P.T, trans_b=1, overwrite_c=1)
    if not np.shares_memory(out, P):  # P not C-ordered: BLAS worked on a copy
        P[...] = out.T
