"""Shared fixtures: where the real drives are, a session cache of loaded drives, and the tiers.

Plain ``pytest`` runs the fast tier; ``pytest -m regression`` the regression tier (pyproject.toml's
``addopts`` deselects it by default; see ``pytest_collection_modifyitems`` for what is in it
whether marked or not).

Real-data tests skip with a clear reason when the data folder or a drive is absent, except in
CI (``CI=true``), where a missing drive is a failure: CI must never pass by skipping them.
"""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path

# One BLAS thread per test process (and per process a test starts) unless the environment
# says otherwise: the tests run in one worker process per core (``-n auto``), and OpenBLAS's
# own threads on top of them only contend for the same cores (they spin while they wait):
# measured on 2 cores, a tenth of the CPU (docs/findings.md, 2026-12-04). Set before numpy is
# first imported; pytest_configure applies it to a numpy imported earlier.
BLAS_THREADS = int(os.environ.setdefault("OPENBLAS_NUM_THREADS", "1"))

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
    from threadpoolctl import ThreadpoolController

    ThreadpoolController().limit(limits=BLAS_THREADS, user_api="blas")  # BLAS_THREADS
    if os.environ.get("VISLAM_BOTH_TIERS") == "1" and not hasattr(config, "workerinput"):
        config.pluginmanager.register(BothTiers(), "vislam-both-tiers")
    config.addinivalue_line(
        "markers",
        "realdata: reads the shared KITTI drives (skipped where absent; with CI=true a missing "
        "drive fails: missing_data)",
    )


#: Test files that share an expensive result with another file (a session fixture, or a
#: module-level cache of identifications of the same simulated drive), mapped to that file:
#: under ``--dist loadfile`` (.ci/run) each file is one unit of work on one
#: worker, and these go to the worker of the file they name (pytest_xdist_make_scheduler), so
#: the result is computed once.
SHARED_WORKER = {
    "tests/test_track_correlation.py": "tests/test_calibrate.py",  # test_calibrate.fit
    "tests/regression/test_agreement.py": "tests/regression/test_consistency.py",  # monte_carlo
    "tests/test_ekf_estimators.py": "tests/regression/test_accuracy_0027.py",  # study_0027
}


@pytest.hookimpl(optionalhook=True)  # pytest-xdist's hook: known only where it is installed
def pytest_xdist_make_scheduler(config, log):
    """``--dist loadfile`` with the files of SHARED_WORKER in one unit of work each."""
    if config.getvalue("dist") != "loadfile":
        return None
    from xdist.scheduler import LoadFileScheduling

    class SharedWorkerScheduling(LoadFileScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return _unit(super()._split_scope(nodeid))

    # Units go out in collection order, which pytest_collection_modifyitems makes dearest
    # first (xdist's own reorder, by number of tests, would send a unit of two long tests last).
    config.option.loadscopereorder = False
    return SharedWorkerScheduling(config, log)


@pytest.hookimpl(optionalhook=True)  # pytest-xdist's hook, on the controller
def pytest_configure_node(node):
    """Tell each worker the run's distribution mode: xdist sets a worker's own ``dist`` to
    "no", and the workers' collection order is the one the scheduler sends out (_distribution)."""
    node.workerinput["vislam_dist"] = node.config.getvalue("dist")


def _distribution(config) -> str:
    """The run's ``--dist`` mode, in the controller and in an xdist worker alike."""
    return getattr(config, "workerinput", {}).get("vislam_dist", config.getvalue("dist"))


def _unit(module: str) -> str:
    """The unit of work of a test file under ``--dist loadfile`` (SHARED_WORKER)."""
    return SHARED_WORKER.get(module, module)


#: Seconds of the dearest units of work (SHARED_WORKER), measured in the regression tier on 2
#: busy cores (docs/findings.md, 2026-12-02; the campaign's fixture runs its own two
#: processes): ``--dist loadfile`` sends them out first, so that the run does not end on one
#: worker while the other idles (longest first). The rest follow, regression units before
#: fast ones, in file order. Only the order of the run depends on these figures, never a
#: verdict.
UNIT_SECONDS = {
    "tests/regression/test_campaign_drives.py": 206,
    "tests/test_calibrate.py": 293,  # with tests/test_track_correlation.py
    "tests/test_extrinsic.py": 161,
    "tests/regression/test_accuracy_identified.py": 122,
    "tests/test_time_offset.py": 110,
    "tests/regression/test_inertial_time_offset.py": 110,
    "tests/test_motion_correlation.py": 87,
    "tests/regression/test_accuracy_0027.py": 75,  # with tests/test_ekf_estimators.py
    "tests/test_robust_estimators.py": 42,
    "tests/test_out_of_sample.py": 37,
    "tests/regression/test_loop_drive.py": 34,
    "tests/regression/test_consistency.py": 33,  # with tests/regression/test_agreement.py
}


def _dearest_first(items) -> None:
    """Reorder ``items`` (in place, stable within a unit) by UNIT_SECONDS, dearest first."""
    units = {id(item): _unit(item.nodeid.split("::")[0]) for item in items}
    regression = {units[id(i)] for i in items if i.get_closest_marker("regression")}
    first: dict[str, int] = {}
    for i, item in enumerate(items):
        first.setdefault(units[id(item)], i)

    def key(item):
        u = units[id(item)]
        return -UNIT_SECONDS.get(u, 0), u not in regression, first[u]

    items.sort(key=key)


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    """Two kinds of test are in the regression tier (``pytest -m regression``) whether marked
    or not, so that a new one cannot slip into the fast tier: every real-data test, and every
    test of a research script in benchmarks/ (the ``benchmark_script`` fixture; the fast tier
    only checks that each script starts: tests/test_benchmark_scripts.py). The mark is added
    before ``-m`` selects."""
    for item in items:
        if item.get_closest_marker("regression"):
            continue
        if item.get_closest_marker("realdata") or "benchmark_script" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.regression)


