"""A campaign that measures generalisation: simulated drives with random combinations of the
faults real drives have, each run as ``vislam bench`` with no flags runs it (issue 34, item 5).

A drive nobody tuned for
------------------------
:func:`draw_drive` turns a seed into a :class:`CampaignDrive`, deterministically (its own
random stream, ``numpy.random.default_rng([seed, DRAW_STREAM])``; the simulator's streams come
from ``SimConfig.seed = seed``). Every drive has KITTI's geometry and motion (the simulator's
defaults, ``frames`` steps at 10 Hz) and draws:

* **Tracks a frame**: a target of observations per frame, log-uniform in
  [:data:`MIN_OBS_PER_FRAME`, :data:`MAX_OBS_PER_FRAME`] (1-60, the shared drives and the
  sparse 2019 edition of KITTI 06 at about 3); ``detect_probability`` in [0.05, 0.3] and
  ``mean_track_length`` in [5, 20] frames, then ``landmark_density`` scaled so that the drive
  meets the target: the number of observations is close to proportional to the density
  (measured: 0.1 landmark/m gives 1-4 a frame, 2.7 gives 20-90, depending on the other two),
  so one pilot simulation of the same seed at density 1 gives the scale. The realised figure
  differs from the target by the draw's own randomness; the outcome records it.
* **Velocity noise** of one of two editions, like the shared KITTI drives: "noisy" (added white
  noise, 0.5 m/s and 0.05 rad/s on every axis, the shared files) or "clean" (per axis
  log-uniform in 0.003-0.05 m/s and 0.001-0.02 rad/s, the 2019 edition's GPS/IMU velocities).
* With probability :data:`FAULT_PROBABILITY` each, independently, the faults:
  ``speed-scale`` (:class:`SpeedScaleFault`, below), ``velocity-correlation``
  (``SimConfig.velocity_correlation`` in [0.5, 0.95]), ``pixel-correlation``
  (``pixel_correlation`` in [0.3, 0.9]), ``file-extrinsic`` (the file's ``cam_T_imu`` wrong:
  KITTI's swapped translation, an offset of up to 0.3 m and 0.02 rad per axis, or both),
  ``lens`` (``radial_k1`` of magnitude 0.002-0.02 either sign), ``gyro-bias`` (up to
  0.005 rad/s per axis).
* Pixel noise sigma uniform in [0.5, 1.5] px.

The speed-scale fault (applied here; the simulator has no such fault)
--------------------------------------------------------------------
A real vehicle's speed source is off by a slowly varying factor (on the 2019 edition of KITTI
06 the file's speed agrees with the ground truth's path length to 0.01 % overall, but is off by
up to 1.6 % over tenths of the drive). :class:`SpeedScaleFault` multiplies the simulated
drive's measured linear velocities (all three axes of sample k) by ``1 + s(t_k)``, the ground
truth unchanged, before anything is estimated. ``s`` is a smooth random function: knots every
``time_scale_s`` seconds (the first at a random phase before the drive's start), values uniform
in [-amplitude, amplitude], joined by monotone cubic interpolation (PCHIP), so ``|s| <=
amplitude`` everywhere and the knot values are independent: ``s`` decorrelates over about one
``time_scale_s`` (its correlation falls to zero at lags of two knot spacings).
:func:`draw_drive` draws the amplitude uniform in [0.2, 2] % and the time scale in [10, 40] s.

What a drive's outcome is
-------------------------
:func:`evaluate_drive` simulates the drive, applies the speed-scale fault, writes it as the
shared data lays it out (:func:`eval.simulate.write_simulation`) into a temporary folder and
runs dead reckoning, ekf-joint, ekf-invariant and the smoother on it with
:func:`vislam.testing.run_drive` under the model identified from the drive's own data
(``model="identified"``, the default filter and smoother settings): what ``vislam bench DIR``
with no flags does, ground truth converted with the model's extrinsic. The identified model is
cached by content as bench caches it (``$VISLAM_CACHE_DIR``, :mod:`eval.model_cache`); point
that at an empty folder to measure the identification as the code is now.

The assertions (:func:`assess`), per drive:

* ``ate``: every SLAM estimator's (:data:`SLAM_ESTIMATORS`) aligned ATE at most
  :data:`ATE_RATIO_MAX` (1.1) times dead reckoning's;
* ``nees``: dead reckoning's and the smoother's mean pose NEES against ground truth inside
  :data:`eval.consistency.POSE_NEES_BAND`, the band ``vislam bench`` reports.

An estimator that failed, or a figure that is missing, fails its assertion.
"""

