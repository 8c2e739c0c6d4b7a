"""A raw-IMU drive's camera-IMU time offset by maximum likelihood around the raw-IMU smoother
(issue 39 item 1; the key ``imu_time_offset``, s, positive when the IMU's stamps are late
against the camera's: :func:`ekf.inertial.imu_on_camera_clock` applies it).

**The profile.** With the IMU's stamps moved by ``-d`` onto the camera's clock, every interval's
preintegrated measurement changes (its samples, and the pieces of the first and last one, by
:func:`ekf.strapdown.held_pieces`: a continuous function of ``d``), and with the noise models
fixed the negative log-likelihood of ``d``, the states and landmarks profiled out, is the
smoother's graph error at its minimum, ``C(d) = min 1/2 sum |r|^2`` (the Huber kernel's cost
for the pixels; the log-determinants do not depend on ``d``). So each cost (``_Profile.cost``) is one
Levenberg-Marquardt solve of the smoother's batch graph with the IMU factors preintegrated
again, warm-started from the solution at the nearest offset already tried; the pixel sigma,
the landmarks and the outlier set are those of one batch solve at ``d = 0``
(:func:`graph.inertial_smoother.batch_solve`), so that only ``d`` moves the cost.

**The search.** A bracket of the minimum from ``d = 0`` (steps of ``FIRST_STEP``, doubled
downhill, never beyond ``SEARCH_LIMIT``), then SciPy's bounded Brent minimisation
(:func:`scipy.optimize.minimize_scalar`) inside it to ``XATOL``. The drive is cut to the
frames ``SEARCH_LIMIT`` inside the IMU's span at both ends, so that every offset tried covers
the same frames. **The sigma** is the profile's curvature, ``sigma = H / sqrt(2 dC)`` with
``dC`` the mean rise of ``C`` at ``d_hat +- H``, ``H`` from ``CURVATURE_STEP`` grown 3x at a
time until the rise is at least ``MIN_RISE`` (measured over about a sigma, where the profile is
quadratic and the solver's tolerance negligible).

**The decision** is the BIC's, as for the velocity streams' offsets (:mod:`graph.time_offset`):
the offset is kept when the likelihood ratio ``2 (C(0) - C(d_hat))`` exceeds ``ln n``, ``n`` the
IMU intervals; otherwise it is zero. An estimate at the search limit is not kept (the drive's
offset may lie beyond it); :attr:`ImuOffsetFit.at_limit` says so. The sigma is that of the
noise model in force (the data sheet's, or the identified one): under figures that misweigh the
IMU against vision it is off by as much.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import minimize_scalar

from vislam.ekf.errors import InputError
from vislam.ekf.filter import ImuSamples
from vislam.ekf.inertial import InertialDrive, with_frames
from vislam.graph.inertial_factors import preintegrate, preintegration_params
from vislam.graph import inertial_smoother as smoother

#: Offsets tried at most (s, either sign); the frames this close to the IMU's ends are left out.
SEARCH_LIMIT = 0.2
#: The bracket's first step (s).
FIRST_STEP = 0.005
#: Brent's absolute tolerance on the offset (s).
XATOL = 1e-4
#: The curvature's first half-width (s), and the smallest rise of the cost it is read from.
CURVATURE_STEP = 0.002
MIN_RISE = 0.5
#: Fewest frames the cut drive must keep.
MIN_FRAMES = 10


@dataclass
class ImuOffsetFit:
    """The camera-IMU offset of one drive (module docstring); seconds throughout."""

    estimate: float  # the profile's minimum
    sigma: float
    statistic: float  # 2 (C(0) - C(estimate))
    n_intervals: int
    at_limit: bool
    #: every offset tried and its cost C, ascending in offset
    profile: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    frames_used: int = 0
    pixel_sigma: float = float("nan")
    seconds: float = 0.0

    @property
    def threshold(self) -> float:
        """The BIC's threshold on :attr:`statistic`, ``ln n``."""
        return float(np.log(max(self.n_intervals, 2)))

    @property
    def kept(self) -> bool:
        return bool(self.statistic > self.threshold and not self.at_limit)

    @property
    def offset(self) -> float:
        """The offset to apply: the estimate when kept, else 0."""
        return float(self.estimate) if self.kept else 0.0

    def words(self) -> str:
        """The estimate, its sigma and the decision, in words."""
        est = f"{1e3 * self.estimate:+.2f} +- {1e3 * self.sigma:.2f} ms"
        if self.at_limit:
            return (f"the likelihood still falls at the search limit ({1e3 * self.estimate:+.0f} "
                    "ms): the offset may be larger; not applied")
        verdict = (f"kept (likelihood ratio {self.statistic:.3g} > ln n = {self.threshold:.3g})"
                   if self.kept else f"not supported by the data (likelihood ratio "
                   f"{self.statistic:.3g} <= ln n = {self.threshold:.3g}): zero")
        return f"{est}, {verdict}"

    def to_dict(self) -> dict:
        return {"estimate_s": float(self.estimate), "sigma_s": float(self.sigma),
                "statistic": float(self.statistic), "threshold": self.threshold,
                "kept": self.kept, "at_limit": bool(self.at_limit), "offset_s": self.offset,
                "n_intervals": int(self.n_intervals), "frames_used": int(self.frames_used),
                "seconds": float(self.seconds)}


