"""A KITTI-like simulated drive with exact ground truth.

The drive
---------
A car at 10 Hz, 5-12 m/s, moving forward along its body x axis (IMU frame: x forward, y left,
z up), on smooth curves (yaw rates up to about 0.3 rad/s) and gentle slopes (pitch within a few
degrees). Speed, yaw rate and pitch angle are smooth random functions of time (monotone cubic
interpolation, PCHIP, through random knots, so they never leave the knots' range); the body
angular velocity follows from the Z-Y-X Euler kinematics with zero roll,
``w = [-psi' sin(theta), theta', psi' cos(theta)]``, and the body linear velocity is
``[speed, 0, 0]``. ``true_velocities[k]`` is this instantaneous twist ``u_k`` at ``t_k``.

Scenarios (``scenario``; :func:`eval.sim_config.scenario_config` gives each one's defaults)
-------------------------------------------------------------------------------------------
* ``"road"`` (default): the drive above; tracks never come back. Every road drive is the same,
  to the byte, as before the scenarios existed.
* ``"loop"``: a car on a flat closed loop, a rounded rectangle (:func:`eval.sim_drawing.loop_curvature`)
  sized so that the drive is ``1 + loop_overlap`` laps: it comes back to its start (within a
  fraction of a metre) and drives the start again. Landmarks stand along one lap as the road's do
  (the same kinds and offsets); every landmark within reach of the car is looked at, so the start's
  landmarks are seen again at the end.
* ``"room"``: a platform on the floor of a ``room_size`` room, planar motion with yaw (no pitch,
  roll or height change), driving round the room through random waypoints at walking speed,
  stopping (twists exactly zero for 1-4 s) at a share ``stop_probability`` of them and looking
  round on the spot at most (:func:`eval.sim_drawing.room_drive`); ``room_landmarks`` landmarks on
  the walls near the camera's height, each seen again and again. Same camera, stereo rig and
  extrinsic as the road.

In the loop and the room the tracker recognises a landmark it has seen before: a landmark seen
again after its track ended continues **the same track index** (tracks come back after gaps,
numbered in order of their first frame, one track per landmark). The road's tracker never does.

Velocity pairing (documented convention, exact on noise-free data)
------------------------------------------------------------------
The true motion over ``[t_k, t_{k+1}]`` is the constant body twist equal to the **mean** of the
instantaneous twists at the two ends::

    world_T_imu(k+1) = world_T_imu(k) @ se3_exp(tau_k * (u_k + u_{k+1}) / 2)

so a filter using ``FilterConfig(velocity_pairing="mean")`` integrates the noise-free
velocities into the true poses exactly (to rounding). The world frame is the IMU frame at
frame 0 (pitch and yaw are zero there, so world z is up).

Other pairings (``velocity_pairing``, for tests of identifying it). The trajectory is the same;
only what a velocity sample holds changes. With the interval twist ``w_k = (u_k + u_{k+1}) / 2``
(the true constant twist over ``[t_k, t_{k+1}]``):

* ``"mean"`` (default): sample k is ``u_k``, so the mean of samples k and k+1 is ``w_k``;
* ``"current"``: sample k is ``w_k``, the twist of the interval it starts;
* ``"next"``: sample k is ``w_{k-1}``, the twist of the interval it ends (sample 0: ``u_0``).

A filter with the same pairing integrates the noise-free samples into the true poses exactly.
``true_velocities`` are the noise-free samples.

Measurements
------------
* Velocities: the samples above ``+ N(0, diag(velocity_sigma^2, gyro_sigma^2))`` (one sigma
  for every axis, or three: x, y, z of the IMU body frame) plus a constant gyro bias on the
  angular part.
  With ``velocity_correlation`` a the linear-velocity errors drift like a vehicle's velocity
  source: AR(1) from one sample to the next (each still ``N(0, velocity_sigma^2)``); the true
  model then carries the interval noise's long-run over white variance
  (``velocity_correlation_time``, :mod:`graph.motion_correlation`).
* Landmarks stand on both sides of the path (lateral offset 4-20 m, 0-10 m above the road,
  i.e. about -1.7..8.4 m relative to the camera), plus a share of far points (lateral 20-50 m,
  0-20 m above the road) and a share on the road surface (lateral 1-10 m, 0-0.15 m). The road
  lies 1.65 m below the left camera (KITTI's camera height), following the path's slope. A landmark is visible
  when its depth in the left camera is 3-60 m and both its projections fall in the 1241x376 px
  image, 5 px away from the border. A visible landmark without a track starts one with probability ``detect_probability``
  per frame (every visible landmark at frame 0); the track lasts a geometric number of frames
  (mean ``mean_track_length``) and ends earlier when the landmark leaves the view. On the road a
  track once ended is never observed again; a landmark seen again later gets a new track index,
  as in the real data (the loop and the room: the same index). Track indices are numbered in
  order of their first frame.
* Stereo pixels: ``z = M pi(cam_T_imu @ inv(world_T_imu) @ m)`` (paper eq. 1-3) plus
  ``N(0, pixel_sigma^2)`` on each of uL, vL, uR, vR; an observation whose noisy disparity falls
  below ``min_disparity`` is dropped and ends its track. With ``pixel_correlation`` a the error
  drifts along a track like a tracker's: AR(1), ``e_k = a e_k-1 + sqrt(1 - a^2) w_k`` from one
  observation of a track to the next (each still ``N(0, pixel_sigma^2)``; integrated
  correlation time ``(1 + a) / (1 - a)``, :mod:`graph.track_correlation`).

The file's extrinsic (``file_extrinsic_fault``, ``file_extrinsic_offset``). The data is made
with the true ``cam_T_imu`` (KITTI_CAM_T_IMU), and the written ground truth is the left
camera's poses with that true extrinsic, as in the real data; the ``cam_T_imu`` written into
the file may differ from it, like the shared files' (their README): fault "kitti" stores the
translation of imu_T_cam (``-R^T t``) where cam_T_imu's belongs; an offset ``[dtx, dty, dtz,
drx, dry, drz]`` (m, rad) then adds ``dt`` to the translation and turns the rotation by
``so3_exp(dr)`` on the left (``R_file = so3_exp(dr) @ R``). ``SimResult.sequence`` carries the
file's extrinsic (what the loader reads), ``SimResult.true_cam_T_imu`` the true one, and
``SimResult.model`` (written as ``NAME_model.toml``) the true model of the drive.

Time offsets (``velocity_time_offset``, ``gyro_time_offset``, s; positive when the stream's
stamps are late against the camera's). The sample stamped ``t_k`` holds what the sensor measured
at the true time ``t_k - offset``: the linear (angular) part of the velocity samples is made as
above, under the same pairing, from the instantaneous twists of the same motion evaluated at
``t_all - offset`` instead of ``t_all``: the road's PCHIP curves evaluated there (extended by
their end pieces before time 0); the loop's speed curve there and its arc length by the same
trapezoid from the grid time before; the room's step-by-step twists interpolated linearly (its
accelerations are constant over a step; at rest before time 0, and driven on past the last frame
for a negative offset). The trajectory, the camera's stamps and ``true_velocities`` (the truth at
the stamps) do not change; an offset of zero uses the unshifted twists themselves, so the drive
is the same to the byte. The offsets are recorded in ``SimResult.config``, in the true model's
keys (``velocity_time_offset``, ``gyro_time_offset``: ekf.model) and ``source``, and in ``NAME_landmarks.npz`` (eval.sim_files).

``noise_free=True`` zeroes every noise (pixels, velocities, gyro bias). The random streams of
the trajectory, the landmarks, the tracks, the velocity noise and the pixel noise are separate
children of one ``SeedSequence(seed)``, so for one seed the noise-free drive is the ground truth
of the noisy one. No option draws from a new stream, and with the defaults every drive is the
same, to the byte, as before the options existed.
"""