from __future__ import annotations

import math
import tempfile
import time
from collections.abc import Mapping
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.interpolate import PchipInterpolator

from vislam.eval.consistency import (POSE_NEES_BAND, VERDICT_ABOVE, VERDICT_BELOW, VERDICT_INSIDE,
                                     VERDICT_WORDS)
from vislam.eval.simulate import SimConfig, SimResult, simulate, simulation_stats

#: The estimators of a drive, in the order they are shown; the first is the baseline.
ESTIMATORS = ("dead-reckoning", "ekf-joint", "ekf-invariant", "smoother")
BASELINE = "dead-reckoning"
#: The estimators that use vision, each held to the baseline's aligned ATE.
SLAM_ESTIMATORS = ("ekf-joint", "ekf-invariant", "smoother")
#: The estimators whose mean pose NEES must lie in the band.
NEES_ESTIMATORS = ("dead-reckoning", "smoother")
#: Largest aligned ATE of a SLAM estimator, as a multiple of dead reckoning's.
ATE_RATIO_MAX = 1.1
#: Frames of a drive by default (10 Hz: 25 s, about 200 m).
DEFAULT_FRAMES = 250
#: Range of the target observations per frame (log-uniform).
MIN_OBS_PER_FRAME, MAX_OBS_PER_FRAME = 1.0, 60.0
#: Probability that a drive carries each optional fault.
FAULT_PROBABILITY = 0.4
#: The optional fault classes (a drive's ``faults`` lists those it carries).
FAULT_CLASSES = ("speed-scale", "velocity-correlation", "pixel-correlation", "file-extrinsic",
                 "lens", "gyro-bias")
#: The two editions of velocity noise.
EDITIONS = ("noisy", "clean")
#: Second entry of the draw's seed: the campaign's stream, apart from the simulator's.
DRAW_STREAM = 34
#: Landmark density of the pilot simulation that scales the density to the target.
_PILOT_DENSITY = 1.0
#: The simulator's upper bound of landmark_density.
_MAX_DENSITY = 1000.0


@dataclass(frozen=True)
class SpeedScaleFault:
    """A slow multiplicative error of the linear velocities (module docstring): factor
    ``1 + s(t)``, ``|s| <= amplitude`` (a fraction: 0.02 is 2 %), knots every ``time_scale_s``
    seconds, drawn from ``numpy.random.default_rng(seed)``."""

    amplitude: float
    time_scale_s: float
    seed: int

    def __post_init__(self) -> None:
        if not (math.isfinite(self.amplitude) and 0.0 <= self.amplitude < 1.0):
            raise ValueError(f"speed-scale amplitude must be in [0, 1), got {self.amplitude!r}")
        if not (math.isfinite(self.time_scale_s) and self.time_scale_s > 0.0):
            raise ValueError(f"speed-scale time_scale_s must be positive, got "
                             f"{self.time_scale_s!r}")

    def error(self, timestamps: np.ndarray) -> np.ndarray:
        """``s(t)`` (T,) at ``timestamps`` (s): the relative speed error of each sample."""
        t = np.asarray(timestamps, dtype=float)
        t = t - t[0]
        rng = np.random.default_rng(self.seed)
        phase = rng.random() * self.time_scale_s
        n = int(np.ceil((t[-1] + phase) / self.time_scale_s)) + 2
        knots_t = np.arange(n) * self.time_scale_s - phase
        values = rng.uniform(-self.amplitude, self.amplitude, n)
        return PchipInterpolator(knots_t, values)(t)

    def apply(self, result: SimResult) -> SimResult:
        """``result`` with its measured linear velocities multiplied by ``1 + s(t)``; the
        truth (poses, true velocities, landmarks) and every other measurement unchanged."""
        seq = result.sequence
        factor = 1.0 + self.error(seq.timestamps)
        sequence = replace(seq, linear_velocity=seq.linear_velocity * factor[:, None])
        return replace(result, sequence=sequence)


