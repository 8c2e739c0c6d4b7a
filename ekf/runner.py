"""What every estimator does before and after its work: validating and cleaning the sequence,
BLAS pinning, per-frame timing and counters, track bookkeeping, and building and checking the
:class:`~ekf.estimate.Estimate`. The per-frame loop that uses them is :func:`ekf.driver.run_filter`;
the smoothers (graph/) use :func:`prepare_sequence` and :func:`finish_estimate`.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import time
from typing import Callable

import numpy as np
from threadpoolctl import ThreadpoolController

from vislam.ekf.cleaning import clean_sequence
from vislam.ekf.config import FilterConfig
from vislam.ekf.errors import InputError
from vislam.ekf.estimate import Estimate
from vislam.ekf.numerics import NumericalGuard, check_finite_trajectory
from vislam.ekf.prediction import paired_velocities
from vislam.ekf.sequence import Sequence

log = logging.getLogger(__name__)

Progress = Callable[[int], None] | None


def validate_sequence(seq: Sequence) -> None:
    """InputError naming the array and step where time stamps or velocities are not finite, or
    where time does not increase (in-memory sequences bypass the loader's checks)."""
    for key, arr in (
        ("timestamps", seq.timestamps),
        ("linear_velocity", seq.linear_velocity),
        ("angular_velocity", seq.angular_velocity),
    ):
        bad = np.flatnonzero(~np.all(np.isfinite(np.reshape(arr, (len(arr), -1))), axis=1))
        if bad.size:
            raise InputError(f"sequence {seq.name!r}: {key} is not finite at step {int(bad[0])}")
    if seq.n_frames < 1:
        raise InputError(f"sequence {seq.name!r}: no frames")
    if seq.n_frames > 1 and not np.all(np.diff(seq.timestamps) > 0):
        k = int(np.flatnonzero(~(np.diff(seq.timestamps) > 0))[0])
        raise InputError(f"sequence {seq.name!r}: timestamps do not increase at step {k + 1}")


def prepare_sequence(seq: Sequence, config: FilterConfig) -> tuple[Sequence, dict]:
    """What every estimator (EKF variants and smoothers) does first: :func:`validate_sequence`,
    then the track-cleaning step when ``config.clean_tracks``; returns ``(seq, info)``.

    Depth is not cut here (``max_depth=None``): each estimator rejects points beyond
    ``config.max_depth`` itself, so they show in ``Estimate.n_rejected``.
    ``info`` records whether cleaning ran, its report, and ``track_origin`` of the (cleaned)
    sequence, which relates the Estimate's landmark rows to the source file's columns.
    """
    validate_sequence(seq)
    info: dict = {"clean_tracks": bool(config.clean_tracks), "cleaned": False}
    if config.clean_tracks:
        seq, report = clean_sequence(
            seq, split_repeats=True, min_disparity=config.min_disparity, max_depth=None
        )
        info["cleaned"] = True
        info["cleaning"] = _report_dict(report)
    info["track_origin"] = np.asarray(seq.track_origin, dtype=np.int64).tolist()
    return seq, info


def _report_dict(report) -> dict:
    import dataclasses

    if dataclasses.is_dataclass(report):
        out = {}
        for f in dataclasses.fields(report):
            v = getattr(report, f.name)
            if isinstance(v, (int, float, str, bool)) or v is None:
                out[f.name] = v
            elif isinstance(v, np.generic):
                out[f.name] = v.item()
        return out
    return {"report": str(report)}


@functools.lru_cache(maxsize=1)
def _blas_controller() -> ThreadpoolController:
    """The process's BLAS libraries (numpy's, and scipy's, imported first so that it is seen),
    found once: ``threadpoolctl.threadpool_limits`` scans every loaded library at each call."""
    import scipy.linalg  # noqa: F401

    return ThreadpoolController()


def blas_threads(n: int):
    """Context manager limiting BLAS to ``n`` threads (threadpoolctl)."""
    return _blas_controller().limit(limits=int(n), user_api="blas")


@contextlib.contextmanager
def blas_limits(config: FilterConfig):
    """Context manager pinning BLAS to ``config.blas_threads`` threads (DESIGN.md: 40x).

    Inside it numpy's floating-point warnings (overflow, invalid) are off: on absurd but
    finite input they are expected, and the estimators check the results themselves
    (:mod:`ekf.numerics`) and reject or raise with one line instead."""
    with blas_threads(config.blas_threads), np.errstate(all="ignore"):
        yield


def interval_twists(seq: Sequence, config: FilterConfig) -> tuple[np.ndarray, np.ndarray]:
    """``(tau (T-1,), u (T-1, 6))``: length and twist of each interval [k, k+1]."""
    return seq.dt.astype(float), paired_velocities(seq.velocities, config.velocity_pairing)


def tracks_ending(seq: Sequence) -> list[np.ndarray]:
    """``out[t]``: the tracks whose last observation is at frame ``t`` (sorted)."""
    last = seq.track_last_frame()
    tracks = np.nonzero(last >= 0)[0]
    order = np.argsort(last[tracks], kind="stable")
    tracks = tracks[order]
    ptr = np.searchsorted(last[tracks], np.arange(seq.n_frames + 1))
    return [tracks[ptr[t] : ptr[t + 1]] for t in range(seq.n_frames)]


def report_progress(progress: Progress, t: int, n_frames: int, every: int = 10) -> None:
    """Call ``progress(frames done)`` every ``every`` frames and at the end."""
    if progress is not None and ((t + 1) % every == 0 or t + 1 == n_frames):
        progress(t + 1)


class StepRecorder:
    """Per-step poses, covariances, wall time and counters of one run."""

    def __init__(self, n_frames: int):
        self.poses = np.tile(np.eye(4), (n_frames, 1, 1))
        self.pose_cov = np.full((n_frames, 6, 6), np.nan)
        self.step_time_s = np.zeros(n_frames)
        self.n_updates = np.zeros(n_frames, dtype=np.int64)
        self.n_rejected = np.zeros(n_frames, dtype=np.int64)
        self.n_initialised = np.zeros(n_frames, dtype=np.int64)

    @contextlib.contextmanager
    def step(self, t: int):
        """Time the body as step ``t``."""
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.step_time_s[t] += time.perf_counter() - t0


def build_estimate(
    name: str,
    seq: Sequence,
    rec: StepRecorder,
    landmarks: np.ndarray | None,
    landmark_cov: np.ndarray | None,
    config: FilterConfig,
    info: dict,
    guard: NumericalGuard | None = None,
) -> Estimate:
    """Assemble the Estimate; landmarks are indexed by ``seq``'s (cleaned) track indices.

    ``guard`` the run's numerical rejections (:mod:`ekf.numerics`); see :func:`finish_estimate`.
    """
    est = Estimate.empty(name, seq.timestamps, seq.n_tracks)
    est.poses = rec.poses
    est.pose_cov = rec.pose_cov
    if landmarks is not None:
        est.landmarks = landmarks
        est.landmark_cov = landmark_cov
    est.step_time_s = rec.step_time_s
    est.n_updates = rec.n_updates
    est.n_rejected = rec.n_rejected
    est.n_initialised = rec.n_initialised
    est.info = dict(info)
    est.info.setdefault("config", config.to_dict())
    est.info.setdefault("sequence", seq.name)
    finish_estimate(est, guard if guard is not None else NumericalGuard(name, seq.timestamps))
    return est


def finish_estimate(est: Estimate, guard: NumericalGuard, check_cov: bool = True,
                    drop_unusable_cov: bool = True) -> Estimate:
    """What every estimator does last: record the numerical rejections in ``est.info``, raise
    the estimator's EstimationError if a pose or pose covariance is not finite (naming the first
    such frame), and drop landmarks whose mean is not finite or whose covariance is not finite
    or not usable (:func:`covariance_usable`; logged, counted in ``info["n_landmarks_dropped"]``)
    so that the estimate passes :meth:`Estimate.check_finite` and the estimator contract.
    ``check_cov=False``: the pose covariances were not computed (NaN by design), only the
    poses are checked. ``drop_unusable_cov=False`` (the smoothers, whose marginals come from one
    factorisation and are never left indefinite by rounding): only non-finite landmarks are
    dropped, so that a fault in the marginals still fails the estimator contract."""
    est.info.update(guard.info())
    check_finite_trajectory(guard, est.poses, est.pose_cov if check_cov else np.zeros((est.n_frames, 1)))
    lm, cov = est.landmarks, est.landmark_cov
    if lm.shape[0]:
        ok = np.isfinite(lm).all(axis=1)
        if check_cov:
            ok &= np.isfinite(cov.reshape(cov.shape[0], -1)).all(axis=1)
            if drop_unusable_cov:
                ok[ok] = covariance_usable(cov[ok])
        bad = ~ok & ~np.isnan(lm).all(axis=1)
        if bad.any():
            log.warning("%s: %d landmarks with a non-finite mean or a covariance not finite, not "
                        "symmetric or not positive semi-definite dropped from the map",
                        est.estimator, int(bad.sum()))
            est.landmarks = lm.copy()
            est.landmark_cov = cov.copy()
            est.landmarks[bad] = np.nan
            est.landmark_cov[bad] = np.nan
        est.info["n_landmarks_dropped"] = int(bad.sum())
    return est


#: Relative tolerance of :func:`covariance_usable`, and of the estimator contract's covariance
#: checks (``eval.registry`` imports it), so that what an EKF keeps passes the contract.
COVARIANCE_RTOL = 1e-6


def covariance_defects(cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For finite covariances (n, d, d), relative to each one's largest entry: the largest
    asymmetry (n,) and the smallest eigenvalue of the symmetric part (n,). What
    :func:`covariance_usable` and the estimator contract (``eval.registry``) test against
    :data:`COVARIANCE_RTOL`."""
    if cov.shape[0] == 0:
        return np.zeros(0), np.zeros(0)
    scale = np.maximum(np.abs(cov).max(axis=(1, 2)), 1e-300)
    asym = np.abs(cov - np.swapaxes(cov, 1, 2)).max(axis=(1, 2)) / scale
    low = np.linalg.eigvalsh((cov + np.swapaxes(cov, 1, 2)) / 2)[:, 0] / scale
    return asym, low


def covariance_usable(cov: np.ndarray) -> np.ndarray:
    """Boolean (n,) for finite covariances (n, d, d): symmetric and positive semi-definite
    within :data:`COVARIANCE_RTOL` of the largest entry. On hostile input (pixels 1e5 px off)
    an EKF's gauge transport can cancel a huge correlation into a landmark block that rounding
    has left indefinite; such a landmark is dropped from the map, not reported."""
    asym, low = covariance_defects(cov)
    return (asym <= COVARIANCE_RTOL) & (low >= -COVARIANCE_RTOL)