from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from vislam.ekf.geometry import se3_inv, so3_exp
from vislam.ekf.sequence import Calibration, Observations, Sequence
from vislam.eval.sim_config import (
    DEFAULT_SIM,
    KITTI_BASELINE,
    KITTI_CAM_T_IMU,
    KITTI_CAMERA_HEIGHT,
    KITTI_K,
    SimConfig,
)
from vislam.eval.sim_drawing import (
    LOOKAHEAD_M,
    integrate_mean_pairing,
    interpolated_twists,
    loop_drive,
    nearby_points,
    observe_landmarks,
    offset_samples,
    place_landmarks,
    room_drive,
    room_landmarks,
    twist_profile,
    velocity_noise,
    velocity_samples,
)

# The simulator's API in one place: writing a drive and the AR(1) drift are part of it (their
# homes are eval.sim_files and eval.sim_drawing).
from vislam.eval.sim_drawing import drifting_noise  # noqa: E402,F401
from vislam.eval.sim_files import write_simulation  # noqa: E402,F401

log = logging.getLogger(__name__)

@dataclass
class SimResult:
    """A simulated drive and its ground truth.

    ``sequence`` the measurements, as the loader builds them from the written file;
    ``poses`` (T, 4, 4) true ``world_T_imu`` (world = IMU at frame 0);
    ``landmarks`` (n_tracks, 3) true world position of the landmark of each track index;
    ``true_velocities`` (T, 6) noise-free instantaneous body twists ``[v; w]`` at each sample
    (the truth at the camera's stamps: with a time offset the stream's noise-free samples are
    those of the shifted times, module docstring);
    ``track_landmark`` (n_tracks,) which landmark each track observes;
    ``landmark_points`` (n_landmarks, 3) every landmark placed;
    ``config`` the settings that made it;
    ``true_cam_T_imu`` the extrinsic the data was made with (``sequence.calibration`` holds the
    file's, which differs with a file-extrinsic fault); :attr:`model` the true model.
    """

    sequence: Sequence
    poses: np.ndarray
    landmarks: np.ndarray
    true_velocities: np.ndarray
    track_landmark: np.ndarray
    landmark_points: np.ndarray
    config: SimConfig = field(default_factory=SimConfig)
    true_cam_T_imu: np.ndarray | None = None

    @property
    def cam_T_imu(self) -> np.ndarray:
        """The true extrinsic (the file's when none was recorded)."""
        if self.true_cam_T_imu is not None:
            return self.true_cam_T_imu
        return self.sequence.calibration.cam_T_imu

    @property
    def model(self):
        """The true model of the drive (ekf.model.Model): noise sigmas per axis, pixel sigma,
        gyro bias (None when zero), the pairing the samples were made with, the true
        extrinsic; the file's extrinsic under ``file``. Sigmas of a noise-free drive are
        SIGMA_MIN (a model's smallest)."""
        return true_model(self)


