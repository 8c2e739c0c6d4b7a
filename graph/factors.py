"""Building the smoother's factor graph from a :class:`ekf.sequence.Sequence`.

Variables: ``X(k)`` a ``Pose3`` per time step (``world_T_imu``, world = IMU at step 0) and
``L(j)`` a ``Point3`` per track j with at least two usable observations.

Factors:

* motion: ``BetweenFactorPose3(X(k), X(k+1), exp(tau u))`` with the body twist ``u`` of the
  interval (paper eq. 11, written for the pose instead of its inverse). A twist error ``w`` with
  covariance ``W`` gives ``exp(tau (u + w)) ~= exp(tau u) exp(J_r(tau u) tau w)``, so the
  relative-pose noise in GTSAM's rotation-first right perturbation is
  ``tau^2 J_r W_g J_r^T`` with ``W_g`` the permuted ``W`` and ``J_r`` ``Pose3.ExpmapDerivative``.
* vision: ``GenericStereoFactor3D(StereoPoint2(uL, uR, v), noise, X(k), L(j), K, imu_T_cam)``,
  the stereo model of paper eq. 1-3 with ``v`` the mean of vL and vR (they carry the same
  information, DESIGN.md), so its sigma is ``pixel_sigma / sqrt(2)``; robust (Huber).
* a prior on ``X(0)`` at the identity, and a weak prior on every landmark.
* with ``config.speed_scale`` the motion factors are :mod:`graph.speed_scale`'s instead (a
  speed-scale variable ``S(i)`` per interval, random walk), the scale's prior and walk after
  the smoothness factors (before the gyro bias's prior, which stays last).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import gtsam
import numpy as np

from vislam.ekf.camera import triangulate_with_jacobian
from vislam.ekf.config import FilterConfig
from vislam.ekf.conventions import estimate_cov_to_gtsam
from vislam.ekf.geometry import se3_exp, se3_inv
from vislam.ekf.sequence import Calibration, Sequence
from vislam.graph.gyro_bias import (BIAS_KEY, GyroBiasModel, bias_corrections, biased_motion_factor,
                                    corrected_deltas)
from vislam.graph.pose_conversions import L, X, expmap_right_jacobian, to_pose3, twist_to_gtsam
from vislam.graph.settings import SmootherSettings
from vislam.graph.speed_scale import SpeedScaleModel
from vislam.graph.twist_smoothness import add_smoothness_factors


@dataclass
class TwistSmoothness:
    """Where and how strongly the twist-smoothness prior applies: ``gaps`` (T-1,) the
    intervals without vision, ``tau`` (T-1,) interval lengths, ``sigma`` (6,) rotation first."""

    gaps: np.ndarray
    tau: np.ndarray
    sigma: np.ndarray
    #: Python CustomFactors (exact, slow) instead of factors linearised at the initial values.
    exact: bool = False


# --- motion ---------------------------------------------------------------------------------
def interval_twists(seq: Sequence, pairing: str) -> tuple[np.ndarray, np.ndarray]:
    """Body twists ``u`` (T-1, 6) (translation first) and lengths ``tau`` (T-1,) per interval.

    ``pairing``: ``"current"`` u_k covers [k, k+1] (the paper), ``"next"`` u_{k+1}, ``"mean"``
    the mean of the two.
    """
    u = seq.velocities
    if pairing == "current":
        twist = u[:-1]
    elif pairing == "next":
        twist = u[1:]
    elif pairing == "mean":
        twist = 0.5 * (u[:-1] + u[1:])
    else:  # FilterConfig validates this already
        raise ValueError(f"unknown velocity pairing {pairing!r}")
    return twist, seq.dt


def relative_motions(seq: Sequence, config: FilterConfig) -> tuple[np.ndarray, np.ndarray]:
    """Relative poses ``exp(tau u)`` (T-1, 4, 4) and their covariances (T-1, 6, 6) in GTSAM's
    rotation-first right perturbation (see the module docstring)."""
    twist, tau = interval_twists(seq, config.velocity_pairing)
    xi = tau[:, None] * twist
    deltas = se3_exp(xi)
    W_g = estimate_cov_to_gtsam(config.velocity_cov)
    xi_g = twist_to_gtsam(xi)
    covs = np.empty((len(tau), 6, 6))
    for k in range(len(tau)):
        J = expmap_right_jacobian(xi_g[k])
        covs[k] = tau[k] ** 2 * (J @ W_g @ J.T)
    # a zero-length interval would give a singular covariance: keep it barely positive
    covs += 1e-12 * np.eye(6)
    return deltas, covs


def dead_reckoning(seq: Sequence, config: FilterConfig) -> np.ndarray:
    """Integrated poses ``world_T_imu`` (T, 4, 4), identity at step 0."""
    deltas, _ = relative_motions(seq, config)
    poses = np.empty((seq.n_frames, 4, 4))
    poses[0] = np.eye(4)
    for k, delta in enumerate(deltas):
        poses[k + 1] = poses[k] @ delta
    return poses


# --- vision ---------------------------------------------------------------------------------
def stereo_measurement(z: np.ndarray) -> np.ndarray:
    """GTSAM's stereo rows ``[uL, uR, v]`` (N, 3, ...) of pixel rows ``[uL, vL, uR, vR]``
    (N, 4, ...): ``v`` the mean of vL and vR (pixels, their changes or their Jacobians)."""
    return np.stack([z[:, 0], z[:, 2], 0.5 * (z[:, 1] + z[:, 3])], axis=1)


@dataclass
class StereoRows:
    """Stereo observations in use: frame (N,), track (N,), pixels z (N, 4) [uL, vL, uR, vR]."""

    frame: np.ndarray
    track: np.ndarray
    z: np.ndarray

    def __len__(self) -> int:
        return int(self.frame.size)

    def subset(self, keep: np.ndarray) -> "StereoRows":
        return StereoRows(self.frame[keep], self.track[keep], self.z[keep])

    @property
    def measured(self) -> np.ndarray:
        """GTSAM's stereo measurement ``[uL, uR, v]`` (N, 3), ``v`` the mean of vL and vR."""
        return stereo_measurement(self.z)


