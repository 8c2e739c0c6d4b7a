"""Filter settings: one typed dataclass with sensible defaults, from flags or a TOML file.

Noise model. The velocity noise ``w_t ~ N(0, W)`` of paper eq. 4 is in twist units
(m/s, rad/s), translation first: ``W = diag(sigma_v^2 I3, sigma_w^2 I3)``; over an interval of
length tau it enters the pose as ``tau^2 W`` (to first order). The stereo pixel noise is
``V = pixel_sigma^2 I4`` (full rank: rows 2 and 4 of M carry the same information, so a rank-3
V would make the innovation covariance singular).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from ekf.errors import InputError

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


@dataclass(frozen=True)
class FilterConfig:
    """Every setting of the EKF variants (and the noise model the smoother shares)."""

    #: Stereo pixel noise standard deviation (px), each of uL, vL, uR, vR.
    pixel_sigma: float = 1.0
    #: Linear-velocity noise standard deviation per sample (m/s).
    velocity_sigma: float = 0.5
    #: Angular-velocity noise standard deviation per sample (rad/s).
    gyro_sigma: float = 0.05
    #: Initial pose standard deviations (m, rad); world = IMU at step 0, so near zero.
    initial_position_sigma: float = 1e-3
    initial_rotation_sigma: float = 1e-4
    #: Chi-square gating probability per stereo observation (None: no gating).
    gate_probability: float | None = 0.99
    #: Split tracks at exact repeats (the shared data's quirk) before estimating.
    clean_tracks: bool = True
    #: Reject observations with disparity below this (px) and points beyond max_depth (m).
    min_disparity: float = 1.0
    max_depth: float = 100.0
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
    #: Linearisation of ekf-joint: "standard", "fej" or "oc" (see ekf/joint.py).
    joint_linearisation: str = "oc"
    #: Landmark initialisation of every EKF: "linear" or "unscented" (see TRIANGULATIONS).
    #: "unscented" matches a Monte Carlo of the triangulation (1-3 %, linear: 4 % at 20 m, 29 %
    #: at 50 m) but did not help the filters. Measured, 8 sim runs x 120 frames, linear ->
    #: unscented: pose ANEES invariant 15.8 -> 13.9, joint 15.8 -> 16.7; landmark NEES median
    #: ~4.8 -> 4.3-4.9, mean 36 -> 1200-1600 (far means); 0027 aligned ATE joint 5.98 -> 6.13 m,
    #: invariant 5.89 -> 6.09 m; noise-free data no longer recovered exactly (6 cm ATE).
    triangulation: str = "linear"
    #: Threads BLAS may use in the hot loop (1: small matrices run fastest single-threaded).
    blas_threads: int = 1

    def __post_init__(self) -> None:
        positive = (
            "pixel_sigma",
            "velocity_sigma",
            "gyro_sigma",
            "initial_position_sigma",
            "initial_rotation_sigma",
            "max_depth",
            "gyro_bias_sigma",
        )
        for name in positive:
            value = getattr(self, name)
            if not np.isfinite(value) or value <= 0:
                raise InputError(f"setting {name!r} must be a positive number, got {value!r}")
        if self.min_disparity < 0 or not np.isfinite(self.min_disparity):
            raise InputError(f"setting 'min_disparity' must be >= 0, got {self.min_disparity!r}")
        if self.gyro_bias_walk < 0:
            raise InputError(f"setting 'gyro_bias_walk' must be >= 0, got {self.gyro_bias_walk!r}")
        if self.gate_probability is not None and not 0.0 < self.gate_probability < 1.0:
            raise InputError(
                f"setting 'gate_probability' must be in (0, 1) or None, got {self.gate_probability!r}"
            )
        if self.velocity_pairing not in VELOCITY_PAIRINGS:
            raise InputError(
                f"setting 'velocity_pairing' must be one of {VELOCITY_PAIRINGS}, "
                f"got {self.velocity_pairing!r}"
            )
        if self.joint_linearisation not in JOINT_LINEARISATIONS:
            raise InputError(
                f"setting 'joint_linearisation' must be one of {JOINT_LINEARISATIONS}, "
                f"got {self.joint_linearisation!r}"
            )
        if self.triangulation not in TRIANGULATIONS:
            raise InputError(
                f"setting 'triangulation' must be one of {TRIANGULATIONS}, "
                f"got {self.triangulation!r}"
            )
        if int(self.blas_threads) < 1:
            raise InputError(f"setting 'blas_threads' must be >= 1, got {self.blas_threads!r}")

    # --- derived matrices -------------------------------------------------------------
    @property
    def pixel_cov(self) -> np.ndarray:
        """Stereo noise covariance V (4x4, full rank)."""
        return self.pixel_sigma**2 * np.eye(4)

    @property
    def velocity_cov(self) -> np.ndarray:
        """Twist noise covariance W (6x6), translation first, in (m/s)^2 and (rad/s)^2."""
        return np.diag([self.velocity_sigma**2] * 3 + [self.gyro_sigma**2] * 3)

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
    def from_toml(cls, path: str | Path, section: str | None = "filter") -> "FilterConfig":
        """Read settings from a TOML file (table ``[filter]`` if present, else the top level;
        the tables of other parts, e.g. ``[smoother]``, are left to their readers)."""
        path = Path(path)
        data = read_toml(path)
        if section and isinstance(data.get(section), dict):
            data = data[section]
        else:
            data = {k: v for k, v in data.items() if k not in OTHER_TABLES}
        known = {f.name: f for f in fields(cls)}
        for key in data:
            if key not in known:
                raise InputError(f"{path}: unknown setting {key!r}")
        try:
            return cls(**data)
        except TypeError as exc:
            raise InputError(f"{path}: {exc}") from None

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


#: Tables of a settings file that belong to other parts of the toolkit (graph.settings).
OTHER_TABLES = ("smoother",)


def read_toml(path: str | Path) -> dict:
    """The contents of a TOML settings file; a missing or invalid file is an InputError."""
    path = Path(path)
    try:
        with path.open("rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise InputError(f"{path}: settings file not found") from None
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{path}: not valid TOML: {exc}") from None