def file_extrinsic(config: SimConfig, true_cam_T_imu: np.ndarray) -> np.ndarray:
    """The ``cam_T_imu`` written into the file for ``config`` (module docstring)."""
    out = np.array(true_cam_T_imu, dtype=float)
    if config.file_extrinsic_fault == "kitti":
        out[:3, 3] = se3_inv(true_cam_T_imu)[:3, 3]
    offset = np.asarray(config.file_extrinsic_offset, dtype=float)
    if np.any(offset[3:] != 0.0):
        out[:3, :3] = so3_exp(offset[3:]) @ out[:3, :3]
    if np.any(offset[:3] != 0.0):
        out[:3, 3] = out[:3, 3] + offset[:3]
    return out


def _velocity_correlation_time(config: SimConfig) -> tuple[float, float, float] | None:
    """The interval velocity noise's long-run over white variance (ekf.model) of AR(1) samples
    with correlation a: (1 + a) / (1 - a) over the interval's share of a sample's variance in
    the model (a half for the "mean" pairing, ekf.model.interval_sigma_factor); None for white
    samples or no noise."""
    from vislam.ekf.model import interval_sigma_factor

    a = config.velocity_correlation
    if not a or config.noise_free:
        return None
    share = interval_sigma_factor(config.velocity_pairing) ** 2
    return ((1.0 + a) / (1.0 - a) / share,) * 3


