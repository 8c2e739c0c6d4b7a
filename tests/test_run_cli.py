"""`vislam run` end to end: every registered estimator on a short simulated file."""

from __future__ import annotations

import json

import numpy as np
import pytest

from vislam.ekf.estimate import Estimate
from vislam.eval.cli import main
from vislam.eval.output_dir import MARKER
from vislam.eval.registry import ESTIMATOR_NAMES, get_estimator

OUTPUTS = ("trajectory.tum", "trajectory.kitti", "map.npz", "estimate.npz", "metrics.json",
           "settings.json")
#: The benchmark's per-drive plots of one estimator on a drive with ground truth (map.png only
#: for an estimator that maps landmarks; vs_smoother.png needs an EKF and a smoother together).
PLOTS = ("trajectories.png", "map.png", "error_over_distance.png", "nees.png")
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def sim_file(tmp_path_factory):
    from vislam.eval.simulate import SimConfig, simulate, write_simulation

    folder = tmp_path_factory.mktemp("sim")
    paths = write_simulation(simulate(SimConfig(seed=4, n_frames=60, name="short")), folder)
    return paths["data"]


def test_registry_names_and_unknown_name():
    from vislam.ekf.errors import InputError
    from vislam.eval.registry import DEFAULT_BENCH, parse_estimator_list

    assert ESTIMATOR_NAMES[0] == "dead-reckoning" and ESTIMATOR_NAMES[-1] == "smoother-fixed-lag"
    assert "smoother-isam2" in DEFAULT_BENCH and "smoother-fixed-lag" not in DEFAULT_BENCH
    assert len(DEFAULT_BENCH) == 7
    with pytest.raises(InputError, match="ekf-joint"):
        get_estimator("kalman")
    assert parse_estimator_list("smoother, dead-reckoning", DEFAULT_BENCH) == ["dead-reckoning", "smoother"]
    from vislam.eval.registry import INERTIAL_ESTIMATOR_NAMES

    # "all": every estimator of both kinds of drive (each drive runs those of its kind)
    assert parse_estimator_list("all", DEFAULT_BENCH) == list(ESTIMATOR_NAMES) + list(INERTIAL_ESTIMATOR_NAMES)
    with pytest.raises(InputError, match="bogus"):
        parse_estimator_list("ekf-joint,bogus", DEFAULT_BENCH)


@pytest.mark.parametrize("name", ESTIMATOR_NAMES)
def test_run_writes_every_file(name, sim_file, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["run", str(sim_file), "--estimator", name, "--out", str(out), "--quiet"]) == 0
    est = Estimate.load_npz(out / "estimate.npz")
    plots = [p for p in PLOTS if p != "map.png" or np.any(est.has_landmark)]
    assert sorted(p.name for p in out.iterdir()) == sorted([*OUTPUTS, *plots, MARKER])
    for png in plots:
        assert (out / png).read_bytes()[:8] == PNG_SIGNATURE, png
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["estimator"] == name and metrics["frames"] == 60
    assert metrics["has_ground_truth"] and metrics["ate_m"] is not None
    assert metrics["ate_aligned_m"] is not None and "rpe_trans_pct" in metrics
    assert len((out / "trajectory.tum").read_text().splitlines()) == 60
    assert len((out / "trajectory.kitti").read_text().splitlines()) == 60
    assert est.n_frames == 60
    with np.load(out / "map.npz") as m:
        assert m["landmarks"].shape == (est.landmarks.shape[0], 3)
        assert m["landmark_cov"].shape == (est.landmarks.shape[0], 3, 3)
        assert m["track_origin"].shape == (est.landmarks.shape[0],)
    settings = json.loads((out / "settings.json").read_text())
    assert settings["estimator"] == name and settings["filter"]["pixel_sigma"] == 1.0
    assert name in capsys.readouterr().out
    assert [p.name for p in tmp_path.iterdir()] == ["out"]


