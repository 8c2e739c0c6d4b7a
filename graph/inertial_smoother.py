"""The reference smoother on a raw-IMU drive (:class:`ekf.inertial.InertialDrive`): GTSAM's IMU
preintegration between camera frames, monocular projection factors, an incremental (iSAM2) and a
batch (Levenberg-Marquardt) solve, and marginal covariances in vislam's convention.

**Variables**, per camera frame k: ``X(k)`` a ``Pose3`` (``world_T_imu``), ``V(k)`` the IMU's
velocity in the world frame, ``B(k)`` an ``imuBias.ConstantBias``; ``L(j)`` a ``Point3`` per
track j that could be triangulated (:mod:`graph.inertial_factors`).

**Factors**: a ``CombinedImuFactor`` per interval (``PreintegratedCombinedMeasurements`` of the
samples between the two frames, bias random walk inside, noise from the drive's
:class:`ekf.inertial.ImuNoise`: :func:`graph.inertial_factors.preintegration_params`); a
``GenericProjectionFactorCal3_S2`` per observation of a triangulated track (a stereo drive's:
``GenericStereoFactor3D`` on ``[uL, uR, v]``, ``v`` the rows' mean, sigma / sqrt(2) on it, the
landmark triangulated from the left pixels), with ``body_P_sensor = imu_T_cam`` and a Huber
kernel at ``huber_k`` sigmas of ``pixel_sigma``; priors at frame 0 and zero-velocity priors
over the rest (below).

**Initialisation** (:mod:`graph.inertial_init`): a rest at the start of the drive is detected
from the IMU alone; it gives the gravity direction (hence roll and pitch of frame 0), the gyro
bias and zero velocity. Without a rest, or when camera frame 0 lies outside it, the drive cannot
be initialised: :class:`ekf.errors.EstimationError` says so (a visual-inertial initialisation
from motion is not implemented). The world frame is gravity-aligned (z up), with its origin at
the IMU at frame 0 and the yaw of the IMU at frame 0 (:func:`graph.inertial_init.
gravity_aligned_rotation`). Priors at frame 0: the pose at ``(world_R_imu0, 0)`` with
``gauge_sigma`` on yaw and position (the four directions vision and IMU cannot observe) and
``tilt_sigma`` on roll and pitch (gravity observes them; the rest's estimate is off by the
unknown accelerometer bias); the velocity zero with ``rest_velocity_sigma`` at every frame inside
the rest; the bias at ``(accel 0, gyro = rest mean)`` with ``accel_bias_sigma`` and
``gyro_bias_sigma``.

**Solving.** :func:`incremental_solve` runs iSAM2 (GTSAM's default relinearisation: threshold
0.1, checked every 10 updates) with one update per ``isam_frames_per_update`` frames: each
frame's state is predicted from the last estimate by the preintegrated IMU, a track becomes a
landmark once it has ``min_track_frames`` observations that triangulate, with all of them, and
later observations are added as they come; estimates are looked up key by key (a full
``calculateEstimate`` per frame cost more than the updates). That pass over every frame is the
incremental estimate (``smooth(..., incremental_only=True)``). The batch's initial values come from the same
pass over every ``init_keyframe_stride``-th frame (:mod:`graph.inertial_keyframes`: one IMU
factor across each keyframe interval, the frames between predicted by the IMU), in which a
track back after more than ``init_return_gap`` frames unseen starts a new landmark, so that
its Bayes tree stays as narrow as odometry's on a flight whose landmarks keep coming back.
:func:`batch_solve` starts from those values, triangulates every track again from that
trajectory (also those the pass never took, and joining the returns), solves with LM (GTSAM's
METIS ordering, ``batch_ordering``), drops observations whose reprojection error
exceeds ``outlier_px`` (and tracks left with fewer than two), and solves again. **The pixel
sigma** is then identified from the drive's own residuals unless given
(:func:`identify_pixel_sigma`: ``sigma^2 = sum |r|^2 / (2N - 3M - 6T)`` over the observations
the gate kept, and solved again under it until it moves by less than 5 %). Marginal
covariances come in one pass (:mod:`graph.inertial_marginals`: the frame states' block-
tridiagonal information with the landmarks as a dense border) of the final graph with the
Gaussian pixel noise in place of the kernel (the kernel decides which observations are
outliers, its down-weighting of inliers is not information they lack), converted to vislam's
convention (:mod:`graph.inertial_conventions`). From the same pass, EM's check of the IMU
noise: ``info["imu_noise_em_scale"] = sum(chi2 + leverage) / (15 (T - 1))`` over the IMU
factors (the scale EM would put on the data sheet's IMU covariance; reported, not applied).

**Output**: :class:`InertialSmootherResult`: the :class:`ekf.estimate.Estimate` (poses
``world_T_imu`` at the camera frames, pose covariances translation first in the right
perturbation, landmarks in the world) and :class:`InertialStates` (velocities and biases with
their covariances), which the Estimate has no field for.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass, field

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, L, V, X

from vislam.ekf.errors import EstimationError, InputError
from vislam.ekf.estimate import Estimate
from vislam.ekf.conventions import gtsam_cov_to_estimate
from vislam.ekf.inertial import ACCEL_TURN_ON_BIAS_SIGMA, InertialDrive
from vislam.graph.inertial_conventions import from_gtsam_bias, gtsam_bias_cov_to_vislam
from vislam.graph.inertial_factors import preintegrate, preintegration_params, triangulate_track
from vislam.graph.inertial_marginals import frame_marginals, imu_factor_moments, moment_traces
from vislam.graph.inertial_init import RestDetector, RestInterval, detect_rest, gravity_aligned_rotation
from vislam.graph.inertial_keyframes import keyframe_drive, keyframes
from vislam.graph.pose_conversions import estimation_error

log = logging.getLogger(__name__)

#: The registry's name (pyproject.toml), so that estimates, errors and figures say the same.
ESTIMATOR = "smoother-imu"
#: The incremental solve skips an observation of a landmark already in the graph whose
#: reprojection error against the predicted pose exceeds this many times ``outlier_px``.
GATE_FACTOR = 4.0


@dataclass(frozen=True)
class InertialSmootherSettings:
    """Settings of the raw-IMU smoother (module docstring); the defaults are the same for every
    drive."""

    #: Pixel noise of a track observation (px, each axis), None: identified from the drive's
    #: own residuals (:func:`identify_pixel_sigma`), starting from ``pixel_sigma_start``; and
    #: the Huber threshold in sigmas.
    pixel_sigma: float | None = None
    pixel_sigma_start: float = 1.0
    pixel_sigma_iterations: int = 3
    pixel_sigma_rtol: float = 0.05
    huber_k: float = 1.345
    #: Every IMU noise figure of the drive times this (1: the data sheet's figures as they are).
    imu_noise_inflation: float = 1.0
    rest: RestDetector = field(default_factory=RestDetector)
    #: Priors at frame 0 (module docstring): m/s, rad and m, rad, rad/s, m/s^2.
    rest_velocity_sigma: float = 0.01
    gauge_sigma: float = 1e-4
    tilt_sigma: float = 0.05
    gyro_bias_sigma: float = 1e-3
    #: The accelerometer's turn-on bias (ekf.inertial.ACCEL_TURN_ON_BIAS_SIGMA, the EKFs' and the
    #: simulator's figure; 0.1 before, which left the simulated car drives' tilt underconfident:
    #: rotation NEES 1.8 of 3 over six runs, 3.5 with the shared 0.05).
    accel_bias_sigma: float = ACCEL_TURN_ON_BIAS_SIGMA
    #: Landmarks (:mod:`graph.inertial_factors`).
    min_track_frames: int = 3
    min_parallax_deg: float = 1.0
    max_landmark_distance: float = 50.0
    outlier_px: float = 5.0
    #: A weak prior (m) on each landmark at its triangulated position: it keeps the linear
    #: system determined when a landmark's projections lose their Jacobian (GTSAM's projection
    #: factor has none for a point behind the camera) and is negligible against its pixels.
    landmark_prior_sigma: float = 10.0
    #: Levenberg-Marquardt's stopping rule.
    max_iterations: int = 50
    relative_error_tol: float = 1e-6
    #: iSAM2's relinearisation threshold and the updates between relinearisation checks
    #: (GTSAM's defaults; 0.01 and 1 cost 3x the time for the same batch solution).
    isam_relinearize_threshold: float = 0.1
    isam_relinearize_skip: int = 10
    #: iSAM2's factorisation, "cholesky" (GTSAM's default) or "qr" (on EuRoC's 30 s, 3x the
    #: time). A pass whose Cholesky factorisation fails ("indeterminate system": on the
    #: simulated car drives, 8-12 m/s with landmarks 3-25 m beside the road, every 201-frame
    #: drive of four seeds at frame 109-129) is repeated with QR, which does not square the
    #: condition number (as the velocity drives' iSAM2 smoother does: graph.isam2).
    isam_factorization: str = "cholesky"
    #: Camera frames whose factors go into one iSAM2 update (the frames in between are
    #: predicted by the preintegrated IMU from the last estimate).
    isam_frames_per_update: int = 10
    #: The incremental pass that gives the batch its initial values starts a new landmark
    #: variable for a track that returns after more than this many frames unseen
    #: (:func:`incremental_solve`'s ``return_gap``; None: every return joins its landmark, as
    #: the incremental-only estimate does).
    init_return_gap: int | None = 20
    #: ... and runs over every this-many-th frame only, the frames between predicted by the
    #: IMU (:mod:`graph.inertial_keyframes`; 1: every frame).
    init_keyframe_stride: int = 5
    #: GTSAM's fill-reducing ordering of the batch solves' eliminations ("METIS" or "COLAMD").
    batch_ordering: str = "METIS"
    compute_marginals: bool = True


@dataclass
class InertialStates:
    """Velocities and biases at the camera frames, beside the poses of the Estimate.

    ``velocity`` (T, 3) world frame, m/s, and ``velocity_cov`` (T, 3, 3) (additive error);
    ``bias`` (T, 6) ``[b_gyro (rad/s); b_accel (m/s^2)]`` and ``bias_cov`` (T, 6, 6) in that
    order (:mod:`graph.inertial_conventions`)."""

    velocity: np.ndarray
    velocity_cov: np.ndarray
    bias: np.ndarray
    bias_cov: np.ndarray


@dataclass
class InertialSmootherResult:
    """The Estimate, the velocities and biases, the rest used, and how each solve went."""

    estimate: Estimate
    states: InertialStates
    rest: RestInterval
    info: dict
    #: Per IMU factor, the expected outer product of its whitened residual under the posterior
    #: and its posterior part (:func:`graph.inertial_marginals.imu_factor_moments`); None
    #: without marginals.
    imu_moments: np.ndarray | None = None
    imu_leverage: np.ndarray | None = None


@dataclass
class InertialProblem:
    """What both solves share: the drive, the IMU factors' measurements, the camera model, the
    noise models and the priors."""

    drive: InertialDrive
    settings: InertialSmootherSettings
    rest: RestInterval
    world_R_imu0: np.ndarray
    bias0: gtsam.imuBias.ConstantBias
    pims: list
    calibration: gtsam.Cal3_S2
    body_P_sensor: gtsam.Pose3
    pixel_noise: gtsam.noiseModel.Base
    robust_noise: gtsam.noiseModel.Base
    rest_frames: np.ndarray
    pixel_sigma: float  # the sigma of pixel_noise
    #: the rectified pair of a stereo drive (None: one camera)
    stereo: gtsam.Cal3_S2Stereo | None = None
    #: frames unseen after which the incremental pass takes a track's return as a new landmark
    #: (None: never; :func:`incremental_solve`)
    return_gap: int | None = None

    @property
    def n_frames(self) -> int:
        return self.drive.n_frames

    def priors(self) -> gtsam.NonlinearFactorGraph:
        s = self.settings
        graph = gtsam.NonlinearFactorGraph()
        R0 = self.world_R_imu0
        rot_cov = R0.T @ np.diag([s.tilt_sigma ** 2, s.tilt_sigma ** 2, s.gauge_sigma ** 2]) @ R0
        cov = np.zeros((6, 6))
        cov[:3, :3] = rot_cov
        cov[3:, 3:] = s.gauge_sigma ** 2 * np.eye(3)
        graph.add(gtsam.PriorFactorPose3(X(0), self.initial_pose(),
                                         gtsam.noiseModel.Gaussian.Covariance(cov)))
        graph.add(self.rest_prior(0))
        b_noise = gtsam.noiseModel.Diagonal.Sigmas(np.r_[np.full(3, s.accel_bias_sigma),
                                                         np.full(3, s.gyro_bias_sigma)])
        graph.add(gtsam.PriorFactorConstantBias(B(0), self.bias0, b_noise))
        return graph

    def rest_prior(self, k: int) -> gtsam.PriorFactorVector:
        """Zero velocity at frame ``k`` (inside the rest)."""
        return gtsam.PriorFactorVector(V(k), np.zeros(3), gtsam.noiseModel.Isotropic.Sigma(
            3, self.settings.rest_velocity_sigma))

    def landmark_prior(self, j: int, point: np.ndarray, key: int | None = None) -> gtsam.PriorFactorPoint3:
        """The weak prior on track ``j``'s landmark (variable ``key``, default ``L(j)``)."""
        return gtsam.PriorFactorPoint3(L(j) if key is None else key, np.asarray(point, dtype=float),
                                       gtsam.noiseModel.Isotropic.Sigma(
            3, self.settings.landmark_prior_sigma))

    def initial_pose(self) -> gtsam.Pose3:
        return gtsam.Pose3(gtsam.Rot3(self.world_R_imu0), np.zeros(3))

    def imu_factor(self, k: int) -> gtsam.CombinedImuFactor:
        """The IMU factor of interval ``[k - 1, k]``."""
        return gtsam.CombinedImuFactor(X(k - 1), V(k - 1), X(k), V(k), B(k - 1), B(k), self.pims[k - 1])

    def projection(self, z, frame: int, track: int, robust: bool = True, key: int | None = None):
        """The factor of one observation: a monocular pixel ``[u, v]``, or a stereo one
        ``[uL, vL, uR, vR]`` as GTSAM's ``[uL, uR, v]`` with ``v`` the rows' mean (the velocity
        drives' smoother does the same, :mod:`graph.factors`); on the landmark variable ``key``
        (default ``L(track)``)."""
        noise = self.robust_noise if robust else self.pixel_noise
        point = L(track) if key is None else key
        if self.stereo is None:
            return gtsam.GenericProjectionFactorCal3_S2(
                np.asarray(z, dtype=float), noise, X(frame), point, self.calibration,
                self.body_P_sensor)
        u_l, v_l, u_r, v_r = (float(x) for x in z)
        return gtsam.GenericStereoFactor3D(gtsam.StereoPoint2(u_l, u_r, 0.5 * (v_l + v_r)), noise,
                                           X(frame), point, self.stereo, self.body_P_sensor)