def true_model(result: SimResult):
    """The true model of a simulated drive (see :attr:`SimResult.model`)."""
    from vislam.ekf.config import SIGMA_MIN, per_axis
    from vislam.ekf.model import Model

    config = result.config

    def sig(value) -> tuple:
        value = 0.0 if config.noise_free else value
        return tuple(max(float(x), SIGMA_MIN) for x in per_axis(value))

    bias = None
    if not config.noise_free and any(b != 0.0 for b in config.gyro_bias):
        bias = tuple(config.gyro_bias)
    seed_text = f"seed {config.seed}, {config.n_frames} frames"
    for what, key in (("linear-velocity", "velocity_time_offset"),
                      ("angular-velocity", "gyro_time_offset")):
        if getattr(config, key):  # the model's key below, and in words here
            seed_text += f", {what} stamps late by {getattr(config, key):.6g} s ({key})"
    return Model(
        velocity_sigma=sig(config.velocity_sigma),
        gyro_sigma=sig(config.gyro_sigma),
        pixel_sigma=sig(config.pixel_sigma)[0],
        velocity_pairing=config.velocity_pairing,
        cam_T_imu=result.cam_T_imu,
        gyro_bias=bias,
        radial_k1=config.radial_k1 or None,
        pixel_correlation_time=(1.0 + a) / (1.0 - a) if (a := config.pixel_correlation) else None,
        velocity_correlation_time=_velocity_correlation_time(config),
        velocity_time_offset=config.velocity_time_offset or None,
        gyro_time_offset=config.gyro_time_offset or None,
        source=f"vislam simulate: the true model of {result.sequence.name} ({seed_text})",
        file={"cam_T_imu": result.sequence.calibration.cam_T_imu},
    )


def default_simulation(seed: int = 0) -> SimResult:
    """The benchmark's default drive for ``seed``."""
    return simulate(SimConfig(**{**DEFAULT_SIM.__dict__, "seed": int(seed)}))


def default_sequence(seed: int = 0) -> Sequence:
    """The measurements of :func:`default_simulation`."""
    return default_simulation(seed).sequence


# --------------------------------------------------------------------------- entry points