@dataclass(frozen=True)
class CampaignDrive:
    """One drive of the campaign: ``seed``; ``sim`` the simulator's settings (the landmark
    density already scaled to the target); ``faults`` the optional fault classes it carries
    (:data:`FAULT_CLASSES`); ``edition`` of its velocity noise (:data:`EDITIONS`);
    ``target_obs_per_frame`` what the density was scaled for; ``speed_scale`` the speed-scale
    fault, or None."""

    seed: int
    sim: SimConfig
    faults: tuple[str, ...]
    edition: str
    target_obs_per_frame: float
    speed_scale: SpeedScaleFault | None = None

    def simulate(self) -> SimResult:
        """The drive as the estimators see it: simulated, the speed-scale fault applied."""
        result = simulate(self.sim)
        return result if self.speed_scale is None else self.speed_scale.apply(result)

    def describe(self) -> str:
        """The faults in a few words, e.g. ``clean; speed-scale 1.4 %/23 s, lens -0.012``."""
        s = self.sim
        words = []
        for fault in self.faults:
            if fault == "speed-scale" and self.speed_scale is not None:
                words.append(f"speed {100 * self.speed_scale.amplitude:.1f}%/"
                             f"{self.speed_scale.time_scale_s:.0f}s")
            elif fault == "velocity-correlation":
                words.append(f"vcorr {s.velocity_correlation:.2f}")
            elif fault == "pixel-correlation":
                words.append(f"pcorr {s.pixel_correlation:.2f}")
            elif fault == "file-extrinsic":
                off = np.asarray(s.file_extrinsic_offset)
                kind = "kitti" if s.file_extrinsic_fault == "kitti" else ""
                if np.any(off != 0.0):
                    kind += ("+" if kind else "") + (f"{100 * np.abs(off[:3]).max():.0f}cm/"
                                                     f"{np.degrees(np.abs(off[3:]).max()):.1f}deg")
                words.append(f"extr {kind}")
            elif fault == "lens":
                words.append(f"k1 {s.radial_k1:+.3f}")
            elif fault == "gyro-bias":
                words.append(f"bias {1000 * np.abs(s.gyro_bias).max():.1f}mrad/s")
        return "; ".join([self.edition] + words)


def _log_uniform(rng: np.random.Generator, low: float, high: float, size=None):
    return np.exp(rng.uniform(np.log(low), np.log(high), size))


def draw_drive(seed: int, frames: int = DEFAULT_FRAMES) -> CampaignDrive:
    """The campaign's drive ``seed`` (module docstring): the same seed always gives the same
    drive. ``frames`` steps at 10 Hz."""
    seed = int(seed)
    if seed < 0:
        raise ValueError(f"seed must be >= 0, got {seed}")
    rng = np.random.default_rng([seed, DRAW_STREAM])
    target = float(_log_uniform(rng, MIN_OBS_PER_FRAME, MAX_OBS_PER_FRAME))
    detect = float(rng.uniform(0.05, 0.3))
    track_length = float(rng.uniform(5.0, 20.0))
    edition = EDITIONS[int(rng.random() < 0.5)]
    if edition == "noisy":
        velocity_sigma: tuple[float, ...] = (0.5, 0.5, 0.5)
        gyro_sigma: tuple[float, ...] = (0.05, 0.05, 0.05)
    else:
        velocity_sigma = tuple(float(x) for x in _log_uniform(rng, 0.003, 0.05, 3))
        gyro_sigma = tuple(float(x) for x in _log_uniform(rng, 0.001, 0.02, 3))
    pixel_sigma = float(rng.uniform(0.5, 1.5))
    present = {f: bool(rng.random() < FAULT_PROBABILITY) for f in FAULT_CLASSES}
    # Every value is drawn whether or not its fault is present, so that one fault's presence
    # never changes another's value.
    speed = SpeedScaleFault(float(rng.uniform(0.002, 0.02)), float(rng.uniform(10.0, 40.0)),
                            int(rng.integers(2**63)))
    v_corr = float(rng.uniform(0.5, 0.95))
    p_corr = float(rng.uniform(0.3, 0.9))
    extr_kind = int(rng.integers(3))  # 0 KITTI's swap, 1 an offset, 2 both
    offset = np.r_[rng.uniform(-0.3, 0.3, 3), rng.uniform(-0.02, 0.02, 3)]
    k1 = float(rng.uniform(0.002, 0.02) * rng.choice([-1.0, 1.0]))
    bias = rng.uniform(-0.005, 0.005, 3)

    sim = SimConfig(
        seed=seed, n_frames=int(frames), name=f"campaign{seed}",
        velocity_sigma=velocity_sigma, gyro_sigma=gyro_sigma, pixel_sigma=pixel_sigma,
        detect_probability=detect, mean_track_length=track_length,
        landmark_density=_PILOT_DENSITY,
        velocity_correlation=v_corr if present["velocity-correlation"] else 0.0,
        pixel_correlation=p_corr if present["pixel-correlation"] else 0.0,
        file_extrinsic_fault="kitti" if present["file-extrinsic"] and extr_kind != 1 else "none",
        file_extrinsic_offset=tuple(offset) if present["file-extrinsic"] and extr_kind != 0
        else (0.0,) * 6,
        radial_k1=k1 if present["lens"] else 0.0,
        gyro_bias=tuple(bias) if present["gyro-bias"] else (0.0, 0.0, 0.0),
    )
    pilot = simulation_stats(simulate(sim))["obs_per_frame_mean"]
    density = _PILOT_DENSITY * target / max(pilot, 1e-3)
    sim = replace(sim, landmark_density=float(min(density, _MAX_DENSITY)))
    faults = tuple(f for f in FAULT_CLASSES if present[f])
    return CampaignDrive(seed, sim, faults, edition, target,
                         speed if present["speed-scale"] else None)


