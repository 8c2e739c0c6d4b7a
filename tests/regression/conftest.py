"""Fixtures of the regression tests (settings and the deliberate break: tests/regression/breaks.py)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from vislam.ekf.config import FilterConfig
from tests.regression.breaks import REPO, broken_config, regression_break, run_name, skip_or_fail


@pytest.fixture(scope="session")
def regression_config() -> FilterConfig:
    """The filter settings every regression test runs with (the defaults, unless broken)."""
    config = broken_config(FilterConfig())
    brk = regression_break()
    if brk:
        print(f"\nVISLAM_REGRESSION_BREAK={brk}: deliberately broken estimators")
    return config


@pytest.fixture(scope="session")
def kitti_data_dir() -> Path:
    """The folder of the shared KITTI drives."""
    env = os.environ.get("VISLAM_DATA")
    folder = Path(env) if env else REPO.parent / "shared" / "data" / "kitti-pr3"
    if not folder.is_dir():
        skip_or_fail(f"data folder {folder} not found (set VISLAM_DATA)")
    return folder


#: EuRoC V1_01 (the ASL folder; its first 30 s of camera tracks ship inside gtsam's wheel).
EUROC = REPO.parent / "shared" / "data" / "euroc-v1_01"


@pytest.fixture(scope="session")
def euroc_drive():
    """EuRoC V1_01's first 30 s as a raw-IMU drive (the ASL IMU and noise, gtsam's eqvio tracks)
    and the true ``world_T_imu`` at its camera frames (within 1 ms) in the raw-IMU smoother's
    world, read once per session for every test of a raw-IMU estimator on it."""
    if not (EUROC / "mav0" / "imu0" / "data.csv").is_file():
        skip_or_fail(f"EuRoC V1_01 not found at {EUROC}")
    from vislam.ekf.errors import InputError
    from vislam.eval.asl import read_asl_folder
    from vislam.eval.eqvio import EQVIO_FILE
    from vislam.eval.trajectory_files import read_trajectory
    from vislam.graph.inertial_init import to_gravity_world

    try:
        drive = read_asl_folder(EUROC, "eqvio")
    except (InputError, OSError) as exc:  # gtsam without its eqvio file
        skip_or_fail(f"{EQVIO_FILE} not readable: {exc}")
    gt = read_trajectory(EUROC / "groundtruth" / "V1_01_easy.csv")
    t = drive.timestamps + drive.time_origin_ns * 1e-9
    i = np.clip(np.searchsorted(gt.times, t - 1e-3), 0, gt.times.size - 1)
    assert np.all(np.abs(gt.times[i] - t) < 1e-3)
    return drive, to_gravity_world(gt.poses[i])


@pytest.fixture(scope="session")
def monte_carlo(regression_config):
    """The Monte Carlo study on the near-field simulation (tests/regression/simulation.py,
    NEAR_FIELD: landmarks within 25 m, the second case), run once per session."""
    from tests.regression.simulation import NEAR_FIELD, run_monte_carlo

    mc = run_monte_carlo(regression_config, run_name, sim_changes=NEAR_FIELD)
    print(f"\nMonte Carlo (near field): {mc.runs} runs x {mc.frames} frames in {mc.wall_s:.1f} s")
    return mc


@pytest.fixture(scope="session")
def monte_carlo_default(regression_config):
    """The same study on the default simulation (landmarks to 60 m), run once per session."""
    from tests.regression.simulation import run_monte_carlo

    mc = run_monte_carlo(regression_config, run_name)
    print(f"\nMonte Carlo (default simulation): {mc.runs} runs x {mc.frames} frames in {mc.wall_s:.1f} s")
    return mc