@pytest.hookimpl(trylast=True, specname="pytest_collection_modifyitems")
def pytest_collection_modifyitems_selected(config, items):
    """After ``-m`` selected: under ``--dist loadfile`` the dearest units first
    (UNIT_SECONDS)."""
    if _distribution(config) == "loadfile":
        _dearest_first(items)


class BothTiers:
    """``VISLAM_BOTH_TIERS=1`` (.ci/run runs both tiers in one session): the session fails
    when either tier ran nothing, which pytest's "no tests ran" (exit 5) cannot see in the
    sum. Counted where the reports arrive (the controller under xdist: a report's keywords
    carry its marks)."""

    def __init__(self):
        self.ran = {"fast": 0, "regression": 0}

    def pytest_runtest_logreport(self, report):
        if report.when == "setup":
            self.ran["regression" if "regression" in report.keywords else "fast"] += 1

    @pytest.hookimpl(trylast=True)
    def pytest_sessionfinish(self, session):
        empty = [name for name, n in self.ran.items() if n == 0]
        if empty:
            reporter = session.config.pluginmanager.get_plugin("terminalreporter")
            reporter.ensure_newline()
            reporter.write_line(f"CI: the {' and the '.join(empty)} tier ran no tests; "
                                f"failing", red=True)
            session.exitstatus = pytest.ExitCode.TESTS_FAILED


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


#: Every estimator run on shared 0027 by ``study_0027`` (logical names; tests/regression/breaks.py
#: may swap what runs for one).
STUDY_0027_ESTIMATORS = ("dead-reckoning", "mapping", "ekf-decoupled", "ekf-joint", "ekf-invariant",
                         "smoother")


@pytest.fixture(scope="session")
def study_0027(drive_path):
    """Every estimator on shared 0027 against its ground truth (:func:`vislam.testing.run_drive`,
    2 worker processes, the file's model and the default settings, or the regression tier's
    deliberate break), computed once per session for every test that reads it."""
    from tests.regression.breaks import broken_config, run_name
    from vislam.ekf.config import FilterConfig
    from vislam.eval.drives import load_bench_sequence
    from vislam.testing import run_drive

    path = drive_path("0027")
    bs = load_bench_sequence(path)
    if bs.gt is None:
        missing_data(f"no ground truth for {path} (expected {path.parent}/groundtruth/0027.txt)")
    study = run_drive({n: run_name(n) for n in STUDY_0027_ESTIMATORS}, bs,
                      config=broken_config(FilterConfig()), jobs=2)
    print(f"\n0027: {len(STUDY_0027_ESTIMATORS)} estimators in {study.wall_s:.1f} s")
    return study