def sparse_slow_speed_drive(seed: int = 1, frames: int = 300) -> CampaignDrive:
    """The measured failure of issue 34, as a simulated drive: the 2019-edition drive of KITTI
    06 has about 3 observations a frame, clean velocities (the model identified there: 0.0030 /
    0.0024 / 0.0094 m/s) and a speed off by up to 1.6 % over tenths of the drive; there the
    identified model made every estimator overconfident (mean pose NEES 1,200-2,100). This drive
    has the same: about 2-3 observations a frame (landmark density 0.12 /m, detection
    probability 0.1, tracks of 15 frames on average), those velocity sigmas, gyro noise 0.002
    rad/s, and a speed-scale error of amplitude 1.6 % with knots every 15 s. Not drawn: its
    ``faults`` say ``speed-scale`` and its target is 3 observations a frame."""
    sim = SimConfig(seed=int(seed), n_frames=int(frames), name=f"sparse-slow-speed{seed}",
                    velocity_sigma=(0.003, 0.0024, 0.0094), gyro_sigma=(0.002, 0.002, 0.002),
                    pixel_sigma=1.0, landmark_density=0.12, detect_probability=0.1,
                    mean_track_length=15.0)
    return CampaignDrive(int(seed), sim, ("speed-scale",), "clean", 3.0,
                         SpeedScaleFault(0.016, 15.0, int(seed)))


# --- outcomes ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class EstimatorFigures:
    """One estimator on one drive: aligned ATE (m), KITTI drift t_rel (%, None where the drive
    is shorter than 100 m), mean pose NEES against ground truth; ``error`` when it failed."""

    ate_aligned_m: float | None
    t_rel_pct: float | None
    nees_pose_mean: float | None
    error: str | None = None


@dataclass(frozen=True)
class AssertionResult:
    """One assertion on one drive: ``name`` ("ate" or "nees"), ``ok``, and ``detail``, one line
    per estimator held to it with its figure and bound, e.g. ``smoother ATE 2.31 m = 1.43x
    dead reckoning's 1.61 m (max 1.1x): fails``."""

    name: str
    ok: bool
    detail: tuple[str, ...]

    def __bool__(self) -> bool:
        return self.ok


@dataclass(frozen=True)
class DriveOutcome:
    """What a campaign drive gave: ``figures`` per estimator, the assertions, the realised
    observations per frame, the identified model (results.json's ``model`` record, trimmed to
    its ``model`` table), wall and CPU time (s)."""

    drive: CampaignDrive
    obs_per_frame: float
    figures: dict[str, EstimatorFigures]
    assertions: tuple[AssertionResult, ...]
    model: dict | None = None
    wall_s: float = float("nan")
    #: CPU time of this process (s): the whole drive with ``jobs`` 1
    cpu_s: float = float("nan")

    @property
    def ok(self) -> bool:
        return all(a.ok for a in self.assertions)

    def assertion(self, name: str) -> AssertionResult:
        return next(a for a in self.assertions if a.name == name)

    @property
    def ate_ratio(self) -> float:
        """The worst SLAM estimator's aligned ATE over dead reckoning's (inf where one failed)."""
        return ate_ratio(self.figures)

    @property
    def worst_nees(self) -> float:
        """The largest distance of a NEES-held estimator from the band, as a factor (1 inside;
        inf where one failed)."""
        lo, hi = POSE_NEES_BAND
        worst = 1.0
        for name in NEES_ESTIMATORS:
            f = self.figures.get(name)
            v = None if f is None or f.error else f.nees_pose_mean
            if v is None or not np.isfinite(v) or v <= 0:
                return math.inf
            worst = max(worst, v / hi, lo / v)
        return worst


