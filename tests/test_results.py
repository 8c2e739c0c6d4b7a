"""vislam.load_results: bench and nees folders as typed objects (eval/results.py)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

import vislam
from vislam.ekf.errors import InputError
from vislam.eval.cli import main
from vislam.eval.results import (
    BENCH_SCHEMA,
    BenchResults,
    DriveResult,
    DriveRpe,
    ErrorStats,
    EstimatorResult,
    NeesEstimatorResult,
    NeesResults,
    Results,
    load_results,
)


def _stats(x: float) -> dict:
    return {"mean": x, "median": 0.9 * x, "rmse": 1.1 * x}


#: results.json's rpe_drive of a 44 m drive: two lengths, the second without a segment.
RPE_DRIVE = {"lengths_m": [4.0, 8.0], "path_length_m": 44.1, "frames": 60, "n_segments": 40,
             "trans_pct": _stats(1.5), "rot_deg_per_m": _stats(0.02),
             "per_length": [{"length_m": 4.0, "n_segments": 40, "trans_m": _stats(0.06),
                             "trans_pct": _stats(1.5), "rot_deg": _stats(0.08),
                             "rot_deg_per_m": _stats(0.02)},
                            {"length_m": 8.0, "n_segments": 0, "trans_m": None,
                             "trans_pct": None, "rot_deg": None, "rot_deg_per_m": None}],
             "note": None}


def _row(name: str, **figures) -> dict:
    row = {"name": name, "error": None, "runtime_s": 1.5, "frames_per_s": 40.0, "landmarks": 12,
           "ate_m": 2.0, "ate_aligned_m": 1.0, "rpe_trans_pct": None,
           "rpe_rot_deg_per_100m": None, "rpe_drive_trans_pct": 1.5,
           "rpe_drive_rot_deg_per_m": 0.02, "rpe_drive": RPE_DRIVE,
           "nees_pose_mean": 7.5, "map_rmse_m": 0.4,
           "nees_landmark_mean": 3.3,
           "vs_smoother": {"ate_m": 0.5, "ate_aligned_m": 0.25, "map_rmse_m": 0.1,
                           "nees_pose_mean": 6.1, "inside_95_fraction": 0.93}}
    row.update(figures)
    return row


def _bench(*rows: dict) -> dict:
    return {"schema": BENCH_SCHEMA, "rpe_definition": "KITTI", "rpe_drive_definition": "fitted",
            "alignment": "sim3",
            "alignment_definition": "ate_aligned_m: after a Sim(3) alignment",
            "estimators": [r["name"] for r in rows], "wall_s": 3.25,
            "sequences": [{"name": "drive", "path": None, "frames": 60, "has_ground_truth": True,
                           "has_landmark_truth": False, "model": {"mode": "as-given"},
                           "reference_smoother": "smoother", "estimators": list(rows)}]}


def _nees() -> dict:
    return {"runs": 3, "seed": 4, "frames": 5, "simulation": {"seed": 4}, "filter": {"a": 1},
            "smoother": {}, "settings": {"command": "vislam nees --runs 3"},
            "timestamps": [0.0, 0.1, 0.2, 0.3, 0.4],
            "estimators": {"ekf-joint": {
                "anees_pose": 6.5, "anees_landmark": None, "bounds_pose": [4.2, 8.1],
                "bounds_landmark": [1.5, 5.0], "verdict_pose": "inside", "verdict_landmark": None,
                "inside_fraction_pose": 0.75, "inside_fraction_landmark": None,
                "landmarks_scored": 0, "runs_failed": 1, "errors": ["boom"],
                "runtime_s_mean": 0.5, "nees_pose_over_time": [None, 6.0, 7.0, 6.5, 6.5],
                "nees_pose_per_run_mean": [6.0, None, 7.0]}}}


def _write(folder: Path, **files) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for name, content in files.items():
        (folder / name.replace("_json", ".json")).write_text(
            content if isinstance(content, str) else json.dumps(content))
    return folder


def test_bench_folder_as_typed_objects(tmp_path):
    folder = _write(tmp_path / "a", results_json=_bench(_row("ekf-joint"),
                                                        _row("smoother", error="it broke")),
                    settings_json={"command": "vislam bench", "filter": {"pixel_sigma": 2.0},
                                   "sequences": [{"name": "drive", "simulation": {"seed": 7}}]})
    (folder / "drive").mkdir()
    (folder / "drive" / "ekf-joint.tum").write_text("0 0 0 0 0 0 0 1\n")
    res = vislam.load_results(folder)
    assert isinstance(res, Results) and res.kinds == ["bench"] and res.nees is None
    bench = res.bench
    assert isinstance(bench, BenchResults) and bench.schema == BENCH_SCHEMA
    assert bench.alignment == "sim3" and bench.wall_s == 3.25 and bench.command == "vislam bench"
    assert bench.filter == {"pixel_sigma": 2.0}
    drive = bench.drives["drive"]
    assert isinstance(drive, DriveResult) and drive.frames == 60 and drive.has_ground_truth
    assert drive.simulation == {"seed": 7} and drive.reference_smoother == "smoother"
    assert list(drive.estimators) == ["ekf-joint", "smoother"]
    joint, smoother = drive.estimators["ekf-joint"], drive.estimators["smoother"]
    assert isinstance(joint, EstimatorResult) and joint.ok and not smoother.ok
    assert smoother.error == "it broke"
    assert joint.ate_m == 2.0 and joint.rpe_trans_pct is None and joint.landmarks == 12
    assert joint.vs_smoother.inside_95_fraction == 0.93
    assert joint.figure("vs_smoother.ate_m") == 0.5 and joint.figure("nees_pose_mean") == 7.5
    assert joint.trajectory_path == folder / "drive" / "ekf-joint.tum"
    assert joint.estimate_path is None
    with pytest.raises(InputError, match="no saved estimate"):
        joint.load_estimate()
    assert res.files == [folder / "results.json", folder / "settings.json"]


def test_the_drive_fitted_rpe_reads_as_typed_objects(tmp_path):
    folder = _write(tmp_path / "a", results_json=_bench(_row("e"), _row("f", error="broke",
                                                                        rpe_drive=None)))
    bench = load_results(folder).bench
    assert bench.rpe_drive_definition == "fitted"
    e = bench.drives["drive"].estimators["e"]
    assert e.rpe_drive_trans_pct == 1.5 and e.figure("rpe_drive_rot_deg_per_m") == 0.02
    fitted = e.rpe_drive
    assert isinstance(fitted, DriveRpe) and fitted.lengths_m == (4.0, 8.0)
    assert fitted.lengths_text == "4 and 8 m" and fitted.note is None
    assert fitted.path_length_m == 44.1 and fitted.frames == 60 and fitted.n_segments == 40
    assert fitted.trans_pct == ErrorStats(1.5, 0.9 * 1.5, 1.1 * 1.5)
    four, eight = fitted.per_length
    assert four.length_m == 4.0 and four.n_segments == 40 and four.rot_deg.mean == 0.08
    assert eight.n_segments == 0 and eight.trans_m is None
    assert bench.drives["drive"].estimators["f"].rpe_drive is None


def test_a_schema_1_folder_reads_without_the_drive_fitted_rpe(tmp_path):
    old = _bench(_row("e"))
    old["schema"] = 1
    del old["rpe_drive_definition"]
    for key in ("rpe_drive_trans_pct", "rpe_drive_rot_deg_per_m", "rpe_drive"):
        del old["sequences"][0]["estimators"][0][key]
    bench = load_results(_write(tmp_path / "old", results_json=old)).bench
    e = bench.drives["drive"].estimators["e"]
    assert bench.schema == 1 and bench.rpe_drive_definition is None
    assert e.rpe_drive is None and e.rpe_drive_trans_pct is None and e.ate_m == 2.0


def test_results_file_stands_for_its_folder_and_non_finite_is_none(tmp_path):
    text = json.dumps(_bench(_row("e"))).replace("2.0", "NaN", 1)
    folder = _write(tmp_path / "a", results_json=text)
    res = load_results(folder / "results.json")
    assert res.folder == folder and res.bench.settings is None
    assert res.bench.drives["drive"].estimators["e"].ate_m is None


def test_nees_folder_arrays_and_bounds(tmp_path):
    folder = _write(tmp_path / "n", nees_json=_nees())
    res = load_results(folder)
    assert res.kinds == ["nees"] and res.bench is None
    nees = res.nees
    assert isinstance(nees, NeesResults) and nees.runs == 3 and nees.seed == 4
    assert nees.command == "vislam nees --runs 3"
    joint = nees.estimators["ekf-joint"]
    assert isinstance(joint, NeesEstimatorResult)
    assert joint.bounds_pose == (4.2, 8.1) and joint.anees_landmark is None
    assert joint.runs_failed == 1 and joint.errors == ["boom"]
    per_run = joint.nees_pose_per_run_mean
    assert per_run.shape == (3,) and per_run[0] == 6.0 and math.isnan(per_run[1])
    assert joint.per_run() == [6.0, 7.0]
    assert np.isnan(joint.nees_pose_over_time[0]) and joint.nees_pose_over_time[1] == 6.0
    np.testing.assert_allclose(nees.timestamps, [0.0, 0.1, 0.2, 0.3, 0.4])


def test_folder_with_both_kinds(tmp_path):
    folder = _write(tmp_path / "both", results_json=_bench(_row("e")), nees_json=_nees())
    res = load_results(folder)
    assert res.kinds == ["bench", "nees"]
    assert res.files == [folder / "results.json", folder / "nees.json"]


BAD = {
    "no such folder": (None, "no such folder"),
    "not a results folder": ({"notes.txt": "hello"}, "holds neither results.json"),
    "not JSON": ({"results_json": "{"}, "results.json: not valid JSON"),
    "unknown schema": ({"results_json": json.dumps({**_bench(), "schema": 7})}, "'schema' is 7"),
    "figure not a number": ({"results_json": json.dumps(_bench(_row("e", ate_m="far")))},
                            "sequences[0].estimators[0].ate_m: expected a number"),
    "vs smoother figure": ({"results_json": json.dumps(_bench(_row(
        "e", vs_smoother={"ate_m": [1]})))}, "vs_smoother.ate_m: expected a number"),
    "rpe_drive not an object": ({"results_json": json.dumps(_bench(_row("e", rpe_drive=3)))},
                                "estimators[0].rpe_drive: expected an object"),
    "rpe_drive length": ({"results_json": json.dumps(_bench(_row(
        "e", rpe_drive={**RPE_DRIVE, "lengths_m": [4.0, -1]})))},
        "rpe_drive.lengths_m[1]: expected a length"),
    "rpe_drive statistics": ({"results_json": json.dumps(_bench(_row(
        "e", rpe_drive={**RPE_DRIVE, "trans_pct": {"mean": "big"}})))},
        "rpe_drive.trans_pct.mean: expected a number"),
    "landmarks not a count": ({"results_json": json.dumps(_bench(_row("e", landmarks=-3)))},
                              "estimators[0].landmarks: expected a count"),
    "duplicate estimator": ({"results_json": json.dumps(_bench(_row("e"), _row("e")))},
                            "estimator 'e' appears twice"),
    "nees without runs": ({"nees_json": json.dumps({"estimators": {}})}, "missing key 'runs'"),
    "nees bounds": ({"nees_json": json.dumps({"runs": 2, "estimators": {"e": {
        "bounds_pose": [1]}}})}, "estimators.e.bounds_pose: expected two numbers"),
    "nees timestamps": ({"nees_json": json.dumps({"runs": 2, "estimators": {},
                                                  "timestamps": "soon"})},
                        "timestamps: expected a list"),
    "settings not an object": ({"results_json": json.dumps(_bench()), "settings_json": "3"},
                               "settings.json: expected a JSON object"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_damaged_folder_is_an_input_error_naming_file_and_key(case, tmp_path, capsys):
    files, words = BAD[case]
    bad = tmp_path / "bad"
    if files is not None:
        _write(bad, **files)
    with pytest.raises(InputError, match=words.replace("(", r"\(").replace("[", r"\[")):
        load_results(bad)
    # on the command line: exit code 2, one line naming the folder
    good = _write(tmp_path / "good", results_json=_bench(_row("e")))
    rc = main(["compare", str(good), str(bad), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert rc == 2 and str(bad) in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()


def test_schema_is_the_one_bench_writes():
    from vislam.eval.bench_scores import SCHEMA

    assert BENCH_SCHEMA == SCHEMA


def test_bench_writes_the_drive_fitted_rpe_and_load_results_reads_it_back(tmp_path):
    out = tmp_path / "bench"
    assert main(["bench", "--frames", "40", "-e", "dead-reckoning", "--model", "as-given",
                 "--quiet", "--out", str(out)]) == 0
    raw = json.loads((out / "results.json").read_text())
    assert raw["schema"] == BENCH_SCHEMA and raw["rpe_drive_definition"]
    (row,) = raw["sequences"][0]["estimators"]
    assert row["rpe_trans_pct"] is None  # 40 frames: no KITTI segment
    assert row["rpe_drive_trans_pct"] > 0 and row["rpe_drive"]["note"] is None
    assert row["rpe_drive"]["lengths_m"] and row["rpe_drive"]["n_segments"] > 0
    est = load_results(out).bench.drives[raw["sequences"][0]["name"]].estimators["dead-reckoning"]
    assert est.rpe_drive_trans_pct == row["rpe_drive_trans_pct"]
    assert est.rpe_drive_rot_deg_per_m == row["rpe_drive_rot_deg_per_m"]
    assert list(est.rpe_drive.lengths_m) == row["rpe_drive"]["lengths_m"]
    for got, written in zip(est.rpe_drive.per_length, row["rpe_drive"]["per_length"]):
        assert got.length_m == written["length_m"] and got.n_segments == written["n_segments"]
        assert got.trans_m.rmse == written["trans_m"]["rmse"]
        assert got.rot_deg_per_m.median == written["rot_deg_per_m"]["median"]


@pytest.mark.slow
def test_a_real_bench_folder_loads_its_estimates_and_its_drive(tmp_path):
    out = tmp_path / "bench"
    assert main(["bench", "--frames", "40", "-e", "dead-reckoning,smoother", "-j", "1",
                 "--model", "as-given", "--quiet", "--out", str(out)]) == 0
    res = vislam.load_results(out)
    (drive,) = res.bench.drives.values()
    assert drive.simulation is not None and drive.frames == 40
    est = drive.estimators["dead-reckoning"].load_estimate()
    assert est.n_frames == 40
    data = drive.load_drive()
    assert data.sequence.n_frames == 40 and data.truth_poses.shape == (40, 4, 4)
    assert data.landmark_truth.shape == (data.sequence.n_tracks, 3)
    t, poses = vislam.read_tum(drive.estimators["smoother"].trajectory_path)
    np.testing.assert_allclose(poses[:, :3, 3],
                               drive.estimators["smoother"].load_estimate().positions, atol=1e-6)


def test_a_raw_imu_drives_truth_check_reads_as_its_typed_object(tmp_path):
    from vislam.eval.inertial_truth import GyroAgreement

    check = GyroAgreement(1.0, 581, (1.22, 1.10, 1.64), 0.17, True)
    data = _bench(_row("e"))
    data["sequences"][0]["truth_check"] = check.to_dict()
    drive = load_results(_write(tmp_path / "a", results_json=data)).bench.drives["drive"]
    assert drive.truth_check == check and drive.truth_check.ratio == pytest.approx(check.ratio)
    data["sequences"][0]["truth_check"] = None
    assert load_results(_write(tmp_path / "b", results_json=data)).bench.drives["drive"].truth_check is None
    for bad in ({"pairs": 3}, [1, 2], dict(check.to_dict(), rms_mrad=[1.0, "x", 2.0]),
                dict(check.to_dict(), rms_mrad=[1.0, 2.0])):
        data["sequences"][0]["truth_check"] = bad
        with pytest.raises(InputError, match=r"sequences\[0\].*truth_check"):
            load_results(_write(tmp_path / "c", results_json=data))
