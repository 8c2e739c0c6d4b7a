"""The raw-IMU simulator: an :class:`ekf.inertial.InertialDrive` with exact ground truth.

``simulate_imu(config) -> (drive, truth)`` (settings: :class:`eval.imu_sim_config.ImuSimConfig`;
the trajectories: :mod:`eval.imu_trajectories`). Deterministic per seed: the trajectory, the
landmarks, the biases, the IMU noise and the pixel noise each draw from their own stream of the
seed, so changing one setting does not reshuffle the others.

World frame: gravity-aligned, z up, gravity ``g_world = [0, 0, -g]`` with ``g`` the
calibration's magnitude. Room and hand-held scenarios: origin at the centre of the room's floor,
x along its long walls (10 m), y along the short ones (8 m); road: origin where the car stands at
the start, x along the road's general direction (the car's heading at the start is the path's
tangent there, generally not x).

IMU (every ``1 / imu_rate_hz`` s from t = 0). A sample stamped ``t_i`` holds the motion of the
interval ``[t_i, t_i+1]`` it opens (``sampling="interval"``, the default: the delta angle and delta
velocity an integrating IMU outputs, divided by dt), so that holding it over that interval, as the
strapdown scheme of :mod:`ekf.strapdown` and GTSAM's preintegration do, reproduces the
trajectory's rotation and velocity at every sample exactly and its position to within
``dt^2 / 12 * max|a(t) - a(0)|`` (the trapezoid rule's error; it does not grow with time)::

    gyro_i  = Log(R_i^T R_i+1) / dt + b_g(t_i) + n_g,   n_g ~ N(0, gyro_noise_density^2 / dt)
    accel_i = R_i^T ((v_i+1 - v_i) / dt - g_world) + b_a(t_i) + n_a,   likewise

``sampling="instant"``: the trajectory's derivatives at the stamp instead, ``gyro = w_body(t_i)``,
``accel = R^T (a_world(t_i) - g_world)`` (the held-sample scheme then lags by half a sample: its
error is first order in dt). The biases are drawn at t = 0 (sigmas ``gyro_bias_sigma``,
``accel_bias_sigma``) and walk per sample, ``b(t_i+1) = b(t_i) + N(0, random_walk^2 dt)``; the
white noise of a sample is that of the continuous density averaged over dt.

Faults with a known answer. ``imu_time_offset`` S (s, positive when the IMU's stamps are late
against the camera's): the sample stamped ``t_i`` holds what the IMU measured at the true time
``t_i - S``, made by the formulas above with the trajectory evaluated at ``t_i - S`` (and
``t_i - S + dt``); the sample's bias is still ``b(t_i)`` of its index (the biases are the
sensor's own). The camera's stamps, the truth (at the camera's clock: ``imu_poses`` etc. at
``imu_time``, the stamps) and everything else do not change; S = 0 evaluates at ``t_i`` itself,
the drive unchanged to the byte. ``imu_noise_scale`` X: the white noise and the bias walks are
drawn with X times ``noise``'s densities (the same draws, scaled), while the calibration keeps
declaring ``noise`` (the data sheet); X = 1 multiplies nothing. Both are recorded in
:class:`ImuTruth` (``imu_time_offset``, ``imu_noise_scale``), in the drive's ``source`` text
when not the defaults, and in ``NAME_landmarks.npz`` (:mod:`eval.imu_sim_files`).

Camera (every ``frame_stride`` IMU samples, so every frame is taken with a sample): an ideal
pinhole through a ``cam_T_imu`` that is not the identity (camera z along the IMU's x, a few
degrees of mounting rotation and a lever arm of centimetres (room) or a metre (car)).
Monocular pixels ``[u, v] = K pi(p_cam)``; stereo ``[uL, vL, uR, vR]`` of a rectified pair with
the right camera at ``+baseline`` along the left's x (:func:`ekf.camera.project`). A landmark is
seen when it is in front (depth >= ``min_depth``), within ``max_range`` of the camera and inside
the image (both images for stereo); each pixel gets N(0, pixel_sigma^2) independently. A track is
a landmark: its id is the landmark's index, kept every time the landmark is seen again.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from vislam.ekf.camera import project, stereo_matrix
from vislam.ekf.filter import ImuSamples
from vislam.ekf.geometry import se3_inv, so3_exp, so3_log
from vislam.ekf.imu_init import InitialState
from vislam.ekf.inertial import ImuNoise, InertialCalibration, InertialDrive
from vislam.ekf.sequence import Observations
from vislam.ekf.strapdown import N_ERROR, NavState
from vislam.eval.imu_sim_config import ImuSimConfig
from vislam.eval.imu_trajectories import (ROOM_HALF_X, ROOM_HALF_Y, ROOM_HEIGHT, Trajectory,
                                          TrajectoryPoint, make_trajectory)
from vislam.eval.sim_config import KITTI_BASELINE, KITTI_IMAGE_SIZE, KITTI_K

#: EuRoC-like camera of the room scenarios: intrinsics, image size (px), stereo baseline (m).
ROOM_K = np.array([[458.0, 0.0, 376.0], [0.0, 458.0, 240.0], [0.0, 0.0, 1.0]])
ROOM_IMAGE_SIZE = (752, 480)
ROOM_BASELINE = 0.11
#: Default ``max_range`` (m) per scenario kind.
ROOM_MAX_RANGE, ROAD_MAX_RANGE = 12.0, 60.0

#: Camera axes in the IMU frame: camera z (optical axis) along IMU x, camera x along IMU -y,
#: camera y along IMU -z (rows: the camera's axes in IMU coordinates).
_CAM_R_IMU_AXES = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
#: Mounting rotation (rad, camera frame) and the camera's position in the IMU frame (m).
_MOUNT_ROTATION = np.array([0.02, -0.03, 0.015])
_ROOM_LEVER_ARM = np.array([0.06, -0.02, 0.01])
_ROAD_LEVER_ARM = np.array([0.8, 0.3, 0.7])

#: World gravity direction (unit, z up): ``g_world = g * GRAVITY_DIRECTION``.
GRAVITY_DIRECTION = np.array([0.0, 0.0, -1.0])


@dataclass(frozen=True)
class ImuTruth:
    """Ground truth of a simulated raw-IMU drive (module docstring for the world frame).

    At the IMU samples: ``imu_time`` (n,), ``imu_poses`` (n, 4, 4) world_T_imu, ``imu_velocity``
    (n, 3) world m/s, ``angular_rate`` (n, 3) body rad/s, ``gyro_bias`` and ``accel_bias``
    (n, 3) (the biases inside sample i). At the camera frames (sample ``k * frame_stride``):
    ``frame_poses`` (T, 4, 4), ``frame_velocity``, ``frame_gyro_bias``, ``frame_accel_bias``
    (T, 3). ``landmarks`` (n_tracks, 3) the world point of each track index of the drive;
    ``scene_landmarks`` (M, 3) every landmark of the scene, seen or not (the drive's
    ``track_id`` indexes it);
    ``gravity_world`` (3,) m/s^2; ``motion_start_s`` the end of the rest; ``trajectory`` the
    analytic trajectory (evaluate it at any time). The faults made (module docstring):
    ``imu_time_offset`` (s, the IMU's stamps late against the camera's: a sample stamped ``t``
    holds the motion of ``trajectory`` at ``t - imu_time_offset``) and ``imu_noise_scale`` (the
    true white noise and bias walks over the calibration's declared ones)."""

    scenario: str
    imu_time: np.ndarray
    imu_poses: np.ndarray
    imu_velocity: np.ndarray
    angular_rate: np.ndarray
    gyro_bias: np.ndarray
    accel_bias: np.ndarray
    frame_poses: np.ndarray
    frame_velocity: np.ndarray
    frame_gyro_bias: np.ndarray
    frame_accel_bias: np.ndarray
    landmarks: np.ndarray
    scene_landmarks: np.ndarray
    gravity_world: np.ndarray
    motion_start_s: float
    frame_stride: int
    trajectory: Trajectory
    imu_time_offset: float = 0.0
    imu_noise_scale: float = 1.0

    def frame_state(self, k: int) -> NavState:
        """The true :class:`ekf.strapdown.NavState` at camera frame ``k``."""
        T = self.frame_poses[k]
        return NavState(T[:3, :3].copy(), self.frame_velocity[k].copy(), T[:3, 3].copy(),
                        self.frame_gyro_bias[k].copy(), self.frame_accel_bias[k].copy())

    def initial_state(self, time: float, k: int = 0) -> InitialState:
        """The true state at frame ``k`` (time ``time``, the drive's ``timestamps[k]``) with a
        zero covariance: dead reckoning from the truth."""
        return InitialState(float(time), self.frame_state(k), np.zeros((N_ERROR, N_ERROR)))


def camera_setup(config: ImuSimConfig
                 ) -> tuple[np.ndarray, tuple[int, int], float, np.ndarray, float]:
    """``K``, image size, baseline, ``cam_T_imu`` and the default range of the scenario."""
    road = config.scenario == "road"
    K = KITTI_K.copy() if road else ROOM_K.copy()
    size = KITTI_IMAGE_SIZE if road else ROOM_IMAGE_SIZE
    baseline = KITTI_BASELINE if road else ROOM_BASELINE
    R = so3_exp(_MOUNT_ROTATION) @ _CAM_R_IMU_AXES
    arm = _ROAD_LEVER_ARM if road else _ROOM_LEVER_ARM
    cam_T_imu = np.eye(4)
    cam_T_imu[:3, :3] = R
    cam_T_imu[:3, 3] = -R @ arm
    return K, size, baseline, cam_T_imu, ROAD_MAX_RANGE if road else ROOM_MAX_RANGE


def room_landmarks(rng: np.random.Generator, n: int) -> np.ndarray:
    """``n`` points uniform over the room's walls, floor and ceiling (area-weighted)."""
    X, Y, H = ROOM_HALF_X, ROOM_HALF_Y, ROOM_HEIGHT
    areas = np.array([2 * Y * H, 2 * Y * H, 2 * X * H, 2 * X * H, 4 * X * Y, 4 * X * Y])
    face = rng.choice(6, size=n, p=areas / areas.sum())
    u, v = rng.uniform(-1.0, 1.0, size=(2, n))
    h = rng.uniform(0.0, H, size=n)
    pts = np.empty((n, 3))
    for f, (x, y, z) in enumerate([(X, Y * u, h), (-X, Y * u, h), (X * u, Y, h), (X * u, -Y, h),
                                   (X * u, Y * v, 0.0), (X * u, Y * v, H)]):
        m = face == f
        pts[m] = np.stack(np.broadcast_arrays(x, y, z), axis=-1)[m]
    return pts


def road_landmarks(rng: np.random.Generator, trajectory: Trajectory, s_end: float,
                   per_100m: int) -> np.ndarray:
    """Points beside the road from 20 m behind the start to 80 m past the end: lateral 3-25 m
    either side, 0-8 m above the road (buildings, poles, trees), ``per_100m`` per 100 m."""
    speed = float(np.hypot(*trajectory.position.rate[:2])) or 1.0
    s_lo, s_hi = -20.0 / speed, s_end + 80.0 / speed
    n = max(1, int(round(per_100m * speed * (s_hi - s_lo) / 100.0)))
    s = rng.uniform(s_lo, s_hi, size=n)
    centre, tangent = trajectory.position(s), trajectory.position(s, 1)
    heading = np.arctan2(tangent[:, 1], tangent[:, 0])
    normal = np.stack([-np.sin(heading), np.cos(heading), np.zeros(n)], axis=-1)
    lateral = rng.choice([-1.0, 1.0], size=n) * rng.uniform(3.0, 25.0, size=n)
    height = rng.uniform(0.0, 8.0, size=n)
    return centre + lateral[:, None] * normal + height[:, None] * np.array([0.0, 0.0, 1.0])


def imu_measurements(point: TrajectoryPoint, gravity: float) -> tuple[np.ndarray, np.ndarray]:
    """Noise-free, bias-free ``(gyro, accel)`` of a trajectory: body rate and specific force
    ``R^T (a_world - g_world)``."""
    g_world = gravity * GRAVITY_DIRECTION
    accel = np.einsum("nji,nj->ni", point.R, point.a - g_world)
    return point.w.copy(), accel


def interval_measurements(trajectory: Trajectory, t: np.ndarray, dt: float, gravity: float
                          ) -> tuple[np.ndarray, np.ndarray]:
    """Noise-free, bias-free ``(gyro, accel)`` holding each interval ``[t_i, t_i + dt]``
    (module docstring): ``Log(R_i^T R_i+1) / dt`` and ``R_i^T ((v_i+1 - v_i) / dt - g_world)``."""
    a, b = trajectory(t), trajectory(t + dt)
    g_world = gravity * GRAVITY_DIRECTION
    gyro = so3_log(np.swapaxes(a.R, -1, -2) @ b.R) / dt
    accel = np.einsum("nji,nj->ni", a.R, (b.v - a.v) / dt - g_world)
    return gyro, accel


def _scaled_noise(noise: ImuNoise, scale: float) -> ImuNoise:
    """The noise the samples are drawn with: ``noise``'s densities and walks times ``scale``
    (``noise`` itself when 1, so nothing is multiplied)."""
    if scale == 1.0:
        return noise
    return dataclasses.replace(
        noise, **{key: getattr(noise, key) * scale for key in
                  ("gyro_noise_density", "gyro_random_walk", "accel_noise_density",
                   "accel_random_walk")})


def _bias_walk(rng, n: int, sigma0: float, walk: float, dt: float, off: bool) -> np.ndarray:
    if off:
        return np.zeros((n, 3))
    steps = rng.normal(size=(n, 3)) * (walk * np.sqrt(dt))
    steps[0] = rng.normal(size=3) * sigma0
    return np.cumsum(steps, axis=0)


def _observe(points_world: np.ndarray, world_T_imu: np.ndarray, cam_T_imu: np.ndarray, K, size,
             baseline: float | None, min_depth: float, max_range: float):
    """Indices of the visible points and their noise-free pixels (2 or 4 columns)."""
    cam_T_world = cam_T_imu @ se3_inv(world_T_imu)
    p = points_world @ cam_T_world[:3, :3].T + cam_T_world[:3, 3]
    depth = p[:, 2]
    ok = (depth >= min_depth) & (np.linalg.norm(p, axis=1) <= max_range)
    idx = np.flatnonzero(ok)
    q = np.concatenate([p[idx], np.ones((idx.size, 1))], axis=1)
    z = project(stereo_matrix(K, baseline or 0.0), q)
    W, H = size
    inside = (z[:, 0] >= 0) & (z[:, 0] < W) & (z[:, 1] >= 0) & (z[:, 1] < H)
    if baseline is not None:
        inside &= (z[:, 2] >= 0) & (z[:, 2] < W)
    else:
        z = z[:, :2]
    return idx[inside], z[inside]


def simulate_imu(config: ImuSimConfig = ImuSimConfig()) -> tuple[InertialDrive, ImuTruth]:
    """The simulated drive and its truth (module docstring)."""
    root = np.random.SeedSequence([config.seed, 37])
    rng_bias, rng_imu, rng_px = (np.random.default_rng(s) for s in root.spawn(3))
    rng_lm = np.random.default_rng([config.scene, 38])
    trajectory = make_trajectory(config.scenario, config.scene, config.rest_s, config.ramp)

    stride = config.frame_stride
    n = (config.n_frames - 1) * stride + 1
    t = np.arange(n) / config.imu_rate_hz
    dt = 1.0 / config.imu_rate_hz
    point = trajectory(t)
    t_sensor = t - config.imu_time_offset if config.imu_time_offset else t
    if config.sampling == "instant":
        sensed = point if t_sensor is t else trajectory(t_sensor)
        w, f = imu_measurements(sensed, config.gravity)
    else:
        w, f = interval_measurements(trajectory, t_sensor, dt, config.gravity)
    off = config.noise_free
    nz = _scaled_noise(config.noise, config.imu_noise_scale)
    bg = _bias_walk(rng_bias, n, config.gyro_bias_sigma, nz.gyro_random_walk, dt, off)
    ba = _bias_walk(rng_bias, n, config.accel_bias_sigma, nz.accel_random_walk, dt, off)
    gyro, accel = w + bg, f + ba
    if not off:
        rate_sqrt = np.sqrt(config.imu_rate_hz)
        gyro = gyro + rng_imu.normal(size=(n, 3)) * (nz.gyro_noise_density * rate_sqrt)
        accel = accel + rng_imu.normal(size=(n, 3)) * (nz.accel_noise_density * rate_sqrt)
    imu = ImuSamples(t, accel, gyro)

    K, size, baseline, cam_T_imu, default_range = camera_setup(config)
    max_range = config.max_range or default_range
    if config.scenario == "road":
        s_end = float(trajectory.warp(np.array([t[-1]]))[0][0])
        landmarks = road_landmarks(rng_lm, trajectory, s_end, config.landmark_count)
    else:
        landmarks = room_landmarks(rng_lm, config.landmark_count)

    poses = point.poses
    frame_samples = np.arange(config.n_frames) * stride
    stereo_b = baseline if config.stereo else None
    rows_f, rows_l, rows_z = [], [], []
    for k, i in enumerate(frame_samples):
        idx, z = _observe(landmarks, poses[i], cam_T_imu, K, size, stereo_b, config.min_depth,
                          max_range)
        rows_f.append(np.full(idx.size, k))
        rows_l.append(idx)
        rows_z.append(z)
    frame = np.concatenate(rows_f).astype(np.int64)
    lm = np.concatenate(rows_l).astype(np.int64)
    z = np.concatenate(rows_z).reshape(-1, 4 if config.stereo else 2)
    if not off and config.pixel_sigma > 0:
        z = z + rng_px.normal(size=z.shape) * config.pixel_sigma
    ids, track = np.unique(lm, return_inverse=True)
    order = np.lexsort((track, frame))
    ptr = np.zeros(config.n_frames + 1, dtype=np.int64)
    np.cumsum(np.bincount(frame, minlength=config.n_frames), out=ptr[1:])
    obs = Observations(ptr, track[order].astype(np.int64), z[order])

    calib = InertialCalibration(K=K, cam_T_imu=cam_T_imu, noise=config.noise, baseline=stereo_b,
                                gravity=float(config.gravity))
    drive = InertialDrive(config.drive_name, t[frame_samples].copy(), imu, obs, int(ids.size),
                          calib, 0, ids.astype(np.int64), f"simulated: {config.scenario}, "
                          f"{config.camera}, seed {config.seed}{_fault_text(config)}")
    truth = ImuTruth(
        scenario=config.scenario, imu_time=t, imu_poses=poses, imu_velocity=point.v,
        angular_rate=point.w, gyro_bias=bg, accel_bias=ba, frame_poses=poses[frame_samples],
        frame_velocity=point.v[frame_samples], frame_gyro_bias=bg[frame_samples],
        frame_accel_bias=ba[frame_samples], landmarks=landmarks[ids], scene_landmarks=landmarks,
        gravity_world=config.gravity * GRAVITY_DIRECTION, motion_start_s=float(config.rest_s),
        frame_stride=stride, trajectory=trajectory, imu_time_offset=config.imu_time_offset,
        imu_noise_scale=config.imu_noise_scale)
    return drive, truth


def _fault_text(config: ImuSimConfig) -> str:
    """The faults made, in words for the drive's ``source`` ("" for none)."""
    text = ""
    if config.imu_time_offset:
        text += f", IMU stamps late by {config.imu_time_offset:.6g} s (imu_time_offset)"
    if config.imu_noise_scale != 1.0:
        text += (f", IMU noise {config.imu_noise_scale:.6g} times its declared densities "
                 "(imu_noise_scale)")
    return text