def test_run_plots_are_recorded_in_the_marker_and_skipped_with_no_plots(sim_file, tmp_path):
    out = tmp_path / "out"
    assert main(["run", str(sim_file), "-e", "ekf-invariant", "--out", str(out), "-q"]) == 0
    recorded = json.loads((out / MARKER).read_text())["files"]
    assert sorted(recorded) == sorted([*OUTPUTS, *PLOTS])  # every plot is vislam's file
    bare = tmp_path / "bare"
    assert main(["run", str(sim_file), "-e", "ekf-invariant", "--out", str(bare), "-q",
                 "--no-plots"]) == 0
    assert sorted(p.name for p in bare.iterdir()) == sorted([*OUTPUTS, MARKER])
    assert sorted(json.loads((bare / MARKER).read_text())["files"]) == sorted(OUTPUTS)


def test_run_without_ground_truth_plots_trajectory_and_map_only(sim_file, tmp_path):
    import shutil

    alone = tmp_path / "data"
    alone.mkdir()
    data = shutil.copy(sim_file, alone / sim_file.name)  # no groundtruth/ folder beside it
    out = tmp_path / "out"
    assert main(["run", str(data), "-e", "ekf-joint", "--out", str(out), "-q"]) == 0
    assert not json.loads((out / "metrics.json").read_text())["has_ground_truth"]
    assert sorted(p.name for p in out.glob("*.png")) == ["map.png", "trajectories.png"]


@pytest.mark.parametrize("exc", [RuntimeError("no font"), KeyboardInterrupt()])
def test_a_failing_plot_writes_nothing_and_keeps_the_previous_results(exc, sim_file, tmp_path,
                                                                     monkeypatch):
    import vislam.eval.plots as plots
    out = tmp_path / "out"
    assert main(["run", str(sim_file), "-e", "dead-reckoning", "--out", str(out), "-q"]) == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}

    def fail(*args, **kwargs):
        raise exc

    monkeypatch.setattr(plots, "plot_nees", fail)  # the last plot, after the others are drawn
    argv = ["run", str(sim_file), "-e", "dead-reckoning", "--out", str(out), "-q",
            "--pixel-sigma", "2"]
    if isinstance(exc, KeyboardInterrupt):
        assert main(argv) == 130
    else:  # as in `vislam bench`: the error goes up (loud), saying nothing was written
        with pytest.raises(RuntimeError, match="no font") as info:
            main(argv)
        assert any("--no-plots" in note for note in info.value.__notes__)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert [p.name for p in tmp_path.iterdir()] == ["out"]  # no staging folder left
    assert main([*argv, "--no-plots"]) == 0  # the way out the message names
    assert json.loads((out / "settings.json").read_text())["filter"]["pixel_sigma"] == 2.0


def test_run_flags_override_the_settings_file(sim_file, tmp_path):
    toml = tmp_path / "s.toml"
    toml.write_text("[filter]\npixel_sigma = 2.0\nvelocity_sigma = 0.3\n")
    out = tmp_path / "out"
    rc = main(["run", str(sim_file), "-e", "dead-reckoning", "--out", str(out), "-q",
               "--config", str(toml), "--pixel-sigma", "1.5", "--no-clean", "--gate-probability",
               "none", "--velocity-pairing", "next"])
    assert rc == 0
    f = json.loads((out / "settings.json").read_text())["filter"]
    assert f["pixel_sigma"] == 1.5 and f["velocity_sigma"] == 0.3
    assert f["clean_tracks"] is False and f["gate_probability"] is None
    assert f["velocity_pairing"] == "next"


