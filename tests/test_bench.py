"""`vislam bench` and `vislam nees` end to end on short simulated drives."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from vislam.ekf.config import FilterConfig
from vislam.eval import bench_output, bench_scores, drives, montecarlo, readings, study
from vislam.eval.cli import main

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
FAST = "dead-reckoning,ekf-joint,smoother"


def _check_schema(results: dict, estimators: list[str]) -> None:
    assert results["schema"] == bench_scores.SCHEMA and results["rpe_definition"]
    for s in results["sequences"]:
        assert set(bench_scores.SEQUENCE_KEYS) <= set(s)
        assert [r["name"] for r in s["estimators"]] == estimators
        for r in s["estimators"]:
            assert set(bench_scores.ESTIMATOR_KEYS) <= set(r), r
            assert set(bench_scores.VS_SMOOTHER_KEYS) <= set(r["vs_smoother"]), r


@pytest.mark.slow
def test_bench_on_a_short_simulation_writes_everything(tmp_path, capsys):
    out = tmp_path / "bench"
    rc = main(["bench", "--frames", "70", "-e", FAST, "-j", "2", "--out", str(out), "--quiet"])
    assert rc == 0
    results = json.loads((out / "results.json").read_text())
    _check_schema(results, FAST.split(","))
    (seq,) = results["sequences"]
    assert seq["has_ground_truth"] and seq["frames"] == 70 and seq["path"] is None
    rows = {r["name"]: r for r in seq["estimators"]}
    for r in rows.values():
        assert r["error"] is None
        assert r["runtime_s"] > 0 and r["ate_m"] is not None and r["nees_pose_mean"] is not None
        assert r["rpe_trans_pct"] is None  # 70 frames: shorter than every KITTI segment
        assert r["rpe_drive_trans_pct"] is not None and r["rpe_drive"]["note"] is None
        assert r["rpe_drive"]["lengths_m"] == rows["smoother"]["rpe_drive"]["lengths_m"]
    assert rows["ekf-joint"]["map_rmse_m"] is not None
    assert rows["ekf-joint"]["vs_smoother"]["map_rmse_m"] is not None
    assert rows["ekf-joint"]["vs_smoother"]["inside_95_fraction"] is not None
    assert all(v is None for v in rows["smoother"]["vs_smoother"].values())
    assert rows["dead-reckoning"]["map_rmse_m"] is None  # no landmarks: null, not absent
    summary = (out / "summary.md").read_text()
    # one row in the table of figures, one in the RPE per segment length
    assert summary.count("| ekf-joint |") == 2 and "| RPE (%) | RPE (°/m) |" in summary
    lengths = rows["smoother"]["rpe_drive"]["lengths_m"]
    assert f"RPE over segments of {readings.lengths_text(lengths)}" in summary
    settings = json.loads((out / "settings.json").read_text())
    assert settings["estimators"] == FAST.split(",") and "filter" in settings
    folder = out / seq["name"]
    for name in FAST.split(","):
        assert len((folder / f"{name}.tum").read_text().splitlines()) == 70
    pngs = sorted(p.name for p in folder.glob("*.png"))
    assert pngs == ["error_over_distance.png", "map.png", "nees.png", "trajectories.png",
                    "vs_smoother.png"]
    for p in folder.glob("*.png"):
        assert p.read_bytes().startswith(PNG_MAGIC) and p.stat().st_size > 5000
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_bench_default_folder_and_latest_link(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["bench", "--frames", "30", "-e", "dead-reckoning", "-j", "1"]) == 0
    assert "| dead-reckoning |" in capsys.readouterr().out
    latest = tmp_path / "results" / "latest"
    assert latest.is_symlink() and (latest / "results.json").is_file()
    (run_dir,) = [p for p in (tmp_path / "results").iterdir() if p.name != "latest"]
    assert os.readlink(latest) == run_dir.name


@pytest.mark.parametrize("exc", [RuntimeError("boom"), KeyboardInterrupt()])
def test_bench_leaves_nothing_when_interrupted(tmp_path, monkeypatch, exc):
    def fail(*args, **kwargs):
        raise exc

    monkeypatch.setattr(bench_output, "summary_markdown", fail)  # after TUM files and figures
    out = tmp_path / "bench"
    with pytest.raises(type(exc)):
        bench_output.run_benchmark(
            drives.collect_sequences([], frames=30), ["dead-reckoning"],
            FilterConfig(), out,
            show_progress=False,
        )
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_bench_keeps_a_previous_result_when_a_rerun_fails(tmp_path, monkeypatch):
    out = tmp_path / "bench"
    assert main(["bench", "--frames", "30", "-e", "dead-reckoning", "-j", "1", "--out", str(out), "-q"]) == 0
    before = (out / "results.json").read_text()
    monkeypatch.setattr(bench_output, "summary_markdown", lambda r: 1 / 0)
    with pytest.raises(ZeroDivisionError):
        main(["bench", "--frames", "30", "-e", "dead-reckoning", "-j", "1", "--out", str(out), "-q"])
    assert (out / "results.json").read_text() == before
    assert [p.name for p in tmp_path.iterdir()] == ["bench"]


def test_bench_bad_input_exits_2_and_writes_nothing(tmp_path, capsys):
    out = tmp_path / "bench"
    assert main(["bench", str(tmp_path / "missing.npz"), "--out", str(out)]) == 2
    assert main(["bench", "--frames", "30", "-e", "ekf-nonsense", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "missing.npz" in err and "ekf-joint" in err  # names the file; lists valid names
    assert not out.exists()


def test_failed_estimator_is_recorded_with_null_figures(tmp_path, monkeypatch):
    from vislam.ekf.errors import EstimationError
    import vislam.eval.registry as registry
    real = registry.get_estimator

    def fake(name):
        if name == "ekf-joint":
            def broken(seq, config, progress=None, initial=None, smoother=None):
                raise EstimationError("ekf-joint: innovation covariance not positive definite")
            return broken
        return real(name)

    monkeypatch.setattr(registry, "get_estimator", fake)
    res = bench_output.run_benchmark(
        drives.collect_sequences([], frames=30), ["dead-reckoning", "ekf-joint"],
        FilterConfig(), tmp_path / "b",
        show_progress=False,
    )
    rows = {r["name"]: r for r in res.results["sequences"][0]["estimators"]}
    assert "positive definite" in rows["ekf-joint"]["error"]
    assert rows["ekf-joint"]["ate_m"] is None and rows["dead-reckoning"]["ate_m"] is not None
    _check_schema(res.results, ["dead-reckoning", "ekf-joint"])


def test_redrawn_noise_keeps_the_drive_and_changes_the_noise():
    from vislam.eval.simulate import SimConfig, simulate

    cfg = SimConfig(seed=3, n_frames=40)
    truth = simulate(SimConfig(seed=3, n_frames=40, noise_free=True))
    a = montecarlo.redraw_noise(truth, cfg, np.random.default_rng([3, 0]))
    b = montecarlo.redraw_noise(truth, cfg, np.random.default_rng([3, 1]))
    assert a.n_tracks == b.n_tracks == truth.sequence.n_tracks
    dv = a.linear_velocity - truth.true_velocities[:, :3]
    assert 0.3 < dv.std() < 0.7  # velocity_sigma 0.5
    assert not np.allclose(a.linear_velocity, b.linear_velocity)
    assert np.array_equal(a.timestamps, truth.sequence.timestamps)


@pytest.mark.slow
def test_nees_command_writes_json_and_plot(tmp_path, capsys):
    out = tmp_path / "nees"
    rc = main(["nees", "--runs", "3", "--frames", "40", "-e", "dead-reckoning,ekf-joint",
               "-j", "2", "--out", str(out)])
    assert rc == 0
    data = json.loads((out / "nees.json").read_text())
    assert data["runs"] == 3 and data["frames"] == 40
    for name in ("dead-reckoning", "ekf-joint"):
        r = data["estimators"][name]
        for key in ("anees_pose", "anees_landmark", "bounds_pose", "bounds_landmark",
                    "verdict_pose", "verdict_landmark", "nees_pose_over_time"):
            assert key in r
        assert len(r["nees_pose_over_time"]) == 40 and r["anees_pose"] > 0
        assert r["verdict_pose"] in ("inside", "above", "below")
        assert r["bounds_pose"][0] < 6 < r["bounds_pose"][1]
    assert data["estimators"]["ekf-joint"]["anees_landmark"] is not None
    assert data["estimators"]["dead-reckoning"]["anees_landmark"] is None
    assert (out / "nees.png").read_bytes().startswith(PNG_MAGIC)
    assert "ANEES" in capsys.readouterr().out


def test_bench_on_a_folder_of_files_finds_ground_truth_and_landmarks(tmp_path):
    from vislam.eval.simulate import SimConfig, simulate, write_simulation

    data = tmp_path / "data"
    for seed in (1, 2):
        write_simulation(simulate(SimConfig(seed=seed, n_frames=40, name=f"s{seed}")), data)
    out = tmp_path / "bench"
    rc = main(["bench", str(data), "-e", "dead-reckoning,ekf-joint", "-j", "2", "--out", str(out), "-q"])
    assert rc == 0
    results = json.loads((out / "results.json").read_text())
    _check_schema(results, ["dead-reckoning", "ekf-joint"])
    assert [s["name"] for s in results["sequences"]] == ["s1", "s2"]
    for s in results["sequences"]:
        assert s["has_ground_truth"] and s["has_landmark_truth"]
        assert s["path"].endswith(f"{s['name']}.npz")
        joint = s["estimators"][1]
        assert joint["ate_m"] is not None and joint["map_rmse_m"] is not None
        assert all(v is None for v in joint["vs_smoother"].values())  # no smoother ran
        assert (out / s["name"] / "ekf-joint.tum").is_file()


def test_bench_hostile_landmark_file_is_one_line_exit_2(tmp_path, capsys):
    from vislam.eval.simulate import SimConfig, simulate, write_simulation

    data = tmp_path / "data"
    write_simulation(simulate(SimConfig(seed=1, n_frames=20, name="s1")), data)
    (data / "s1_landmarks.npz").write_bytes(b"PK\x03\x04 not really a zip")
    code = main(["bench", str(data), "-e", "dead-reckoning", "--out", str(tmp_path / "o"), "-q"])
    err = capsys.readouterr().err
    assert code == 2 and "s1_landmarks.npz" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()


def test_bench_identifies_the_model_by_default_caches_it_and_records_it(tmp_path, monkeypatch):
    import json

    from vislam.eval.cli import main

    model_cache = tmp_path / "cache"  # this test's own: the first run must identify
    monkeypatch.setenv("VISLAM_CACHE_DIR", str(model_cache))
    out1, out2, out3 = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    argv = ["bench", "--frames", "60", "-e", "dead-reckoning,ekf-invariant", "-j", "1", "-q"]
    assert main([*argv, "--out", str(out1)]) == 0
    seq = json.loads((out1 / "results.json").read_text())["sequences"][0]
    model = seq["model"]
    assert model["mode"] == "identified" and model["cached"] is False
    entry = model["cache_entry"]
    assert entry and entry.startswith(str(model_cache)) and Path(entry).is_file()
    assert model["model"]["file"]["cam_T_imu"] is not None  # the file's values beside
    assert model["identification"]["extrinsic_test"]["decision"]
    assert model["ground_truth_extrinsic"].startswith("none needed")  # simulated truth
    settings = json.loads((out1 / "settings.json").read_text())
    assert settings["model_mode"] == "identify"
    assert settings["sequences"][0]["filter"]["velocity_pairing"] == model["model"]["velocity_pairing"]
    # a second run reads the cache: same model, no identification
    assert main([*argv, "--out", str(out2)]) == 0
    again = json.loads((out2 / "results.json").read_text())["sequences"][0]["model"]
    assert again["cached"] is True and again["model"] == model["model"]
    # --model as-given: the file's extrinsic and the settings as given
    assert main([*argv, "--model", "as-given", "--out", str(out3)]) == 0
    given = json.loads((out3 / "results.json").read_text())["sequences"][0]["model"]
    assert given["mode"] == "as-given" and given["model"] is None
    assert given["cam_T_imu"] == model["model"]["file"]["cam_T_imu"]


def test_bench_falls_back_to_as_given_when_the_model_cannot_be_identified(tmp_path, caplog):
    import json

    from vislam.eval.cli import main

    out = tmp_path / "o"
    assert main(["bench", "--frames", "2", "-e", "dead-reckoning", "-j", "1", "-q",
                 "--out", str(out)]) == 0
    model = json.loads((out / "results.json").read_text())["sequences"][0]["model"]
    assert model["mode"] == "as-given" and "at least 3 frames" in model["identification_failed"]
    assert "cannot identify the model" in caplog.text


def test_summary_says_which_model_and_when_the_reference_is_not_a_fair_yardstick():
    base = {"name": "d", "frames": 10, "has_ground_truth": True, "reference_smoother": "smoother"}
    row = {k: None for k in bench_scores.ESTIMATOR_KEYS}
    row["vs_smoother"] = {k: None for k in bench_scores.VS_SMOOTHER_KEYS}

    def summary(nees, model):
        r = {**row, "name": "smoother", "nees_pose_mean": nees}
        return readings.summary_markdown({"rpe_definition": "x", "sequences": [
            {**base, "model": model, "estimators": [r]}]})

    identified = {"mode": "identified", "cached": True, "model": {
        "velocity_sigma": [0.5, 0.5, 0.5], "gyro_sigma": [0.05] * 3, "pixel_sigma": 0.7,
        "velocity_pairing": "mean", "gyro_bias": None},
        "identification": {"extrinsic_test": {"decision": "identified (the data refute the file's)",
                                              "statistic": 991.0, "dof": 5}}}
    text = summary(97.5, identified)
    assert "Model identified from the data (cached): velocity sigma 0.5, 0.5, 0.5 m/s" in text
    assert "no gyro bias" in text and "the data refute the file's" in text
    assert "The smoother is overconfident on this drive: pose NEES 97.5, band [1.24, 14.45]" in text
    assert "overconfident" not in summary(6.1, identified)
    assert "underconfident" in summary(0.5, identified)
    assert "Model: the file's extrinsic and the settings as given." in summary(6.0, {"mode": "as-given"})
    assert "identified on frames" not in text and "returning tracks" not in text
    identified["identification"].update(frames=[1520, 3020], n_frames=4541, returning_tracks_split=357)
    text = summary(6.1, identified)
    assert "identified on frames 1520-3019 of 4541 (the drive's central 1500:" in text
    assert "; 357 returning tracks identified as new landmarks (the estimators keep each as one)" in text
    identified["identification"].update(frames=[0, 4541], returning_tracks_split=0)
    assert "identified on frames" not in summary(6.1, identified)


def test_summary_reads_the_results_in_words_and_drops_empty_columns():
    row = {k: None for k in bench_scores.ESTIMATOR_KEYS}
    vs = {k: None for k in bench_scores.VS_SMOOTHER_KEYS}

    def est(name, ate, nees, vs_nees=None, error=None):
        return {**row, "name": name, "error": error, "runtime_s": 1.0, "ate_aligned_m": ate,
                "nees_pose_mean": nees, "vs_smoother": {**vs, "nees_pose_mean": vs_nees}}

    seq = {"name": "d", "frames": 10, "has_ground_truth": True, "reference_smoother": "smoother",
           "estimators": [est("dead-reckoning", 3.5, 7.3), est("ekf-decoupled", 13.0, 2.04e10, 6.7e14),
                          est("ekf-joint", 5.2, 17.8, 6.6), est("smoother", 2.6, 146.0),
                          est("ekf-invariant", None, None, error="boom")]}
    text = readings.summary_markdown({"rpe_definition": "x", "sequences": [seq]})
    said = readings.readings(seq)
    assert said[0] == "Failed: ekf-invariant (see results.json)."
    assert said[1] == "Most accurate: smoother (aligned ATE 2.60 m); the best EKF is ekf-joint (5.20 m)."
    assert ("consistent: dead-reckoning (7.3); overconfident: ekf-decoupled (2.0e10), "
            "ekf-joint (17.8), smoother (146.0).") in said[2]
    assert said[3].startswith("Pose NEES against the smoother") and "consistent: ekf-joint (6.6)" in said[3]
    assert said[4].startswith("The smoother is overconfident on this drive")
    assert all(f"- {x}" in text for x in said)
    header = next(line for line in text.splitlines() if line.startswith("| estimator"))
    assert header == "| estimator | time (s) | ATE al. (m) | NEES | vs sm. NEES |"
    assert "| ekf-decoupled | 1.00 | 13.00 | 2.0e10 | 6.7e14 |" in text
    assert "20400000000" not in text
    assert readings.format_figure(0.0054) == "5.4e-3" and readings.format_figure(0.0) == "0.00" and readings.format_figure(123.456) == "123.46"


def test_bench_on_a_missing_path_says_where_the_drives_are(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("VISLAM_DATA", str(tmp_path / "nowhere"))
    assert main(["bench", str(tmp_path / "missing"), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "missing: no such file or folder (no drives in" in err and "set VISLAM_DATA" in err
    assert not (tmp_path / "out").exists()


def test_progress_names_the_jobs_running_not_the_one_finished():
    import concurrent.futures as cf

    futs = [cf.Future() for _ in range(4)]
    labels = dict(zip(futs, ["smoother on 0027", "ekf-joint on 0027", "ekf-joint on 0034", "mapping on 0034"]))
    assert study.progress_words(labels, set(futs)) == "waiting"  # queued, none started
    futs[0].set_running_or_notify_cancel()
    assert study.progress_words(labels, set(futs)) == "running smoother on 0027"
    for f in futs[1:]:
        f.set_running_or_notify_cancel()
    assert study.progress_words(labels, set(futs)) == "running ekf-joint on 0027, ekf-joint on 0034 and 2 more"
    assert study.progress_words(labels, set()) == "finishing"


def test_model_cache_key_ignores_what_identification_overrides():
    """Identification solves every smoother round to its EM tolerance, so the smoother's
    rejection-round tolerance does not make another model: same key (and models cached before
    that setting existed stay valid); a setting it does read changes the key."""
    from vislam.eval.model_cache import cache_key
    from vislam.eval.simulate import SimConfig, simulate
    from vislam.graph.settings import SmootherSettings

    seq = simulate(SimConfig(seed=1, n_frames=20)).sequence
    base = cache_key(seq, FilterConfig(), SmootherSettings(), ("mean",))
    assert cache_key(seq, FilterConfig(), SmootherSettings(rejection_relative_error_tol=0.5),
                     ("mean",)) == base
    assert cache_key(seq, FilterConfig(), SmootherSettings(huber_k=2.0), ("mean",)) != base


def test_a_model_on_a_drive_with_ground_truth_records_the_truths_lever_arm(tmp_path):
    """Where the ground truth has camera poses, results.json puts the model's lever arm beside
    the one the truth and the velocities agree on (eval.lever_arm_truth), and summary.md
    says both; the file's wrong extrinsic (the KITTI fault) does not enter it."""
    from vislam.ekf.model import Model
    from vislam.eval.simulate import SimConfig, simulate, write_simulation
    from vislam.graph.extrinsic import lever_arm

    result = simulate(SimConfig(seed=3, n_frames=120, name="arm", velocity_sigma=0.05,
                                file_extrinsic_fault="kitti"))
    paths = write_simulation(result, tmp_path)
    (bs,) = drives.collect_sequences([str(paths["data"])])
    model = Model(velocity_sigma=(0.05,) * 3, gyro_sigma=(0.05,) * 3, pixel_sigma=1.0,
                  velocity_pairing="mean", cam_T_imu=result.cam_T_imu)
    (done,) = drives.apply_model_to([bs], model, FilterConfig(), "config")
    arm = done.model["lever_arm"]
    true = lever_arm(result.cam_T_imu)
    np.testing.assert_allclose(arm["model"], true)
    z = (np.array(arm["ground_truth"]) - true) / np.array(arm["ground_truth_sigma"])
    assert np.all(np.abs(z[:2]) < 3), arm
    line = readings.model_line(done.model)
    assert "the ground truth's" in line and "no vision" in line
    short = drives.collect_sequences([str(write_simulation(
        simulate(SimConfig(seed=3, n_frames=12, name="short")), tmp_path / "s")["data"])])
    (done,) = drives.apply_model_to(short, model, FilterConfig(), "config")
    assert done.model["lever_arm"]["ground_truth"] is None
    assert "usable intervals" in done.model["lever_arm"]["ground_truth_error"]
    assert "the ground truth's" not in readings.model_line(done.model)


def test_the_model_line_names_which_errors_are_correlated_in_time():
    """summary.md's model line says which of the velocity and gyro errors the model carries a
    long-run sigma for, with their variance ratios, and nothing where it carries none."""
    from vislam.ekf.model import Model

    def line(**times):
        model = Model(velocity_sigma=(0.05,) * 3, gyro_sigma=(0.005,) * 3, pixel_sigma=1.0,
                      velocity_pairing="next", cam_T_imu=np.eye(4), **times)
        return readings.model_line({"mode": "config", "model": model.to_dict()})

    assert "correlated in time" not in line()
    both = line(velocity_correlation_time=(7.0, 11.5, 1.0), gyro_correlation_time=(2.5, 1.0, 1.0))
    assert ("velocity and gyro errors correlated in time (long-run / white variance velocity "
            "7, 11.5, 1; gyro 2.5, 1, 1:") in both
    gyro = line(gyro_correlation_time=(2.5, 1.0, 1.0))
    assert "gyro errors correlated in time (long-run / white variance gyro 2.5, 1, 1:" in gyro
    assert "velocity errors correlated" not in gyro