def usable_rows(seq: Sequence, min_disparity: float) -> tuple[StereoRows, np.ndarray]:
    """Observations with disparity ``uL - uR`` above ``min_disparity`` (and above 0), and the
    number rejected per frame (T,)."""
    frame = seq.obs.frame_index
    z = seq.obs.z
    disparity = z[:, 0] - z[:, 2]
    ok = np.isfinite(z).all(axis=1) & (disparity > max(min_disparity, 1e-6))
    rejected = np.bincount(frame[~ok], minlength=seq.n_frames)
    return StereoRows(frame[ok], seq.obs.track[ok], z[ok]), rejected


def keep_multi_observed(rows: StereoRows, n_tracks: int, minimum: int = 2) -> np.ndarray:
    """Boolean (N,): the row's track has at least ``minimum`` rows."""
    counts = np.bincount(rows.track, minlength=n_tracks)
    return counts[rows.track] >= minimum


def camera_points(poses: np.ndarray, landmarks: np.ndarray, calib: Calibration,
                  rows: StereoRows) -> np.ndarray:
    """Landmark of each row in the left camera of its frame (N, 3)."""
    cam_T_world = calib.cam_T_imu @ se3_inv(poses[rows.frame])
    p = landmarks[rows.track]
    return np.einsum("nij,nj->ni", cam_T_world[:, :3, :3], p) + cam_T_world[:, :3, 3]


