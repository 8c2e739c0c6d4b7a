"""vislam.testing on a saved ``vislam nees`` folder (eval/folder_checks.py): the folder's ANEES
against its own bounds, read through vislam.load_results; a folder whose estimator is outside
its bounds, has failed runs, or is not there fails with the figure in words."""

from __future__ import annotations

import json
import shutil

import pytest

from vislam.ekf.errors import InputError
from vislam.eval.cli import main
from vislam.testing import assert_folder_consistent, folder_checks


@pytest.fixture(scope="module")
def nees_folder(tmp_path_factory):
    out = tmp_path_factory.mktemp("nees") / "study"
    assert main(["nees", "--runs", "3", "--frames", "30", "-e", "dead-reckoning", "-j", "1",
                 "--out", str(out), "-q"]) == 0
    return out


def _edited(src, tmp_path, **changes):
    dst = tmp_path / "edited"
    shutil.copytree(src, dst)
    doc = json.loads((dst / "nees.json").read_text())
    doc["estimators"]["dead-reckoning"].update(changes)
    (dst / "nees.json").write_text(json.dumps(doc))
    return dst


def test_a_saved_study_gives_the_folders_own_figures(nees_folder):
    doc = json.loads((nees_folder / "nees.json").read_text())["estimators"]["dead-reckoning"]
    (pose,) = folder_checks(nees_folder, what="pose")
    assert pose.value == pytest.approx(doc["anees_pose"])
    assert pose.bounds == tuple(doc["bounds_pose"]) and pose.verdict == doc["verdict_pose"]
    if doc["verdict_pose"] == "inside":  # dead reckoning on the simulator: consistent
        assert assert_folder_consistent(nees_folder, "dead-reckoning", what="pose")


def test_outside_its_bounds_fails_with_the_figure(nees_folder, tmp_path):
    folder = _edited(nees_folder, tmp_path, anees_pose=99.0, verdict_pose="above")
    with pytest.raises(AssertionError, match=r"pose ANEES 99.00 .* above \(overconfident\)"):
        assert_folder_consistent(folder, what="pose")


def test_failed_runs_fail_the_check(nees_folder, tmp_path):
    folder = _edited(nees_folder, tmp_path, runs_failed=1, verdict_pose="inside")
    (check,) = folder_checks(folder, what="pose")
    assert not check and check.verdict == "failed" and "1 runs failed" in check.message
    assert folder_checks(folder, what="pose", max_failed_runs=1)[0]


def test_a_missing_landmark_anees_is_missing_not_passed(nees_folder):
    (check,) = folder_checks(nees_folder, what="landmark")  # dead reckoning maps nothing
    assert not check and check.verdict == "missing"


def test_the_wrong_folder_or_name_is_an_input_error(nees_folder, tmp_path):
    with pytest.raises(InputError, match="no estimator 'ekf-joint'"):
        folder_checks(nees_folder, "ekf-joint")
    with pytest.raises(InputError, match="no such folder"):
        folder_checks(tmp_path / "absent")
