"""The raw-IMU drives of a Monte Carlo consistency study (``vislam nees --imu``): one simulated
scene (:mod:`eval.imu_sim`: trajectory and landmarks of ``scene_seed``), each run with its own
simulator seed (biases, IMU noise and pixel noise), and the truth each estimate is scored
against, in that estimate's own gauge as ``vislam bench`` scores raw-IMU drives
(:func:`eval.bench_scores.truth_in_gauge`).

Run ``i`` of a study of seed ``S`` is ``ImuSimConfig(scene_seed=S, seed=run_seed(S, i))``: the
same trajectory, landmarks and tracks in every run (visibility is decided before the pixel
noise), the noise of run ``i`` drawn from ``numpy.random.SeedSequence([S, i])`` as the velocity
simulator's runs draw theirs from ``default_rng([S, i])`` (:func:`eval.montecarlo.redraw_noise`).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from vislam.ekf.estimate import Estimate
from vislam.ekf.inertial import InertialDrive
from vislam.eval.bench_scores import landmark_truth_in_gauge, truth_in_gauge
from vislam.eval.groundtruth import GroundTruth
from vislam.eval.imu_sim import ImuTruth, simulate_imu
from vislam.eval.imu_sim_config import ImuSimConfig

#: Camera frames of each raw-IMU Monte Carlo drive (10 s at 20 Hz: the 2 s rest, the start and
#: 7 s of motion; the length of benchmarks/inertial_smoother_nees.py's drives).
DEFAULT_IMU_NEES_FRAMES = 201

#: What the runs of a raw-IMU study share and what each draws anew, in words (nees.json).
IMU_NOISE_WORDS = ("trajectory, landmarks and tracks of ImuSimConfig(scene_seed=seed) fixed; run "
                   "i simulated with its own seed, noise_seeds[i] (numpy SeedSequence([seed, i])), "
                   "which draws its initial biases, bias walks, IMU white noise and pixel noise")


def run_seed(seed: int, run: int) -> int:
    """The simulator seed of run ``run`` of a study of seed ``seed``: the first 63 bits that
    ``numpy.random.SeedSequence([seed, run])`` generates (every run its own noise, the same
    for the same ``seed`` and ``run``)."""
    word = np.random.SeedSequence([int(seed), int(run)]).generate_state(1, np.uint64)[0]
    return int(word >> np.uint64(1))


def imu_nees_config(seed: int, scenario: str = "room", camera: str = "mono",
                    frames: int | None = None) -> ImuSimConfig:
    """The scene of a raw-IMU study: the simulator's defaults with ``scenario``, ``camera`` and
    ``frames`` camera frames (None: :data:`DEFAULT_IMU_NEES_FRAMES`), its trajectory and
    landmarks drawn by ``scene_seed = seed``. A bad value is an InputError naming it."""
    n = DEFAULT_IMU_NEES_FRAMES if frames is None else int(frames)
    return ImuSimConfig(seed=int(seed), scene_seed=int(seed), scenario=scenario, camera=camera,
                        n_frames=n, name=f"mc-imu-{scenario}-{camera}-seed{seed}")


def imu_monte_carlo_drives(config: ImuSimConfig, runs: int
                           ) -> tuple[ImuTruth, InertialDrive, dict[str, InertialDrive]]:
    """The truth of ``config``'s scene (its noise-free drive's :class:`ImuTruth`), that
    noise-free drive, and ``{"run000": drive, ...}``: run ``i`` simulated with seed
    :func:`run_seed` ``(config.scene, i)`` on the same scene."""
    base = dataclasses.replace(config, noise_free=False)
    free, truth = simulate_imu(dataclasses.replace(base, seed=config.scene, noise_free=True))
    drives = {}
    for i in range(runs):
        key = f"run{i:03d}"
        drive, _ = simulate_imu(dataclasses.replace(base, seed=run_seed(config.scene, i)))
        drives[key] = dataclasses.replace(drive, name=f"{config.drive_name}-{key}")
    return truth, free, drives


def truth_in_estimate_gauge(drive: InertialDrive, est: Estimate, poses: np.ndarray,
                            landmarks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The true poses (T, 4, 4) and landmarks (n_tracks, 3) of a simulated raw-IMU drive (the
    simulator's gravity-aligned world) moved into ``est``'s gauge: the rotation about gravity
    and the translation that put the truth's frame-0 pose on the estimate's in yaw and position
    (:func:`eval.bench_scores.truth_in_gauge`, what ``vislam bench`` scores poses with); the
    landmarks by the same move, so that map and poses are scored in one world."""
    gt = GroundTruth(np.arange(poses.shape[0]), poses, source="simulation")
    return (truth_in_gauge(gt, drive, est).poses,
            landmark_truth_in_gauge(gt, drive, est, landmarks))