def stereo_residuals(poses: np.ndarray, landmarks: np.ndarray, calib: Calibration,
                     rows: StereoRows) -> tuple[np.ndarray, np.ndarray]:
    """Residuals ``[uL, uR, v]`` measured minus predicted (N, 3) and depths (N,)."""
    q = camera_points(poses, landmarks, calib, rows)
    depth = q[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        x, y = q[:, 0] / depth, q[:, 1] / depth
        uL = calib.fsu * x + calib.cu
        uR = calib.fsu * (x - calib.baseline / depth) + calib.cu
        v = calib.fsv * y + calib.cv
    predicted = np.stack([uL, uR, v], axis=1)
    return rows.measured - predicted, depth


def triangulate_landmarks(poses: np.ndarray, calib: Calibration, rows: StereoRows,
                          n_tracks: int) -> np.ndarray:
    """World position (n_tracks, 3) of each track from its largest-disparity observation
    (the best-conditioned depth), NaN for tracks without rows."""
    disparity = rows.z[:, 0] - rows.z[:, 2]
    order = np.lexsort((-disparity, rows.track))  # by track, largest disparity first
    first = np.ones(order.size, dtype=bool)
    first[1:] = rows.track[order][1:] != rows.track[order][:-1]
    best = order[first]
    p_cam, _ = triangulate_with_jacobian(rows.z[best], calib.K, calib.baseline)
    world_T_cam = poses[rows.frame[best]] @ calib.imu_T_cam
    out = np.full((n_tracks, 3), np.nan)
    out[rows.track[best]] = np.einsum("nij,nj->ni", world_T_cam[:, :3, :3], p_cam) + world_T_cam[:, :3, 3]
    return out


def cheirality_ok(poses: np.ndarray, landmarks: np.ndarray, calib: Calibration, rows: StereoRows,
                  n_tracks: int, min_depth: float) -> np.ndarray:
    """Boolean (n_tracks,): the landmark lies at least ``min_depth`` in front of every camera
    that observes it (False for tracks without rows or landmark)."""
    q = camera_points(poses, landmarks, calib, rows)
    bad = ~(q[:, 2] >= min_depth)
    bad_tracks = np.bincount(rows.track[bad], minlength=n_tracks) > 0
    has = np.bincount(rows.track, minlength=n_tracks) > 0
    return has & ~bad_tracks & np.all(np.isfinite(landmarks), axis=1)


# --- the graph ------------------------------------------------------------------------------
@dataclass
class NoiseModels:
    """The GTSAM noise models shared by the batch and incremental smoothers."""

    calibration: gtsam.Cal3_S2Stereo
    body_P_sensor: gtsam.Pose3
    stereo: gtsam.noiseModel.Base
    landmark_prior: gtsam.noiseModel.Base
    pose_prior: gtsam.noiseModel.Base
    motion: list = field(default_factory=list)  # one per interval
    #: The stereo noise without the robust kernel (the marginals': :func:`gaussian_stereo`).
    stereo_gaussian: gtsam.noiseModel.Base | None = None

    @classmethod
    def create(cls, seq: Sequence, config: FilterConfig, settings: SmootherSettings,
               motion_covs: np.ndarray) -> "NoiseModels":
        c = seq.calibration
        sigma = config.pixel_sigma
        base = gtsam.noiseModel.Diagonal.Sigmas(np.array([sigma, sigma, sigma / np.sqrt(2.0)]))
        stereo = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(settings.huber_k), base)
        return cls(
            calibration=gtsam.Cal3_S2Stereo(c.fsu, c.fsv, 0.0, c.cu, c.cv, c.baseline),
            body_P_sensor=to_pose3(c.imu_T_cam),
            stereo=stereo,
            stereo_gaussian=base,
            landmark_prior=gtsam.noiseModel.Isotropic.Sigma(3, settings.landmark_prior_sigma),
            pose_prior=gtsam.noiseModel.Gaussian.Covariance(estimate_cov_to_gtsam(config.initial_pose_cov)),
            motion=[gtsam.noiseModel.Gaussian.Covariance(cov) for cov in motion_covs],
        )

    def add_stereo_factors(self, graph: gtsam.NonlinearFactorGraph, rows: StereoRows,
                           robust: bool = True) -> None:
        """A ``GenericStereoFactor3D`` on ``(X(frame), L(track))`` per row of ``rows``
        (measurement ``[uL, uR, v]``, the robust or the Gaussian stereo noise), appended to
        ``graph`` in row order (keys and pixels converted to Python numbers once, not per
        factor: a batch graph has some 10^5 of them, built two or three times per solve)."""
        factor, point = gtsam.GenericStereoFactor3D, gtsam.StereoPoint2
        noise = self.stereo if robust else self.stereo_gaussian
        calibration, body_P_sensor = self.calibration, self.body_P_sensor
        x_keys = (X(0) + rows.frame.astype(np.int64)).tolist()  # a Symbol's index is its low bits
        l_keys = (L(0) + rows.track.astype(np.int64)).tolist()
        add = graph.add
        for (u_l, u_r, v), x, l in zip(rows.measured.tolist(), x_keys, l_keys):
            add(factor(point(u_l, u_r, v), noise, x, l, calibration, body_P_sensor))


