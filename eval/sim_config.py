"""The simulator's settings (:class:`SimConfig`, every one checked where it is made) and the
KITTI constants the simulated drive is made with. The drive itself: :mod:`eval.simulate`."""

from __future__ import annotations

import numbers
from dataclasses import dataclass

import numpy as np

from vislam.ekf.errors import InputError

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

#: Longest simulated drive (KITTI's longest sequence has about 4500 frames).
MAX_SIM_FRAMES = 20000
#: Upper end (excluded) of ``SimConfig.pixel_correlation`` and ``velocity_correlation``.
MAX_CORRELATION = 0.99
#: Upper bounds of the settings: beyond them a drive is no longer KITTI-like, and squares of
#: the noise levels would overflow.
SIM_UPPER_BOUNDS = {
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
#: The shapes of drive the simulator makes (module docstring of :mod:`eval.simulate`): "road"
#: (the KITTI-like drive, tracks never return), "loop" (a car that drives a closed loop and sees
#: its first landmarks again at the end), "room" (a platform in a room, every landmark seen again
#: and again, stops included).
SIM_SCENARIOS = ("road", "loop", "room")
#: Each scenario's defaults where they differ from :class:`SimConfig`'s (the road's):
#: :func:`scenario_config` applies them. The room's platform moves at up to ``speed_max`` m/s
#: and turns at up to ``max_yaw_rate`` rad/s; its landmarks are 1-12 m deep; its velocity noise
#: (0.15 m/s, 0.03 rad/s per sample) makes dead reckoning drift about 1 m over 2,000 frames, as
#: on the real room drive of issue 36 (aligned ATE 0.83 m).
SCENARIO_DEFAULTS: dict[str, dict] = {
    "road": {},
    "loop": {"max_pitch_deg": 0.0},
    "room": {
        "speed_min": 0.1, "speed_max": 0.7, "max_yaw_rate": 0.8, "max_pitch_deg": 0.0,
        "velocity_sigma": 0.15, "gyro_sigma": 0.03, "min_depth": 1.0, "max_depth": 12.0,
        "mean_track_length": 20.0,
    },
}
#: Largest file-extrinsic offset: translation (m) and rotation (rad) components.
_MAX_OFFSET_M, _MAX_OFFSET_RAD = 100.0, 3.0
#: Largest time offset of a motion stream against the camera (s); it must also be at most a
#: tenth of the drive (TIME_OFFSET_SHARE of its duration).
MAX_TIME_OFFSET_S = 1.0
TIME_OFFSET_SHARE = 0.1


def check_time_offset(what: str, key: str, value, duration_s: float) -> float:
    """A stream's time offset (s) as a float: finite, within MAX_TIME_OFFSET_S and a tenth of
    the drive's ``duration_s``; InputError naming ``key`` otherwise."""
    top = min(MAX_TIME_OFFSET_S, TIME_OFFSET_SHARE * duration_s)
    if (isinstance(value, bool) or not isinstance(value, numbers.Real)
            or not np.isfinite(value) or abs(value) > top):
        raise InputError(f"{what}: {key} must be a number of seconds within +-{top:g} (at most "
                         f"{MAX_TIME_OFFSET_S:g} s and a tenth of the {duration_s:g} s drive), "
                         f"got {value!r}")
    return float(value)


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
    #: The drive's shape: SIM_SCENARIOS (:func:`scenario_config` gives each one's defaults).
    scenario: str = "road"
    #: room: the floor (x, y), m, centred on the start; landmarks on its walls; the share of
    #: the platform's waypoints where it stops (1-4 s at zero velocity).
    room_size: tuple[float, float] = (10.0, 8.0)
    room_landmarks: int = 50
    stop_probability: float = 0.5
    #: loop: the share of the loop driven a second time at the end of the drive (the drive is
    #: ``1 + loop_overlap`` laps).
    loop_overlap: float = 0.15
    #: Time offsets (s) of the linear-velocity and the angular-velocity streams against the
    #: camera, positive when the stream's stamps are late: the sample stamped ``t_k`` holds the
    #: motion at ``t_k - offset`` (eval.simulate's module docstring). Within
    #: MAX_TIME_OFFSET_S and a tenth of the drive.
    velocity_time_offset: float = 0.0
    gyro_time_offset: float = 0.0

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
        for key, top in SIM_UPPER_BOUNDS.items():
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
        duration = (self.n_frames - 1) / self.rate_hz
        for key in ("velocity_time_offset", "gyro_time_offset"):
            object.__setattr__(self, key, check_time_offset("simulation", key, getattr(self, key),
                                                            duration))
        self._check_scenario()

    def _check_scenario(self) -> None:
        if self.scenario not in SIM_SCENARIOS:
            raise InputError(f"simulation: scenario must be one of {', '.join(SIM_SCENARIOS)}, "
                             f"got {self.scenario!r}")
        try:
            size = np.asarray(self.room_size, dtype=float)
        except (TypeError, ValueError):
            size = np.zeros(0)
        if size.shape != (2,) or not np.all((size >= 3.0) & (size <= 100.0)):
            raise InputError(f"simulation: room_size must be 2 numbers (x, y) in [3, 100] m, got "
                             f"{self.room_size!r}")
        object.__setattr__(self, "room_size", tuple(float(x) for x in size))
        if isinstance(self.room_landmarks, bool) or not isinstance(self.room_landmarks, (int, np.integer)) \
                or not 4 <= self.room_landmarks <= 100000:
            raise InputError(f"simulation: room_landmarks must be an integer in [4, 100000], got "
                             f"{self.room_landmarks!r}")
        for key in ("stop_probability", "loop_overlap"):
            value = getattr(self, key)
            if not isinstance(value, numbers.Real) or not 0.0 <= value <= 1.0:
                raise InputError(f"simulation: {key} must be in [0, 1], got {value!r}")


def scenario_config(scenario: str = "road", **settings) -> SimConfig:
    """A :class:`SimConfig` of ``scenario`` (SIM_SCENARIOS) with that scenario's defaults
    (SCENARIO_DEFAULTS), then ``settings`` on top; ``scenario_config()`` is ``SimConfig()``."""
    if scenario not in SCENARIO_DEFAULTS:
        raise InputError(f"simulation: scenario must be one of {', '.join(SIM_SCENARIOS)}, "
                         f"got {scenario!r}")
    return SimConfig(**{**SCENARIO_DEFAULTS[scenario], **settings, "scenario": scenario})


#: The benchmark's default simulated drive (seed 0, 600 frames).
DEFAULT_SIM = SimConfig()