def build_problem(drive: InertialDrive, settings: InertialSmootherSettings = InertialSmootherSettings()
                  ) -> InertialProblem:
    """The rest, the priors and the preintegrated IMU of every interval (module docstring)."""
    c = drive.calibration
    if c.distortion_model != "none":
        raise InputError(f"{drive.name}: tracks with lens distortion ({c.distortion_model}) are not "
                         "supported by the raw-IMU smoother yet; give undistorted pixels")
    if drive.n_frames < 2:
        raise InputError(f"{drive.name}: {drive.n_frames} camera frame(s); the smoother needs two or more")
    rest = detect_rest(drive.imu, settings.rest)
    if rest is None:
        raise EstimationError(
            f"{ESTIMATOR}: {drive.name}: the drive cannot be initialised: no rest of at least "
            f"{settings.rest.min_rest_s:g} s at its start (0.1 s means of the gyro within "
            f"{settings.rest.gyro_tol:g} rad/s and of the accelerometer within "
            f"{settings.rest.accel_tol:g} m/s^2, less its last {settings.rest.margin_blocks} "
            "blocks), and initialisation from motion is not implemented")
    t = drive.timestamps
    if not rest.t_start <= t[0] <= rest.t_end:
        raise EstimationError(
            f"{ESTIMATOR}: {drive.name}: the drive cannot be initialised: its rest "
            f"[{rest.t_start:.3f}, {rest.t_end:.3f}] s does not hold camera frame 0 (t={t[0]:.3f} s)")
    world_R_imu0 = gravity_aligned_rotation(rest.up)
    bias0 = gtsam.imuBias.ConstantBias(np.zeros(3), rest.gyro_mean.copy())
    params = preintegration_params(c.noise, c.gravity, settings.imu_noise_inflation)
    pims = [preintegrate(drive.imu, float(t[k - 1]), float(t[k]), params, bias0)
            for k in range(1, drive.n_frames)]
    K = c.K
    sigma = settings.pixel_sigma if settings.pixel_sigma is not None else settings.pixel_sigma_start
    pixel, robust = pixel_noise_models(sigma, settings.huber_k, c.stereo)
    stereo = (gtsam.Cal3_S2Stereo(K[0, 0], K[1, 1], K[0, 1], K[0, 2], K[1, 2], float(c.baseline))
              if c.stereo else None)
    return InertialProblem(
        drive, settings, rest, world_R_imu0, bias0, pims,
        gtsam.Cal3_S2(K[0, 0], K[1, 1], K[0, 1], K[0, 2], K[1, 2]),
        gtsam.Pose3(c.imu_T_cam), pixel, robust, np.flatnonzero(t <= rest.t_end), float(sigma),
        stereo)


