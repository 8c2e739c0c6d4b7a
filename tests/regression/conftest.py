"""Fixtures of the regression tests (settings and the deliberate break: tests/regression/breaks.py)."""

from __future__ import annotations

import os
from pathlib import Path

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
