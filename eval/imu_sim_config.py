"""Settings of the raw-IMU simulator (:class:`ImuSimConfig`, every one checked where it is made).
The drive itself: :mod:`eval.imu_sim`."""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field

import numpy as np

from vislam.ekf.errors import InputError
from vislam.ekf.inertial import ACCEL_TURN_ON_BIAS_SIGMA, STANDARD_GRAVITY, ImuNoise
from vislam.eval.imu_trajectories import DEFAULT_RAMP_S, SCENARIOS
from vislam.eval.sim_config import check_time_offset

#: Camera kinds the simulator makes: two pixel columns (monocular) or four (stereo).
CAMERAS = ("mono", "stereo")

#: What a simulated IMU sample holds: the interval it opens, or the instant of its stamp.
SAMPLINGS = ("interval", "instant")

#: EuRoC's ADIS16448 data-sheet figures (the dataset's ``imu0/sensor.yaml``).
EUROC_IMU_NOISE = ImuNoise(gyro_noise_density=1.6968e-04, gyro_random_walk=1.9393e-05,
                           accel_noise_density=2.0000e-3, accel_random_walk=3.0000e-3)

#: Landmarks per scenario when ``n_landmarks`` is None (road: per 100 m of road).
DEFAULT_LANDMARKS = {"room": 800, "handheld": 800, "road": 200}

#: Longest simulated raw-IMU drive, camera frames (10 minutes at 20 Hz).
MAX_IMU_SIM_FRAMES = 12000

#: Largest ``imu_noise_scale``.
MAX_IMU_NOISE_SCALE = 1000.0


def _positive(name: str, value, top: float | None = None) -> None:
    if (isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(value)
            or value <= 0):
        raise InputError(f"imu simulation: {name} must be a positive number, got {value!r}")
    if top is not None and value > top:
        raise InputError(f"imu simulation: {name} must be at most {top:g}, got {value!r}")


def _nonnegative(name: str, value, top: float | None = None) -> None:
    if (isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(value)
            or value < 0):
        raise InputError(f"imu simulation: {name} must be a number >= 0, got {value!r}")
    if top is not None and value > top:
        raise InputError(f"imu simulation: {name} must be at most {top:g}, got {value!r}")


def _integer(name: str, value, lo: int, hi: int) -> None:
    if (isinstance(value, bool) or not isinstance(value, (int, np.integer))
            or not lo <= value <= hi):
        raise InputError(f"imu simulation: {name} must be an integer between {lo} and {hi}, "
                         f"got {value!r}")


def _choice(name: str, value, choices: tuple[str, ...]) -> None:
    if not isinstance(value, str) or value not in choices:
        raise InputError(f"imu simulation: {name} must be one of {', '.join(choices)}, "
                         f"got {value!r}")