@dataclass
class GraphProblem:
    """A built graph, its initial values and what its factors stand for."""

    graph: gtsam.NonlinearFactorGraph
    values: gtsam.Values
    rows: StereoRows  # the stereo factors, in graph order after the motion factors
    landmark_tracks: np.ndarray  # tracks that have a landmark variable
    scale: SpeedScaleModel | None = None  # the speed-scale variables' model, when in the graph


def build_graph(poses: np.ndarray, landmarks: np.ndarray, rows: StereoRows,
                deltas: np.ndarray, noise: NoiseModels, bias: GyroBiasModel | None = None,
                smoothness: TwistSmoothness | None = None,
                scale: SpeedScaleModel | None = None) -> GraphProblem:
    """The full batch graph: prior, motion, stereo and landmark-prior factors, with initial
    values ``poses`` (T, 4, 4) and ``landmarks`` (n_tracks, 3) (only the tracks in ``rows``).

    With ``smoothness`` a twist-smoothness factor (:mod:`graph.twist_smoothness`) is added for
    each of its gap intervals, after the landmark priors.

    With ``bias`` the motion factors share one gyro-bias variable (:mod:`graph.gyro_bias`),
    which gets a zero-mean prior and is added last (factor and value).

    With ``scale`` the motion factors are its speed-scaled ones (:mod:`graph.speed_scale`, on
    the bias too with ``bias``; ``deltas`` then only counts the intervals) and its variables,
    prior and random walk come after the smoothness factors."""
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    graph.add(gtsam.PriorFactorPose3(X(0), gtsam.Pose3(), noise.pose_prior))
    for k, delta in enumerate(deltas):
        if scale is not None:
            graph.add(scale.factor(k, noise.motion[k], X(k), X(k + 1),
                                   None if bias is None else BIAS_KEY, None if bias is None else bias.D[k]))
        elif bias is None:
            graph.add(gtsam.BetweenFactorPose3(X(k), X(k + 1), to_pose3(delta), noise.motion[k]))
        else:
            graph.add(biased_motion_factor(X(k), X(k + 1), BIAS_KEY, delta, bias.D[k], noise.motion[k]))
    for k, T in enumerate(poses):
        values.insert(X(k), to_pose3(T))
    noise.add_stereo_factors(graph, rows)
    tracks = np.unique(rows.track)
    for j in tracks:
        p = landmarks[j]
        values.insert(L(int(j)), p)
        graph.add(gtsam.PriorFactorPoint3(L(int(j)), p, noise.landmark_prior))
    if smoothness is not None:
        add_smoothness_factors(graph, smoothness.gaps, smoothness.tau, smoothness.sigma,
                               None if smoothness.exact else values)
    if scale is not None:
        scale.add_variables(graph, values)
    if bias is not None:
        values.insert(BIAS_KEY, np.asarray(bias.initial, dtype=float))
        graph.add(gtsam.PriorFactorPoint3(BIAS_KEY, np.zeros(3), bias.prior))
    return GraphProblem(graph, values, rows, tracks, scale)


