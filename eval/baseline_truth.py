"""The stereo baseline on which a drive's ground truth and its pixels agree.

A file's baseline ``b`` turns a disparity ``d = uL - uR`` into a depth ``Z = f b / d``, so it sets
vision's metric scale. Where a drive has ground truth, the depth can be had without the right
image: each track's landmark is triangulated from its left-image rays alone, seen from the
ground truth's camera poses (a linear least-squares solve per track), and its depth ``Z_k`` in
each frame predicts the disparity ``f b / Z_k``. The measured disparities over the predicted
ones, ``d / (f b / Z)``, are ``b_pixels / b`` where the pixels were made with another baseline
than the file gives (a calibration error, or a matcher biased along the rows): 1 when the file's
baseline is the pixels'.

Only tracks whose left rays span enough parallax (``min_parallax_deg``) and fit the
triangulated point (``max_rms_px``) are used, and the ratio is read per depth band, because
a left-only triangulation along a forward drive loses depth precision with range: the near
bands are the ones to trust.

This is what the pixels' scale *is* against the ground truth: vision's translations come out
``b / b_pixels`` of the truth's, whatever estimator reads them. ``benchmarks/baseline_truth.py``
prints it per drive.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vislam.ekf.errors import InputError
from vislam.ekf.sequence import track_runs

#: Depth bands (m) of the report: near landmarks carry most of the left-only depth precision.
DEPTH_BANDS = ((1.0, 10.0), (10.0, 20.0), (20.0, 40.0), (40.0, 80.0))


@dataclass(frozen=True)
class BaselineBand:
    """One depth band: its bounds (m), the observations in it and the median of the measured
    over the predicted disparities (``b_pixels / b``)."""

    near: float
    far: float
    n_observations: int
    ratio: float


@dataclass(frozen=True)
class BaselineFit:
    """The disparity ratio ``b_pixels / b`` per depth band, over the bands nearer than
    ``near_limit`` m in one (``ratio``, the median of their observations), the tracks used
    and the file's baseline."""

    bands: tuple[BaselineBand, ...]
    ratio: float
    near_limit: float
    n_tracks: int
    baseline: float

    @property
    def pixels_baseline(self) -> float:
        """The baseline the pixels were made with (m), as the near bands give it."""
        return self.baseline * self.ratio


def triangulate_left(camera_poses: np.ndarray, K: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """The point (3,) in the poses' world frame whose left-image projections from the camera
    poses ``camera_poses`` (m, 4, 4; camera to world) best fit the pixels ``uv`` (m, 2): the
    homogeneous linear solve (two rows a view)."""
    cam_T_world = np.linalg.inv(camera_poses)[:, :3, :]
    x = (uv[:, 0] - K[0, 2]) / K[0, 0]
    y = (uv[:, 1] - K[1, 2]) / K[1, 1]
    A = np.concatenate([x[:, None] * cam_T_world[:, 2] - cam_T_world[:, 0],
                        y[:, None] * cam_T_world[:, 2] - cam_T_world[:, 1]])
    _, _, Vt = np.linalg.svd(A)
    h = Vt[-1]
    return h[:3] / h[3] if abs(h[3]) > 1e-12 else np.full(3, np.nan)


def baseline_from_truth(camera_poses: np.ndarray, frame: np.ndarray, track: np.ndarray,
                        z: np.ndarray, K: np.ndarray, baseline: float, *,
                        min_views: int = 5, min_parallax_deg: float = 5.0,
                        max_rms_px: float = 1.5, near_limit: float = 40.0) -> BaselineFit:
    """The disparity ratio of a drive (module docstring). ``camera_poses`` (T, 4, 4): the
    ground truth's left-camera poses (camera to world) of frames 0..T-1; ``frame``, ``track``
    (N,) and ``z`` (N, 4) ``[uL, vL, uR, vR]``: the stereo observations; ``K`` the left
    intrinsics; ``baseline`` the file's (m). Observations of frames past the ground truth are
    left out."""
    P = np.asarray(camera_poses, dtype=float)
    K = np.asarray(K, dtype=float)
    frame = np.asarray(frame)
    track = np.asarray(track)
    z = np.asarray(z, dtype=float)
    if P.ndim != 3 or P.shape[1:] != (4, 4) or P.shape[0] < 2:
        raise InputError(f"ground truth: camera poses of shape {P.shape}, need (T >= 2, 4, 4)")
    if z.ndim != 2 or z.shape[1] != 4:
        raise InputError(f"observations of shape {z.shape}: need stereo pixels (N, 4)")
    if not baseline > 0.0:
        raise InputError(f"baseline {baseline}: must be positive")
    seen = (frame < P.shape[0]) & np.all(np.isfinite(P[np.minimum(frame, P.shape[0] - 1)]),
                                         axis=(1, 2))
    frame, track, z = frame[seen], track[seen], z[seen]
    order, starts, ends = track_runs(frame, track)
    frame, z = frame[order], z[order]
    depth, measured, used = [], [], 0
    for a, e in zip(starts, ends):
        if e - a < min_views:
            continue
        poses = P[frame[a:e]]
        X = triangulate_left(poses, K, z[a:e, :2])
        if not np.all(np.isfinite(X)):
            continue
        rays = X[None, :] - poses[:, :3, 3]
        cos = rays[0] @ rays[-1] / (np.linalg.norm(rays[0]) * np.linalg.norm(rays[-1]))
        if np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))) < min_parallax_deg:
            continue
        Xc = np.einsum("kij,kj->ki", np.linalg.inv(poses)[:, :3, :3], rays)
        Z = Xc[:, 2]
        if np.any(Z < 1.0):
            continue
        u = K[0, 0] * Xc[:, 0] / Z + K[0, 2]
        v = K[1, 1] * Xc[:, 1] / Z + K[1, 2]
        if np.sqrt(np.mean((u - z[a:e, 0]) ** 2 + (v - z[a:e, 1]) ** 2)) > max_rms_px:
            continue
        used += 1
        depth.append(Z)
        measured.append(z[a:e, 0] - z[a:e, 2])
    if not used:
        raise InputError("ground truth: no track spans enough views and parallax to triangulate "
                         "from the left image alone")
    Z = np.concatenate(depth)
    ratio = np.concatenate(measured) / (K[0, 0] * baseline / Z)
    bands = tuple(BaselineBand(lo, hi, int(np.count_nonzero(m)),
                               float(np.median(ratio[m])) if m.any() else float("nan"))
                  for lo, hi in DEPTH_BANDS for m in [(Z >= lo) & (Z < hi)])
    near = Z < near_limit
    return BaselineFit(bands=bands, ratio=float(np.median(ratio[near])) if near.any() else float("nan"),
                       near_limit=float(near_limit), n_tracks=used, baseline=float(baseline))


__all__ = ["BaselineBand", "BaselineFit", "DEPTH_BANDS", "baseline_from_truth", "triangulate_left"]
