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
  (mean ``mean_track_length``) and ends earlier when the landmark leaves the view. A track once
  ended is never observed again; a landmark seen again later gets a new track index, as in the
  real data. Track indices are numbered in order of their first frame.
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

``noise_free=True`` zeroes every noise (pixels, velocities, gyro bias). The random streams of
the trajectory, the landmarks, the tracks, the velocity noise and the pixel noise are separate
children of one ``SeedSequence(seed)``, so for one seed the noise-free drive is the ground truth
of the noisy one. No option draws from a new stream, and with the defaults every drive is the
same, to the byte, as before the options existed.
"""

from __future__ import annotations

import logging
import numbers
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.interpolate import PchipInterpolator

from vislam.ekf.camera import distort_pixels, project
from vislam.ekf.errors import InputError
from vislam.ekf.geometry import homogeneous, se3_exp, se3_inv, so3_exp
from vislam.ekf.sequence import Calibration, Observations, Sequence
from vislam.eval.export import FLOAT_FORMAT, atomic_write, save_npz_reproducible

log = logging.getLogger(__name__)

#: KITTI left camera intrinsics of the shared drives (rectified).
KITTI_K = np.array([[707.0912, 0.0, 601.8873], [0.0, 707.0912, 183.1104], [0.0, 0.0, 1.0]])
#: KITTI stereo baseline of the shared drives (m).
KITTI_BASELINE = 0.5371506532679237
#: ``cam_T_imu`` copied exactly from the shared drive 0027.npz.
KITTI_CAM_T_IMU = np.array(
    [
        [-1.0886351426112831e-03, -9.9997634720088269e-01, 6.7871818004070234e-03, 1.1438987057554275e00],
        [-8.5120721364696054e-03, -6.7776711518013708e-03, -9.9994087157728695e-01, -3.1271847125070873e-01],
        [9.9996317699677706e-01, -1.1463429256237557e-03, -8.5044931029854397e-03, 7.2654604549397805e-01],
        [0.0, 0.0, 0.0, 1.0],
    ]
)
#: Height of the KITTI left camera above the road (m): sets the road level of the landmarks.
KITTI_CAMERA_HEIGHT = 1.65
#: KITTI image size (px).
KITTI_IMAGE_SIZE = (1241, 376)

#: Extra path (m) simulated beyond the last frame so landmarks ahead of it exist.
_LOOKAHEAD_M = 80.0
#: Landmarks further than this along the path from the car are never looked at (m).
_WINDOW_M = 150.0
#: Noise-free projections closer than this to the image border are not tracked (px), so that
#: noisy pixels stay inside the image (and never equal the -1 of "unobserved").
_BORDER_PX = 5.0


#: Longest simulated drive (KITTI's longest sequence has about 4500 frames).
MAX_SIM_FRAMES = 20000
#: Upper end (excluded) of ``SimConfig.pixel_correlation`` and ``velocity_correlation``.
MAX_CORRELATION = 0.99
#: Upper bounds of the settings: beyond them a drive is no longer KITTI-like, and squares of
#: the noise levels would overflow.
_SIM_UPPER_BOUNDS = {
    "rate_hz": 1000.0, "speed_min": 100.0, "speed_max": 100.0, "max_yaw_rate": 10.0,
    "max_pitch_deg": 45.0, "velocity_sigma": 100.0, "gyro_sigma": 10.0, "pixel_sigma": 1000.0,
    "landmark_density": 1000.0, "min_depth": 1e4, "max_depth": 1e4, "mean_track_length": 1e4,
    "knot_spacing_s": 1e4,
}
#: How a velocity sample relates to the motion (module docstring).
SIM_VELOCITY_PAIRINGS = ("current", "next", "mean")
#: Faults of the extrinsic written into the file: "none" (the true one) or "kitti" (the
#: translation of imu_T_cam stored where cam_T_imu's belongs, as in the shared data).
FILE_EXTRINSIC_FAULTS = ("none", "kitti")
#: Largest file-extrinsic offset: translation (m) and rotation (rad) components.
_MAX_OFFSET_M, _MAX_OFFSET_RAD = 100.0, 3.0


@dataclass(frozen=True)
class SimConfig:
    """Every setting of the simulator; the defaults give a quick KITTI-like drive (60 s)."""

    seed: int = 0
    n_frames: int = 600
    rate_hz: float = 10.0
    name: str = "sim"
    # The drive.
    speed_min: float = 5.0
    speed_max: float = 12.0
    max_yaw_rate: float = 0.3
    #: Share of yaw-rate knots that are exactly straight (zero yaw rate).
    straight_fraction: float = 0.4
    max_pitch_deg: float = 3.0
    #: Spacing (s) of the random knots of speed and yaw rate (pitch: twice this).
    knot_spacing_s: float = 4.0
    # Velocity noise, per sample (the shared data: about 0.5 m/s and 0.05 rad/s): one number
    # for every axis, or three (x, y, z of the IMU body frame).
    velocity_sigma: float | tuple[float, float, float] = 0.5
    gyro_sigma: float | tuple[float, float, float] = 0.05
    #: Constant gyro bias (rad/s), one value per axis.
    gyro_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)
    # Stereo.
    pixel_sigma: float = 1.0
    #: Landmarks per metre of path (both sides together).
    landmark_density: float = 2.7
    #: Share of landmarks placed far from the road (lateral 20-50 m).
    far_fraction: float = 0.2
    #: Share of landmarks on the road surface (lateral 1-10 m, up to 0.15 m above the road):
    #: road markings and kerbs, the lower half of the image.
    ground_fraction: float = 0.25
    min_depth: float = 3.0
    max_depth: float = 60.0
    min_disparity: float = 0.5
    mean_track_length: float = 10.0
    #: Probability per frame that a visible landmark without a track starts one.
    detect_probability: float = 0.3
    #: Probability per frame (from frame 2 on) of a repeat event like those of the shared
    #: drives (0027: 91 in 1106 frames): every track continuing into that frame repeats its
    #: previous observation exactly (the tracker's image did not update) and then goes on.
    #: After track cleaning each event leaves one interval without visual constraint.
    repeat_event_rate: float = 0.0
    noise_free: bool = False
    #: Which velocity sample covers [k, k+1] in the data made (SIM_VELOCITY_PAIRINGS).
    velocity_pairing: str = "mean"
    #: The extrinsic written into the file: FILE_EXTRINSIC_FAULTS, then the offset
    #: [dtx, dty, dtz, drx, dry, drz] (m, rad) added (module docstring).
    file_extrinsic_fault: str = "none"
    file_extrinsic_offset: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    #: A radial lens term the file's pixels carry beyond its pinhole K (ekf.camera: x_d =
    #: x (1 + k1 r^2)); the image bounds apply to the distorted pixels, the noise is added after.
    radial_k1: float = 0.0
    #: Correlation of a track's pixel errors from one frame to the next (AR(1), module
    #: docstring), in [0, 1); 0: independent.
    pixel_correlation: float = 0.0
    #: Correlation of the linear-velocity errors from one sample to the next (AR(1), module
    #: docstring), in [0, 1); 0: white, as the shared drives' added noise.
    velocity_correlation: float = 0.0

    def __post_init__(self) -> None:
        if not isinstance(self.seed, (int, np.integer)) or not 0 <= self.seed < 2**63:
            raise InputError(f"simulation: seed must be an integer in [0, 2^63), got {self.seed!r}")
        if not 2 <= self.n_frames <= MAX_SIM_FRAMES:
            raise InputError(
                f"simulation: n_frames must be between 2 and {MAX_SIM_FRAMES}, got {self.n_frames}"
            )
        for key in ("velocity_sigma", "gyro_sigma"):
            value = getattr(self, key)
            if isinstance(value, (list, tuple, np.ndarray)):
                try:
                    arr = np.asarray(value, dtype=float)
                except (TypeError, ValueError):
                    arr = np.zeros(0)
                if arr.shape != (3,):
                    raise InputError(f"simulation: {key} must be one number or three (x, y, z), "
                                     f"got {value!r}")
                object.__setattr__(self, key, tuple(float(x) for x in arr))
        for key, top in _SIM_UPPER_BOUNDS.items():
            value = getattr(self, key)
            if np.any(np.isfinite(value) & (np.asarray(value) > top)):
                raise InputError(f"simulation: {key} must be at most {top:g}, got {value!r}")
        positive = ("rate_hz", "speed_min", "landmark_density", "mean_track_length", "max_depth")
        for key in positive:
            value = getattr(self, key)
            if not np.isfinite(value) or value <= 0:
                raise InputError(f"simulation: {key} must be positive, got {value!r}")
        nonneg = ("velocity_sigma", "gyro_sigma", "pixel_sigma", "max_yaw_rate", "max_pitch_deg")
        for key in nonneg:
            value = getattr(self, key)
            if not np.all(np.isfinite(value)) or np.any(np.asarray(value) < 0):
                raise InputError(f"simulation: {key} must be >= 0, got {value!r}")
        if self.speed_max < self.speed_min:
            raise InputError(
                f"simulation: speed_max {self.speed_max} is below speed_min {self.speed_min}"
            )
        if self.far_fraction + self.ground_fraction > 1.0:
            raise InputError(
                f"simulation: far_fraction + ground_fraction must be <= 1, got "
                f"{self.far_fraction} + {self.ground_fraction}"
            )
        for key in ("straight_fraction", "far_fraction", "ground_fraction", "detect_probability",
                    "repeat_event_rate"):
            value = getattr(self, key)
            if not 0.0 <= value <= 1.0:
                raise InputError(f"simulation: {key} must be in [0, 1], got {value!r}")
        for key in ("pixel_correlation", "velocity_correlation"):
            a = getattr(self, key)
            if isinstance(a, bool) or not isinstance(a, numbers.Real) \
                    or not 0.0 <= a < MAX_CORRELATION:
                raise InputError(f"simulation: {key} must be a number in [0, "
                                 f"{MAX_CORRELATION:g}), got {a!r}")
            object.__setattr__(self, key, float(a))
        if self.mean_track_length < 1:
            raise InputError(
                f"simulation: mean_track_length must be >= 1, got {self.mean_track_length}"
            )
        if not 0 < self.min_depth < self.max_depth:
            raise InputError(
                f"simulation: need 0 < min_depth < max_depth, got {self.min_depth}, {self.max_depth}"
            )
        bias = np.asarray(self.gyro_bias, dtype=float)
        if bias.shape != (3,) or not np.all(np.isfinite(bias)) or np.any(np.abs(bias) > 10.0):
            raise InputError(
                f"simulation: gyro_bias must be 3 numbers within +-10 rad/s, got {self.gyro_bias!r}"
            )
        object.__setattr__(self, "gyro_bias", tuple(float(x) for x in bias))
        from vislam.ekf.model import MODEL_CHECKS

        try:  # the model file's rule for the same value
            object.__setattr__(self, "radial_k1", MODEL_CHECKS["radial_k1"](self.radial_k1))
        except ValueError as exc:
            raise InputError(f"simulation: radial_k1 {exc}") from None
        if self.velocity_pairing not in SIM_VELOCITY_PAIRINGS:
            raise InputError(f"simulation: velocity_pairing must be one of "
                             f"{', '.join(SIM_VELOCITY_PAIRINGS)}, got {self.velocity_pairing!r}")
        if self.file_extrinsic_fault not in FILE_EXTRINSIC_FAULTS:
            raise InputError(f"simulation: file_extrinsic_fault must be one of "
                             f"{', '.join(FILE_EXTRINSIC_FAULTS)}, got {self.file_extrinsic_fault!r}")
        try:
            offset = np.asarray(self.file_extrinsic_offset, dtype=float)
        except (TypeError, ValueError):
            offset = np.zeros(0)
        if (offset.shape != (6,) or not np.all(np.isfinite(offset))
                or np.any(np.abs(offset[:3]) > _MAX_OFFSET_M)
                or np.any(np.abs(offset[3:]) > _MAX_OFFSET_RAD)):
            raise InputError(
                "simulation: file_extrinsic_offset must be 6 numbers, translation within "
                f"+-{_MAX_OFFSET_M:g} m then rotation within +-{_MAX_OFFSET_RAD:g} rad, got "
                f"{self.file_extrinsic_offset!r}"
            )
        object.__setattr__(self, "file_extrinsic_offset", tuple(float(x) for x in offset))


#: The benchmark's default simulated drive (seed 0, 600 frames).
DEFAULT_SIM = SimConfig()


@dataclass
class SimResult:
    """A simulated drive and its ground truth.

    ``sequence`` the measurements, as the loader builds them from the written file;
    ``poses`` (T, 4, 4) true ``world_T_imu`` (world = IMU at frame 0);
    ``landmarks`` (n_tracks, 3) true world position of the landmark of each track index;
    ``true_velocities`` (T, 6) noise-free instantaneous body twists ``[v; w]`` at each sample;
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
        source=f"vislam simulate: the true model of {result.sequence.name} ({seed_text})",
        file={"cam_T_imu": result.sequence.calibration.cam_T_imu},
    )


