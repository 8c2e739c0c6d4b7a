"""Settings of the GTSAM smoother that are not part of the shared noise model.

The noise model itself (pixel, velocity and gyro sigmas, velocity pairing, track cleaning,
minimum disparity) comes from :class:`ekf.config.FilterConfig`, so the EKF and the smoother are
always compared under the same assumptions.

Every field is checked by its rule in SMOOTHER_RULES (types, finiteness, ranges and choices as
described in ekf.config) wherever it comes from: the constructor, ``replace``, the ``[smoother]``
table of a settings file, ``--smoother-init`` / ``--gap-prior``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

from vislam.ekf.config import Rule, check_mapping, check_settings, settings_tables
from vislam.ekf.errors import InputError

#: Where the batch smoother's initial trajectory comes from.
INITIALISERS = ("ekf", "dead-reckoning", "isam2")
#: How the smoother treats the gyro bias (SmootherSettings.gyro_bias).
GYRO_BIAS_MODES = ("alternate", "joint", "off")
#: How Levenberg-Marquardt updates its damping (SmootherSettings.lm_damping).
LM_DAMPING_MODES = ("nielsen", "fixed")
#: The batch smoother's linear solvers (SmootherSettings.linear_solver) and GTSAM's names.
LINEAR_SOLVERS = {"sequential-cholesky": "SEQUENTIAL_CHOLESKY",
                  "multifrontal-cholesky": "MULTIFRONTAL_CHOLESKY",
                  "multifrontal-qr": "MULTIFRONTAL_QR"}
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
    #: LM's relative error tolerance in the rounds before the last (at least
    #: ``relative_error_tol``): they only decide which observations are outliers, and their
    #: solution is where the last round starts, which converges as before, to
    #: ``relative_error_tol``. A looser tolerance here saves iterations and changes only the
    #: rejections of residuals within a hair of the threshold. Identification solves every
    #: round to its own tolerance.
    rejection_relative_error_tol: float = 1e-2
    #: How LM changes its damping after a step: "nielsen" (GTSAM's ``useFixedLambdaFactor``
    #: off: the damping follows the gain ratio, Nielsen's rule) or "fixed" (divided or
    #: multiplied by 10). Nielsen's rule spares the repeated solves of a step that fails
    #: several times over.
    lm_damping: str = "nielsen"
    #: The linear solver of each LM step (LINEAR_SOLVERS: GTSAM's SEQUENTIAL_CHOLESKY,
    #: MULTIFRONTAL_CHOLESKY, MULTIFRONTAL_QR). Sequential Cholesky is the same arithmetic
    #: as the multifrontal one in another grouping, with the same solution.
    linear_solver: str = "sequential-cholesky"
    #: Weak prior (m) on every landmark, centred on its initial triangulation: it keeps the
    #: system determinate for marginals (without it a long drive's Marginals can throw).
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
    #: iSAM2 relinearisation threshold and skip; skip 0: never relinearise during the run
    #: (each variable stays linearised where it entered, at the prediction from the latest
    #: estimate, which is good to first order), then ``isam2_final_relinearizations`` rounds.
    #: Fluid relinearisation (GTSAM's skip 10) is slower and was less accurate.
    isam2_relinearize_threshold: float = 0.1
    isam2_relinearize_skip: int = 0
    #: Gauss-Newton steps after the last frame, each relinearising every variable (what iSAM2
    #: updates with no new factors, ``force_relinearize`` and ``forceFullSolve`` do; solved in
    #: batch: graph.isam2.final_relinearizations).
    isam2_final_relinearizations: int = 3
    #: iSAM2's factorisation, "cholesky" (GTSAM's default) or "qr" (slower). A run whose
    #: Cholesky factorisation fails ("indeterminate system": an ill-conditioned system) is
    #: repeated with QR, which does not square the condition number.
    isam2_factorization: str = "cholesky"
    #: Returning tracks in iSAM2: an observation of a landmark unseen for more than this many
    #: frames waits, with the later observations of the same landmarks, until this many frames
    #: have passed, and they enter in one update (each update that touches a returning landmark
    #: re-eliminates the Bayes tree from its clique to the root: the whole loop); 1: each frame
    #: alone. Drives whose tracks never return are not affected.
    isam2_return_batch: int = 10
    #: iSAM2's back-substitution after each update stops where the solution moved by less than
    #: this (GTSAM's wildfire threshold; its default is 0.001): the frame's new variables are
    #: exact, older ones at most this stale; the final estimate is solved in full whatever it is.
    isam2_wildfire_threshold: float = 0.01
    #: iSAM2's relinearisation threshold during the run (with ``isam2_relinearize_skip`` above 0)
    #: on a drive whose returning observations waited: they entered at linearisation points up
    #: to ``isam2_return_batch`` frames old. The final relinearisations relinearise every
    #: variable whatever the threshold.
    isam2_return_relinearize_threshold: float = 0.01
    #: The fixed-lag smoother's window (``smoother-fixed-lag``), seconds: a pose leaves it this
    #: long after its frame, a landmark this long after its last observation.
    fixed_lag_s: float = 3.0
    #: The fixed-lag smoother's relinearisation skip (it reports each variable as it leaves the
    #: window, so it cannot wait for final relinearisations; 0: never).
    fixed_lag_relinearize_skip: int = 10

    def __post_init__(self) -> None:
        values = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        for name, value in check_settings(SMOOTHER_RULES, values, "smoother setting").items():
            object.__setattr__(self, name, value)

    def replace(self, **changes) -> "SmootherSettings":
        known = {f.name for f in dataclasses.fields(self)}
        unknown = sorted(set(changes) - known)
        if unknown:
            raise InputError(f"unknown smoother setting(s): {', '.join(unknown)}")
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_mapping(cls, data: Mapping, source: str) -> "SmootherSettings":
        """Settings from a mapping (a TOML table); ``source`` names it in errors."""
        return cls(**check_mapping(SMOOTHER_RULES, data, source, "smoother settings"))

    @classmethod
    def from_toml(cls, path: str | Path) -> "SmootherSettings":
        """Settings from the ``[smoother]`` table of a TOML settings file (defaults without
        one); every problem is an InputError naming the file, the table and the key."""
        table, source = settings_tables(path)["smoother"]
        return cls.from_mapping(table, source)


#: The rule of every SmootherSettings field, in field order (units and bounds in the comments).
SMOOTHER_RULES: dict[str, Rule] = {
    "init": Rule("choice", choices=INITIALISERS),
    "huber_k": Rule("float", 1e-6, 1e6),  # whitened units
    "max_iterations": Rule("int", 1, 1_000_000),
    "relative_error_tol": Rule("float", 0.0, 1.0, lo_open=True),
    "absolute_error_tol": Rule("float", 0.0, 1e12),  # in units of the whitened squared error
    "outlier_threshold_px": Rule("float", 1e-6, 1e6),  # px
    "rejection_rounds": Rule("int", 0, 1000),
    "rejection_relative_error_tol": Rule("float", 0.0, 1.0, lo_open=True),
    "lm_damping": Rule("choice", choices=LM_DAMPING_MODES),
    "linear_solver": Rule("choice", choices=tuple(LINEAR_SOLVERS)),
    "landmark_prior_sigma": Rule("float", 1e-6, 1e6),  # m; squared into a noise model
    "min_depth": Rule("float", 0.0, 1e6, lo_open=True),  # m
    "gyro_bias": Rule("choice", choices=GYRO_BIAS_MODES),
    "gap_twist_prior": Rule("choice", choices=GAP_PRIOR_MODES),
    "compute_marginals": Rule("bool"),
    "isam2_relinearize_threshold": Rule("float", 0.0, 1e6, lo_open=True),
    "isam2_relinearize_skip": Rule("int", 0, 1_000_000),
    "isam2_final_relinearizations": Rule("int", 0, 1000),
    "isam2_factorization": Rule("choice", choices=("qr", "cholesky")),
    "isam2_return_batch": Rule("int", 1, 1_000_000),
    "isam2_wildfire_threshold": Rule("float", 0.0, 1e6),
    "isam2_return_relinearize_threshold": Rule("float", 0.0, 1e6, lo_open=True),
    "fixed_lag_s": Rule("float", 0.0, 1e6, lo_open=True),  # s
    "fixed_lag_relinearize_skip": Rule("int", 0, 1_000_000),
}

assert list(SMOOTHER_RULES) == [f.name for f in dataclasses.fields(SmootherSettings)]