@dataclass
class _Profile:
    """The cut drive, the fixed parts of its batch graph, and every solve so far."""

    drive: InertialDrive
    problem: smoother.InertialProblem
    solution: smoother.Solution
    params: object
    solved: dict = field(default_factory=dict)  # offset -> (cost, values)

    def cost(self, d: float) -> float:
        d = float(d)
        if d in self.solved:
            return self.solved[d][0]
        nearest = min(self.solved, key=lambda x: abs(x - d)) if self.solved else None
        start = self.solution.values if nearest is None else self.solved[nearest][1]
        drive = _stamps_moved(self.drive, d)
        t = drive.timestamps
        pims = [preintegrate(drive.imu, float(t[k - 1]), float(t[k]), self.params, self.problem.bias0)
                for k in range(1, t.size)]
        problem = dataclasses.replace(self.problem, drive=drive, pims=pims)
        graph = smoother._graph(problem, self.solution.rows, self.solution.anchors)
        values = smoother._lm(problem, graph, start, f"the time offset's profile at {d:+.4f} s")
        cost = float(graph.error(values))
        self.solved[d] = (cost, values)
        return cost

    def table(self) -> np.ndarray:
        return np.array(sorted((d, c) for d, (c, _) in self.solved.items()), dtype=float).reshape(-1, 2)


def _stamps_moved(drive: InertialDrive, d: float) -> InertialDrive:
    """``drive`` with its IMU's stamps earlier by ``d`` (its frames and time origin as they are:
    the search's cut drive keeps every frame covered for ``|d|`` up to the limit)."""
    imu = drive.imu
    return dataclasses.replace(drive, imu=ImuSamples(imu.time - d, imu.accel, imu.gyro))


def _profile_frames(drive: InertialDrive) -> np.ndarray:
    t, ti = np.asarray(drive.timestamps), drive.imu.time
    return np.flatnonzero((t >= ti[0] + SEARCH_LIMIT) & (t <= ti[-1] - SEARCH_LIMIT))


def too_short(drive: InertialDrive) -> str | None:
    """Why ``drive`` is too short for the search (None when it is not)."""
    n = int(_profile_frames(drive).size)
    if n >= MIN_FRAMES:
        return None
    return (f"{drive.name}: {n} camera frames lie more than {SEARCH_LIMIT:g} s inside the IMU's "
            f"span; the time offset needs {MIN_FRAMES} or more")