def pixel_noise_models(sigma: float, huber_k: float, stereo: bool = False
                       ) -> tuple[gtsam.noiseModel.Base, gtsam.noiseModel.Base]:
    """The Gaussian pixel noise (``sigma`` px each axis; a stereo observation's ``[uL, uR, v]``
    with ``sigma / sqrt(2)`` on the mean row ``v``) and the same under Huber at ``huber_k``
    sigmas."""
    if stereo:
        pixel = gtsam.noiseModel.Diagonal.Sigmas(float(sigma) * np.array([1.0, 1.0, np.sqrt(0.5)]))
    else:
        pixel = gtsam.noiseModel.Isotropic.Sigma(2, float(sigma))
    return pixel, gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(huber_k), pixel)


def identify_pixel_sigma(residuals_px: np.ndarray, n_landmarks: int, n_frames: int,
                         dims: int = 2) -> float:
    """The pixel sigma (each axis) the residuals of a solve call for: ``sigma^2 = sum |r_i|^2 /
    (d N - 3 M - 6 T)`` over the ``N`` observations kept by the outlier gate (``|r_i|`` the
    reprojection error in px, :func:`_reprojection_errors`; observations beyond ``outlier_px``
    are outliers and leave the model, here as in the solve), ``d`` the measurement's dimension
    (2 for a pixel, 3 for a stereo ``[uL, uR, v]``), ``M`` landmarks and ``T`` frames: the
    residual degrees of freedom of the tracks, counting every landmark's 3 and every pose's 6
    as determined by them (the IMU determines part of the poses, so this rule leans towards a
    larger sigma)."""
    r = np.asarray(residuals_px, dtype=float)
    dof = int(dims) * r.size - 3 * int(n_landmarks) - 6 * int(n_frames)
    if dof <= 0:
        raise EstimationError(f"{ESTIMATOR}: {r.size} observations cannot identify the pixel noise of "
                              f"{n_landmarks} landmarks and {n_frames} frames; give pixel_sigma")
    return float(np.sqrt(np.sum(r ** 2) / dof))