@pytest.mark.parametrize(
    "argv",
    [
        ["--estimator", "kalman"],
        ["--estimator", "dead-reckoning", "--pixel-sigma", "-1"],
        ["--estimator", "dead-reckoning", "--config", "MISSING.toml"],
    ],
)
def test_run_bad_options_exit_2_and_write_nothing(argv, sim_file, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["run", str(sim_file), *argv, "--out", str(out), "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("vislam run: error:") and len(err.splitlines()) == 1
    assert list(tmp_path.iterdir()) == []


def test_run_bad_file_exits_2_and_writes_nothing(sim_file, tmp_path, capsys):
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip file")
    for path in (bad, tmp_path / "missing.npz"):
        out = tmp_path / "out"
        assert main(["run", str(path), "-e", "dead-reckoning", "--out", str(out), "-q"]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and path.name in err
        assert not out.exists()


def test_run_leaves_nothing_when_the_estimator_fails(sim_file, tmp_path, monkeypatch):
    import vislam.eval.commands.run as run_command
    def boom(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(run_command, "write_map_npz", boom)  # mid-way through writing outputs
    out = tmp_path / "out"
    assert main(["run", str(sim_file), "-e", "dead-reckoning", "--out", str(out), "-q"]) == 130
    assert list(tmp_path.iterdir()) == []


def test_smoother_settings_from_the_settings_file_and_flags(sim_file, tmp_path):
    toml = tmp_path / "s.toml"
    # filter settings at the top level, smoother settings in their own table
    toml.write_text('pixel_sigma = 1.0\n[smoother]\ninit = "dead-reckoning"\ngap_twist_prior = "off"\n'
                    'max_iterations = 50\n')
    out = tmp_path / "out"
    rc = main(["run", str(sim_file), "-e", "smoother", "--out", str(out), "-q",
               "--config", str(toml), "--gap-prior", "exact"])
    assert rc == 0
    settings = json.loads((out / "settings.json").read_text())
    assert settings["filter"]["pixel_sigma"] == 1.0
    s = settings["smoother"]
    assert (s["init"], s["gap_twist_prior"], s["max_iterations"]) == ("dead-reckoning", "exact", 50)
    est = Estimate.load_npz(out / "estimate.npz")
    assert est.info["init"] == "dead-reckoning"
    assert est.info["settings"]["gap_twist_prior"] == "exact"


@pytest.mark.parametrize(
    "table, fault",
    [
        ("[smoother]\nbogus = 1\n", "bogus"),
        ('[smoother]\ninit = "magic"\n', "init"),
        ('[smoother]\nmax_iterations = "many"\n', "max_iterations"),
    ],
)
def test_bad_smoother_settings_exit_2_naming_file_and_key(table, fault, sim_file, tmp_path_factory,
                                                          tmp_path, capsys):
    toml = tmp_path_factory.mktemp("settings") / "bad.toml"
    toml.write_text(table)
    out = tmp_path / "out"
    assert main(["run", str(sim_file), "-e", "smoother", "--out", str(out), "-q", "--config", str(toml)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "bad.toml" in err and fault in err, err
    assert not out.exists()


@pytest.mark.parametrize("argv", [
    ["run", "x.npz", "-e", "ekf-joint", "--out", "o", "--pixel-sigma", "-inf"],
    ["bogus"],
    [],
    ["bench", "--jobs", "many"],
])
def test_usage_errors_are_one_line_exit_2(argv, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "--help" in err


def test_messages_stay_one_line_and_printable(sim_file, tmp_path, capsys, monkeypatch):
    odd = tmp_path / "new\nline" / "résultats"
    assert main(["run", str(sim_file), "-e", "dead-reckoning", "--out", str(odd), "--gt", " ",
                 "-q"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "--gt" in err
    monkeypatch.setenv("MPLBACKEND", "nosuchbackend")  # the command line draws into files
    assert main(["bench", "--frames", "20", "-e", "dead-reckoning", "-j", "1", "-q",
                 "--out", str(tmp_path / "b")]) == 0


def test_absurd_but_finite_values_are_refused_naming_the_key(tmp_path, capsys):
    from vislam.eval.loader import read_arrays

    arrays = read_arrays(_small(tmp_path))
    for key, index, value, words in (("linear_velocity", (0, 3), 1e300, "not a velocity"),
                                     ("rotational_velocity", (2, 1), -1e300, "not a velocity"),
                                     ("cam_T_imu", (0, 3), 1e300, "translation")):
        bad = {k: v.copy() for k, v in arrays.items()}
        bad[key][index] = value
        path = tmp_path / f"bad-{key}.npz"
        _write(path, bad)
        assert main(["inspect", str(path)]) == 2
        err = capsys.readouterr().err
        assert key in err and words in err and len(err.strip().splitlines()) == 1


def _small(tmp_path):
    from vislam.eval.simulate import SimConfig, simulate, write_simulation

    return write_simulation(simulate(SimConfig(seed=2, n_frames=10, name="tiny")),
                            tmp_path / "tiny")["data"]


def _write(path, arrays):
    import numpy as np

    np.savez(path, **arrays)