def default_simulation(seed: int = 0) -> SimResult:
    """The benchmark's default drive for ``seed``."""
    return simulate(SimConfig(**{**DEFAULT_SIM.__dict__, "seed": int(seed)}))


def default_sequence(seed: int = 0) -> Sequence:
    """The measurements of :func:`default_simulation`."""
    return default_simulation(seed).sequence


# --------------------------------------------------------------------------- the drive


def _smooth_profile(rng, t_end: float, spacing: float, draw) -> PchipInterpolator:
    """A PCHIP curve through knots every ``spacing`` seconds with values ``draw(n)``."""
    n = int(np.ceil(t_end / spacing)) + 2
    knots_t = np.arange(n) * spacing
    return PchipInterpolator(knots_t, draw(n))


def _instantaneous_twists(config: SimConfig, rng, t: np.ndarray) -> np.ndarray:
    """Body twists (n, 6) at times ``t``: forward speed, Euler-kinematics angular velocity."""
    span = float(t[-1]) + 1.0
    speed = _smooth_profile(
        rng, span, config.knot_spacing_s, lambda n: rng.uniform(config.speed_min, config.speed_max, n)
    )

    def yaw_knots(n):
        rates = rng.uniform(-config.max_yaw_rate, config.max_yaw_rate, n)
        return np.where(rng.random(n) < config.straight_fraction, 0.0, rates)

    yaw_rate = _smooth_profile(rng, span, config.knot_spacing_s, yaw_knots)
    max_pitch = np.deg2rad(config.max_pitch_deg)

    def pitch_knots(n):
        values = rng.uniform(-max_pitch, max_pitch, n)
        values[0] = 0.0  # level at frame 0, so the world z axis is up
        return values

    pitch = _smooth_profile(rng, span, 2.0 * config.knot_spacing_s, pitch_knots)
    theta, dtheta, dpsi = pitch(t), pitch.derivative()(t), yaw_rate(t)
    u = np.zeros((t.size, 6))
    u[:, 0] = speed(t)
    u[:, 3] = -dpsi * np.sin(theta)
    u[:, 4] = dtheta
    u[:, 5] = dpsi * np.cos(theta)
    return u


