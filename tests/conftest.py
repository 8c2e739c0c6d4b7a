"""Shared fixtures: where the real drives are, and a session cache of loaded drives.

Real-data tests skip with a clear reason when the data folder or a drive is absent, except in
CI (``CI=true``), where a missing drive is a failure: CI must never pass by skipping them.
"""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings

# Property-based tests are deterministic (fixed seed via derandomize) and bounded, so CI gives
# the same verdict every time and the whole hypothesis suite stays well under two minutes.
settings.register_profile(
    "vislam",
    derandomize=True,
    deadline=None,
    max_examples=50,
    print_blob=True,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
settings.load_profile("vislam")

from vislam.eval.datasets import DATA_ENV, SHARED_DRIVES, data_dir as _data_dir
from vislam.eval.datasets import drive_path as _drive_path


def pytest_configure(config):
    config.addinivalue_line(
        "markers", "realdata: reads the shared KITTI drives (skipped where absent, never in CI)"
    )


def missing_data(reason: str):
    """Skip the test, or fail it in CI (``CI=true``), because real data is absent."""
    if os.environ.get("CI") == "true":
        pytest.fail(f"{reason} (CI=true: real-data tests must run)")
    pytest.skip(reason)


@pytest.fixture(scope="session")
def data_dir() -> Path:
    """The folder of the shared drives ($VISLAM_DATA or ../shared/data/kitti-pr3)."""
    folder = _data_dir()
    if not folder.is_dir():
        missing_data(f"data folder {folder} not found (set {DATA_ENV} to the shared drives)")
    return folder


@pytest.fixture(scope="session")
def drive_path(data_dir):
    """Factory: ``drive_path("0027")`` -> the .npz path (skips/fails if it is absent)."""

    def get(name: str) -> Path:
        path = _drive_path(name, data_dir)
        if not path.is_file():
            missing_data(f"drive {path} not found in {data_dir}")
        return path

    return get


@pytest.fixture(scope="session")
def load_drive(drive_path):
    """Factory: ``load_drive("0027")`` -> the loaded Sequence, read once per session."""
    from vislam.eval.loader import load_sequence

    cache: dict[str, object] = {}

    def get(name: str):
        if name not in cache:
            cache[name] = load_sequence(drive_path(name))
        return cache[name]

    return get


@pytest.fixture(params=SHARED_DRIVES)
def shared_drive(request, drive_path) -> Path:
    """Each shared drive in turn (0022, 0027, 0034)."""
    return drive_path(request.param)


@pytest.fixture(scope="session", autouse=True)
def model_cache(tmp_path_factory):
    """Identified models (``vislam bench``'s default, eval.model_cache) are kept in a folder of
    this test session, never in the user's cache: a drive is identified once per session."""
    folder = tmp_path_factory.mktemp("vislam-model-cache")
    previous = os.environ.get("VISLAM_CACHE_DIR")
    os.environ["VISLAM_CACHE_DIR"] = str(folder)
    yield folder
    if previous is None:
        os.environ.pop("VISLAM_CACHE_DIR", None)
    else:
        os.environ["VISLAM_CACHE_DIR"] = previous


@pytest.fixture(scope="session")
def benchmark_script():
    """``get(name)``: the script ``benchmarks/<name>.py`` loaded as a module (the scripts are
    not a package), once per session."""
    loaded = {}

    def get(name: str):
        if name not in loaded:
            path = Path(__file__).resolve().parents[1] / "benchmarks" / f"{name}.py"
            spec = importlib.util.spec_from_file_location(name, path)
            module = importlib.util.module_from_spec(spec)
            spec.loader.exec_module(module)
            loaded[name] = module
        return loaded[name]

    return get
