"""The model of a drive: what is identified about it, used by every estimator on it.

A :class:`Model` holds the noise levels, the gyro bias, which velocity sample covers an
interval and the camera-IMU extrinsic of one drive (DESIGN.md, "The model is part of the
data"). It is read and written as a TOML ``[model]`` table, with the file's own values beside
it in an optional ``[file]`` table (same keys, all optional) so that a report can say where the
two disagree::

    [model]
    source = "vislam calibrate 0027.npz"
    velocity_sigma = [0.05, 0.05, 0.05]         # m/s, x y z of the IMU body frame
    gyro_sigma = [0.005, 0.005, 0.005]          # rad/s
    pixel_sigma = 0.3                           # px, each of uL vL uR vR (white)
    pixel_correlation_time = 5.3                # frames; absent: errors independent along a track
    velocity_correlation_time = [1.0, 30.0, 8.0]  # frames, x y z; absent: white velocity errors
    gyro_correlation_time = [1.0, 1.0, 1.0]       # frames, x y z; absent: white gyro errors
    velocity_sigma_log_sd = [0.05, 0.3, 2.0]    # sd of log velocity_sigma, x y z (optional)
    gyro_sigma_log_sd = [0.05, 0.05, 0.05]      # sd of log gyro_sigma (optional)
    noise_undetermined = ["velocity_sigma_z", "velocity_correlation_time_x"]  # conservative values
    gyro_bias = [0.001, -0.002, 0.0005]         # rad/s; absent: the data supports none
    gyro_bias_sigma = [1e-4, 1e-4, 1e-4]        # rad/s (optional, informative)
    radial_k1 = 0.01                            # lens radial term; absent: the data supports none
    radial_k1_sigma = 0.001                     # (optional, informative)
    velocity_time_offset = 0.03                 # s, linear-velocity stamps late; absent: none
    velocity_time_offset_sigma = 0.002          # s (optional, informative)
    gyro_time_offset = -0.01                    # s, angular-velocity stamps late; absent: none
    gyro_time_offset_sigma = 0.001              # s (optional, informative)
    velocity_pairing = "next"                   # "current", "next" or "mean"
    cam_T_imu = [                               # 4x4, rows; rigid
        [r11, r12, r13, tx], [r21, r22, r23, ty], [r31, r32, r33, tz], [0.0, 0.0, 0.0, 1.0],
    ]
    cam_T_imu_sigma = [0.01, 0.01, 0.5, 1e-3, 1e-3, 1e-3]  # translation (m) then rotation (rad)
    cam_T_imu_undetermined = ["tz"]             # components the drive cannot determine

    [file]
    cam_T_imu = [...]                           # the data file's matrix

The extrinsic's uncertainty. ``cam_T_imu_sigma`` are the standard deviations of a
perturbation of ``cam_T_imu``: translation ``[tx, ty, tz]`` (m, of the translation column)
then rotation ``[rx, ry, rz]`` (rad, a rotation vector applied on the left,
``R_true = so3_exp([rx, ry, rz]) @ R``). It is None (absent) when the extrinsic was not
estimated (taken from the file, or known exactly as in simulation). A component the drive
cannot determine (the vertical lever arm of a planar drive, say) is named in
``cam_T_imu_undetermined`` (names from EXTRINSIC_COMPONENTS); its value in ``cam_T_imu`` is
then the file's or the prior's, and its sigma, if one is given, is no confident figure
(:meth:`Model.extrinsic_sigmas` reports it as inf). TOML can write inf, but every other
setting refuses it, so the list is the one representation of "undetermined".

Validation is as strict as ekf.config's: every key checked for type, finiteness and range;
errors are :class:`ekf.errors.InputError` naming the file, the table and the key
(``m.toml [model]: setting 'pixel_sigma' must be ..., got -1``); unknown and missing keys are
named too. ``Model.to_toml()`` writes the small TOML subset needed (numbers with ``repr``
precision, so a model reads back exactly equal).

Pixel errors correlated along a track. ``pixel_sigma`` is the sigma of one observation's
error; ``pixel_correlation_time`` (tau >= 1, :mod:`graph.track_correlation`) says how many
consecutive observations of a track one independent one is worth: a tracker's errors drift
slowly along a track. The estimators treat observations as independent, so they use the
error's long-run sigma, ``pixel_sigma * sqrt(tau)`` (:func:`model_config`). Absent: 1.

Velocity and gyro errors correlated in time. ``velocity_sigma`` and ``gyro_sigma`` are the
white sigmas of one sample; ``velocity_correlation_time`` and ``gyro_correlation_time`` (per
axis, >= 1, :mod:`graph.motion_correlation`) the long-run variance of an interval's twist noise
over its white variance: a velocity source's errors drift slowly, and a drive's drift is built
from their slow part. The estimators treat intervals as independent, so they use the long-run
interval sigma, the interval sigma times ``sqrt(tau)`` (:func:`model_config`). Absent: the
pairing's own ratio for white samples, :func:`white_sample_ratio` (2 under "mean", whose two
consecutive intervals share a sample; 1 otherwise), which is also the least any axis takes.

What the drive cannot determine (issue 34). ``noise_undetermined`` names the noise levels
(:data:`NOISE_LEVELS`: ``velocity_sigma_x`` ... ``gyro_correlation_time_z``) that the drive
does not determine (:mod:`graph.parameter_uncertainty`: where vision barely constrains the
motion, EM's fixed point is flat); their values are then conservative, not point estimates:
the upper end of what the data allow, capped by the samples' own second differences (white
sigmas) or by a prior on slow speed errors (long-run ratios). ``velocity_sigma_log_sd`` and
``gyro_sigma_log_sd`` are the data's standard deviations of each log sigma; the estimators
widen a determined sigma by ``exp(sd^2)`` (:func:`sigma_widening`), so that a model fitted to
a few tracks a frame is not used as if it were known. Absent: no widening, nothing
undetermined (a model written by hand, or before issue 34).

The radial term. ``radial_k1`` is a lens distortion the file's pixels carry beyond its pinhole
``K``: ``x_d = x (1 + k1 r^2)`` in normalised coordinates about the principal point
(:mod:`ekf.camera`). It is absent when the data support none.

Time offsets. ``velocity_time_offset`` and ``gyro_time_offset`` (s, within
+-MAX_TIME_OFFSET) say how late the linear-velocity and the angular-velocity streams' stamps are
against the camera's: a sample stamped ``t`` was measured at ``t - offset``, so the stream's
value at camera time ``t`` is its value at stamp ``t + offset``. :func:`model_sequence`
resamples each stream so (:func:`time_shifted`: linear interpolation in time over the stream's
own stamps; beyond its first or last stamp the end sample is held, not extrapolated). Absent (or
zero): the stream is taken as stamped, unchanged to the bit. ``*_time_offset_sigma`` are their
standard deviations when identified. The offsets and ``velocity_pairing`` describe different
things and do not fight: the pairing says which samples cover the interval ``[t_k, t_k+1]``
once the streams are on the camera's clock ("current" sample k, "next" sample k+1, "mean" the
two), a shift by whole or half intervals; the offset is the remaining continuous shift of the
stamps, measured with the pairing the model has (the resampling comes first, then the pairing
is applied to the resampled samples). A stream whose samples are in truth "mean"-paired (sample k
the twist at ``t_k``) but read as "current" (sample k the twist of the interval's middle) looks
half an interval late, and read as "next" half an interval early: an identified offset near
half an interval is the sign of a pairing the model got wrong.

Using a model (:func:`apply_model`): the sequence gets the model's ``cam_T_imu``, has its
velocity streams moved onto the camera's clock by the model's time offsets (if any), the
model's gyro bias subtracted from its angular velocities and its radial term removed from its
pixels (:func:`ekf.camera.undistort_pixels`); the config gets the model's velocity
and gyro sigmas, long-run pixel sigma and velocity pairing. A model with a bias leaves
``config.gyro_bias`` (estimating a residual bias, from zero) as the config says, with the
model's ``gyro_bias_sigma`` as its prior where the model has one (the largest axis); a model
saying "no bias" sets ``gyro_bias=False``. Ground truth must be converted
with the same extrinsic (eval.groundtruth ``GroundTruth.with_extrinsic``).
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from vislam.ekf.config import (
    FILTER_RULES,
    SIGMA_MIN,
    FilterConfig,
    Rule,
    per_axis,
    settings_tables,
    show_path,
    show_value,
    sigma,
    sigma3,
)
from vislam.ekf.errors import InputError
from vislam.ekf.geometry import is_rigid

#: Names of the six extrinsic components, in the order of ``cam_T_imu_sigma``.
#: How every model file vislam writes begins (a file that does not is the user's).
MODEL_FILE_HEADER = "# The model of a drive (vislam"
EXTRINSIC_COMPONENTS = ("tx", "ty", "tz", "rx", "ry", "rz")
#: Rigidity tolerance of ``cam_T_imu`` (the loader's: files carry it to about 1e-7).
MODEL_RIGID_TOL = 1e-5
#: Largest translation accepted in ``cam_T_imu`` (m).
MAX_LEVER_ARM = 1e3
#: Largest gyro bias accepted (rad/s), as the simulator's.
MAX_GYRO_BIAS = 10.0
#: Largest radial coefficient accepted (normalised coordinates; KITTI's raw lenses: about 0.37).
MAX_RADIAL_K1 = 1.0
#: Largest pixel correlation time accepted (frames; graph.track_correlation sums at most 30
#: lags, so it reports at most 61).
MAX_PIXEL_CORRELATION_TIME = 1000.0
#: Largest velocity or gyro correlation time accepted (frames: the long-run variance over the
#: white interval variance, graph.motion_correlation).
MAX_MOTION_CORRELATION_TIME = 1e6
#: Names of the noise levels a drive may leave undetermined (``noise_undetermined``): the white
#: per-sample sigmas and the long-run ratios (correlation times), per axis.
NOISE_LEVELS = tuple(f"{key}_{axis}" for key in ("velocity_sigma", "gyro_sigma",
                                                 "velocity_correlation_time",
                                                 "gyro_correlation_time")
                     for axis in "xyz")
#: Largest standard deviation of a log sigma accepted (graph.parameter_uncertainty.MAX_LOG_SD).
MAX_LOG_SIGMA_SD = 10.0
#: Largest sd of a log sigma that widens a determined sigma: graph.parameter_uncertainty's
#: UNDETERMINED_LOG_SD (above it a level is undetermined and not widened).
MAX_WIDENED_LOG_SD = 0.15
#: Largest stream time offset accepted (s), as the simulator's (eval.sim_config).
MAX_TIME_OFFSET = 1.0
#: Longest ``source`` text.
MAX_SOURCE_CHARS = 10_000
#: FilterConfig fields a model sets (``gyro_bias`` only when the model says "no bias").
MODEL_CONFIG_FIELDS = ("velocity_sigma", "gyro_sigma", "pixel_sigma", "velocity_pairing")


# --- checks of one key -------------------------------------------------------------------------


def _items(value: Any) -> list | None:
    """The elements of an array (a list, a tuple, a numpy array's first axis), else None."""
    if isinstance(value, (list, tuple)):
        return list(value)
    if isinstance(value, np.ndarray) and value.ndim >= 1:
        return list(value)
    return None


def _vector(value: Any, rule: Rule, n: int, what: str) -> tuple[float, ...]:
    """``n`` numbers each allowed by ``rule``; ValueError "must be ..., got ..." otherwise."""
    items = _items(value)
    if items is not None and len(items) == n:
        try:
            return tuple(rule.check(x) for x in items)
        except ValueError:
            pass
    raise ValueError(f"must be {what}, got {show_value(value)}")


def _check_sigma3(value: Any) -> tuple[float, float, float]:
    rule = sigma3(1e3)
    try:
        out = rule.check(value)
    except ValueError:
        raise ValueError(f"must be an array of 3 positive numbers from {SIGMA_MIN:g} to 1000 "
                         f"(x, y, z; one number means every axis), got {show_value(value)}") from None
    return tuple(float(x) for x in per_axis(out))


def _check_pixel_sigma(value: Any) -> float:
    return FILTER_RULES["pixel_sigma"].check(value)


def _check_correlation_time(value: Any) -> float:
    return Rule("float", 1.0, MAX_PIXEL_CORRELATION_TIME).check(value)


def _check_motion_correlation_time(value: Any) -> tuple[float, float, float]:
    return _vector(value, Rule("float", 1.0, MAX_MOTION_CORRELATION_TIME), 3,
                   f"an array of 3 numbers from 1 to {MAX_MOTION_CORRELATION_TIME:g} (frames, x y z)")


def _check_pairing(value: Any) -> str:
    return FILTER_RULES["velocity_pairing"].check(value)


def _check_bias(value: Any) -> tuple[float, float, float]:
    return _vector(value, Rule("float", -MAX_GYRO_BIAS, MAX_GYRO_BIAS), 3,
                   f"an array of 3 numbers within +-{MAX_GYRO_BIAS:g} rad/s (absent: no bias)")


def _check_bias_sigma(value: Any) -> tuple[float, float, float]:
    return _vector(value, sigma(1e3), 3,
                   f"an array of 3 positive numbers from {SIGMA_MIN:g} to 1000 rad/s")


def _check_radial(value: Any) -> float:
    return Rule("float", -MAX_RADIAL_K1, MAX_RADIAL_K1).check(value)


def _check_radial_sigma(value: Any) -> float:
    return sigma(1e3).check(value)


def _check_time_offset(value: Any) -> float:
    return _number(value, Rule("float", -MAX_TIME_OFFSET, MAX_TIME_OFFSET),
                   f"a number of seconds within +-{MAX_TIME_OFFSET:g} (positive: the stream's "
                   "stamps late against the camera's; absent: none)")


def _check_time_offset_sigma(value: Any) -> float:
    return _number(value, sigma(MAX_TIME_OFFSET),
                   f"a positive number of seconds from {SIGMA_MIN:g} to {MAX_TIME_OFFSET:g}")


def _number(value: Any, rule: Rule, what: str) -> float:
    """One number allowed by ``rule``; ValueError "must be ..., got ..." otherwise."""
    try:
        return float(rule.check(value))
    except ValueError:
        raise ValueError(f"must be {what}, got {show_value(value)}") from None


def _check_extrinsic_sigma(value: Any) -> tuple[float, ...]:
    return _vector(value, sigma(1e6), 6,
                   f"an array of 6 positive numbers from {SIGMA_MIN:g} to 1e+06 (translation m, "
                   "then rotation rad)")


def _check_matrix(value: Any) -> np.ndarray:
    what = ("a rigid 4x4 transform, 4 arrays (rows) of 4 numbers (rotation orthonormal with "
            f"det +1, last row 0 0 0 1, translation within {MAX_LEVER_ARM:g} m)")
    rows = _items(value)
    if rows is None or len(rows) != 4:
        raise ValueError(f"must be {what}, got {show_value(value)}")
    number = Rule("float", -MAX_LEVER_ARM, MAX_LEVER_ARM)
    try:
        m = np.array([_vector(r, number, 4, "") for r in rows], dtype=float)
    except ValueError:
        raise ValueError(f"must be {what}, got {show_value(value)}") from None
    if not is_rigid(m, tol=MODEL_RIGID_TOL):
        raise ValueError(f"must be {what}, got a matrix that is not rigid")
    m.setflags(write=False)
    return m


def _check_undetermined(value: Any) -> tuple[str, ...]:
    what = ("an array of distinct names from " + ", ".join(repr(c) for c in EXTRINSIC_COMPONENTS))
    if isinstance(value, (list, tuple)) and all(isinstance(v, str) for v in value) \
            and all(v in EXTRINSIC_COMPONENTS for v in value) and len(set(value)) == len(value):
        return tuple(c for c in EXTRINSIC_COMPONENTS if c in value)  # canonical order
    raise ValueError(f"must be {what}, got {show_value(value)}")


def _check_log_sd(value: Any) -> tuple[float, float, float]:
    return _vector(value, Rule("float", 0.0, MAX_LOG_SIGMA_SD), 3,
                   f"an array of 3 numbers from 0 to {MAX_LOG_SIGMA_SD:g} (x, y, z)")


def _check_noise_undetermined(value: Any) -> tuple[str, ...]:
    if isinstance(value, (list, tuple)) and all(isinstance(v, str) for v in value) \
            and all(v in NOISE_LEVELS for v in value) and len(set(value)) == len(value):
        return tuple(c for c in NOISE_LEVELS if c in value)  # canonical order
    raise ValueError("must be an array of distinct names from "
                     + ", ".join(repr(c) for c in NOISE_LEVELS) + f", got {show_value(value)}")


def _check_speed_scale_sigma(value: Any) -> float:
    return FILTER_RULES["speed_scale_sigma"].check(value)


def _check_speed_scale_walk(value: Any) -> float:
    return FILTER_RULES["speed_scale_walk"].check(value)


def _check_source(value: Any) -> str:
    if isinstance(value, str) and len(value) <= MAX_SOURCE_CHARS:
        return value
    raise ValueError(f"must be text of at most {MAX_SOURCE_CHARS} characters, "
                     f"got {show_value(value)}")


#: The check of every key of a ``[model]`` table, in the order to_toml writes them.
MODEL_CHECKS = {
    "source": _check_source,
    "velocity_sigma": _check_sigma3,
    "gyro_sigma": _check_sigma3,
    "pixel_sigma": _check_pixel_sigma,
    "pixel_correlation_time": _check_correlation_time,
    "velocity_correlation_time": _check_motion_correlation_time,
    "gyro_correlation_time": _check_motion_correlation_time,
    "velocity_sigma_log_sd": _check_log_sd,
    "gyro_sigma_log_sd": _check_log_sd,
    "noise_undetermined": _check_noise_undetermined,
    "speed_scale_sigma": _check_speed_scale_sigma,
    "speed_scale_walk": _check_speed_scale_walk,
    "gyro_bias": _check_bias,
    "gyro_bias_sigma": _check_bias_sigma,
    "radial_k1": _check_radial,
    "radial_k1_sigma": _check_radial_sigma,
    "velocity_time_offset": _check_time_offset,
    "velocity_time_offset_sigma": _check_time_offset_sigma,
    "gyro_time_offset": _check_time_offset,
    "gyro_time_offset_sigma": _check_time_offset_sigma,
    "velocity_pairing": _check_pairing,
    "cam_T_imu": _check_matrix,
    "cam_T_imu_sigma": _check_extrinsic_sigma,
    "cam_T_imu_undetermined": _check_undetermined,
}
#: Keys a ``[model]`` table must have (the others are optional).
REQUIRED_KEYS = ("velocity_sigma", "gyro_sigma", "pixel_sigma", "velocity_pairing", "cam_T_imu")


def _check_table(data: Any, source: str, required: tuple[str, ...]) -> dict:
    """A ``[model]`` or ``[file]`` table checked key by key (InputError naming ``source`` and
    the key); values normalised."""
    if not isinstance(data, Mapping):
        raise InputError(f"{source}: expected a table of model settings, got {show_value(data)}")
    for key, value in data.items():
        if key not in MODEL_CHECKS:
            kind = "table" if isinstance(value, Mapping) else "setting"
            raise InputError(f"{source}: unknown {kind} {key!r} (valid model settings: "
                             f"{', '.join(MODEL_CHECKS)})")
    for key in required:
        if key not in data:
            raise InputError(f"{source}: missing setting {key!r} (a model needs "
                             f"{', '.join(required)})")
    return _check_values(data, f"{source}: setting")


def _check_values(data: Mapping, label: str) -> dict:
    out = {}
    for key, value in data.items():
        try:
            out[key] = MODEL_CHECKS[key](value)
        except ValueError as exc:
            raise InputError(f"{label} {key!r} {exc}") from None
    return out


# --- the model ---------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Model:
    """What is identified about a drive (module docstring); every field checked like a TOML
    value. Compare with ``==`` (exact, matrices included); not hashable."""

    #: Linear-velocity noise sigma per axis (m/s), x y z of the IMU body frame.
    velocity_sigma: tuple[float, float, float]
    #: Angular-velocity noise sigma per axis (rad/s).
    gyro_sigma: tuple[float, float, float]
    #: Stereo pixel noise sigma (px).
    pixel_sigma: float
    #: Which velocity sample covers [k, k+1]: "current", "next" or "mean".
    velocity_pairing: str
    #: The camera-IMU extrinsic (4x4, rigid, read-only): p_cam = cam_T_imu @ p_imu.
    cam_T_imu: np.ndarray
    #: Constant gyro bias (rad/s, 3), or None when the data supports none.
    gyro_bias: tuple[float, float, float] | None = None
    #: Standard deviation of the identified bias (rad/s, 3), if known.
    gyro_bias_sigma: tuple[float, float, float] | None = None
    #: Radial lens term of the pixels (normalised coordinates), or None when the data
    #: support none.
    radial_k1: float | None = None
    #: Standard deviation of the identified radial term, if known.
    radial_k1_sigma: float | None = None
    #: How late the linear-velocity stream's stamps are against the camera's (s; a sample
    #: stamped t was measured at t - offset), or None when the data support none (zero is
    #: stored as None). model_sequence resamples the stream onto the camera's clock.
    velocity_time_offset: float | None = None
    #: Standard deviation of the identified velocity_time_offset (s), if known.
    velocity_time_offset_sigma: float | None = None
    #: The same for the angular-velocity (gyro) stream.
    gyro_time_offset: float | None = None
    #: Standard deviation of the identified gyro_time_offset (s), if known.
    gyro_time_offset_sigma: float | None = None
    #: Integrated correlation time of the pixel errors along a track (frames, >= 1), or None
    #: when the data support none (independent errors).
    pixel_correlation_time: float | None = None
    #: Long-run over white variance of the interval's velocity noise per axis (frames, >= 1,
    #: :mod:`graph.motion_correlation`), or None when the data support none.
    velocity_correlation_time: tuple[float, float, float] | None = None
    #: The same for the gyro noise.
    gyro_correlation_time: tuple[float, float, float] | None = None
    #: Standard deviation of log velocity_sigma per axis, from the data (None: unknown); the
    #: estimators widen a determined sigma by exp(sd^2) (model_config).
    velocity_sigma_log_sd: tuple[float, float, float] | None = None
    #: The same for gyro_sigma.
    gyro_sigma_log_sd: tuple[float, float, float] | None = None
    #: Noise levels the drive cannot determine (names from NOISE_LEVELS): their values are the
    #: conservative ones graph.parameter_uncertainty takes, not point estimates.
    noise_undetermined: tuple[str, ...] = ()
    #: A slow speed-scale error of the linear velocities the estimators carry as a state
    #: (FilterConfig.speed_scale): its initial sigma (relative) and random walk
    #: (relative/sqrt(s)); None: none (the velocity noise model is the whole story).
    speed_scale_sigma: float | None = None
    speed_scale_walk: float | None = None
    #: Sigmas of the extrinsic (translation m, then rotation rad), None if not estimated.
    cam_T_imu_sigma: tuple[float, ...] | None = None
    #: Extrinsic components the drive cannot determine (names from EXTRINSIC_COMPONENTS).
    cam_T_imu_undetermined: tuple[str, ...] = ()
    #: Where the model comes from (free text).
    source: str = ""
    #: The data file's own values ([file] table): any model key, e.g. {"cam_T_imu": ...}.
    file: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        values = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)
                  if f.name != "file"}
        for key in ("gyro_bias", "gyro_bias_sigma", "radial_k1", "radial_k1_sigma",
                    "pixel_correlation_time", "velocity_correlation_time",
                    "gyro_correlation_time", "cam_T_imu_sigma", "velocity_sigma_log_sd",
                    "gyro_sigma_log_sd", "speed_scale_sigma", "speed_scale_walk",
                    "velocity_time_offset", "velocity_time_offset_sigma", "gyro_time_offset",
                    "gyro_time_offset_sigma"):
            if values[key] is None:
                del values[key]
        for name, value in _check_values(values, "model setting").items():
            object.__setattr__(self, name, value)
        for key in ("velocity_time_offset", "gyro_time_offset"):
            if getattr(self, key) == 0.0:  # absent when zero: one representation of "none"
                object.__setattr__(self, key, None)
        file_values = self.file if self.file is not None else {}
        if not isinstance(file_values, Mapping):
            raise InputError(f"model setting 'file' must be a table of the file's values, got "
                             f"{show_value(file_values)}")
        unknown = [k for k in file_values if k not in MODEL_CHECKS]
        if unknown:
            raise InputError(f"model [file]: unknown setting {unknown[0]!r} (valid model "
                             f"settings: {', '.join(MODEL_CHECKS)})")
        object.__setattr__(self, "file", _check_values(
            {k: v for k, v in file_values.items() if v is not None}, "model [file] setting"))

    # --- derived ------------------------------------------------------------------------
    @property
    def has_bias(self) -> bool:
        return self.gyro_bias is not None

    def extrinsic_sigmas(self) -> np.ndarray:
        """Sigmas (6,) of the extrinsic, inf for undetermined components, nan when the
        extrinsic was not estimated."""
        out = np.full(6, np.nan) if self.cam_T_imu_sigma is None \
            else np.array(self.cam_T_imu_sigma, dtype=float)
        for name in self.cam_T_imu_undetermined:
            out[EXTRINSIC_COMPONENTS.index(name)] = np.inf
        return out

    def replace(self, **changes) -> "Model":
        """A copy with ``changes`` applied (validated)."""
        known = {f.name for f in dataclasses.fields(self)}
        unknown = sorted(set(changes) - known)
        if unknown:
            raise InputError(f"unknown model setting(s): {', '.join(unknown)}")
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict:
        """The model as JSON-able values ([model] keys, ``file`` a dict of the [file] keys):
        matrices as lists of rows, absent values as None."""
        out = {name: _plain(getattr(self, name)) for name in MODEL_CHECKS}
        out["file"] = {k: _plain(v) for k, v in self.file.items()}
        return out

    def _canonical(self) -> tuple:
        d = self.to_dict()
        d["file"] = tuple(sorted(d["file"].items()))
        return tuple((k, _frozen(v)) for k, v in d.items())

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Model):
            return NotImplemented
        return self._canonical() == other._canonical()

    __hash__ = None  # type: ignore[assignment]

    # --- TOML ---------------------------------------------------------------------------
    @classmethod
    def from_mapping(cls, model: Mapping, source: str, file: Mapping | None = None,
                     file_source: str | None = None) -> "Model":
        """A model from a ``[model]`` table (and the ``[file]`` table, if any); ``source`` and
        ``file_source`` name them in errors."""
        values = _check_table(model, source, REQUIRED_KEYS)
        file_values = {} if file is None else _check_table(
            file, file_source or f"{source} [file]", ())
        return cls(**values, file=file_values)

    @classmethod
    def from_toml(cls, path: str | Path) -> "Model":
        """The model of TOML file ``path`` (its ``[model]`` table and optional ``[file]``
        table; a ``[filter]`` table or top-level filter settings beside them are checked as
        settings). InputError naming the file, table and key at any fault."""
        model = model_from_settings(path)
        if model is None:
            raise InputError(f"{show_path(path)}: no [model] table (a model file has a [model] "
                             "table and, optionally, a [file] table)")
        return model

    def to_toml(self) -> str:
        """The model as TOML text: a ``[model]`` table and, when the file's values are known,
        a ``[file]`` table. Reads back (``from_toml``) exactly equal."""
        lines = [f"{MODEL_FILE_HEADER}, ekf/model.py): noise sigmas per axis x y z",
                 "# (m/s, rad/s) and their correlation times (frames, absent: none), pixel",
                 "# sigma (px) and its correlation time along a track",
                 "# (frames, absent: none), gyro bias (rad/s, absent: none), radial lens term",
                 "# (absent: none), the velocity and gyro streams' time offsets (s, stamps late",
                 "# against the camera's; absent: none), velocity pairing, cam_T_imu (rows) and its sigmas",
                 "# (translation m, then rotation rad); noise_undetermined names the levels the",
                 "# drive cannot determine (their values are conservative, not estimates).",
                 "[model]"]
        lines += _toml_items(self.to_dict())
        if self.file:
            lines += ["", "# The data file's own values, for comparison.", "[file]"]
            lines += _toml_items({k: _plain(v) for k, v in self.file.items()})
        return "\n".join(lines) + "\n"

    def write_toml(self, path: str | Path) -> Path:
        """Write :meth:`to_toml` to ``path`` (UTF-8)."""
        path = Path(path)
        path.write_text(self.to_toml(), encoding="utf-8")
        return path