@dataclass(frozen=True)
class ImuSimConfig:
    """Every setting of the raw-IMU simulator; the defaults give a 30 s monocular room drive.

    ``scene_seed`` draws the trajectory and the landmarks (None: ``seed``), ``seed`` the biases,
    the IMU noise and the pixel noise: runs of a Monte Carlo keep the scene and change the seed.
    ``sampling``: what an IMU sample holds, one of :data:`SAMPLINGS` (:mod:`eval.imu_sim`).

    ``scenario`` one of :data:`eval.imu_trajectories.SCENARIOS`; ``camera`` one of
    :data:`CAMERAS`; ``n_frames`` camera frames at ``camera_rate_hz``; the IMU at
    ``imu_rate_hz`` (an integer multiple of the camera rate: every frame is taken with an IMU
    sample); ``rest_s`` seconds standing still at the start, then a ``ramp_s`` second smooth
    start (None: the scenario's :data:`eval.imu_trajectories.DEFAULT_RAMP_S`). IMU noise:
    ``noise`` (densities and random walks, :class:`ekf.inertial.ImuNoise`), initial biases drawn with sigmas ``gyro_bias_sigma`` (rad/s) and ``accel_bias_sigma``
    (m/s^2). ``noise_free``: no white noise, zero biases and no bias walk, no pixel noise.
    Landmarks: ``n_landmarks`` (room: on the walls, floor and ceiling; road: per 100 m of road,
    both sides; None: :data:`DEFAULT_LANDMARKS`), seen within ``[min_depth, max_range]`` m
    (``max_range`` None: the scenario's, 12 m in the room, 60 m on the road) and inside the
    image.

    Faults with a known answer (:mod:`eval.imu_sim`): ``imu_time_offset`` (s) the IMU's stamps
    late against the camera's (a sample stamped ``t`` holds the motion at ``t - offset``; within
    1 s and a tenth of the drive); ``imu_noise_scale`` the IMU's white noise and bias walks are
    this many times ``noise``'s densities, which the drive's calibration still declares (an IMU
    noisier than its data sheet; the initial bias sigmas are not scaled)."""

    seed: int = 0
    scene_seed: int | None = None
    scenario: str = "room"
    camera: str = "mono"
    n_frames: int = 601
    camera_rate_hz: float = 20.0
    imu_rate_hz: float = 200.0
    rest_s: float = 2.0
    ramp_s: float | None = None
    noise: ImuNoise = field(default_factory=lambda: EUROC_IMU_NOISE)
    gyro_bias_sigma: float = 0.005
    accel_bias_sigma: float = ACCEL_TURN_ON_BIAS_SIGMA
    gravity: float = STANDARD_GRAVITY
    pixel_sigma: float = 1.0
    n_landmarks: int | None = None
    min_depth: float = 0.2
    max_range: float | None = None
    noise_free: bool = False
    sampling: str = "interval"
    name: str = ""
    imu_time_offset: float = 0.0
    imu_noise_scale: float = 1.0

    def __post_init__(self) -> None:
        _integer("seed", self.seed, 0, 2**63 - 1)
        if self.scene_seed is not None:
            _integer("scene_seed", self.scene_seed, 0, 2**63 - 1)
        _choice("scenario", self.scenario, SCENARIOS)
        _choice("camera", self.camera, CAMERAS)
        _choice("sampling", self.sampling, SAMPLINGS)
        _integer("n_frames", self.n_frames, 2, MAX_IMU_SIM_FRAMES)
        _positive("camera_rate_hz", self.camera_rate_hz, 1000.0)
        _positive("imu_rate_hz", self.imu_rate_hz, 100000.0)
        ratio = self.imu_rate_hz / self.camera_rate_hz
        if abs(ratio - round(ratio)) > 1e-9 * ratio or round(ratio) < 1:
            raise InputError(f"imu simulation: imu_rate_hz ({self.imu_rate_hz:g}) must be an "
                             f"integer multiple of camera_rate_hz ({self.camera_rate_hz:g})")
        _nonnegative("rest_s", self.rest_s, 600.0)
        if self.ramp_s is not None:
            _nonnegative("ramp_s", self.ramp_s, 600.0)
        if not isinstance(self.noise, ImuNoise):
            raise InputError(f"imu simulation: noise must be an ImuNoise, got {self.noise!r}")
        for key in ("gyro_noise_density", "gyro_random_walk", "accel_noise_density",
                    "accel_random_walk"):
            _nonnegative(f"noise.{key}", getattr(self.noise, key), 10.0)
        _nonnegative("gyro_bias_sigma", self.gyro_bias_sigma, 1.0)
        _nonnegative("accel_bias_sigma", self.accel_bias_sigma, 10.0)
        _positive("gravity", self.gravity, 100.0)
        _nonnegative("pixel_sigma", self.pixel_sigma, 1000.0)
        if self.n_landmarks is not None:
            _integer("n_landmarks", self.n_landmarks, 1, 1_000_000)
        _positive("min_depth", self.min_depth, 1e4)
        if self.max_range is not None:
            _positive("max_range", self.max_range, 1e4)
            if self.max_range <= self.min_depth:
                raise InputError(f"imu simulation: max_range ({self.max_range:g}) must be above "
                                 f"min_depth ({self.min_depth:g})")
        if not isinstance(self.noise_free, bool):
            raise InputError(f"imu simulation: noise_free must be true or false, "
                             f"got {self.noise_free!r}")
        object.__setattr__(self, "imu_time_offset", check_time_offset(
            "imu simulation", "imu_time_offset", self.imu_time_offset, self.duration_s))
        _positive("imu_noise_scale", self.imu_noise_scale, MAX_IMU_NOISE_SCALE)
        object.__setattr__(self, "imu_noise_scale", float(self.imu_noise_scale))
        if not isinstance(self.name, str):
            raise InputError(f"imu simulation: name must be a string, got {self.name!r}")

    @property
    def scene(self) -> int:
        """The seed of the trajectory and the landmarks."""
        return int(self.seed if self.scene_seed is None else self.scene_seed)

    @property
    def ramp(self) -> float:
        """The ramp from rest to full motion, s."""
        return DEFAULT_RAMP_S[self.scenario] if self.ramp_s is None else float(self.ramp_s)

    @property
    def landmark_count(self) -> int:
        """``n_landmarks`` or the scenario's default."""
        if self.n_landmarks is None:
            return DEFAULT_LANDMARKS[self.scenario]
        return int(self.n_landmarks)

    @property
    def frame_stride(self) -> int:
        """IMU samples per camera frame."""
        return int(round(self.imu_rate_hz / self.camera_rate_hz))

    @property
    def duration_s(self) -> float:
        return (self.n_frames - 1) / self.camera_rate_hz

    @property
    def stereo(self) -> bool:
        return self.camera == "stereo"

    @property
    def drive_name(self) -> str:
        return self.name or f"imu-{self.scenario}-{self.camera}-{self.seed}"
