"""The tiers' machinery in tests/conftest.py: .ci/run's one session of both tiers fails when
either ran no tests (BothTiers), and ``--dist loadfile`` sends the dearest units first
(UNIT_SECONDS) with the regression units before the fast ones."""

from __future__ import annotations

import importlib.util
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

CONFTEST = Path(__file__).with_name("conftest.py")


def _load_conftest():
    spec = importlib.util.spec_from_file_location("tiers_conftest", CONFTEST)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


#: A copy of tests/conftest.py as a module, loaded once (its helpers and UNIT_SECONDS).
conftest = _load_conftest()


def _session(tmp_path: Path, files: dict[str, str], *args: str) -> subprocess.CompletedProcess:
    """A pytest session of ``files`` (path -> source) under this suite's conftest, as .ci/run
    starts it."""
    shutil.copy(CONFTEST, tmp_path / "conftest.py")
    for name, body in files.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(body)
    env = {**os.environ, "VISLAM_BOTH_TIERS": "1"}
    return subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                           "-m", "regression or not regression", *args, *files],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)


def test_both_tiers_in_one_session_pass_and_an_empty_tier_fails(tmp_path):
    both = _session(tmp_path, {"test_one.py": "import pytest\n\ndef test_fast():\n    pass\n\n"
                                              "@pytest.mark.regression\ndef test_slow():\n    pass\n"})
    assert both.returncode == 0, both.stdout + both.stderr
    fast_only = _session(tmp_path, {"test_one.py": "def test_fast():\n    pass\n"})
    assert fast_only.returncode == 1, fast_only.stdout + fast_only.stderr
    assert "CI: the regression tier ran no tests; failing" in fast_only.stdout


def test_an_xdist_worker_sends_the_dearest_unit_first(tmp_path):
    """Through xdist itself: a worker's own ``dist`` is "no", so the order must reach it from
    the controller (pytest_configure_node)."""
    run = _session(tmp_path, {"tests/test_a.py": "def test_a():\n    pass\n",
                              "tests/test_motion_correlation.py": "def test_m():\n    pass\n"},
                   "-n", "1", "--dist", "loadfile", "-v", "-v")  # past -q
    assert run.returncode == 1, run.stdout + run.stderr  # no regression test: BothTiers fails
    ran = [line.split()[-1] for line in run.stdout.splitlines() if "PASSED" in line]
    assert ran == ["tests/test_motion_correlation.py::test_m", "tests/test_a.py::test_a"], run.stdout


class _Item:
    def __init__(self, nodeid: str, regression: bool):
        self.nodeid, self._regression = nodeid, regression

    def get_closest_marker(self, name: str):
        return True if name == "regression" and self._regression else None


def test_dearest_units_go_first_then_regression_units_in_file_order():
    items = [_Item("tests/test_a.py::x", False), _Item("tests/test_b.py::x", True),
             _Item("tests/test_track_correlation.py::y", True),  # joins test_calibrate.py's unit
             _Item("tests/test_motion_correlation.py::z", True),
             _Item("tests/test_calibrate.py::w", True), _Item("tests/test_b.py::y", False)]
    conftest._dearest_first(items)
    assert [i.nodeid for i in items] == [
        "tests/test_track_correlation.py::y", "tests/test_calibrate.py::w",  # 293 s
        "tests/test_motion_correlation.py::z",  # 87 s
        "tests/test_b.py::x", "tests/test_b.py::y",  # a regression unit, in file order
        "tests/test_a.py::x"]  # fast only
    assert conftest.UNIT_SECONDS and all(s > 0 for s in conftest.UNIT_SECONDS.values())


@pytest.mark.parametrize("unit", sorted(conftest.UNIT_SECONDS))
def test_every_costed_unit_is_a_test_file(unit):
    assert (CONFTEST.parents[1] / unit).is_file(), unit