def profile_drive(drive: InertialDrive) -> InertialDrive:
    """The frames that every offset within the search limit keeps covered by the IMU."""
    why = too_short(drive)
    if why is not None:
        raise InputError(why)
    return with_frames(drive, _profile_frames(drive))


def _bracket(cost) -> tuple[float, float, float]:
    """``(a, b, c)`` with ``C(b)`` below ``C(a)`` and ``C(c)`` (or ``b`` at the limit)."""
    c0, cm, cp = cost(0.0), cost(-FIRST_STEP), cost(FIRST_STEP)
    if c0 <= cm and c0 <= cp:
        return -FIRST_STEP, 0.0, FIRST_STEP
    sign = 1.0 if cp < cm else -1.0
    a, b, step = 0.0, sign * FIRST_STEP, FIRST_STEP
    while True:
        step *= 2.0
        nxt = float(np.clip(b + sign * step, -SEARCH_LIMIT, SEARCH_LIMIT))
        if nxt == b or cost(nxt) >= cost(b):
            return (a, b, nxt) if sign > 0 else (nxt, b, a)
        a, b = b, nxt


def identify_imu_time_offset(drive: InertialDrive,
                             settings: smoother.InertialSmootherSettings = smoother.InertialSmootherSettings()
                             ) -> ImuOffsetFit:
    """The camera-IMU offset of ``drive`` under its calibration's IMU noise (module docstring).
    Ground truth is never used."""
    start = time.perf_counter()
    cut = profile_drive(drive)
    first = _profile_round(cut, settings)
    fit = first
    if first.kept:  # again about the estimate: its own outlier set and pixel sigma
        second = _profile_round(_stamps_moved(cut, first.estimate), settings)
        if not second.at_limit:
            fit = dataclasses.replace(second, estimate=first.estimate + second.estimate,
                                      profile=first.profile, statistic=first.statistic)
    return dataclasses.replace(fit, seconds=time.perf_counter() - start)


def _profile_round(cut: InertialDrive, settings: smoother.InertialSmootherSettings) -> ImuOffsetFit:
    """One profile about the IMU stamps of ``cut`` as they are: its minimum, sigma and test."""
    settings = dataclasses.replace(settings, compute_marginals=False)
    problem, initial = smoother.robust_initial_solve(smoother.build_problem(cut, settings))
    solution = smoother.batch_solve(problem, initial)
    pixel, robust = smoother.pixel_noise_models(solution.pixel_sigma, settings.huber_k,
                                                problem.stereo is not None)
    problem = dataclasses.replace(problem, pixel_noise=pixel, robust_noise=robust,
                                  pixel_sigma=solution.pixel_sigma)
    c = cut.calibration
    prof = _Profile(cut, problem, solution,
                    preintegration_params(c.noise, c.gravity, settings.imu_noise_inflation))
    a, b, cc = _bracket(prof.cost)
    if abs(b) < SEARCH_LIMIT:
        minimize_scalar(prof.cost, bounds=(a, cc), method="bounded", options={"xatol": XATOL})
    d_hat = min(prof.solved, key=lambda x: prof.solved[x][0])
    at_limit = abs(d_hat) >= SEARCH_LIMIT - XATOL
    sigma = float("nan")
    h = CURVATURE_STEP
    while not at_limit and h <= SEARCH_LIMIT:
        lo, hi = max(d_hat - h, -SEARCH_LIMIT), min(d_hat + h, SEARCH_LIMIT)
        rise = 0.5 * (prof.cost(lo) + prof.cost(hi)) - prof.cost(d_hat)
        if rise >= MIN_RISE:
            sigma = float(h / np.sqrt(2.0 * rise))
            break
        h *= 3.0
    statistic = 2.0 * (prof.cost(0.0) - prof.cost(d_hat))
    return ImuOffsetFit(float(d_hat), sigma, float(max(statistic, 0.0)), cut.n_frames - 1,
                        bool(at_limit), prof.table(), cut.n_frames, float(solution.pixel_sigma))