def simulate(config: SimConfig = DEFAULT_SIM) -> SimResult:
    """Simulate one drive (see the module docstring for the model)."""
    # spawn(6)'s first five children equal spawn(5)'s: adding a stream changed no old drive
    streams = [np.random.default_rng(s) for s in np.random.SeedSequence(config.seed).spawn(6)]
    rng_drive, rng_landmarks, rng_tracks, rng_velocity, rng_pixels, rng_events = streams
    dt = 1.0 / config.rate_hz
    T = config.n_frames
    road_z = float(se3_inv(KITTI_CAM_T_IMU)[2, 3]) - KITTI_CAMERA_HEIGHT
    candidates, same_track = None, config.scenario != "road"
    # A stream stamped early (negative offset) reads the motion up to |offset| past the last
    # frame: the room's step-by-step drive goes on that far (its first T + 1 steps unchanged).
    n_late = int(np.ceil(max(0.0, -config.velocity_time_offset, -config.gyro_time_offset) / dt))
    if config.scenario == "room":
        t_all = np.arange(T + 1) * dt
        u_long, poses_long = room_drive(config, rng_drive, T + 1 + n_late, dt)
        twists = interpolated_twists(np.arange(T + 1 + n_late) * dt, u_long)
        u_all, poses_all = u_long[: T + 1], poses_long[: T + 1]
        points = room_landmarks(config, rng_landmarks, float(se3_inv(KITTI_CAM_T_IMU)[2, 3]))
        point_arc = np.zeros(points.shape[0])
        every = np.arange(points.shape[0])
        candidates = lambda k: every  # noqa: E731 (a room: every landmark may be in view)
    elif config.scenario == "loop":
        t_all = np.arange(T + 1) * dt
        u_all, poses_all, lap, twists = loop_drive(config, rng_drive, t_all, T)
        pos = poses_all[:, :3, 3]
        arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pos, axis=0), axis=1))])
        one_lap = poses_all[: max(int(np.searchsorted(arc, lap)), 2)]
        points, point_arc = place_landmarks(config, rng_landmarks, one_lap, road_z)
        reach = config.max_depth + float(np.linalg.norm(KITTI_CAM_T_IMU[:3, 3])) + 1.0
        candidates = nearby_points(points, pos, reach)
    else:
        # Simulate past the last frame so that landmarks exist up to max_depth ahead of it.
        n_extra = int(np.ceil((LOOKAHEAD_M + config.max_depth) / config.speed_min * config.rate_hz))
        n_all = config.n_frames + n_extra
        t_all = np.arange(n_all) * dt
        twists = twist_profile(config, rng_drive, float(t_all[-1]) + 1.0)
        u_all = twists(t_all)
        poses_all = integrate_mean_pairing(u_all, np.full(n_all - 1, dt))
        points, point_arc = place_landmarks(config, rng_landmarks, poses_all, road_z)

    poses, timestamps = poses_all[:T], t_all[:T]
    u_true = velocity_samples(u_all, T, config.velocity_pairing)
    u_stream = offset_samples(u_all, t_all, twists, T, config.velocity_pairing,
                              config.velocity_time_offset, config.gyro_time_offset)
    true_cam_T_imu = KITTI_CAM_T_IMU.copy()
    calib = Calibration(K=KITTI_K.copy(), baseline=KITTI_BASELINE, cam_T_imu=true_cam_T_imu)
    repeat_frames = (rng_events.random(T) < config.repeat_event_rate) & (np.arange(T) >= 2)
    frame, track, z, _, track_landmark = observe_landmarks(
        config, rng_tracks, rng_pixels, poses, points, point_arc, calib, repeat_frames,
        candidates, same_track,
    )
    file_calib = Calibration(K=calib.K, baseline=calib.baseline,
                             cam_T_imu=file_extrinsic(config, true_cam_T_imu))

    noise = velocity_noise(config, rng_velocity, T)
    u_meas = u_stream + noise

    n_tracks = int(track_landmark.size)
    sequence = Sequence(
        name=config.name,
        timestamps=timestamps.copy(),
        linear_velocity=u_meas[:, :3].copy(),
        angular_velocity=u_meas[:, 3:].copy(),
        obs=Observations.from_rows(frame, track, z, T),
        n_tracks=n_tracks,
        calibration=file_calib,
    )
    log.info(
        "simulated %s: %d frames, %d landmarks, %d tracks, %d observations",
        config.name,
        T,
        points.shape[0],
        n_tracks,
        frame.size,
    )
    return SimResult(
        sequence=sequence,
        poses=poses,
        landmarks=points[track_landmark],
        true_velocities=u_true,
        track_landmark=track_landmark,
        landmark_points=points,
        config=config,
        true_cam_T_imu=true_cam_T_imu.copy(),
    )


def simulation_stats(result: SimResult) -> dict[str, float]:
    """Summary figures of a drive: observations per frame, track lengths, speed, depth."""
    seq = result.sequence
    per_frame = seq.obs.per_frame
    lengths = seq.track_lengths()
    speed = np.linalg.norm(result.true_velocities[:, :3], axis=1)
    pos = result.poses[:, :3, 3]
    return {
        "frames": float(seq.n_frames),
        "tracks": float(seq.n_tracks),
        "observations": float(len(seq.obs)),
        "obs_per_frame_mean": float(per_frame.mean()),
        "obs_per_frame_min": float(per_frame.min()),
        "obs_per_frame_max": float(per_frame.max()),
        "track_length_mean": float(lengths.mean()) if lengths.size else 0.0,
        "track_length_median": float(np.median(lengths)) if lengths.size else 0.0,
        "speed_min": float(speed.min()),
        "speed_mean": float(speed.mean()),
        "speed_max": float(speed.max()),
        "yaw_rate_max_abs": float(np.abs(result.true_velocities[:, 5]).max()),
        "path_length_m": float(np.sum(np.linalg.norm(np.diff(pos, axis=0), axis=1))),
    }