@dataclass
class Solution:
    """A solve's values, the tracks that have landmarks and the observations in the graph."""

    values: gtsam.Values
    tracks: np.ndarray
    rows: np.ndarray  # observation rows (indices into drive.obs) in the graph
    anchors: dict  # track -> the landmark prior's mean (its first triangulation)
    graph: gtsam.NonlinearFactorGraph
    n_prior: int  # factors before the projection factors
    timing: dict = field(default_factory=dict)
    pixel_sigma: float | None = None  # the pixel sigma of the solve (None: the problem's)


def _camera_pose(values: gtsam.Values, frame: int, body_P_sensor: gtsam.Pose3) -> gtsam.Pose3:
    return values.atPose3(X(frame)).compose(body_P_sensor)


def _triangulate(problem: InertialProblem, values: gtsam.Values, frames: np.ndarray, z: np.ndarray):
    s = problem.settings
    cams = [_camera_pose(values, int(f), problem.body_P_sensor) for f in frames]
    z = np.asarray(z, dtype=float)[:, :2]  # the left camera's pixels (stereo: [uL, vL, ...])
    noise = gtsam.noiseModel.Isotropic.Sigma(2, problem.pixel_sigma)  # a left pixel's
    return triangulate_track(cams, z, problem.calibration, noise, s.min_parallax_deg,
                             s.max_landmark_distance, s.outlier_px)


