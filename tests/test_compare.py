"""`vislam compare`: result folders of bench and nees side by side (eval/compare.py, eval/results.py)."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import pytest
from vislam.eval import compare, compare_readings
from vislam.eval.cli import main

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


# --- synthetic inputs ------------------------------------------------------------------------


def _est(name: str, **figures) -> dict:
    row = {"name": name, "error": None, "runtime_s": 1.0, "frames_per_s": 60.0, "landmarks": 0,
           "ate_m": None, "ate_aligned_m": None, "rpe_trans_pct": None,
           "rpe_rot_deg_per_100m": None, "nees_pose_mean": None, "map_rmse_m": None,
           "nees_landmark_mean": None,
           "vs_smoother": {"ate_m": None, "ate_aligned_m": None, "map_rmse_m": None,
                           "nees_pose_mean": None, "inside_95_fraction": None}}
    for k, v in figures.items():
        if k.startswith("vs_"):
            row["vs_smoother"][k[3:]] = v
        else:
            row[k] = v
    return row


def _seq(name: str, *estimators: dict, frames: int = 60) -> dict:
    return {"name": name, "path": None, "frames": frames, "has_ground_truth": True,
            "model": None, "reference_smoother": "smoother", "estimators": list(estimators)}


def _results(*sequences: dict) -> dict:
    names = []
    for s in sequences:
        names += [e["name"] for e in s["estimators"] if e["name"] not in names]
    return {"schema": 1, "rpe_definition": "x", "reference": "smoother", "alignment": "se3",
            "estimators": names, "sequences": list(sequences), "wall_s": 1.0}


def _settings(pixel_sigma: float = 1.0, **extra) -> dict:
    return {"estimators": ["ekf-joint"], "filter": {"pixel_sigma": pixel_sigma,
                                                   "gate_probability": 0.99},
            "command": "vislam bench", "created": "now", **extra}


def _write(folder: Path, name: str, data) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / name).write_text(data if isinstance(data, str) else json.dumps(data))
    return folder


def _nees(per_run: dict[str, list[float]], runs: int | None = None, pixel_sigma: float = 1.0,
          landmark: float | None = 3.1) -> dict:
    from vislam.eval.consistency import chi2_bounds

    n = runs or len(next(iter(per_run.values())))
    ests = {}
    for name, values in per_run.items():
        anees = sum(values) / len(values)
        ests[name] = {
            "anees_pose": anees, "anees_landmark": landmark,
            "bounds_pose": list(chi2_bounds(n, 6)), "bounds_landmark": list(chi2_bounds(n, 3)),
            "verdict_pose": "inside", "verdict_landmark": "inside",
            "inside_fraction_pose": 0.95, "inside_fraction_landmark": 0.95,
            "landmarks_scored": 10, "runs_failed": 0, "errors": [], "runtime_s_mean": 0.25,
            "nees_pose_over_time": [None, anees], "nees_pose_per_run_mean": list(values),
        }
    return {"runs": n, "seed": 0, "frames": 60, "simulation": {"seed": 0, "pixel_sigma": 1.0},
            "filter": {"pixel_sigma": pixel_sigma}, "smoother": {}, "estimators": ests,
            "timestamps": [0.0, 0.1], "settings": {"command": "vislam nees", "created": "now"}}


def _run(argv, capsys):
    rc = main(["compare", *map(str, argv)])
    captured = capsys.readouterr()
    return rc, captured.out, captured.err


def _row(out: str, estimator: str, figure: str) -> list[str]:
    """The cells of the Markdown row of ``estimator`` whose figure starts with ``figure``."""
    for line in out.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split(" | ")]
        if len(cells) > 2 and cells[0] == estimator and cells[1].startswith(figure):
            return cells
    raise AssertionError(f"no row {estimator} / {figure} in\n{out}")


# --- bench folders ---------------------------------------------------------------------------


def test_bench_changes_by_hand_and_every_file_written(tmp_path, capsys):
    a = _write(tmp_path / "a", "results.json", _results(_seq(
        "drive_1", _est("ekf-joint", ate_m=2.0, nees_pose_mean=20.0, map_rmse_m=1.0,
                        nees_landmark_mean=3.0, vs_inside_95_fraction=0.9))))
    _write(a, "settings.json", _settings(1.0))
    b = _write(tmp_path / "b", "results.json", _results(_seq(
        "drive_1", _est("ekf-joint", ate_m=1.5, nees_pose_mean=10.0, map_rmse_m=1.2,
                        nees_landmark_mean=3.0, runtime_s=1.0005, vs_inside_95_fraction=0.8))))
    _write(b, "settings.json", _settings(2.0))
    out = tmp_path / "out"
    rc, printed, err = _run([a, b, "--out", out], capsys)
    assert rc == 0, err
    # ATE 2.0 -> 1.5: -0.5 m, -25 %, lower is better
    assert _row(printed, "ekf-joint", "ATE (m)")[2:] == ["2.000", "1.500", "-0.5000 (-25.0 %)",
                                                         "better"]
    # map RMSE 1.0 -> 1.2: +20 %, worse
    assert _row(printed, "ekf-joint", "map RMSE")[4:] == ["+0.2000 (+20.0 %)", "worse"]
    # NEES 20 (above the 6-dof band [1.24, 14.45]) -> 10 (inside): better
    assert _row(printed, "ekf-joint", "NEES [1.24, 14.45]")[5] == "better (inside the band)"
    assert _row(printed, "ekf-joint", "lm NEES")[4:] == ["0 (0 %)", "same"]
    assert _row(printed, "ekf-joint", "runtime")[5] == "same"  # within 0.1 %
    assert _row(printed, "ekf-joint", "vs sm. in 95%")[5] == ""  # no better / worse
    # the differing setting, and only it (command and time are not compared)
    assert "| filter.pixel_sigma | 1.000 | 2.000 |" in printed
    assert "gate_probability" not in printed and "| created" not in printed
    assert printed == (out / "compare.md").read_text()
    tex = (out / "compare.tex").read_text()
    assert r"\toprule" in tex and r"\bottomrule" in tex and r"\begin{longtable}" in tex
    assert r"filter.pixel\_sigma" in tex and r"drive\_1" in tex and r"($-$25.0 \%)" in tex
    assert "drive_1" not in tex.replace(r"drive\_1", "")
    assert (out / "compare.png").read_bytes().startswith(PNG_MAGIC)
    assert sorted(p.name for p in out.iterdir()) == [".vislam-output.json", "compare.md",
                                                    "compare.png", "compare.tex"]


def test_missing_sequence_and_estimator_shown_as_dash(tmp_path, capsys):
    a = _write(tmp_path / "a", "results.json", _results(
        _seq("s1", _est("ekf-joint", ate_m=1.0), _est("smoother", ate_m=0.5)),
        _seq("s2", _est("ekf-joint", ate_m=3.0))))
    b = _write(tmp_path / "b", "results.json", _results(
        _seq("s1", _est("ekf-joint", ate_m=1.0), _est("ekf-invariant", ate_m=0.9)),
        _seq("s3", _est("ekf-joint", ate_m=2.0))))
    rc, printed, err = _run([a, b, "--out", tmp_path / "out"], capsys)
    assert rc == 0, err
    sections = printed.split("## Benchmark: ")[1:]
    assert [s.split(" ")[0] for s in sections] == ["s1", "s2", "s3"]
    s1, s2, s3 = sections
    assert _row(s1, "smoother", "ATE (m)")[2:4] == ["0.5000", "–"]
    assert _row(s1, "ekf-invariant", "ATE (m)")[2:4] == ["–", "0.9000"]
    assert _row(s1, "ekf-joint", "ATE (m)")[4:] == ["0 (0 %)", "same"]
    assert _row(s2, "ekf-joint", "ATE (m)")[2:4] == ["3.000", "–"]
    assert _row(s3, "ekf-joint", "ATE (m)")[2:4] == ["–", "2.000"]
    assert "sequence 's2' is not in B" in s2 and "sequence 's3' is not in A" in s3
    assert "smoother is not in B" in s1 and "ekf-invariant is not in A" in s1


def test_failed_estimator_and_no_figures_are_kept(tmp_path, capsys):
    failed = _est("ekf-joint")
    failed["error"] = "diverged"
    a = _write(tmp_path / "a", "results.json", _results(_seq("s", _est("ekf-joint", ate_m=1.0),
                                                             _est("odd"))))
    b = _write(tmp_path / "b", "results.json", _results(_seq("s", failed, _est("odd"))))
    rc, printed, _ = _run([a, b, "-o", tmp_path / "out"], capsys)
    assert rc == 0
    assert _row(printed, "ekf-joint", "error")[2:4] == ["ok", "failed: diverged"]
    assert _row(printed, "ekf-joint", "ATE (m)")[2:4] == ["1.000", "failed"]
    assert _row(printed, "odd", "runtime")[2:5] == ["1.000", "1.000", "0 (0 %)"]


# --- nees folders ----------------------------------------------------------------------------


def test_nees_spread_beyond_for_a_clear_change_and_not_for_identical_folders(tmp_path, capsys):
    base = {"ekf-joint": [5.0, 6.0, 7.0, 6.0, 5.5, 6.5], "smoother": [1.0, 2.0, 3.0, 10.0]}
    worse = {"ekf-joint": [30.0, 36.0, 41.0, 33.0, 38.0, 35.0]}
    a = _write(tmp_path / "a", "nees.json", _nees(base, runs=6))
    b = _write(tmp_path / "b", "nees.json", _nees(worse, runs=6, pixel_sigma=0.5))
    same = _write(tmp_path / "same", "nees.json", _nees(base, runs=6))
    rc, printed, err = _run([a, b, same, "--out", tmp_path / "out"], capsys)
    assert rc == 0, err
    row = _row(printed, "ekf-joint", "pose NEES per run")
    # columns: estimator, figure, A, B, B-A, B vs A, C, C-A, C vs A
    assert row[2] == "6.000, 6.000 (5.000, 7.000)"
    assert row[3] == "35.50, 35.50 (30.00, 41.00)"
    assert row[4] == "+29.50 (+491.7 %)"
    assert row[5].startswith("beyond the run-to-run spread (Welch p = ")
    assert row[6] == row[2] and row[7] == "0 (0 %)"
    assert row[8] == "within the run-to-run spread (Welch p = 1)"
    # mean, median (min, max) of [1, 2, 3, 10]; smoother absent from B
    srow = _row(printed, "smoother", "pose NEES per run")
    assert srow[2:4] == ["4.000, 2.500 (1.000, 10.00)", "–"]
    assert "smoother is not in B" in printed
    assert _row(printed, "ekf-joint", "ANEES pose")[5] == "worse (outside the band)"
    assert "| filter.pixel_sigma | 1.000 | 0.5000 | 1.000 |" in printed
    assert "Welch's t-test" in printed
    assert "Welch" in (tmp_path / "out" / "compare.tex").read_text()

    comp = compare.compare_folders([a, b, same])
    (nees,) = comp.sections
    r = next(r for r in nees.rows if r.estimator == "ekf-joint" and r.runs)
    assert r.changes[1].beyond is True and r.changes[1].p_value < 1e-4
    assert r.changes[2].beyond is False and r.changes[2].delta == 0


def test_spread_test_edge_cases():
    assert compare_readings.spread_test([1.0], [2.0, 3.0]) == (None, None)
    assert compare_readings.spread_test([2.0, 2.0], [2.0, 2.0]) == (1.0, False)
    assert compare_readings.spread_test([2.0, 2.0], [3.0, 3.0]) == (0.0, True)
    p, beyond = compare_readings.spread_test([5.0, 6.0, 7.0], [5.5, 6.5, 6.0, None])
    assert beyond is False and p > 0.5


def test_nees_reading_closer_to_the_band_is_better():
    band = (3.8, 8.6)
    assert compare_readings.reading("band", 40.0, 20.0, band, band) == "better (closer to the band)"
    assert compare_readings.reading("band", 5.0, 7.0, band, band) == "both inside the band"
    assert compare_readings.reading("band", 1.0, 40.0, band, band) == "worse (further from the band)"
    assert compare_readings.reading("band", 2.0, 30.0, band, band) == "worse (further from the band)"
    assert compare_readings.reading("lower", 1.0, 1.0005) == "same"
    assert compare_readings.num(6183.71) == "6184" and compare_readings.num(0.000123) == "1.230e-4"


# --- mixed kinds -----------------------------------------------------------------------------


def test_folder_with_both_kinds_against_one_of_each(tmp_path, capsys):
    both = _write(tmp_path / "both", "results.json",
                  _results(_seq("s", _est("ekf-joint", ate_m=1.0))))
    _write(both, "nees.json", _nees({"ekf-joint": [5.0, 6.0, 7.0]}))
    bench = _write(tmp_path / "bench", "results.json",
                   _results(_seq("s", _est("ekf-joint", ate_m=2.0))))
    nees = _write(tmp_path / "nees", "nees.json", _nees({"ekf-joint": [6.0, 7.0, 8.0]}))
    out = tmp_path / "out"
    rc, printed, err = _run([both, bench, nees, "--out", out], capsys)
    assert rc == 0, err
    assert "## Benchmark: s" in printed and "## Monte Carlo NEES" in printed
    assert "C holds no results.json" in printed and "B holds no nees.json" in printed
    assert _row(printed, "ekf-joint", "ATE (m)")[3:5] == ["2.000", "+1.000 (+100.0 %)"]
    assert (out / "compare.png").read_bytes().startswith(PNG_MAGIC)


def test_bench_against_nees_only_is_a_clear_error(tmp_path, capsys):
    bench = _write(tmp_path / "bench", "results.json",
                   _results(_seq("s", _est("ekf-joint", ate_m=1.0))))
    nees = _write(tmp_path / "nees", "nees.json", _nees({"ekf-joint": [6.0, 7.0]}))
    rc, _, err = _run([bench, nees, "--out", tmp_path / "out"], capsys)
    assert rc == 2 and len(err.strip().splitlines()) == 1
    assert "nothing to compare" in err and "nees.json" in err
    assert not (tmp_path / "out").exists()


# --- output options --------------------------------------------------------------------------


def test_format_latex_quiet_and_default_out(tmp_path, capsys, monkeypatch):
    a = _write(tmp_path / "a", "results.json", _results(_seq("s", _est("e", ate_m=1.0))))
    b = _write(tmp_path / "b", "results.json", _results(_seq("s", _est("e", ate_m=2.0))))
    monkeypatch.chdir(tmp_path)
    rc, printed, err = _run([a, b, "--format", "latex"], capsys)
    assert rc == 0, err
    assert printed.startswith("% vislam compare") and r"\midrule" in printed
    (made,) = (tmp_path / "results").iterdir()
    assert made.name.startswith("compare-") and (made / "compare.tex").read_text() == printed
    rc, printed, _ = _run([a, b, "-q", "--out", tmp_path / "q"], capsys)
    assert rc == 0 and printed == "" and (tmp_path / "q" / "compare.md").is_file()


def test_results_file_stands_for_its_folder_and_same_folder_twice(tmp_path, capsys):
    a = _write(tmp_path / "a", "results.json", _results(_seq("s", _est("e", ate_m=1.0))))
    rc, printed, err = _run([a / "results.json", a, "--out", tmp_path / "out"], capsys)
    assert rc == 0, err
    assert _row(printed, "e", "ATE (m)")[4:] == ["0 (0 %)", "same"]


# --- bad input -------------------------------------------------------------------------------

GOOD = _results(_seq("s", _est("e", ate_m=1.0)))


def _bad_results(mutate):
    data = copy.deepcopy(GOOD)
    mutate(data)
    return json.dumps(data)


HOSTILE = {
    "missing folder": (None, "no such folder"),
    "empty folder": ({}, "holds neither results.json"),
    "malformed JSON": ({"results.json": "{\"schema\": 1,"}, "not valid JSON"),
    "not UTF-8": ({"results.json": b"\xff\xfe{}"}, "not UTF-8"),
    "deep nesting": ({"results.json": "[" * 100000 + "]" * 100000}, "results.json"),
    "unknown schema": ({"results.json": _bad_results(lambda d: d.update(schema=99))},
                       "'schema' is 99"),
    "not an object": ({"results.json": "[1, 2]"}, "expected a JSON object"),
    "sequences not a list": ({"results.json": _bad_results(lambda d: d.update(sequences=3))},
                             "sequences: expected list"),
    "figure not a number": ({"results.json": _bad_results(
        lambda d: d["sequences"][0]["estimators"][0].update(ate_m="far"))},
        "sequences[0].estimators[0].ate_m: expected a number"),
    "estimator without name": ({"results.json": _bad_results(
        lambda d: d["sequences"][0]["estimators"][0].pop("name"))}, "missing key 'name'"),
    "nees runs not a number": ({"nees.json": json.dumps({"runs": "8", "estimators": {}})},
                               "runs: expected int"),
    "nees per-run not numbers": ({"nees.json": json.dumps({"runs": 2, "estimators": {"e": {
        "nees_pose_per_run_mean": ["x"]}}})}, "nees_pose_per_run_mean[0]"),
    "settings not an object": ({"results.json": json.dumps(GOOD), "settings.json": "[]"},
                               "settings.json: expected a JSON object"),
}


@pytest.mark.parametrize("case", list(HOSTILE))
def test_hostile_input_exits_2_with_one_line_and_writes_nothing(case, tmp_path, capsys):
    files, words = HOSTILE[case]
    good = _write(tmp_path / "good", "results.json", GOOD)
    bad = tmp_path / "bad"
    if files is not None:
        bad.mkdir()
        for name, content in files.items():
            (bad / name).write_bytes(content if isinstance(content, bytes) else content.encode())
    out = tmp_path / "out"
    rc, printed, err = _run([good, bad, "--out", out], capsys)
    assert rc == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("vislam compare: error: "), err
    assert words in lines[0] and str(bad) in lines[0]
    assert printed == "" and not out.exists()


def test_fewer_than_two_folders_and_out_inside_an_input(tmp_path, capsys):
    a = _write(tmp_path / "a", "results.json", GOOD)
    b = _write(tmp_path / "b", "results.json", GOOD)
    rc, _, err = _run([a, "--out", tmp_path / "out"], capsys)
    assert rc == 2 and "at least two result folders" in err and len(err.splitlines()) == 1
    for out in (a / "cmp", b, a / "x" / "y"):
        rc, _, err = _run([a, b, "--out", out], capsys)
        assert rc == 2 and "inside the input folder" in err and len(err.splitlines()) == 1
        assert not out.exists() or out == b
    assert sorted(p.name for p in b.iterdir()) == ["results.json"]


def test_foreign_non_empty_out_folder_is_refused(tmp_path, capsys):
    a = _write(tmp_path / "a", "results.json", GOOD)
    b = _write(tmp_path / "b", "results.json", GOOD)
    mine = _write(tmp_path / "mine", "notes.txt", "keep me")
    rc, _, err = _run([a, b, "--out", mine], capsys)
    assert rc == 2 and "did not write" in err
    assert sorted(p.name for p in mine.iterdir()) == ["notes.txt"]


# --- end to end with real benchmark runs -----------------------------------------------------


@pytest.mark.slow
def test_real_bench_before_and_after_a_settings_change(tmp_path, capsys):
    common = ["bench", "--frames", "60", "-e", "dead-reckoning,ekf-joint", "-j", "2",
              "--model", "as-given", "--quiet"]
    assert main([*common, "--out", str(tmp_path / "before")]) == 0
    assert main([*common, "--pixel-sigma", "3", "--out", str(tmp_path / "after")]) == 0
    capsys.readouterr()
    out = tmp_path / "cmp"
    rc, printed, err = _run([tmp_path / "before", tmp_path / "after", "--out", out], capsys)
    assert rc == 0, err
    assert "| filter.pixel_sigma | 1.000 | 3.000 |" in printed
    before = json.loads((tmp_path / "before" / "results.json").read_text())
    after = json.loads((tmp_path / "after" / "results.json").read_text())
    (sa,), (sb,) = before["sequences"], after["sequences"]
    ra = {r["name"]: r for r in sa["estimators"]}["ekf-joint"]
    rb = {r["name"]: r for r in sb["estimators"]}["ekf-joint"]
    x, y = ra["ate_m"], rb["ate_m"]
    row = _row(printed, "ekf-joint", "ATE (m)")
    assert row[2:4] == [compare_readings.num(x), compare_readings.num(y)]
    assert row[4] == f"{compare_readings.signed(y - x)} ({compare_readings.relative(y - x, x)})"
    assert row[5] == ("same" if abs(y - x) <= 1e-3 * max(abs(x), abs(y))
                      else "better" if y < x else "worse")
    for name in ("dead-reckoning", "ekf-joint"):
        assert _row(printed, name, "runtime")
    assert (out / "compare.md").read_text() == printed
    assert r"\bottomrule" in (out / "compare.tex").read_text()
    png = (out / "compare.png").read_bytes()
    assert png.startswith(PNG_MAGIC) and len(png) > 20000


# --- the drive-fitted RPE ----------------------------------------------------------------------


def _fitted(lengths: list[float], trans_pct: float) -> dict:
    stats = {"mean": trans_pct, "median": trans_pct, "rmse": trans_pct}
    return {"lengths_m": lengths, "path_length_m": 10 * lengths[0], "frames": 60,
            "n_segments": 50, "trans_pct": stats, "rot_deg_per_m": None,
            "per_length": [{"length_m": L, "n_segments": 10, "trans_m": None, "trans_pct": stats,
                            "rot_deg": None, "rot_deg_per_m": None} for L in lengths],
            "note": None}


def _rpe_folder(folder: Path, lengths: list[float], trans_pct: float) -> Path:
    data = _results(_seq("s", _est("ekf-joint", ate_m=1.0, rpe_drive_trans_pct=trans_pct,
                                   rpe_drive_rot_deg_per_m=0.02,
                                   rpe_drive=_fitted(lengths, trans_pct))))
    data["schema"] = 2
    return _write(folder, "results.json", data)


def test_drive_fitted_rpe_is_compared_and_its_lengths_said(tmp_path, capsys):
    a = _rpe_folder(tmp_path / "a", [4.0, 8.0, 12.0], 2.0)
    b = _rpe_folder(tmp_path / "b", [4.0, 8.0, 12.0], 1.0)
    rc, printed, err = _run([a, b, "--out", tmp_path / "out"], capsys)
    assert rc == 0, err
    assert _row(printed, "ekf-joint", "RPE (%)")[2:] == ["2.000", "1.000", "-1.000 (-50.0 %)",
                                                         "better"]
    assert _row(printed, "ekf-joint", "RPE (°/m)")[5] == "same"
    assert "RPE over segments of 4, 8 and 12 m" in printed
    # Folders whose drives gave other lengths: said, since the rows compare other segments.
    c = _rpe_folder(tmp_path / "c", [5.0, 10.0], 1.0)
    rc, printed, err = _run([a, c, "--out", tmp_path / "out2"], capsys)
    assert rc == 0, err
    assert ("RPE over different segment lengths (A: 4, 8 and 12 m; B: 5 and 10 m)" in printed)
    # A schema 1 folder (written before the drive-fitted RPE) has no value there.
    old = _write(tmp_path / "old", "results.json", _results(_seq("s", _est("ekf-joint",
                                                                           ate_m=1.0))))
    rc, printed, err = _run([old, b, "--out", tmp_path / "out3"], capsys)
    assert rc == 0, err
    assert _row(printed, "ekf-joint", "RPE (%)")[2:4] == ["n/a", "1.000"]