def integrate_mean_pairing(twists: np.ndarray, dt: np.ndarray) -> np.ndarray:
    """Poses (T, 4, 4) from identity with the constant twist ``(u_k + u_{k+1}) / 2`` on each
    interval ``[k, k+1]`` of length ``dt[k]``: the simulator's definition of the true motion."""
    twists = np.asarray(twists, dtype=float)
    steps = se3_exp(np.asarray(dt, dtype=float)[:, None] * 0.5 * (twists[:-1] + twists[1:]))
    poses = np.empty((twists.shape[0], 4, 4))
    poses[0] = np.eye(4)
    for k, step in enumerate(steps):
        poses[k + 1] = poses[k] @ step
    return poses


# --------------------------------------------------------------------------- landmarks


def _place_landmarks(
    config: SimConfig, rng, poses: np.ndarray, road_z: float
) -> tuple[np.ndarray, np.ndarray]:
    """Landmarks (N, 3) along both sides of the path of ``poses``, sorted by the arc length
    (N,) of the path point they stand beside (returned too). ``road_z``: height of the road
    relative to the IMU."""
    pos = poses[:, :3, 3]
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pos, axis=0), axis=1))])
    n = int(round(config.landmark_density * arc[-1]))
    s = np.sort(rng.uniform(0.0, arc[-1], n))
    # Fractional frame index of each arc length; positions and headings interpolated there.
    f = np.interp(s, arc, np.arange(arc.size))
    i0 = np.minimum(np.floor(f).astype(int), arc.size - 2)
    a = (f - i0)[:, None]
    base = (1 - a) * pos[i0] + a * pos[i0 + 1]
    forward = (1 - a) * poses[i0, :3, 0] + a * poses[i0 + 1, :3, 0]
    left = np.stack([-forward[:, 1], forward[:, 0], np.zeros(n)], axis=1)
    left /= np.linalg.norm(left, axis=1, keepdims=True)
    kind = rng.random(n)
    far = kind < config.far_fraction
    ground = ~far & (kind < config.far_fraction + config.ground_fraction)
    side = np.where(rng.random(n) < 0.5, -1.0, 1.0)
    lateral = np.select(
        [far, ground],
        [rng.uniform(20.0, 50.0, n), rng.uniform(1.0, 10.0, n)],
        rng.uniform(4.0, 20.0, n),
    ) * side
    above_road = np.select(
        [far, ground],
        [rng.uniform(0.0, 20.0, n), rng.uniform(0.0, 0.15, n)],
        rng.uniform(0.0, 10.0, n),
    )
    height = road_z + above_road
    return base + lateral[:, None] * left + height[:, None] * np.array([0.0, 0.0, 1.0]), s