def incremental_solve(problem: InertialProblem) -> Solution:
    """iSAM2, frame by frame (module docstring). ``problem.return_gap`` (frames, None: never): a track
    seen again after more than this many frames without an observation starts a new landmark
    variable (``Symbol('m', i)``, not in the Solution's tracks, anchors or rows), as if it were
    a new track: the pass is then visual-inertial odometry without the returns, whose Bayes
    tree (and so its time and memory per frame) stays bounded when every landmark comes back
    (a room flight); the batch solve closes the returns (:func:`batch_solve`)."""
    drive, s = problem.drive, problem.settings
    return_gap = problem.return_gap
    start = time.perf_counter()
    params = gtsam.ISAM2Params()
    params.setRelinearizeThreshold(s.isam_relinearize_threshold)
    params.relinearizeSkip = s.isam_relinearize_skip
    params.setFactorization(s.isam_factorization.upper())
    isam = gtsam.ISAM2(params)
    full = gtsam.NonlinearFactorGraph()
    new = problem.priors()
    n_prior = new.size()
    values = gtsam.Values()
    values.insert(X(0), problem.initial_pose())
    values.insert(V(0), np.zeros(3))
    values.insert(B(0), problem.bias0)
    obs = drive.obs
    pending: dict[int, list[int]] = {}
    in_graph: set[int] = set()
    rows_used: list[int] = []
    estimate = _IsamLookup(isam)
    rest_frames = set(problem.rest_frames.tolist())
    anchors: dict[int, np.ndarray] = {}
    current: dict[int, int] = {}  # track -> the landmark variable of its current visit
    last_seen: dict[int, int] = {}
    n_returns = 0
    estimate.new = values
    lookup = estimate
    for k in range(drive.n_frames):
        if k > 0:
            nav = gtsam.NavState(estimate.atPose3(X(k - 1)), estimate.atVector(V(k - 1)))
            bias = estimate.atConstantBias(B(k - 1))
            predicted = problem.pims[k - 1].predict(nav, bias)
            values.insert(X(k), predicted.pose())
            values.insert(V(k), predicted.velocity())
            values.insert(B(k), bias)
            new.add(problem.imu_factor(k))
            if k in rest_frames:
                new.add(problem.rest_prior(k))
        a, b = int(obs.frame_ptr[k]), int(obs.frame_ptr[k + 1])
        for r in range(a, b):
            j = int(obs.track[r])
            key = current.get(j)
            if key is not None and return_gap is not None and k - last_seen[j] > return_gap:
                del current[j]
                key = None
            last_seen[j] = k
            if key is not None:
                if _reprojection(problem, lookup, k, key, obs.z[r]) > GATE_FACTOR * s.outlier_px:
                    continue
                new.add(problem.projection(obs.z[r], k, j, key=key))
                if key == L(j):
                    rows_used.append(r)
                continue
            pending.setdefault(j, []).append(r)
            if len(pending[j]) < s.min_track_frames:
                continue
            rs = np.asarray(pending[j])
            frames = _frames_of(obs, rs)
            found = _triangulate(problem, lookup, frames, obs.z[rs])
            if found is None or found[1].sum() < s.min_track_frames:
                continue
            point, inliers = found
            first = j not in in_graph
            key = L(j) if first else gtsam.Symbol("m", n_returns).key()
            n_returns += 0 if first else 1
            values.insert(key, point)
            new.add(problem.landmark_prior(j, point, key))
            if first:
                anchors[j] = point
            for rr, f in zip(rs[inliers].tolist(), frames[inliers].tolist()):
                new.add(problem.projection(obs.z[rr], f, j, key=key))
                if first:
                    rows_used.append(rr)
            in_graph.add(j)
            current[j] = key
            del pending[j]
        if (k + 1) % s.isam_frames_per_update and k + 1 < drive.n_frames:
            continue
        for i in range(new.size()):
            full.add(new.at(i))
        try:
            isam.update(new, values)
        except RuntimeError as exc:
            raise estimation_error(exc, f"adding frame {k} (iSAM2)", estimator=ESTIMATOR) from None
        estimate.clear()
        new = gtsam.NonlinearFactorGraph()
        values = estimate.new
    estimate = isam.calculateEstimate()
    tracks = np.array(sorted(in_graph), dtype=np.int64)
    return Solution(estimate, tracks, np.array(rows_used, dtype=np.int64), anchors, full, n_prior,
                    {"isam2_s": time.perf_counter() - start})


class _IsamLookup:
    """Poses and landmarks of an iSAM2 estimate, computed key by key when asked (cached until
    the next update) and first from ``new``, the values about to be added: one full
    ``calculateEstimate`` per frame cost more than the update itself."""

    def __init__(self, isam: gtsam.ISAM2):
        self.isam = isam
        self.new = gtsam.Values()
        self.cache: dict = {}

    def clear(self) -> None:
        self.cache.clear()
        self.new = gtsam.Values()

    def atPose3(self, key: int) -> gtsam.Pose3:
        if self.new.exists(key):
            return self.new.atPose3(key)
        if key not in self.cache:
            self.cache[key] = self.isam.calculateEstimatePose3(key)
        return self.cache[key]

    def atPoint3(self, key: int) -> np.ndarray:
        if self.new.exists(key):
            return self.new.atPoint3(key)
        if key not in self.cache:
            self.cache[key] = self.isam.calculateEstimatePoint3(key)
        return self.cache[key]

    def atVector(self, key: int) -> np.ndarray:
        return self.new.atVector(key) if self.new.exists(key) else self.isam.calculateEstimateVector(key)

    def atConstantBias(self, key: int) -> gtsam.imuBias.ConstantBias:
        if self.new.exists(key):
            return self.new.atConstantBias(key)
        return self.isam.calculateEstimateConstantBias(key)