def _plain(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return [[float(x) for x in row] for row in value]
    if isinstance(value, tuple):
        return list(value)
    return value


def _frozen(value: Any) -> Any:
    if isinstance(value, (list, tuple)):
        return tuple(_frozen(v) for v in value)
    if isinstance(value, dict):
        return tuple(sorted((k, _frozen(v)) for k, v in value.items()))
    return value


# --- a small TOML writer -----------------------------------------------------------------------


def _toml_string(text: str) -> str:
    out = []
    for ch in text:
        if ch in '"\\':
            out.append("\\" + ch)
        elif ch == "\n":
            out.append("\\n")
        elif ch == "\t":
            out.append("\\t")
        elif ord(ch) < 0x20 or ord(ch) == 0x7F or 0xD800 <= ord(ch) <= 0xDFFF:
            out.append(f"\\u{ord(ch):04X}")
        else:
            out.append(ch)
    return '"' + "".join(out) + '"'


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, numbers.Integral):
        return str(int(value))
    if isinstance(value, numbers.Real):
        x = float(value)
        if not math.isfinite(x):
            raise ValueError(f"cannot write {x!r} to a model file")
        return repr(x)  # shortest text that reads back to the same float
    if isinstance(value, str):
        return _toml_string(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise TypeError(f"cannot write {type(value).__name__} to a model file")


def _toml_items(values: Mapping[str, Any]) -> list[str]:
    lines = []
    for key, value in values.items():
        if value is None or key == "file" or (key in ("cam_T_imu_undetermined",
                                                      "noise_undetermined") and not value):
            continue
        if key == "cam_T_imu":
            rows = ",\n".join("    " + _toml_value(row) for row in value)
            lines.append(f"{key} = [\n{rows},\n]")
        else:
            lines.append(f"{key} = {_toml_value(value)}")
    return lines


# --- reading a settings file ---------------------------------------------------------------


def model_from_settings(path: str | Path) -> Model | None:
    """The model of settings file ``path`` (its ``[model]`` and ``[file]`` tables), None when
    it has no ``[model]`` table; a ``[file]`` table alone is an error, and the file's filter
    settings are checked too (a model file is a settings file)."""
    tables = settings_tables(path)
    FilterConfig.from_mapping(*tables["filter"])
    (model, source), (file, file_source) = tables["model"], tables["file"]
    for table, where in ((model, source), (file, file_source)):
        if table is not None and not isinstance(table, dict):
            raise InputError(f"{where} must be a table of model settings, "
                             f"got {show_value(table)}")
    if model is None:
        if file is not None:
            raise InputError(f"{file_source}: a [file] table needs a [model] table beside it")
        return None
    return Model.from_mapping(model, source, file, file_source)


# --- using a model ------------------------------------------------------------------------------


def with_extrinsic(seq, cam_T_imu: np.ndarray):
    """``seq`` with ``cam_T_imu`` as its extrinsic (``calibration.cam_T_imu``)."""
    return dataclasses.replace(seq, calibration=dataclasses.replace(
        seq.calibration, cam_T_imu=np.array(cam_T_imu, dtype=float)))


def time_shifted(timestamps: np.ndarray, values: np.ndarray, offset: float) -> np.ndarray:
    """A stream (T, n) stamped ``timestamps`` (T,) whose stamps are ``offset`` s late, on the
    camera's clock: row k is the stream's value at stamp ``timestamps[k] + offset``, linearly
    interpolated between the stream's own stamps; before its first or after its last stamp the
    end sample is held (no extrapolation: an end frame's error is at most the stream's change
    over ``offset``, where extrapolating would double its noise)."""
    t = np.asarray(timestamps, dtype=float)
    v = np.asarray(values, dtype=float)
    q = t + float(offset)
    return np.stack([np.interp(q, t, v[:, j]) for j in range(v.shape[1])], axis=1)


def model_sequence(seq, model: Model):
    """``seq`` with the model's extrinsic as ``calibration.cam_T_imu``, its linear and angular
    velocities moved onto the camera's clock by the model's time offsets (if any,
    :func:`time_shifted`; the pairing then applies to the moved samples), the model's gyro
    bias (if any) subtracted from the angular velocities and its radial term (if any) removed
    from the pixels. Apply once per sequence."""
    seq = with_extrinsic(seq, model.cam_T_imu)
    if model.radial_k1 is not None:
        seq = without_radial(seq, model.radial_k1)
    if model.velocity_time_offset is not None:
        seq = dataclasses.replace(seq, linear_velocity=time_shifted(
            seq.timestamps, seq.linear_velocity, model.velocity_time_offset))
    if model.gyro_time_offset is not None:
        seq = dataclasses.replace(seq, angular_velocity=time_shifted(
            seq.timestamps, seq.angular_velocity, model.gyro_time_offset))
    if model.gyro_bias is None:
        return seq
    return dataclasses.replace(seq, angular_velocity=np.asarray(seq.angular_velocity, dtype=float)
                               - np.asarray(model.gyro_bias)[None, :])


def without_radial(seq, k1: float):
    """``seq`` with the radial term ``k1`` removed from its pixels
    (:func:`ekf.camera.undistort_pixels`); InputError where ``k1`` folds its image over."""
    from vislam.ekf.camera import undistort_pixels

    try:
        z = undistort_pixels(seq.obs.z, np.asarray(seq.calibration.K, dtype=float), float(k1))
    except ValueError as exc:
        raise InputError(f"model setting 'radial_k1': {exc}") from None
    return dataclasses.replace(seq, obs=dataclasses.replace(seq.obs, z=z))


def interval_sigma_factor(pairing: str) -> float:
    """Sigma of an interval's twist noise / sigma of one velocity sample: 1/sqrt(2) for the
    "mean" pairing (the mean of two independent samples), 1 otherwise. A model's sigmas are
    per sample (what a data sheet or the simulator states); the estimators' velocity
    covariance is per interval."""
    return math.sqrt(0.5) if pairing == "mean" else 1.0


def white_sample_ratio(pairing: str) -> float:
    """The long-run over white variance of the interval twist noise that white samples give
    under ``pairing``: 2 for "mean" (intervals k and k + 1 share sample k + 1, so their errors
    correlate by a half: ``1 + 2 * 0.5``), 1 otherwise. Estimators that treat intervals as
    independent need the long-run sigma, the sample's own under "mean"; the interval's white
    sigma (:func:`interval_sigma_factor`) left them half the variance over any stretch
    (docs/findings.md, "The mean pairing's intervals are not independent")."""
    return 1.0 / interval_sigma_factor(pairing) ** 2


def ar1_coefficient(correlation_time: float | None) -> float:
    """The per-frame correlation ``a = (tau - 1) / (tau + 1)`` of AR(1) errors whose integrated
    correlation time is ``tau = (1 + a) / (1 - a)`` (module docstring); 0 (white) for None or
    ``tau <= 1``."""
    if correlation_time is None or correlation_time <= 1.0:
        return 0.0
    return (correlation_time - 1.0) / (correlation_time + 1.0)


def long_run_pixel_sigma(pixel_sigma: float, correlation_time: float | None) -> float:
    """The pixel sigma the estimators use: ``pixel_sigma * sqrt(tau)`` for errors correlated
    along a track over ``tau`` frames (module docstring), ``pixel_sigma`` for none."""
    return pixel_sigma * math.sqrt(correlation_time or 1.0)


def sigma_widening(model: Model, kind: str) -> tuple[float, float, float]:
    """The factor per axis on the ``kind`` ("velocity" or "gyro") sigma for its own
    uncertainty: ``exp(sd^2)``, ``sd`` the model's ``<kind>_sigma_log_sd`` (a Gaussian whose log
    sigma is uncertain by ``sd`` has, averaged over it, the variance ``sigma^2 exp(2 sd^2)``);
    1 where the sd is unknown or the axis's sigma or long-run ratio is undetermined (its value
    is already the conservative one, graph.parameter_uncertainty)."""
    sd = getattr(model, f"{kind}_sigma_log_sd")
    if sd is None:
        return (1.0, 1.0, 1.0)
    out = []
    for axis, s in zip("xyz", sd):
        undetermined = (f"{kind}_sigma_{axis}" in model.noise_undetermined
                        or f"{kind}_correlation_time_{axis}" in model.noise_undetermined)
        out.append(1.0 if undetermined else math.exp(min(s, MAX_WIDENED_LOG_SD) ** 2))
    return tuple(out)


def model_config(config: FilterConfig, model: Model) -> FilterConfig:
    """``config`` with the model's noise model: velocity and gyro sigmas per axis (per
    interval: the model's per-sample sigmas times :func:`interval_sigma_factor`, the covariance
    ``vislam calibrate`` fitted, times sqrt of the velocity's and gyro's correlation times, each
    at least the pairing's :func:`white_sample_ratio`: the long-run interval sigma, module
    docstring, and times :func:`sigma_widening` for the sigma's own uncertainty), the pixel
    sigma times sqrt of its correlation time along a track (the long-run sigma, module
    docstring) and the AR(1) coefficient of that correlation (``pixel_ar1``, read by
    ekf-joint's ``pixel_reading = "ar1"``), velocity pairing; ``gyro_bias=False`` when the
    model says the data has no bias (a model with a bias leaves ``gyro_bias`` as the config has
    it: the bias is subtracted from the data by :func:`model_sequence`, and a filter estimating
    one starts from zero, with the model's ``gyro_bias_sigma`` (the largest axis) where it has
    one)."""
    f = interval_sigma_factor(model.velocity_pairing)
    null = white_sample_ratio(model.velocity_pairing)
    v_time = tuple(max(t, null) for t in (model.velocity_correlation_time or (1.0, 1.0, 1.0)))
    g_time = tuple(max(t, null) for t in (model.gyro_correlation_time or (1.0, 1.0, 1.0)))
    v_wide = sigma_widening(model, "velocity")
    g_wide = sigma_widening(model, "gyro")
    changes: dict[str, Any] = {
        "velocity_sigma": tuple(f * x * math.sqrt(t) * w
                                for x, t, w in zip(model.velocity_sigma, v_time, v_wide)),
        "gyro_sigma": tuple(f * x * math.sqrt(t) * w
                            for x, t, w in zip(model.gyro_sigma, g_time, g_wide)),
        "pixel_sigma": long_run_pixel_sigma(model.pixel_sigma, model.pixel_correlation_time),
        "pixel_ar1": ar1_coefficient(model.pixel_correlation_time),
        "velocity_pairing": model.velocity_pairing,
    }
    if model.gyro_bias is None:
        changes["gyro_bias"] = False
    elif model.gyro_bias_sigma is not None:
        # The residual bias the filters and the smoother estimate (the model's is subtracted
        # from the data) starts from the identified bias's own uncertainty, not the settings'
        # generic prior: on a clean drive that prior lets sparse vision turn the heading.
        changes["gyro_bias_sigma"] = max(max(model.gyro_bias_sigma), SIGMA_MIN)
    if model.speed_scale_sigma is not None:
        changes.update(speed_scale=True, speed_scale_sigma=model.speed_scale_sigma,
                       speed_scale_walk=model.speed_scale_walk or 0.0)
    return config.replace(**changes)


def per_interval_config(config: FilterConfig, model: Model) -> FilterConfig:
    """``model_config(config, model)`` (``config``, already under the model, from it) with the
    pairing's :func:`white_sample_ratio` taken back out of the velocity and gyro sigmas, axis by
    axis where the model's own correlation time is below it: the white interval sigmas that a
    test of one interval at a time (:mod:`graph.data_check`) reads, where the estimators need
    the long-run ones."""
    null = white_sample_ratio(model.velocity_pairing)
    if null == 1.0:
        return config

    def back(sigmas: np.ndarray, times) -> tuple:
        t = np.asarray(times or (1.0, 1.0, 1.0), dtype=float)
        return tuple(float(x) for x in sigmas * np.sqrt(np.maximum(t, 1.0) / np.maximum(t, null)))

    return config.replace(velocity_sigma=back(config.velocity_sigmas, model.velocity_correlation_time),
                          gyro_sigma=back(config.gyro_sigmas, model.gyro_correlation_time))


def apply_model(seq, config: FilterConfig, model: Model):
    """``(sequence, config)`` to estimate ``seq`` under ``model``: :func:`model_sequence` and
    :func:`model_config` together."""
    return model_sequence(seq, model), model_config(config, model)