def gaussian_stereo(graph: gtsam.NonlinearFactorGraph, rows: StereoRows, first: int,
                    noise: NoiseModels) -> gtsam.NonlinearFactorGraph:
    """``graph`` with its stereo factors (``len(rows)`` of them from index ``first``, in
    ``rows`` order) under the Gaussian pixel noise instead of the robust kernel: the graph of
    the marginals. The kernel is how the solution is found in the presence of outliers (those
    beyond ``outlier_threshold_px`` are then removed); its weights are not information the
    inliers lack: with them an inlier residual beyond ``huber_k`` sigmas counts for less, and
    the smoother's covariance on the default simulation came out too large (pose ANEES 4.90 over
    50 runs, 95 % band [5.08, 7.00]; 5.24 with the Gaussian marginals)."""
    out = gtsam.NonlinearFactorGraph()
    for i in range(first):
        out.add(graph.at(i))
    noise.add_stereo_factors(out, rows, robust=False)
    n = len(rows)
    for i in (0, n // 2, n - 1) if n else ():  # rows in graph order (build_graph puts them so)
        if i + first >= graph.size() or list(graph.at(first + i).keys()) != list(out.at(first + i).keys()):
            raise ValueError(f"graph factor {first + i} is not the stereo factor of row {i}")
    for i in range(first + n, graph.size()):
        out.add(graph.at(i))
    return out


def poses_from_values(values: gtsam.Values, n_frames: int) -> np.ndarray:
    return np.stack([values.atPose3(X(k)).matrix() for k in range(n_frames)])


def landmarks_from_values(values: gtsam.Values, tracks: np.ndarray, n_tracks: int) -> np.ndarray:
    out = np.full((n_tracks, 3), np.nan)
    for j in tracks:
        out[j] = values.atPoint3(L(int(j)))
    return out


def fix_bias(problem: GraphProblem, values: gtsam.Values, deltas: np.ndarray, noise: NoiseModels,
             bias: GyroBiasModel) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    """The graph of ``problem`` (built with ``bias``) with the bias fixed at its value in
    ``values``: plain between-factors on the bias-corrected motions, no bias variable. Used for
    the marginals, which are then conditional on the estimated bias (its uncertainty, about
    1e-4 rad/s over a drive, is neglected). With a speed scale (``problem.scale``) the motion
    factors stay speed-scaled, their bias correction fixed, and the scale variables stay."""
    b = values.atPoint3(BIAS_KEY)
    n_motion = len(deltas)
    graph = gtsam.NonlinearFactorGraph()
    graph.add(problem.graph.at(0))
    if problem.scale is not None:
        fixed_scale = dataclasses.replace(problem.scale, corrections=bias_corrections(bias.D, b)
                                          if n_motion else None)
        for k in range(n_motion):
            graph.add(fixed_scale.factor(k, noise.motion[k], X(k), X(k + 1)))
    for k, delta in enumerate(corrected_deltas(deltas, bias.D, b) if problem.scale is None else ()):
        graph.add(gtsam.BetweenFactorPose3(X(k), X(k + 1), to_pose3(delta), noise.motion[k]))
    for i in range(1 + n_motion, problem.graph.size() - 1):  # stereo, landmark priors, smoothness; not the bias prior
        graph.add(problem.graph.at(i))
    fixed = gtsam.Values(values)
    fixed.erase(BIAS_KEY)
    return graph, fixed


# --- intervals without vision ---------------------------------------------------------------
def unconstrained_intervals(rows: StereoRows, n_frames: int) -> np.ndarray:
    """Boolean (T-1,): no track is observed at both ends of the interval ``[k, k+1]``, so only
    the velocity spans it (a tracker's repeat events, after track cleaning)."""
    order = np.lexsort((rows.frame, rows.track))
    f, t = rows.frame[order], rows.track[order]
    linked = (t[1:] == t[:-1]) & (f[1:] == f[:-1] + 1)
    covered = np.zeros(max(n_frames - 1, 0), dtype=bool)
    covered[f[:-1][linked]] = True
    return ~covered