def _reprojection(problem: InertialProblem, values: gtsam.Values, frame: int, key: int, z) -> float:
    q = _camera_pose(values, frame, problem.body_P_sensor).transformTo(values.atPoint3(key))
    if q[2] <= 0:
        return np.inf
    return float(np.hypot(*(problem.calibration.uncalibrate(q[:2] / q[2]) - np.asarray(z)[:2])))


def _frames_of(obs, rows: np.ndarray) -> np.ndarray:
    return np.searchsorted(obs.frame_ptr, rows, side="right") - 1


def _reprojection_errors(problem: InertialProblem, values: gtsam.Values, rows: np.ndarray) -> np.ndarray:
    """Per observation of ``rows``, its reprojection error (px): ``|r|`` of a monocular pixel;
    for a stereo one ``sqrt(r_uL^2 + r_uR^2 + 2 r_v^2)``, the norm its noise model whitens
    (:func:`pixel_noise_models`, times sigma). Inf behind the camera."""
    obs = problem.drive.obs
    frames = _frames_of(obs, rows)
    out = np.empty(rows.size)
    for i, (r, f) in enumerate(zip(rows.tolist(), frames.tolist())):
        cam = _camera_pose(values, f, problem.body_P_sensor)
        q = cam.transformTo(values.atPoint3(L(int(obs.track[r]))))
        if q[2] <= 0:
            out[i] = np.inf
            continue
        z = obs.z[r]
        if problem.stereo is None:
            out[i] = np.hypot(*(problem.calibration.uncalibrate(q[:2] / q[2]) - z))
            continue
        p = gtsam.StereoCamera(cam, problem.stereo).project(values.atPoint3(L(int(obs.track[r]))))
        r_ul, r_ur, r_v = p.uL() - z[0], p.uR() - z[2], p.v() - 0.5 * (z[1] + z[3])
        out[i] = np.sqrt(r_ul * r_ul + r_ur * r_ur + 2.0 * r_v * r_v)
    return out


def _graph(problem: InertialProblem, rows: np.ndarray, anchors: dict, robust: bool = True
           ) -> gtsam.NonlinearFactorGraph:
    """Priors, IMU factors, the projections of observation ``rows`` and the landmark priors at
    ``anchors`` (track -> point), in that order."""
    graph = problem.priors()
    for k in range(1, problem.n_frames):
        graph.add(problem.imu_factor(k))
    for k in problem.rest_frames.tolist():
        if k > 0:
            graph.add(problem.rest_prior(k))
    obs = problem.drive.obs
    frames = _frames_of(obs, rows)
    for r, f in zip(rows.tolist(), frames.tolist()):
        graph.add(problem.projection(obs.z[r], f, int(obs.track[r]), robust))
    for j, point in anchors.items():
        graph.add(problem.landmark_prior(j, point))
    return graph


def _lm(problem: InertialProblem, graph, values, what: str) -> gtsam.Values:
    s = problem.settings
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(s.max_iterations)
    params.setRelativeErrorTol(s.relative_error_tol)
    params.setAbsoluteErrorTol(0.0)
    params.setOrderingType(s.batch_ordering)
    try:
        return gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    except RuntimeError as exc:
        raise estimation_error(exc, what, estimator=ESTIMATOR) from None


def _rows_by_track(obs, n_tracks: int):
    """``rows(j)``: the observation rows of track ``j``, ascending (one stable sort of the
    tracks for every track, where ``np.flatnonzero(obs.track == j)`` read every row per track)."""
    order = np.argsort(obs.track, kind="stable")
    bounds = np.searchsorted(obs.track[order], np.arange(n_tracks + 1))
    return lambda j: order[bounds[j]:bounds[j + 1]]


def batch_solve(problem: InertialProblem, initial: Solution | None = None) -> Solution:
    """Levenberg-Marquardt over the whole drive from ``initial`` (the incremental solve's
    estimate when None), with one round of outlier rejection (module docstring)."""
    drive, s = problem.drive, problem.settings
    timing = {}
    if initial is None:
        initial = initial_solve(problem)
        timing.update(initial.timing)
    start = time.perf_counter()
    values = _states_only(initial.values, problem.n_frames)
    obs = drive.obs
    rows, tracks, anchors = [], [], {}
    all_frames = obs.frame_index
    by_track = _rows_by_track(obs, drive.n_tracks)
    for j in range(drive.n_tracks):
        rs = by_track(j)
        if rs.size < 2:
            continue
        if j in initial.anchors:
            point, anchors[j] = initial.values.atPoint3(L(j)), initial.anchors[j]
        else:
            found = _triangulate(problem, initial.values, all_frames[rs], obs.z[rs])
            if found is None:
                continue
            point, inliers = found
            rs = rs[inliers]
            anchors[j] = point
        values.insert(L(j), point)
        rows.append(rs)
        tracks.append(j)
    rows = np.concatenate(rows) if rows else np.zeros(0, dtype=np.int64)
    values = _lm(problem, _graph(problem, rows, anchors), values, "optimising")
    err = _reprojection_errors(problem, values, rows)
    keep = err <= s.outlier_px
    counts = np.bincount(obs.track[rows[keep]], minlength=drive.n_tracks)
    keep &= counts[obs.track[rows]] >= 2
    rows = rows[keep]
    kept_tracks = np.unique(obs.track[rows])
    for j in set(tracks) - set(kept_tracks.tolist()):
        values.erase(L(int(j)))
        del anchors[j]
    graph = _graph(problem, rows, anchors)
    values = _lm(problem, graph, values, "optimising after outlier rejection")
    # The pixel sigma identified from the residuals (an EM fixed point: solve, identify, solve
    # again under the identified sigma while it moves by more than pixel_sigma_rtol).
    for _ in range(s.pixel_sigma_iterations if s.pixel_sigma is None else 0):
        sigma = identify_pixel_sigma(_reprojection_errors(problem, values, rows), kept_tracks.size,
                                     problem.n_frames, 2 if problem.stereo is None else 3)
        if abs(sigma / problem.pixel_sigma - 1.0) <= s.pixel_sigma_rtol:
            break
        pixel, robust = pixel_noise_models(sigma, s.huber_k, problem.stereo is not None)
        problem = dataclasses.replace(problem, pixel_noise=pixel, robust_noise=robust, pixel_sigma=sigma)
        graph = _graph(problem, rows, anchors)
        values = _lm(problem, graph, values, "optimising under the identified pixel sigma")
    timing["batch_s"] = time.perf_counter() - start
    return Solution(values, kept_tracks, rows, anchors, graph, 0, timing, problem.pixel_sigma)