# --------------------------------------------------------------------------- observations


def drifting_noise(white: np.ndarray, previous: np.ndarray, continuing: np.ndarray,
                   a: float) -> np.ndarray:
    """One frame's pixel errors (k, 4) from its white draws ``white`` (k, 4, already times
    pixel_sigma): ``a previous + sqrt(1 - a^2) white`` where a track ``continuing`` from the
    frame before (its error there ``previous``), ``white`` where a track starts (the AR(1)
    drift of the module docstring; ``a`` 0: ``white`` itself)."""
    if not a:
        return white
    out = white.copy()
    out[continuing] = a * previous[continuing] + np.sqrt(1.0 - a * a) * white[continuing]
    return out


def _observe(
    config: SimConfig, rng_tracks, rng_pixels, poses, points, point_arc, calib: Calibration,
    repeat_frames: np.ndarray | None = None,
):
    """Run the tracker over the first ``len(poses)`` frames; at ``repeat_frames`` (bool per
    frame) every continuing track repeats its previous observation exactly.

    Returns rows (frame, track, z) of the observations, the noise-free pixels of those rows,
    and the landmark of each track index.
    """
    M = calib.M
    width, height = KITTI_IMAGE_SIZE
    n_pts = points.shape[0]
    sigma = 0.0 if config.noise_free else config.pixel_sigma
    p_len = 1.0 / config.mean_track_length
    active = np.zeros(n_pts, dtype=bool)
    track_of = np.full(n_pts, -1, dtype=np.int64)
    last_z = np.zeros((n_pts, 4))
    last_error = np.zeros((n_pts, 4))  # each point's pixel error at its previous observation
    remaining = np.zeros(n_pts, dtype=np.int64)
    track_landmark: list[np.ndarray] = []
    next_id = 0
    rows_f, rows_t, rows_z, rows_z0 = [], [], [], []
    cam_T_world = calib.cam_T_imu @ se3_inv(poses)
    # Only landmarks placed within _WINDOW_M of path length of the car are looked at (points
    # are sorted by arc length): this keeps the cost linear in the drive's length. A landmark
    # outside that window would have to be seen across a loop of the road; it counts as occluded.
    pos = poses[:, :3, 3]
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pos, axis=0), axis=1))])
    lo_all = np.searchsorted(point_arc, arc - _WINDOW_M, side="left")
    hi_all = np.searchsorted(point_arc, arc + _WINDOW_M, side="right")
    for k in range(poses.shape[0]):
        lo, hi = int(lo_all[k]), int(hi_all[k])
        q = points[lo:hi] @ cam_T_world[k, :3, :3].T + cam_T_world[k, :3, 3]
        depth = q[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            z0 = project(M, homogeneous(q))  # paper eq. 1-3
            if config.radial_k1:
                z0 = distort_pixels(z0, calib.K, config.radial_k1)
        visible = (
            (depth >= config.min_depth)
            & (depth <= config.max_depth)
            & (z0[:, 0] <= width - 1 - _BORDER_PX)
            & (z0[:, 2] >= _BORDER_PX)
            & (z0[:, 1] >= _BORDER_PX)
            & (z0[:, 1] <= height - 1 - _BORDER_PX)
        )
        was_active = active[lo:hi]
        keep = was_active & visible & (remaining[lo:hi] > 0)
        p_detect = 1.0 if k == 0 else config.detect_probability
        # A track that ends now cannot restart now (ended tracks were active).
        start = ~was_active & visible & (rng_tracks.random(hi - lo) < p_detect)
        local = np.flatnonzero(keep | start)
        error = drifting_noise(sigma * rng_pixels.standard_normal((local.size, 4)),
                               last_error[lo + local], keep[local], config.pixel_correlation)
        z = z0[local] + error
        ok = z[:, 0] - z[:, 2] >= config.min_disparity
        local, z = local[ok], z[ok]
        seen = lo + local
        error = error[ok]
        if repeat_frames is not None and repeat_frames[k]:
            again = keep[local]
            z[again] = last_z[seen[again]]
            error[again] = last_error[seen[again]]
        last_z[seen] = z
        last_error[seen] = error
        new = seen[start[local]]
        track_of[new] = next_id + np.arange(new.size)
        remaining[new] = rng_tracks.geometric(p_len, new.size)
        track_landmark.append(new)
        next_id += new.size
        # Every track not observed now has ended for good (also any left outside the window).
        active[:] = False
        active[seen] = True
        remaining[seen] -= 1
        rows_f.append(np.full(seen.size, k, dtype=np.int64))
        rows_t.append(track_of[seen])
        rows_z.append(z)
        rows_z0.append(z0[local])
    return (
        np.concatenate(rows_f),
        np.concatenate(rows_t),
        np.concatenate(rows_z),
        np.concatenate(rows_z0),
        np.concatenate(track_landmark),
    )


# --------------------------------------------------------------------------- entry points


def simulate(config: SimConfig = DEFAULT_SIM) -> SimResult:
    """Simulate one drive (see the module docstring for the model)."""
    # spawn(6)'s first five children equal spawn(5)'s: adding a stream changed no old drive
    streams = [np.random.default_rng(s) for s in np.random.SeedSequence(config.seed).spawn(6)]
    rng_drive, rng_landmarks, rng_tracks, rng_velocity, rng_pixels, rng_events = streams
    dt = 1.0 / config.rate_hz
    # Simulate past the last frame so that landmarks exist up to max_depth ahead of it.
    n_extra = int(np.ceil((_LOOKAHEAD_M + config.max_depth) / config.speed_min * config.rate_hz))
    n_all = config.n_frames + n_extra
    t_all = np.arange(n_all) * dt
    u_all = _instantaneous_twists(config, rng_drive, t_all)
    poses_all = integrate_mean_pairing(u_all, np.full(n_all - 1, dt))
    road_z = float(se3_inv(KITTI_CAM_T_IMU)[2, 3]) - KITTI_CAMERA_HEIGHT
    points, point_arc = _place_landmarks(config, rng_landmarks, poses_all, road_z)

    T = config.n_frames
    poses, timestamps = poses_all[:T], t_all[:T]
    u_true = _velocity_samples(u_all, T, config.velocity_pairing)
    true_cam_T_imu = KITTI_CAM_T_IMU.copy()
    calib = Calibration(K=KITTI_K.copy(), baseline=KITTI_BASELINE, cam_T_imu=true_cam_T_imu)
    repeat_frames = (rng_events.random(T) < config.repeat_event_rate) & (np.arange(T) >= 2)
    frame, track, z, _, track_landmark = _observe(
        config, rng_tracks, rng_pixels, poses, points, point_arc, calib, repeat_frames
    )
    file_calib = Calibration(K=calib.K, baseline=calib.baseline,
                             cam_T_imu=file_extrinsic(config, true_cam_T_imu))

    noise = np.zeros((T, 6))
    if not config.noise_free:
        white = rng_velocity.standard_normal((T, 3))
        if config.velocity_correlation:  # the drive as one track of AR(1) errors
            from vislam.graph.track_correlation import ar1_along_tracks

            white = ar1_along_tracks(np.arange(T), np.zeros(T, dtype=np.int64),
                                     config.velocity_correlation, white)
        noise[:, :3] = _sigma(config.velocity_sigma) * white
        noise[:, 3:] = _sigma(config.gyro_sigma) * rng_velocity.standard_normal((T, 3))
        noise[:, 3:] += np.asarray(config.gyro_bias)
    u_meas = u_true + noise

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


def _sigma(value):
    """A sigma setting as the simulator multiplies it: the float itself (bit for bit what it
    always was) or three numbers (3,)."""
    return value if isinstance(value, float) else np.asarray(value, dtype=float)


def _velocity_samples(u_all: np.ndarray, T: int, pairing: str) -> np.ndarray:
    """The noise-free velocity samples (T, 6) of instantaneous twists ``u_all`` (n > T, 6)
    under ``pairing`` (module docstring)."""
    if pairing == "mean":
        return u_all[:T]
    w = 0.5 * (u_all[:-1] + u_all[1:])  # the true twist of each interval
    if pairing == "current":
        return w[:T].copy()
    out = np.empty((T, 6))
    out[0] = u_all[0]
    out[1:] = w[: T - 1]
    return out


def camera_groundtruth(poses: np.ndarray, cam_T_imu: np.ndarray) -> np.ndarray:
    """KITTI ground truth: left-camera poses in the left-camera frame of frame 0,
    ``P(k) = cam_T_imu @ T_imu(k) @ inv(cam_T_imu)`` (the shared data's README).

    The general matrix inverse is deliberate: the shared ``cam_T_imu`` is orthonormal only to
    about 1e-7, and only the exact inverse makes ``P(0)`` the identity and lets a reader recover
    ``T_imu(k) = inv(cam_T_imu) @ P(k) @ cam_T_imu`` to rounding."""
    return cam_T_imu @ poses @ np.linalg.inv(cam_T_imu)


def write_simulation(
    result: SimResult, out_dir: str | os.PathLike, name: str | None = None
) -> dict[str, Path]:
    """Write a drive as the shared data lays it out; returns the paths by role.

    * ``data``: ``out_dir/NAME.npz``, the real data's keys and shapes (features (4, M, T) with
      -1 where unobserved, time_stamps (1, T), linear/rotational_velocity (3, T), K, b,
      cam_T_imu);
    * ``groundtruth``: ``out_dir/groundtruth/NAME.txt``, KITTI poses of the left camera with the
      time since frame 0 prepended (13 columns);
    * ``landmarks``: ``out_dir/NAME_landmarks.npz`` with ``landmarks`` (n_tracks, 3) the true
      world position per track index (world = IMU at frame 0), ``track_landmark``
      (n_tracks,), ``landmark_points`` (n_landmarks, 3), ``poses`` (T, 4, 4) true world_T_imu
      and ``true_velocities`` (T, 6);
    * ``model``: ``out_dir/NAME_model.toml``, the true model of the drive (ekf.model, a
      ``[model]`` table and the file's extrinsic under ``[file]``).

    The ground truth is made with the true extrinsic: a user converting it with a faulty file
    extrinsic gets wrong IMU poses, exactly as with the shared data.

    Files carry no write time: the same result always gives the same bytes.
    """
    seq = result.sequence
    name = name or seq.name
    out_dir = Path(out_dir)
    calib = seq.calibration
    data = {
        "time_stamps": seq.timestamps[None, :],
        "features": seq.obs.to_dense(seq.n_tracks),
        "linear_velocity": seq.linear_velocity.T,
        "rotational_velocity": seq.angular_velocity.T,
        "K": calib.K,
        "b": np.array(calib.baseline),
        "cam_T_imu": calib.cam_T_imu,
    }
    paths = {
        "data": save_npz_reproducible(out_dir / f"{name}.npz", data),
    }
    gt = camera_groundtruth(result.poses, result.cam_T_imu)
    rows = np.concatenate(
        [(seq.timestamps - seq.timestamps[0])[:, None], gt[:, :3, :4].reshape(-1, 12)], axis=1
    )
    paths["groundtruth"] = atomic_write(
        out_dir / "groundtruth" / f"{name}.txt",
        lambda fh: np.savetxt(fh, rows, fmt=FLOAT_FORMAT, delimiter=" "),
    )
    paths["landmarks"] = save_npz_reproducible(
        out_dir / f"{name}_landmarks.npz",
        {
            "landmarks": result.landmarks,
            "track_landmark": result.track_landmark,
            "landmark_points": result.landmark_points,
            "poses": result.poses,
            "true_velocities": result.true_velocities,
        },
    )
    model_text = result.model.to_toml().encode("utf-8")
    paths["model"] = atomic_write(out_dir / f"{name}_model.toml", lambda fh: fh.write(model_text))
    return paths


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
