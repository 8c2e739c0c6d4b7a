"""The Monte Carlo engine of ``vislam nees`` and :mod:`vislam.testing`: one simulated drive, its
velocity and pixel noise redrawn per run (``numpy.random.default_rng([seed, run])``), every
estimator on every run (:func:`eval.study.run_jobs`), and per estimator and run the pose NEES
against truth (6 dof), the landmark NEES per source track (3 dof) and, with a reference
estimator, the pose NEES against the reference of the same run (:func:`run_monte_carlo`).
:func:`monte_carlo_nees` reduces a study to ``nees.json``'s content.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Any

import numpy as np

from vislam.ekf.config import FilterConfig
from vislam.ekf.errors import InputError
from vislam.ekf.estimate import Estimate
from vislam.ekf.sequence import Observations, Sequence
from vislam.eval.consistency import (
    LANDMARK_DOF,
    POSE_DOF,
    anees,
    chi2_bounds,
    landmark_nees,
    pose_nees,
)
from vislam.eval.imu_sim_config import ImuSimConfig
from vislam.eval.montecarlo_imu import (
    IMU_NOISE_WORDS,
    imu_monte_carlo_drives,
    imu_nees_config,
    run_seed,
    truth_in_estimate_gauge,
)
from vislam.eval.registry import display_name
from vislam.eval.sim_config import SIM_UPPER_BOUNDS
from vislam.eval.sim_drawing import drifting_noise
from vislam.eval.simulate import DEFAULT_SIM, SimConfig, simulate
from vislam.eval.study import JobFailure, run_groups
from vislam.graph.settings import SmootherSettings

#: Frames of each Monte Carlo drive of `vislam nees`.
DEFAULT_NEES_FRAMES = 200
#: Frames of the drives that set the landmark density of another range (nees_sim_config).
DENSITY_PROBE_FRAMES = 200


# --- the drives ------------------------------------------------------------------------------


def monte_carlo_drives(sim_config, runs: int) -> tuple:
    """The Monte Carlo drives of ``sim_config``: (its noise-free SimResult, ``{"run000": drive,
    ...}`` with the noise of run i drawn from ``numpy.random.default_rng([seed, i])``)."""
    truth = simulate(dataclasses.replace(sim_config, noise_free=True))
    seqs = {f"run{i:03d}": redraw_noise(truth, sim_config,
                                        np.random.default_rng([sim_config.seed, i]))
            for i in range(runs)}
    return truth, seqs


def redraw_noise(truth, sim_config, rng: np.random.Generator) -> Sequence:
    """The noise-free simulated drive ``truth`` (a SimResult made with ``noise_free=True``) with
    fresh velocity and pixel noise of ``sim_config``'s levels, drawn from ``rng``.

    The simulator draws all its streams from one seed (no separate noise seed), so the Monte
    Carlo runs add the noise here: same trajectory, landmarks and tracks in every run. As in the
    simulator, an observation whose noisy disparity falls below ``min_disparity`` is dropped
    (here the rest of its track is kept). A ``pixel_correlation`` drifts the pixel errors
    along each track as the simulator does (:func:`drift_along_tracks`).
    """
    seq = truth.sequence
    T = seq.n_frames
    u = np.asarray(truth.true_velocities, dtype=float).copy()
    u[:, :3] += sim_config.velocity_sigma * rng.standard_normal((T, 3))
    u[:, 3:] += sim_config.gyro_sigma * rng.standard_normal((T, 3)) + np.asarray(sim_config.gyro_bias)
    error = sim_config.pixel_sigma * rng.standard_normal(seq.obs.z.shape)
    if sim_config.pixel_correlation:
        error = drift_along_tracks(error, seq.obs.frame_index, seq.obs.track,
                                   sim_config.pixel_correlation)
    z = seq.obs.z + error
    keep = (z[:, 0] - z[:, 2]) >= sim_config.min_disparity
    obs = Observations.from_rows(seq.obs.frame_index[keep], seq.obs.track[keep], z[keep], T)
    return dataclasses.replace(
        seq, linear_velocity=u[:, :3].copy(), angular_velocity=u[:, 3:].copy(), obs=obs
    )


def drift_along_tracks(white: np.ndarray, frame: np.ndarray, track: np.ndarray,
                       a: float) -> np.ndarray:
    """Pixel errors (N, 4) drifting along each track (AR(1) with correlation ``a`` between
    observations of a track in consecutive frames) from white draws ``white``, frame by frame
    as the simulator makes them."""
    out = np.empty_like(white)
    track = np.asarray(track, dtype=np.int64)
    last = np.zeros((int(track.max(initial=-1)) + 1, 4))
    last_frame = np.full(last.shape[0], -2, dtype=np.int64)
    order = np.argsort(frame, kind="stable")
    bounds = np.flatnonzero(np.diff(np.asarray(frame)[order])) + 1
    for rows in np.split(order, bounds):
        k, t = int(frame[rows[0]]), track[rows]
        out[rows] = drifting_noise(white[rows], last[t], last_frame[t] == k - 1, a)
        last[t], last_frame[t] = out[rows], k
    return out


def landmark_nees_by_source(est: Estimate, truth: np.ndarray) -> np.ndarray:
    """Landmark NEES per source track (n_source,): a cleaned estimate's tracks are mapped back
    through ``info["track_origin"]`` (the first track of a split one counts)."""
    nees = landmark_nees(est, truth)
    out = np.full(truth.shape[0], np.nan)
    origin = est.info.get("track_origin")
    origin = np.arange(nees.size) if origin is None else np.asarray(origin, dtype=np.int64)
    ok = np.isfinite(nees) & (origin >= 0) & (origin < out.size)
    idx = np.nonzero(ok)[0][::-1]  # reversed: the first of duplicates is written last
    out[origin[idx]] = nees[idx]
    return out


def nees_sim_config(seed: int, frames: int | None = None, max_depth: float | None = None):
    """The SimConfig of `vislam nees`: the simulator's default drive (``seed``, ``frames``
    steps) with landmarks up to ``max_depth`` m deep (None: the default 60 m, the drive as it
    is). The landmark density is per metre of path and most landmarks stand 4-50 m to the side,
    so a shorter range alone empties the view (10 m: about one observation per frame instead of
    80) and a longer one crowds it; with another range the density is scaled so the drive keeps
    the default range's observations per frame, counted on noise-free drives of the seed,
    ``DENSITY_PROBE_FRAMES`` frames long, at both ranges (capped at the simulator's largest
    density)."""
    config = dataclasses.replace(
        DEFAULT_SIM, seed=int(seed), n_frames=int(frames or DEFAULT_NEES_FRAMES), name=f"mc-seed{seed}"
    )
    if max_depth is None or max_depth == config.max_depth:
        return config
    probe = dataclasses.replace(config, n_frames=DENSITY_PROBE_FRAMES, noise_free=True)
    wanted = simulate(probe).sequence.obs.frame_index.size
    seen = simulate(dataclasses.replace(probe, max_depth=float(max_depth))).sequence.obs.frame_index.size
    top = SIM_UPPER_BOUNDS["landmark_density"]
    density = min(config.landmark_density * wanted / seen, top) if seen else top
    return dataclasses.replace(config, max_depth=float(max_depth), landmark_density=density)


def study_sim_config(sim=None, seed: int | None = None, frames: int | None = None):
    """The drive of :func:`vislam.testing.monte_carlo`: the simulator's default (``seed`` 0,
    ``frames`` 120) with ``sim``'s changes (a dict of SimConfig fields), or ``sim`` a SimConfig
    as it is."""
    if isinstance(sim, SimConfig):
        if seed is not None or frames is not None:
            raise ValueError("sim is a SimConfig: its seed and n_frames are used; leave seed and "
                             "frames out")
        return sim
    if sim is not None and not isinstance(sim, Mapping):
        raise TypeError(f"sim: None, a dict of SimConfig fields or a SimConfig, got {type(sim).__name__}")
    seed = 0 if seed is None else int(seed)
    frames = 120 if frames is None else int(frames)
    changes = dict(sim or {})
    changes.setdefault("name", f"monte-carlo-seed{seed}")
    return dataclasses.replace(DEFAULT_SIM, seed=seed, n_frames=frames, **changes)


# --- the engine ------------------------------------------------------------------------------


@dataclass(frozen=True)
class RunFailure:
    """A failed run of an estimator: ``run`` its key ("run003"; None when a user's estimator
    stopped all its remaining runs) and the error."""

    run: str | None
    error: str

    def __str__(self) -> str:
        return self.error if self.run is None else f"{self.run}: {self.error}"


@dataclass
class MonteCarloRuns:
    """What :func:`run_monte_carlo` measured, per estimator label: ``pose_nees`` (runs, T)
    against truth, NaN at step 0 and in failed runs; ``landmark_nees`` (runs, n_source_tracks),
    NaN where no landmark was estimated; ``versus_reference`` (runs, T) the pose NEES against
    the reference of the same run under the estimator's covariance (not for the reference
    itself); ``completed`` (runs,) which runs gave an estimate; ``failures`` in the order they
    came; ``runtime_s`` the wall time of each completed run."""

    sim: Any  # eval.simulate.SimConfig
    runs: int
    frames: int
    timestamps: np.ndarray  # (T,) s, of the drive
    reference: str | None
    labels: tuple[str, ...]
    pose_nees: dict[str, np.ndarray] = field(default_factory=dict)
    landmark_nees: dict[str, np.ndarray] = field(default_factory=dict)
    versus_reference: dict[str, np.ndarray] = field(default_factory=dict)
    completed: dict[str, np.ndarray] = field(default_factory=dict)
    failures: dict[str, list[RunFailure]] = field(default_factory=dict)
    runtime_s: dict[str, list[float]] = field(default_factory=dict)


def run_monte_carlo(sim_config, runs: int, estimators: Mapping[str, Any], config: FilterConfig,
                    *, reference: str | None = None, smoother: SmootherSettings | None = None,
                    jobs: int = 1, isolate_user_estimators: bool = False,
                    show_progress: bool = False, executor: str = "local",
                    scheduler: str | None = None) -> MonteCarloRuns:
    """Every estimator of ``estimators`` ({label: name, ``MODULE:FUNCTION`` or callable}) on
    ``runs`` noise draws of ``sim_config``'s drive (:func:`monte_carlo_drives`; an
    :class:`eval.imu_sim_config.ImuSimConfig`: :func:`eval.montecarlo_imu.imu_monte_carlo_drives`,
    each estimate scored against the truth in its own gauge), reduced run by run to the NEES
    arrays (no estimate is kept). ``reference`` a label among ``estimators``
    the others are compared with (None: none). ``isolate_user_estimators``: a user's estimator
    that raises or breaks the Estimate contract stops only its own runs (recorded as a
    failure), instead of the whole study (:func:`eval.study.run_groups`). ``jobs``,
    ``executor`` and ``scheduler``: where the runs go; the numbers depend on none of them."""
    if reference is not None and reference not in estimators:
        raise ValueError(f"reference {reference!r} is not among the estimators")
    raw_imu = isinstance(sim_config, ImuSimConfig)
    if raw_imu:  # the truth moves into each estimate's gauge (eval.montecarlo_imu)
        imu_truth, free, seqs = imu_monte_carlo_drives(sim_config, runs)
        true_poses, true_landmarks = imu_truth.frame_poses, imu_truth.landmarks
        timestamps = free.timestamps
    else:
        truth, seqs = monte_carlo_drives(sim_config, runs)
        true_poses, true_landmarks = truth.poses, truth.landmarks
        timestamps = truth.sequence.timestamps
    T = timestamps.size
    out = MonteCarloRuns(sim_config, runs, T, timestamps, reference, tuple(estimators))
    by_run: dict[str, list[str]] = {}  # display name -> its labels (one run serves them all)
    for label, spec in estimators.items():
        by_run.setdefault(display_name(spec), []).append(label)
    for n in estimators:
        out.pose_nees[n] = np.full((runs, T), np.nan)
        out.landmark_nees[n] = np.full((runs, true_landmarks.shape[0]), np.nan)
        out.completed[n] = np.zeros(runs, dtype=bool)
        out.failures[n] = []
        out.runtime_s[n] = []
        if reference is not None and n != reference:
            out.versus_reference[n] = np.full((runs, T), np.nan)
    frames_all = np.arange(T)
    ref_poses: dict[int, np.ndarray] = {}  # run -> the reference's poses
    waiting: dict[int, list] = {}  # run -> [(labels, poses, pose_cov)] until its reference is done

    def compare(i: int, labels, poses, cov) -> None:
        est = SimpleNamespace(n_frames=T, poses=poses, pose_cov=cov)
        nees = pose_nees(est, frames_all, ref_poses[i])
        for n in labels:
            if n != reference:
                out.versus_reference[n][i] = nees

    def reduce(res) -> None:
        i = int(res.sequence[3:])
        labels = by_run[res.estimator]
        if isinstance(res, JobFailure):
            for n in labels:
                out.failures[n].append(RunFailure(res.sequence, res.error))
            return
        est = res.estimate
        poses, landmarks = true_poses, true_landmarks
        if raw_imu:
            poses, landmarks = truth_in_estimate_gauge(seqs[res.sequence], est, poses, landmarks)
        pn = pose_nees(est, frames_all, poses)
        ln = landmark_nees_by_source(est, landmarks)
        for n in labels:
            out.pose_nees[n][i] = pn
            out.landmark_nees[n][i] = ln
            out.completed[n][i] = True
            out.runtime_s[n].append(res.wall_s)
        if reference is None:
            return
        if reference in labels:
            ref_poses[i] = np.array(est.poses)
            for item in waiting.pop(i, []):
                compare(i, *item)
        if any(n != reference for n in labels):
            item = (labels, np.array(est.poses), np.array(est.pose_cov))
            if i in ref_poses:
                compare(i, *item)
            else:
                waiting.setdefault(i, []).append(item)

    def stopped(run_label: str, message: str) -> None:
        for n in by_run[run_label]:
            done = int(np.count_nonzero(out.completed[n]))
            out.failures[n].append(RunFailure(None, f"{message} (a user's estimator that fails "
                                                    f"stops its runs: {done} done before)"))

    run_groups(seqs, list(estimators.values()), config, jobs, smoother, reduce,
               stopped if isolate_user_estimators else None, show_progress=show_progress,
               executor=executor, scheduler=scheduler)
    return out


# --- nees.json -------------------------------------------------------------------------------


def monte_carlo_nees(
    runs: int,
    seed: int,
    estimators: list[str],
    config: FilterConfig,
    frames: int | None = None,
    jobs: int = 1,
    show_progress: bool = True,
    smoother: SmootherSettings | None = None,
    sim_max_depth: float | None = None,
    executor: str = "local",
    scheduler: str | None = None,
    *,
    imu: bool = False,
    scenario: str = "room",
    camera: str = "mono",
) -> dict:
    """ANEES of pose (6 dof, steps 1..T-1) and landmarks (3 dof) over ``runs`` noise draws of
    one simulated drive (seed ``seed``, landmarks up to ``sim_max_depth`` m deep: see
    :func:`nees_sim_config`); the nees.json content. ``executor`` and ``scheduler``: where the
    runs go (:func:`eval.study.run_jobs`); the numbers do not depend on it, nor on ``jobs``.

    ``imu``: raw-IMU drives of the raw-IMU simulator instead (``scenario``, ``camera``: the
    scene of :func:`eval.montecarlo_imu.imu_nees_config`, each run with its own simulator seed),
    each estimate scored against the truth in its own gauge; ``sim_max_depth`` must be None."""
    smoother = smoother if smoother is not None else SmootherSettings()
    if runs < 1:
        raise InputError(f"--runs must be >= 1, got {runs}")
    if imu and sim_max_depth is not None:
        raise InputError("--sim-max-depth: a setting of the velocity simulator; the raw-IMU "
                         "simulator sees landmarks within its scenario's range")
    if imu:
        sim_config = imu_nees_config(seed, scenario, camera, frames)
    else:
        sim_config = nees_sim_config(seed, frames, sim_max_depth)
    # a user's callable by MODULE:FUNCTION
    study = run_monte_carlo(sim_config, runs, {display_name(e): e for e in estimators}, config,
                            smoother=smoother, jobs=jobs, show_progress=show_progress,
                            executor=executor, scheduler=scheduler)
    out = {
        "runs": runs,
        "seed": seed,
        "frames": study.frames,
        "drive_kind": "raw-imu" if imu else "velocity",
        "noise": IMU_NOISE_WORDS if imu else
                 "velocity and pixel noise redrawn per run (numpy default_rng([seed, run])) on "
                 "the noise-free drive of SimConfig(seed); trajectory, landmarks, tracks fixed",
        "definition": "anees_pose: mean over steps 1..T-1 of the per-step NEES averaged over runs; "
                      "anees_landmark: mean over landmarks (estimated in every run) of the per-"
                      "landmark NEES averaged over runs; bounds chi2.ppf([.025,.975], N d)/N; "
                      "verdict 'above' = overconfident, 'below' = underconfident; "
                      "inside_fraction = share of steps / landmarks inside the bounds",
        "simulation": dataclasses.asdict(sim_config),
        **({"noise_seeds": [run_seed(seed, i) for i in range(runs)],
            "truth": "in each estimate's gauge: moved about gravity and translated onto its "
                     "frame-0 yaw and position (eval.bench_scores.truth_in_gauge), landmarks "
                     "by the same move"} if imu else {}),
        "filter": config.to_dict(),
        "smoother": smoother.to_dict(),
        "estimators": {},
    }
    for n in study.labels:
        pose, landmark, runtime = study.pose_nees[n], study.landmark_nees[n], study.runtime_s[n]
        errors = [f.error for f in study.failures[n]]
        p = anees(pose[:, 1:], POSE_DOF)
        lm_ok = np.any(np.isfinite(landmark), axis=0)
        lm = anees(landmark[:, lm_ok], LANDMARK_DOF) if np.any(lm_ok) else None
        per_step = np.concatenate([[np.nan], p.per_item])
        out["estimators"][n] = {
            "anees_pose": p.mean,
            "anees_landmark": lm.mean if lm else None,
            "bounds_pose": list(p.bounds),
            "bounds_landmark": list(lm.bounds if lm else chi2_bounds(runs, LANDMARK_DOF)),
            "verdict_pose": p.verdict,
            "verdict_landmark": lm.verdict if lm else None,
            "inside_fraction_pose": p.inside_fraction,
            "inside_fraction_landmark": lm.inside_fraction if lm else None,
            "landmarks_scored": int(np.count_nonzero(np.isfinite(lm.per_item))) if lm else 0,
            "runs_failed": len(errors),
            "errors": errors[:3],
            "runtime_s_mean": float(np.mean(runtime)) if runtime else None,
            "nees_pose_over_time": per_step,
            "nees_pose_per_run_mean": [
                float(np.nanmean(r[1:])) if np.any(np.isfinite(r[1:])) else None for r in pose
            ],
        }
    out["timestamps"] = study.timestamps - study.timestamps[0]
    return out