def keyframe_solve(problem: InertialProblem, stride: int, return_gap: int | None) -> Solution:
    """A :class:`Solution` for every frame of ``problem``'s drive from the incremental pass over
    its keyframes (:mod:`graph.inertial_keyframes`): the keyframes' states and landmarks as that
    pass left them, the other frames predicted by ``problem.pims`` from the
    keyframe before. ``return_gap`` in frames of the full drive. Rows and tracks are those of
    the keyframe pass (its graph is not returned: an initial value, not an estimate)."""
    start = time.perf_counter()
    drive = problem.drive
    frames = keyframes(drive.n_frames, stride)
    gap = None if return_gap is None else max(1, int(return_gap) // int(stride))
    sub = dataclasses.replace(build_problem(keyframe_drive(drive, frames), problem.settings), return_gap=gap)
    inc = incremental_solve(sub)
    values = gtsam.Values()
    for i, k in enumerate(frames.tolist()):
        nav = gtsam.NavState(inc.values.atPose3(X(i)), inc.values.atVector(V(i)))
        bias = inc.values.atConstantBias(B(i))
        stop = int(frames[i + 1]) if i + 1 < frames.size else k + 1
        for f in range(k, stop):
            if f > k:
                nav = problem.pims[f - 1].predict(nav, bias)
            values.insert(X(f), nav.pose())
            values.insert(V(f), nav.velocity())
            values.insert(B(f), bias)
    anchors = dict(inc.anchors)
    for j in inc.tracks.tolist():
        values.insert(L(j), inc.values.atPoint3(L(j)))
    # The tracks the incremental pass over every frame would have taken (it triangulates a
    # track from its first observations, then adds all later ones) but the keyframes missed
    # (seen in fewer than min_track_frames keyframes): from all their observations.
    obs, s = drive.obs, problem.settings
    by_track = _rows_by_track(obs, drive.n_tracks)
    all_frames = obs.frame_index
    for j in range(drive.n_tracks):
        rs = by_track(j)
        if j in anchors or rs.size < s.min_track_frames:
            continue
        found = _triangulate(problem, values, all_frames[rs], obs.z[rs])
        if found is None or found[1].sum() < s.min_track_frames:
            continue
        anchors[j] = found[0]
        values.insert(L(j), found[0])
    tracks = np.array(sorted(anchors), dtype=np.int64)
    return Solution(values, tracks, np.zeros(0, dtype=np.int64), anchors, gtsam.NonlinearFactorGraph(), 0,
                    {"isam2_s": time.perf_counter() - start})


def initial_solve(problem: InertialProblem) -> Solution:
    """The batch solve's initial values: the incremental pass over keyframes
    (:func:`keyframe_solve`) or, at stride 1, over every frame, with
    returns after ``init_return_gap`` frames as new landmarks (settings)."""
    s = problem.settings
    if s.init_keyframe_stride > 1:
        return keyframe_solve(problem, s.init_keyframe_stride, s.init_return_gap)
    return incremental_solve(dataclasses.replace(problem, return_gap=s.init_return_gap))


def robust_initial_solve(problem: InertialProblem) -> tuple[InertialProblem, Solution]:
    """:func:`initial_solve`, again with QR factorisation when Cholesky finds the system
    indeterminate (as :func:`smooth` does), and the problem it was solved with."""
    try:
        return problem, initial_solve(problem)
    except EstimationError as exc:
        if problem.settings.isam_factorization != "cholesky" or "indeterminate" not in str(exc):
            raise
        problem = dataclasses.replace(problem, settings=dataclasses.replace(
            problem.settings, isam_factorization="qr"))
        return problem, initial_solve(problem)


def _states_only(values: gtsam.Values, n_frames: int) -> gtsam.Values:
    out = gtsam.Values()
    for k in range(n_frames):
        out.insert(X(k), values.atPose3(X(k)))
        out.insert(V(k), values.atVector(V(k)))
        out.insert(B(k), values.atConstantBias(B(k)))
    return out


def to_result(problem: InertialProblem, solution: Solution, name: str = ESTIMATOR) -> InertialSmootherResult:
    """The solution in vislam's convention, with marginal covariances (module docstring)."""
    if solution.pixel_sigma is not None and solution.pixel_sigma != problem.pixel_sigma:
        pixel, robust = pixel_noise_models(solution.pixel_sigma, problem.settings.huber_k,
                                           problem.stereo is not None)
        problem = dataclasses.replace(problem, pixel_noise=pixel, robust_noise=robust,
                                      pixel_sigma=solution.pixel_sigma)
    drive, s = problem.drive, problem.settings
    T, M = problem.n_frames, drive.n_tracks
    values = solution.values
    est = Estimate.empty(name, drive.timestamps, M)
    velocity = np.empty((T, 3))
    bias = np.empty((T, 6))
    for k in range(T):
        est.poses[k] = values.atPose3(X(k)).matrix()
        velocity[k] = values.atVector(V(k))
        bias[k] = from_gtsam_bias(values.atConstantBias(B(k)))
    for j in solution.tracks.tolist():
        est.landmarks[j] = values.atPoint3(L(j))
    velocity_cov = np.full((T, 3, 3), np.nan)
    bias_cov = np.full((T, 6, 6), np.nan)
    moments = leverage = None
    start = time.perf_counter()
    if s.compute_marginals:
        graph = _graph(problem, solution.rows, solution.anchors, robust=False)
        try:
            m = frame_marginals(graph, values, T, solution.tracks)
            P, Pl = m.P, m.Pl
            moments, leverage = imu_factor_moments(graph, m, problem.priors().size(), T)
            chi2, lev = moment_traces(moments, leverage)
        except (RuntimeError, np.linalg.LinAlgError) as exc:
            raise estimation_error(exc, "computing marginals", estimator=ESTIMATOR) from None
        for k in range(T):  # one joint block per frame: [X (6), V (3), B (6)]
            est.pose_cov[k] = gtsam_cov_to_estimate(P[k, 0:6, 0:6])
            velocity_cov[k] = P[k, 6:9, 6:9]
            bias_cov[k] = gtsam_bias_cov_to_vislam(P[k, 9:15, 9:15])
        for i, j in enumerate(solution.tracks.tolist()):
            est.landmark_cov[j] = Pl[i]
    timing = dict(solution.timing, marginals_s=time.perf_counter() - start)
    imu_stats = {}
    if s.compute_marginals:
        em_scale = s.imu_noise_inflation ** 2 * np.sum(chi2 + lev) / (15 * chi2.size)
        imu_stats = {"imu_chi2_mean": float(chi2.mean()), "imu_leverage_mean": float(lev.mean()),
                     "imu_noise_em_scale": float(em_scale)}
    obs = drive.obs
    frames = _frames_of(obs, solution.rows)
    est.n_updates = np.bincount(frames, minlength=T).astype(np.int64)
    est.n_rejected = (obs.per_frame - est.n_updates).astype(np.int64)
    total = float(sum(timing.values()))
    est.step_time_s = np.full(T, total / T)
    counts = np.bincount(obs.track, minlength=M)
    info = {
        "world_frame": "gravity-aligned (z up), origin at the IMU at frame 0, yaw of the IMU at frame 0",
        "rest_s": [problem.rest.t_start, problem.rest.t_end],
        "n_landmarks": int(solution.tracks.size),
        "n_tracks_multi": int(np.sum(counts >= 2)),
        "n_tracks_not_triangulated": int(np.sum(counts >= 2) - solution.tracks.size),
        "n_observations_used": int(solution.rows.size),
        "imu_noise_inflation": s.imu_noise_inflation,
        "pixel_sigma": problem.pixel_sigma,
        "pixel_sigma_identified": s.pixel_sigma is None,
        "marginals_computed": bool(s.compute_marginals),
        "timing": timing,
        **imu_stats,
    }
    est.info.update(info)
    return InertialSmootherResult(est, InertialStates(velocity, velocity_cov, bias, bias_cov),
                                  problem.rest, info, moments, leverage)


def smooth(drive: InertialDrive, settings: InertialSmootherSettings = InertialSmootherSettings(),
           incremental_only: bool = False) -> InertialSmootherResult:
    """The whole pipeline: build, incremental solve, batch solve (unless ``incremental_only``),
    marginals. The pixel sigma is identified in the batch solve only; ``incremental_only`` keeps
    ``pixel_sigma`` (or ``pixel_sigma_start`` when None)."""
    start = time.perf_counter()
    problem = build_problem(drive, settings)
    build_s = time.perf_counter() - start
    factorization = settings.isam_factorization
    def first_pass(problem):
        return incremental_solve(problem) if incremental_only else initial_solve(problem)

    try:
        inc = first_pass(problem)
    except EstimationError as exc:
        if factorization != "cholesky" or "indeterminate" not in str(exc):
            raise
        log.warning("%s; running the incremental pass again with QR factorisation", exc)
        factorization = f"qr (cholesky failed: {exc})"
        problem = dataclasses.replace(problem, settings=dataclasses.replace(settings, isam_factorization="qr"))
        inc = first_pass(problem)
    if incremental_only:
        sol = dataclasses.replace(inc, graph=inc.graph)
        name = ESTIMATOR + "-isam2"
    else:
        sol = batch_solve(problem, inc)
        sol.timing = dict(inc.timing, **sol.timing)
        name = ESTIMATOR
    sol.timing["build_s"] = build_s
    result = to_result(problem, sol, name)
    result.estimate.info["isam_factorization"] = factorization
    return result
