"""Settings of the GTSAM smoother that are not part of the shared noise model.

The noise model itself (pixel, velocity and gyro sigmas, velocity pairing, track cleaning,
minimum disparity) comes from :class:`ekf.config.FilterConfig`, so the EKF and the smoother are
always compared under the same assumptions.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ekf.errors import InputError

#: Where the batch smoother's initial trajectory comes from.
INITIALISERS = ("ekf", "dead-reckoning", "isam2")
#: How the smoother treats the gyro bias (SmootherSettings.gyro_bias).
GYRO_BIAS_MODES = ("alternate", "joint", "off")
#: How the smoother applies the twist-smoothness prior at gaps (SmootherSettings.gap_twist_prior).
GAP_PRIOR_MODES = ("linearised", "exact", "off")


@dataclass(frozen=True)
class SmootherSettings:
    """Robust kernel, stopping rule, outlier rejection and regularisation of the smoother.

    From the command line: ``--smoother-init``, ``--gap-prior``, or a ``[smoother]`` table in
    the ``--config`` TOML file with any of these field names."""

    #: Where the batch smoother's initial trajectory comes from (INITIALISERS): the EKF's
    #: estimate, dead reckoning, or iSAM2 run first.
    init: str = "ekf"

    #: Huber threshold in whitened units (multiples of the pixel sigma).
    huber_k: float = 1.345
    #: Levenberg-Marquardt stopping rule.
    max_iterations: int = 100
    relative_error_tol: float = 1e-5
    absolute_error_tol: float = 1e-6
    #: After the first solve, stereo factors whose residual norm ([uL, uR, v], pixels) exceeds
    #: this are removed and the graph is solved again (``rejection_rounds`` times at most).
    outlier_threshold_px: float = 4.0
    rejection_rounds: int = 1
    #: Weak prior (m) on every landmark, centred on its initial triangulation: it keeps the
    #: system determinate for marginals (a prototype's Marginals threw on 0034 without it).
    landmark_prior_sigma: float = 100.0
    #: Cheirality margin: a landmark closer than this (m) to, or behind, any of its cameras is
    #: dropped (GTSAM's stereo factor returns a constant residual with a zero Jacobian there).
    min_depth: float = 0.1
    #: One constant gyro bias shared by all motion factors (graph.gyro_bias), zero-mean prior
    #: with FilterConfig.gyro_bias_sigma: "alternate" (default: estimated from the trajectory
    #: before each LM solve, the motions corrected for it; at least two solves), "joint" (a
    #: bias variable in the graph; a Python CustomFactor per interval, several times slower
    #: per LM iteration) or "off".
    gyro_bias: str = "alternate"
    #: On intervals no track spans, a prior predicting the twist from the two neighbouring
    #: intervals (graph.twist_smoothness), its sigma measured on the drive itself:
    #: "linearised" (default: relinearised each solve round, C++ factors), "exact" (Python
    #: CustomFactors, about twice as slow) or "off".
    gap_twist_prior: str = "linearised"
    #: Compute the pose and landmark marginal covariances.
    compute_marginals: bool = True
    #: iSAM2 relinearisation threshold and skip (GTSAM's defaults). Relinearising at every
    #: update with a 0.05 threshold gave the same estimate on 0027 in 6.7 times the time
    #: (321 s against 48 s).
    isam2_relinearize_threshold: float = 0.1
    isam2_relinearize_skip: int = 10

    def __post_init__(self) -> None:
        positive = ("huber_k", "outlier_threshold_px", "landmark_prior_sigma", "min_depth",
                    "relative_error_tol", "isam2_relinearize_threshold")
        for name in positive:
            value = getattr(self, name)
            if not np.isfinite(value) or value <= 0:
                raise InputError(f"smoother setting {name!r} must be a positive number, got {value!r}")
        for name in ("max_iterations", "isam2_relinearize_skip"):
            if int(getattr(self, name)) < 1:
                raise InputError(f"smoother setting {name!r} must be >= 1, got {getattr(self, name)!r}")
        if self.init not in INITIALISERS:
            raise InputError(f"smoother setting 'init' must be one of {INITIALISERS}, got {self.init!r}")
        if self.gyro_bias not in GYRO_BIAS_MODES:
            raise InputError(f"smoother setting 'gyro_bias' must be one of {GYRO_BIAS_MODES}, got {self.gyro_bias!r}")
        if self.gap_twist_prior not in GAP_PRIOR_MODES:
            raise InputError(f"smoother setting 'gap_twist_prior' must be one of {GAP_PRIOR_MODES}, "
                             f"got {self.gap_twist_prior!r}")
        if int(self.rejection_rounds) < 0:
            raise InputError(f"smoother setting 'rejection_rounds' must be >= 0, got {self.rejection_rounds!r}")
        if self.absolute_error_tol < 0:
            raise InputError(f"smoother setting 'absolute_error_tol' must be >= 0, got {self.absolute_error_tol!r}")

    def replace(self, **changes) -> "SmootherSettings":
        known = {f.name for f in dataclasses.fields(self)}
        unknown = sorted(set(changes) - known)
        if unknown:
            raise InputError(f"unknown smoother setting(s): {', '.join(unknown)}")
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_mapping(cls, data: dict, source: str) -> "SmootherSettings":
        """Settings from a mapping (a TOML table); ``source`` names it in errors."""
        if not isinstance(data, dict):
            raise InputError(f"{source}: expected a table of smoother settings, got {type(data).__name__}")
        known = {f.name: f for f in dataclasses.fields(cls)}
        for key, value in data.items():
            if key not in known:
                raise InputError(f"{source}: unknown smoother setting {key!r} "
                                 f"(known: {', '.join(sorted(known))})")
            default = getattr(cls(), key)
            if isinstance(default, bool) != isinstance(value, bool) or (
                    not isinstance(default, bool) and not isinstance(value, type(default))
                    and not (isinstance(default, float) and isinstance(value, int))):
                raise InputError(f"{source}: smoother setting {key!r} must be a "
                                 f"{type(default).__name__}, got {value!r}")
        try:
            return cls(**data)
        except InputError as exc:
            raise InputError(f"{source}: {exc}") from None