def ate_ratio(figures: Mapping[str, EstimatorFigures]) -> float:
    """max over SLAM estimators of aligned ATE / dead reckoning's; inf where a figure is
    missing."""
    base = figures.get(BASELINE)
    if base is None or base.error or base.ate_aligned_m is None or not base.ate_aligned_m > 0:
        return math.inf
    worst = 0.0
    for name in SLAM_ESTIMATORS:
        f = figures.get(name)
        if f is None or f.error or f.ate_aligned_m is None or not np.isfinite(f.ate_aligned_m):
            return math.inf
        worst = max(worst, f.ate_aligned_m / base.ate_aligned_m)
    return worst


def _figure_or_why(figures: Mapping[str, EstimatorFigures], name: str, key: str):
    f = figures.get(name)
    if f is None:
        return None, f"{name}: not run"
    if f.error:
        return None, f"{name}: failed ({f.error})"
    value = getattr(f, key)
    if value is None or not np.isfinite(value):
        return None, f"{name}: no {key}"
    return float(value), None


def assess(figures: Mapping[str, EstimatorFigures]) -> tuple[AssertionResult, AssertionResult]:
    """The two assertions of a drive (module docstring) on its ``figures``."""
    base, why = _figure_or_why(figures, BASELINE, "ate_aligned_m")
    lines, ok = [], True
    if base is None:
        lines.append(f"{why}: no baseline")
        ok = False
    for name in SLAM_ESTIMATORS:
        value, why = _figure_or_why(figures, name, "ate_aligned_m")
        if value is None:
            lines.append(why)
            ok = False
            continue
        if base is None:
            continue
        ratio = value / base if base > 0 else math.inf
        good = ratio <= ATE_RATIO_MAX
        ok &= good
        lines.append(f"{name} ATE {value:.3g} m = {ratio:.2f}x dead reckoning's {base:.3g} m "
                     f"(max {ATE_RATIO_MAX:g}x): {'passes' if good else 'fails'}")
    ate = AssertionResult("ate", ok, tuple(lines))
    lo, hi = POSE_NEES_BAND
    lines, ok = [], True
    for name in NEES_ESTIMATORS:
        value, why = _figure_or_why(figures, name, "nees_pose_mean")
        if value is None:
            lines.append(why)
            ok = False
            continue
        good = lo <= value <= hi
        ok &= good
        word = VERDICT_WORDS[VERDICT_INSIDE if good else
                             VERDICT_ABOVE if value > hi else VERDICT_BELOW]
        lines.append(f"{name} pose NEES {value:.3g}, band [{lo:.2f}, {hi:.2f}]: {word}")
    return ate, AssertionResult("nees", ok, tuple(lines))


#: The gyro bias's sigma in a drive's true model (rad/s): the bias is known exactly.
TRUE_BIAS_SIGMA = 1e-6


