"""Filter settings: one typed dataclass with sensible defaults, from flags or a TOML file.

Noise model. The velocity noise ``w_t ~ N(0, W)`` of paper eq. 4 is in twist units
(m/s, rad/s), translation first: ``W = diag(sigma_v^2 I3, sigma_w^2 I3)``; over an interval of
length tau it enters the pose as ``tau^2 W`` (to first order). The stereo pixel noise is
``V = pixel_sigma^2 I4`` (full rank: rows 2 and 4 of M carry the same information, so a rank-3
V would make the innovation covariance singular).

Validation. Every setting (here and in graph.settings) has a :class:`Rule`; a value is checked
wherever it comes from (the constructor, ``replace``, a TOML file, a flag):

- numbers: an int is accepted where a float is expected (and stored as a float); a bool is not
  a number; a float is not accepted where an integer is expected, even an integral one
  (``blas_threads = 2.0`` is refused: TOML tells the two apart, so the file is explicit);
  strings, arrays and tables are not numbers (flags, being text, are parsed first);
- every number is finite (nan, inf, -inf and 1e400, which TOML reads as inf, are refused) and
  inside a documented range: the sigmas lie in [1e-12, upper bound] so that their squares, the
  covariances, are finite and positive definite (a sigma of 1e200 would square to inf, one of
  1e-200 to 0); the upper bounds are far beyond any sensible value (FILTER_RULES);
- probabilities lie in the open interval (0, 1); ``gate_probability`` may also be None, in a
  file or a flag written ``"none"`` or ``"off"``;
- integer counts lie in [1, bound] (``blas_threads`` <= 1024);
- choices (strings) are one of the listed values, bools are bools;
- "float3" settings (``velocity_sigma``, ``gyro_sigma``) are one number (every axis) or an
  array of three (x, y, z of the IMU body frame), each number checked as above; one number is
  stored as a float, three as a tuple of three floats (a flag writes them ``0.5,0.4,0.3``).

Errors are :class:`ekf.errors.InputError` naming the key and, for a file, the file and table
(``s.toml [filter]: setting 'pixel_sigma' must be ..., got -1``); flags are named by
eval.commands.options (``--pixel-sigma: must be ..., got -1``).
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import os
import stat
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from vislam.ekf.errors import InputError

try:  # Python 3.11+
    import tomllib
except ModuleNotFoundError:  # pragma: no cover - Python 3.10
    import tomli as tomllib  # type: ignore[no-redef]

#: Which velocity sample covers the interval [k, k+1].
VELOCITY_PAIRINGS = ("current", "next", "mean")

#: How the joint EKF linearises (ekf/joint.py): "standard" (textbook EKF), "fej" (first-estimates
#: Jacobians) or "oc" (observability-constrained: the gauge nullspace is kept consistent).
JOINT_LINEARISATIONS = ("standard", "fej", "oc")

#: How a new landmark's camera-frame point and covariance come from its first stereo pixels:
#: "linear" (``fsu b / disparity`` and ``J V J^T``) or "unscented" (ekf/camera.py
#: ``triangulate_unscented``: mean and covariance to higher order, the skewed far depths).
TRIANGULATIONS = ("linear", "unscented")

#: How ekf-joint and ekf-invariant hold a landmark in their state (ekf/inverse_depth.py):
#: "euclidean" (world x, y, z from the first observation on) or "inverse-depth" (anchored
#: inverse depth: bearing and inverse depth in the camera frame of the first observation, turned
#: into world x, y, z once Civera's linearity index falls below ``inverse_depth_linearity``).
LANDMARK_PARAMETERISATIONS = ("euclidean", "inverse-depth")

#: How ekf-joint reads a track's pixel errors, which a feature tracker correlates from frame to
#: frame (graph/track_correlation.py): "long-run", every row independent with ``pixel_sigma``
#: (the long-run sigma; what every estimator does), or "ar1", the errors as AR(1) along the
#: track with coefficient ``pixel_ar1``, whitened exactly by differencing each row against the
#: track's previous one (ekf/joint.py, "Pixel errors as AR(1)").
PIXEL_READINGS = ("long-run", "ar1")

#: Smallest standard deviation accepted: its square (1e-24) is still a normal positive float.
SIGMA_MIN = 1e-12
#: Words that switch the chi-square gate off (``gate_probability``), in a file or a flag.
NO_GATE_WORDS = ("none", "off")


# --- rules -------------------------------------------------------------------------------------


def show_value(value: Any, limit: int = 60) -> str:
    """A value as it appears in an error message: one line, at most ``limit`` characters."""
    if isinstance(value, (bool, np.bool_)):
        text = "true" if value else "false"
    elif isinstance(value, Mapping):
        text = "a table " + repr(dict(value))
    elif isinstance(value, (list, tuple)):
        text = "an array " + repr(list(value))
    else:
        text = repr(value.item() if isinstance(value, np.generic) else value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _fmt(x: float) -> str:
    return f"{x:g}"


@dataclass(frozen=True)
class Rule:
    """What one setting may hold: ``kind`` "float", "int", "bool", "choice" or "float3" (one
    number, or an array of three, each a "float" of the same bounds); numbers lie in [lo, hi]
    (``lo_open``: (lo, hi]; ``hi_open``: [lo, hi)); ``optional``: None is allowed."""

    kind: str
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False
    choices: tuple = ()
    optional: bool = False

    def describe(self) -> str:
        """What the setting must be, as the end of "must be ..."."""
        if self.kind == "float3":
            one = dataclasses.replace(self, kind="float", optional=False).describe()
            text = f"{one}, or an array of 3 such numbers (x, y, z)"
        elif self.kind == "bool":
            text = "true or false"
        elif self.kind == "choice":
            text = "one of " + ", ".join(repr(c) for c in self.choices)
        else:
            noun = "an integer" if self.kind == "int" else "a number"
            if self.kind == "float" and self.lo >= 0 and (self.lo > 0 or self.lo_open):
                noun = "a positive number"
            if self.lo_open and self.hi_open:
                if (self.lo, self.hi) == (0, 1):
                    noun = "a probability"
                text = f"{noun} in ({_fmt(self.lo)}, {_fmt(self.hi)})"
            elif self.lo_open:
                text = (f"{noun} up to {_fmt(self.hi)}" if self.lo == 0
                        else f"{noun} > {_fmt(self.lo)} and <= {_fmt(self.hi)}")
            else:
                text = f"{noun} from {_fmt(self.lo)} to {_fmt(self.hi)}"
        if self.optional:
            text += " or " + "/".join(repr(w) for w in NO_GATE_WORDS)
        return text

    def check(self, value: Any) -> Any:
        """``value`` normalised (ints to float where a float is expected, numpy scalars to
        Python ones); ValueError with "must be ..., got ..." when it is not allowed."""
        if self.optional and (value is None or (isinstance(value, str)
                                                and value.strip().lower() in NO_GATE_WORDS)):
            return None
        if self.kind == "float3":
            one = dataclasses.replace(self, kind="float", optional=False)
            if isinstance(value, (list, tuple, np.ndarray)):
                items = list(value) if not isinstance(value, np.ndarray) or value.ndim == 1 \
                    else []
                if len(items) == 3:
                    try:
                        return tuple(one.check(x) for x in items)
                    except ValueError:
                        pass
            else:
                try:
                    return one.check(value)
                except ValueError:
                    pass
        elif self.kind == "bool":
            if isinstance(value, (bool, np.bool_)):
                return bool(value)
        elif self.kind == "choice":
            if isinstance(value, str) and value in self.choices:
                return str(value)
        elif isinstance(value, (bool, np.bool_)):
            pass  # a bool is not a number
        elif self.kind == "int":
            if isinstance(value, numbers.Integral) and self._in_range(value):
                return int(value)
        elif isinstance(value, numbers.Real):
            if self._in_range(value):
                return float(value)
        raise ValueError(f"must be {self.describe()}, got {show_value(value)}")

    def _in_range(self, value) -> bool:
        # exact comparisons (a huge int never goes through float); nan fails every one
        if isinstance(value, numbers.Integral):
            value = int(value)
        elif not math.isfinite(float(value)):
            return False
        else:
            value = float(value)
        low = value > self.lo if self.lo_open else value >= self.lo
        high = value < self.hi if self.hi_open else value <= self.hi
        return bool(low and high)


def sigma(hi: float) -> Rule:
    """A standard deviation: positive, at least SIGMA_MIN, at most ``hi``."""
    return Rule("float", SIGMA_MIN, hi)


def sigma3(hi: float) -> Rule:
    """Standard deviations per axis: one number (every axis) or three (x, y, z)."""
    return Rule("float3", SIGMA_MIN, hi)


def per_axis(value: float | tuple) -> np.ndarray:
    """A "float3" setting as three numbers (3,): one number repeated, or the three given."""
    return np.broadcast_to(np.asarray(value, dtype=float), (3,)).copy()


#: The rule of every FilterConfig field, in field order (units and bounds in the comments).
FILTER_RULES: dict[str, Rule] = {
    "pixel_sigma": sigma(1e4),  # px; images are ~1242 px wide
    "velocity_sigma": sigma3(1e3),  # m/s, one or per axis (x, y, z)
    "gyro_sigma": sigma3(1e3),  # rad/s, one or per axis (x, y, z)
    "initial_position_sigma": sigma(1e6),  # m
    "initial_rotation_sigma": sigma(1e3),  # rad
    "gate_probability": Rule("float", 0.0, 1.0, lo_open=True, hi_open=True, optional=True),
    "clean_tracks": Rule("bool"),
    "min_disparity": Rule("float", 0.0, 1e4),  # px
    "max_depth": Rule("float", 0.0, 1e6, lo_open=True),  # m
    "velocity_pairing": Rule("choice", choices=VELOCITY_PAIRINGS),
    "keep_landmarks": Rule("bool"),
    "gyro_bias": Rule("bool"),
    "gyro_bias_sigma": sigma(1e3),  # rad/s
    "gyro_bias_walk": Rule("float", 0.0, 1e3),  # rad/s/sqrt(s); 0: a constant bias
    "speed_scale": Rule("bool"),
    "speed_scale_sigma": sigma(1.0),  # relative (0.005: 0.5 %)
    "speed_scale_walk": Rule("float", 0.0, 1.0),  # relative/sqrt(s); 0: a constant scale
    "joint_linearisation": Rule("choice", choices=JOINT_LINEARISATIONS),
    "triangulation": Rule("choice", choices=TRIANGULATIONS),
    "landmark_parameterisation": Rule("choice", choices=LANDMARK_PARAMETERISATIONS),
    "inverse_depth_linearity": Rule("float", 0.0, 1e3),  # dimensionless; 0: never convert
    "pixel_reading": Rule("choice", choices=PIXEL_READINGS),
    "pixel_ar1": Rule("float", 0.0, 1.0, hi_open=True),  # correlation of consecutive pixel errors
    "blas_threads": Rule("int", 1, 1024),
}


def check_settings(rules: Mapping[str, Rule], values: Mapping[str, Any], label: str) -> dict:
    """Every value of ``values`` (a dataclass's fields) checked by its rule and normalised;
    InputError "<label> 'name' must be ..., got ..." at the first one not allowed."""
    out = {}
    for name, value in values.items():
        try:
            out[name] = rules[name].check(value)
        except ValueError as exc:
            raise InputError(f"{label} {name!r} {exc}") from None
    return out


def check_mapping(rules: Mapping[str, Rule], data: Any, source: str, what: str = "settings") -> dict:
    """A TOML table of settings checked key by key: InputError "<source>: ..." naming the key
    when it is unknown (the valid keys listed) or its value is not allowed."""
    if not isinstance(data, Mapping):
        raise InputError(f"{source}: expected a table of {what}, got {show_value(data)}")
    for key, value in data.items():
        if key not in rules:
            kind = "table" if isinstance(value, Mapping) else "setting"
            raise InputError(f"{source}: unknown {kind} {key!r} (valid {what}: "
                             f"{', '.join(rules)})")
    return check_settings(rules, data, f"{source}: setting")




@dataclass(frozen=True)
class FilterConfig:
    """Every setting of the EKF variants (and the noise model the smoother shares); each is
    checked by its rule in FILTER_RULES (module docstring)."""

    #: Stereo pixel noise standard deviation (px), each of uL, vL, uR, vR.
    pixel_sigma: float = 1.0
    #: Linear-velocity noise standard deviation per sample (m/s): one number for every axis,
    #: or three (x, y, z of the IMU body frame).
    velocity_sigma: float | tuple[float, float, float] = 0.5
    #: Angular-velocity noise standard deviation per sample (rad/s): one number or three.
    gyro_sigma: float | tuple[float, float, float] = 0.05
    #: Initial pose standard deviations (m, rad); world = IMU at step 0, so near zero.
    initial_position_sigma: float = 1e-3
    initial_rotation_sigma: float = 1e-4
    #: Chi-square gating probability per stereo observation (None: no gating).
    gate_probability: float | None = 0.99
    #: Split tracks at exact repeats (the shared data's quirk) before estimating.
    clean_tracks: bool = True
    #: Reject observations with disparity below this (px) and points beyond max_depth (m).
    #: The default 1,000 m leaves the cut to min_disparity on a KITTI-like rig (1 px is 390 m
    #: there): far points pin the heading, and the smoother keeps them too.
    min_disparity: float = 1.0
    max_depth: float = 1000.0
    #: Which velocity sample covers [k, k+1]: u_k ("current", the paper), u_{k+1} ("next"),
    #: or the mean of the two ("mean").
    velocity_pairing: str = "mean"
    #: Keep every landmark in the state (textbook) instead of marginalising ended tracks.
    keep_landmarks: bool = False
    #: Estimate a constant gyro bias as extra state (ekf-joint and ekf-invariant; the other
    #: filters cannot observe it). On by default: the shared drives carry constant gyro
    #: offsets of 0.005-0.01 rad/s (data README, DESIGN.md). Measured: ekf-invariant on 0027
    #: 6.98 m -> 5.89 m aligned ATE; on simulated drives with and without a bias it changes
    #: aligned ATE by under 1 mm and pose NEES by under 1 %.
    gyro_bias: bool = True
    #: Initial gyro-bias standard deviation (rad/s) and its random walk (rad/s/sqrt(s)).
    gyro_bias_sigma: float = 0.01
    gyro_bias_walk: float = 1e-4
    #: Estimate a slow speed-scale error of the linear velocities as extra state, ``v_true =
    #: (1 + s) v_measured`` with ``s`` a random walk (dead reckoning, ekf-joint, ekf-invariant
    #: and the smoother; the other filters ignore it). Off by default; an identified model
    #: turns it on where the drive cannot determine its slow velocity errors (ekf.model).
    speed_scale: bool = False
    #: Initial speed-scale standard deviation (relative: 0.005 is 0.5 %) and its random walk
    #: (relative/sqrt(s)).
    speed_scale_sigma: float = 0.005
    speed_scale_walk: float = 0.005 / 20.0**0.5
    #: Linearisation of ekf-joint: "standard", "fej" or "oc" (see ekf/joint.py).
    joint_linearisation: str = "oc"
    #: Landmark initialisation of every EKF: "linear" or "unscented" (see TRIANGULATIONS);
    #: inverse-depth landmarks need neither (their initialisation is exactly linear).
    #: "unscented" matches a Monte Carlo of the triangulation (1-3 %, linear: 4 % at 20 m, 29 %
    #: at 50 m) but did not help the filters. Measured, 8 sim runs x 120 frames, linear ->
    #: unscented: pose ANEES invariant 15.8 -> 13.9, joint 15.8 -> 16.7; landmark NEES median
    #: ~4.8 -> 4.3-4.9, mean 36 -> 1200-1600 (far means); 0027 aligned ATE joint 5.98 -> 6.13 m,
    #: invariant 5.89 -> 6.09 m; noise-free data no longer recovered exactly (6 cm ATE).
    triangulation: str = "linear"
    #: Landmark parameterisation of ekf-joint and ekf-invariant (LANDMARK_PARAMETERISATIONS).
    #: Measured, Euclidean -> inverse depth: default simulation, `vislam nees --runs 50`, pose
    #: ANEES joint 25.5 -> ~6, invariant 22.2 -> ~6 (bounds [5.08, 7.00]), landmarks 45.7 / 41.5
    #: -> ~3 ([2.36, 3.72]); 0027 aligned ATE joint 5.65 -> 5.20 m, invariant 5.63 -> 5.22 m;
    #: 2019 edition of 0027 1.73 -> 1.62 / 1.61 m.
    landmark_parameterisation: str = "inverse-depth"
    #: An inverse-depth landmark becomes Euclidean once Civera's linearity index
    #: ``4 sigma_d |cos alpha| / d`` is below this (0: never).
    inverse_depth_linearity: float = 0.1
    #: How ekf-joint reads the pixel errors along a track (PIXEL_READINGS): "long-run", every
    #: row independent with ``pixel_sigma`` (every estimator's reading), or "ar1", exact AR(1)
    #: whitening by differencing each row against the track's previous one; ``pixel_sigma`` is
    #: the long-run sigma either way, so that under "ar1" a row's own sigma is ``pixel_sigma
    #: sqrt((1 - a) / (1 + a))``. Other estimators read "long-run" whatever this says.
    #: Experimental: less accurate than "long-run" on simulated drives (docs/findings.md).
    pixel_reading: str = "long-run"
    #: The correlation ``a`` of a track's consecutive pixel errors (0: none; read by
    #: ``pixel_reading = "ar1"``); an identified model sets it from its correlation time tau,
    #: ``a = (tau - 1) / (tau + 1)`` (ekf.model.model_config).
    pixel_ar1: float = 0.0
    #: Threads BLAS may use in the hot loop (1: small matrices run fastest single-threaded).
    blas_threads: int = 1

    def __post_init__(self) -> None:
        values = {f.name: getattr(self, f.name) for f in fields(self)}
        for name, value in check_settings(FILTER_RULES, values, "setting").items():
            object.__setattr__(self, name, value)

    # --- derived matrices -------------------------------------------------------------
    @property
    def pixel_cov(self) -> np.ndarray:
        """Stereo noise covariance V (4x4, full rank)."""
        return self.pixel_sigma**2 * np.eye(4)

    @property
    def velocity_sigmas(self) -> np.ndarray:
        """Linear-velocity sigma per axis (3,), m/s."""
        return per_axis(self.velocity_sigma)

    @property
    def gyro_sigmas(self) -> np.ndarray:
        """Angular-velocity sigma per axis (3,), rad/s."""
        return per_axis(self.gyro_sigma)

    @property
    def velocity_cov(self) -> np.ndarray:
        """Twist noise covariance W (6x6), translation first, in (m/s)^2 and (rad/s)^2:
        diag(vx^2, vy^2, vz^2, gx^2, gy^2, gz^2)."""
        return np.diag(np.concatenate([self.velocity_sigmas, self.gyro_sigmas]) ** 2)

    @property
    def initial_pose_cov(self) -> np.ndarray:
        return np.diag([self.initial_position_sigma**2] * 3 + [self.initial_rotation_sigma**2] * 3)

    # --- construction -----------------------------------------------------------------
    def replace(self, **changes) -> "FilterConfig":
        """A copy with ``changes`` applied (validated); unknown names are an error."""
        known = {f.name for f in fields(self)}
        unknown = sorted(set(changes) - known)
        if unknown:
            raise InputError(f"unknown setting(s): {', '.join(unknown)}")
        return dataclasses.replace(self, **changes)

    @classmethod
    def from_toml(cls, path: str | Path) -> "FilterConfig":
        """Settings from a TOML file: its ``[filter]`` table if it has one, else its top level
        (the ``[smoother]`` table is graph.settings'). Any problem with the file, its layout
        or a value is an InputError naming the file, the table and the key."""
        table, source = settings_tables(path)["filter"]
        return cls.from_mapping(table, source)

    @classmethod
    def from_mapping(cls, data: Mapping, source: str) -> "FilterConfig":
        """Settings from a mapping (a TOML table); ``source`` names it in errors."""
        return cls(**check_mapping(FILTER_RULES, data, source, "filter settings"))

    def to_dict(self) -> dict:
        """Every setting, JSON-able (three per-axis numbers as a list)."""
        return {k: list(v) if isinstance(v, tuple) else v
                for k, v in dataclasses.asdict(self).items()}


assert list(FILTER_RULES) == [f.name for f in fields(FilterConfig)]


# --- settings files ----------------------------------------------------------------------------

#: The tables of a settings file: ``[filter]`` (FilterConfig), ``[smoother]``
#: (graph.settings.SmootherSettings), ``[model]`` and ``[file]`` (ekf.model.Model: the model of
#: a drive and the file's own values beside it).
SETTINGS_TABLES = ("filter", "smoother", "model", "file")
#: Kept for callers of the old name: tables of a settings file that are not FilterConfig's.
OTHER_TABLES = ("smoother", "model", "file")
#: A settings file larger than this is refused before it is parsed (it is not one).
MAX_SETTINGS_BYTES = 1 << 20


def show_path(path: str | Path) -> str:
    """A path as it appears in an error message (escaped if it holds control characters)."""
    text = str(path)
    return text if text and text.isprintable() else repr(text)


def read_toml(path: str | Path) -> dict:
    """The contents of a TOML settings file; InputError naming the file when it cannot be read
    (missing, a folder, permission denied, too large), is not UTF-8 or is not valid TOML
    (duplicate keys included)."""
    shown = show_path(path)
    if not str(path).strip():
        raise InputError(f"{shown}: empty path, not a settings file")
    try:
        mode = os.stat(path).st_mode
        if not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):  # a FIFO or device would block
            raise InputError(f"{shown}: not a regular file (a FIFO, device or socket), "
                             "not a settings file")
        with Path(path).open("rb") as fh:
            raw = fh.read(MAX_SETTINGS_BYTES + 1)
    except InputError:
        raise
    except FileNotFoundError:
        raise InputError(f"{shown}: settings file not found") from None
    except IsADirectoryError:
        raise InputError(f"{shown}: is a folder, not a settings file") from None
    except PermissionError:
        raise InputError(f"{shown}: permission denied reading the settings file") from None
    except OSError as exc:
        raise InputError(f"{shown}: cannot read the settings file: "
                         f"{exc.strerror or type(exc).__name__}") from None
    except ValueError as exc:  # e.g. an embedded NUL byte
        raise InputError(f"{shown}: not a usable file name: {exc}") from None
    if len(raw) > MAX_SETTINGS_BYTES:
        raise InputError(f"{shown}: larger than {MAX_SETTINGS_BYTES // 1024} KiB, "
                         "not a settings file")
    try:
        text = raw.decode("utf-8-sig")  # a leading byte-order mark (Notepad) is allowed
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise InputError(f"{shown}: not UTF-8 text (byte {exc.start}, line {line}); "
                         "a settings file is TOML, which is UTF-8") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{shown}: not valid TOML: {' '.join(str(exc).split())}") from None
    except RecursionError:
        raise InputError(f"{shown}: not valid TOML: nested too deeply") from None


def settings_tables(path: str | Path) -> dict[str, tuple[dict, str]]:
    """The tables of settings file ``path``: {"filter": (table, source), "smoother": (table,
    source), "model": (table or None, source), "file": (table or None, source)}, ``source``
    naming the file and table for error messages. Filter settings are in a
    ``[filter]`` table or, without one, at the top level; anything else at the top level (an
    unknown table, or keys beside a ``[filter]`` table) is an InputError listing what is valid.
    """
    data = read_toml(path)
    shown = show_path(path)
    for name in SETTINGS_TABLES:
        if name in data and not isinstance(data[name], dict):
            raise InputError(f"{shown}: [{name}] must be a table of settings, "
                             f"got {show_value(data[name])}")
    tables = "[" + "], [".join(SETTINGS_TABLES) + "]"
    if "filter" in data:
        extra = [k for k in data if k not in SETTINGS_TABLES]
        if extra:
            kind = "table" if isinstance(data[extra[0]], dict) else "key"
            raise InputError(f"{shown}: unknown top-level {kind} {extra[0]!r} (with a [filter] "
                             f"table, the file may hold only the tables {tables})")
        filter_table, filter_source = data["filter"], f"{shown} [filter]"
    else:
        filter_table = {k: v for k, v in data.items() if k not in SETTINGS_TABLES}
        filter_source = shown
        for key, value in filter_table.items():
            if isinstance(value, dict) and key not in FILTER_RULES:
                name = key if key.replace("_", "a").replace("-", "a").isalnum() and key.isascii() \
                    else repr(key)
                raise InputError(f"{shown}: unknown table [{name}] (valid tables: {tables})")
    return {
        "filter": (filter_table, filter_source),
        "smoother": (data.get("smoother", {}), f"{shown} [smoother]"),
        "model": (data.get("model"), f"{shown} [model]"),
        "file": (data.get("file"), f"{shown} [file]"),
    }
