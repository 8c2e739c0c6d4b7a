"""The Monte Carlo study behind the consistency and agreement tests: one simulated drive, its
velocity and pixel noise redrawn per run (``eval.benchmark.redraw_noise``), every estimator on
every run (``eval.benchmark.run_jobs``, the smoother starting from the invariant EKF). Only small
per-run arrays are kept: pose NEES against truth, landmark NEES per source track, and each EKF's
pose NEES against the smoother of the same run (normalised by the EKF's covariance)."""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

import numpy as np

from vislam.ekf.config import FilterConfig

#: Monte Carlo size: runs x frames (2 worker processes: about a minute on 2 cores).
RUNS = 10
FRAMES = 120
SEED = 0
#: Logical estimators studied (the deliberate break may run another registry name for one).
ESTIMATORS = ("ekf-decoupled", "ekf-joint", "ekf-invariant", "smoother")
REFERENCE = "smoother"


@dataclass
class MonteCarlo:
    runs: int
    frames: int
    #: (runs, T) pose NEES against truth (NaN at step 0) per logical estimator.
    pose_nees: dict[str, np.ndarray] = field(default_factory=dict)
    #: (runs, n_source_tracks) landmark NEES against truth.
    landmark_nees: dict[str, np.ndarray] = field(default_factory=dict)
    #: (runs, T) EKF pose NEES against the smoother of the same run (NaN at step 0).
    versus_smoother: dict[str, np.ndarray] = field(default_factory=dict)
    errors: dict[str, list[str]] = field(default_factory=dict)
    wall_s: float = float("nan")

    def __repr__(self) -> str:  # pytest prints fixtures of failing tests: keep it short
        return f"MonteCarlo(runs={self.runs}, frames={self.frames}, wall_s={self.wall_s:.1f})"


#: The near field: landmarks within 25 m and no far points (the second case of the consistency
#: tests; on the default simulation far points are held in inverse depth).
NEAR_FIELD = {"max_depth": 25.0, "far_fraction": 0.0}


def run_monte_carlo(config: FilterConfig, run_name, runs: int = RUNS, frames: int = FRAMES,
                    seed: int = SEED, jobs: int = 2, sim_changes: dict | None = None) -> MonteCarlo:
    """The study for ``config``; ``run_name(logical) -> registry name`` (the deliberate break);
    ``sim_changes`` alter the default simulation (e.g. :data:`NEAR_FIELD`)."""
    from vislam.eval.benchmark import JobFailure, landmark_nees_by_source, redraw_noise, run_jobs
    from vislam.eval.consistency import pose_nees
    from vislam.eval.simulate import DEFAULT_SIM, simulate

    t0 = time.perf_counter()
    sim = dataclasses.replace(DEFAULT_SIM, seed=seed, n_frames=frames, name=f"regression-seed{seed}",
                              **(sim_changes or {}))
    truth = simulate(dataclasses.replace(sim, noise_free=True))
    T = truth.sequence.n_frames
    seqs = {f"run{i:03d}": redraw_noise(truth, sim, np.random.default_rng([seed, i])) for i in range(runs)}
    names = {n: run_name(n) for n in ESTIMATORS}
    to_run = list(dict.fromkeys(names.values()))
    by_run = {r: [n for n in ESTIMATORS if names[n] == r] for r in to_run}

    mc = MonteCarlo(runs, T)
    for n in ESTIMATORS:
        mc.pose_nees[n] = np.full((runs, T), np.nan)
        mc.landmark_nees[n] = np.full((runs, truth.landmarks.shape[0]), np.nan)
        mc.errors[n] = []
        if n != REFERENCE:
            mc.versus_smoother[n] = np.full((runs, T), np.nan)
    kept: dict[tuple[int, str], object] = {}  # the estimates of a run until its smoother is done
    frames_all = np.arange(T)

    def compare(i: int) -> None:
        ref = kept.get((i, names[REFERENCE]))
        if ref is None:
            return
        for n in ESTIMATORS:
            est = kept.get((i, names[n]))
            if n != REFERENCE and est is not None:
                mc.versus_smoother[n][i] = pose_nees(est, frames_all, ref.poses)

    def reduce(res) -> None:
        i = int(res.sequence[3:])
        if isinstance(res, JobFailure):
            for n in by_run[res.estimator]:
                mc.errors[n].append(res.error)
            return
        est = res.estimate
        for n in by_run[res.estimator]:
            mc.pose_nees[n][i] = pose_nees(est, frames_all, truth.poses)
            mc.landmark_nees[n][i] = landmark_nees_by_source(est, truth.landmarks)
        kept[(i, res.estimator)] = est
        if all((i, r) in kept for r in to_run):
            compare(i)
            for r in to_run:
                kept.pop((i, r))

    outcomes = run_jobs(seqs, to_run, config, jobs=jobs, show_progress=False, on_result=reduce)
    outcomes.clear()
    mc.wall_s = time.perf_counter() - t0
    return mc