def drive_true_model(drive: CampaignDrive, result: SimResult):
    """The true model of ``drive`` (:func:`eval.simulate.true_model`) as the estimators need it:
    its gyro bias known (sigma :data:`TRUE_BIAS_SIGMA`), white velocity and gyro samples under the "mean" pairing get the long-run ratio 2 the
    simulator's true model leaves out (two intervals that share a sample are correlated by a
    half: the estimators, which treat intervals as independent, need the long-run sigma, the
    sample's; docs/findings.md; :func:`ekf.model.model_config` now takes it for every model,
    so this only says so in the model itself), and where the drive carries a speed-scale fault, the
    speed-scale state that describes it: ``s`` uniform in +-amplitude (sigma ``amplitude /
    sqrt(3)``), independent knots ``time_scale_s`` apart (a walk of ``sqrt(2/3) amplitude /
    sqrt(time_scale_s)``)."""
    from vislam.ekf.model import interval_sigma_factor
    from vislam.eval.simulate import true_model

    model = true_model(result)
    if model.gyro_bias is not None:  # known exactly: nothing left for the filters to estimate
        model = model.replace(gyro_bias_sigma=(TRUE_BIAS_SIGMA,) * 3)
    ratio = 1.0 / interval_sigma_factor(model.velocity_pairing) ** 2
    if ratio != 1.0 and not result.config.noise_free:
        changes = {"gyro_correlation_time": model.gyro_correlation_time or (ratio,) * 3}
        if model.velocity_correlation_time is None:
            changes["velocity_correlation_time"] = (ratio,) * 3
        model = model.replace(**changes)
    fault = drive.speed_scale
    if fault is None or fault.amplitude == 0.0:
        return model
    return model.replace(speed_scale_sigma=fault.amplitude / math.sqrt(3.0),
                         speed_scale_walk=fault.amplitude * math.sqrt(2.0 / 3.0 / fault.time_scale_s))


def evaluate_drive(drive: CampaignDrive, jobs: int = 1, model: str = "identified") -> DriveOutcome:
    """Run :data:`ESTIMATORS` on ``drive`` as ``vislam bench`` with no flags does (module
    docstring; ``jobs`` worker processes) and assess them. ``model="true"`` runs them under
    the drive's true model instead (:func:`drive_true_model`, in memory): what a perfect
    identification would give, the ceiling of the assertions."""
    from vislam.eval.simulate import write_simulation
    from vislam.eval.testing import run_drive

    if model not in ("identified", "true"):
        raise ValueError(f"model: 'identified' or 'true', got {model!r}")
    t0, c0 = time.perf_counter(), time.process_time()
    result = drive.simulate()
    obs = float(simulation_stats(result)["obs_per_frame_mean"])
    name = drive.sim.name
    if model == "true":
        from vislam.ekf.config import FilterConfig
        from vislam.eval.drives import apply_model_to, bench_sequence

        (bs,) = apply_model_to([bench_sequence(result)], drive_true_model(drive, result),
                               FilterConfig(), "true")
        study = run_drive(list(ESTIMATORS), bs, jobs=jobs)
    else:
        with tempfile.TemporaryDirectory(prefix="vislam-campaign-") as folder:
            paths = write_simulation(result, folder, name)
            study = run_drive(list(ESTIMATORS), paths["data"], model="identified", jobs=jobs)
    figures = {}
    for est in ESTIMATORS:
        if est in study.errors:
            figures[est] = EstimatorFigures(None, None, None, study.errors[est])
            continue
        s = study.scores[est]
        figures[est] = EstimatorFigures(s.get("ate_aligned_m"), s.get("rpe_trans_pct"),
                                        s.get("nees_pose_mean"))
    model = None
    if study.model is not None:
        model = {"mode": study.model.get("mode"), **(study.model.get("model") or {})}
    return DriveOutcome(drive, obs, figures, assess(figures), model, time.perf_counter() - t0,
                        time.process_time() - c0)


@dataclass(frozen=True)
class CampaignSummary:
    """Pass rates of a campaign: ``drives`` evaluated, ``passed`` per assertion and for both."""

    drives: int
    passed: dict[str, int] = field(default_factory=dict)

    def rate(self, name: str) -> float:
        return self.passed.get(name, 0) / self.drives if self.drives else math.nan


def summarise(outcomes: list[DriveOutcome]) -> CampaignSummary:
    """How many drives meet each assertion ("ate", "nees") and both ("both")."""
    passed = {"ate": 0, "nees": 0, "both": 0}
    for o in outcomes:
        for a in o.assertions:
            passed[a.name] += int(a.ok)
        passed["both"] += int(o.ok)
    return CampaignSummary(len(outcomes), passed)


__all__ = [
    "ATE_RATIO_MAX", "BASELINE", "DEFAULT_FRAMES", "EDITIONS", "ESTIMATORS", "FAULT_CLASSES",
    "NEES_ESTIMATORS", "SLAM_ESTIMATORS", "AssertionResult", "CampaignDrive", "CampaignSummary",
    "DriveOutcome", "EstimatorFigures", "SpeedScaleFault", "assess", "ate_ratio", "draw_drive",
    "evaluate_drive", "sparse_slow_speed_drive", "summarise",
]
