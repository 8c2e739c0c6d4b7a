"""`vislam nees --sim-max-depth` (the simulated landmark range) and the depth-sweep benchmark."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from vislam.eval.montecarlo import DEFAULT_NEES_FRAMES, nees_sim_config
from vislam.eval.cli import main
from vislam.eval.simulate import DEFAULT_SIM, simulate

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _observed_depths(result) -> np.ndarray:
    """Depth in the left camera of every observed landmark, at its frame."""
    obs = result.sequence.obs
    cam_T_world = result.cam_T_imu @ np.linalg.inv(result.poses[obs.frame_index])
    points = result.landmarks[obs.track]
    return np.einsum("nj,nj->n", cam_T_world[:, 2, :3], points) + cam_T_world[:, 2, 3]


def test_default_range_leaves_the_drive_as_it_was():
    expected = dataclasses.replace(DEFAULT_SIM, seed=3, n_frames=DEFAULT_NEES_FRAMES, name="mc-seed3")
    assert nees_sim_config(3) == expected
    assert nees_sim_config(3, None, DEFAULT_SIM.max_depth) == expected


def test_a_short_range_keeps_the_drive_usable_and_nothing_deeper():
    default = simulate(dataclasses.replace(nees_sim_config(0, 60), noise_free=True))
    config = nees_sim_config(0, 60, 15.0)
    assert config.max_depth == 15.0 and config.landmark_density > DEFAULT_SIM.landmark_density
    short = simulate(dataclasses.replace(config, noise_free=True))
    depths = _observed_depths(short)
    assert depths.max() <= 15.0 and depths.min() >= DEFAULT_SIM.min_depth
    per_frame = np.bincount(short.sequence.obs.frame_index, minlength=60)
    # the density keeps about the default range's observations per frame
    assert per_frame.mean() > 0.7 * default.sequence.obs.frame_index.size / 60
    assert per_frame.min() >= 20


def test_nees_records_the_range(tmp_path, capsys):
    out = tmp_path / "nees"
    assert main(["nees", "--runs", "2", "--frames", "30", "-e", "ekf-joint", "-j", "1",
                 "--sim-max-depth", "15", "--out", str(out), "-q"]) == 0
    data = json.loads((out / "nees.json").read_text())
    assert data["simulation"]["max_depth"] == 15.0
    assert data["simulation"]["landmark_density"] > DEFAULT_SIM.landmark_density
    assert data["estimators"]["ekf-joint"]["anees_landmark"] is not None


@pytest.mark.parametrize("value", ["3", "2.5", "-1", "0", "nan", "inf", "1e5"])
def test_bad_range_is_exit_2_naming_the_flag(value, tmp_path, capsys):
    out = tmp_path / "nees"
    assert main(["nees", "--runs", "2", "-e", "ekf-joint", f"--sim-max-depth={value}",
                 "--out", str(out), "-q"]) == 2
    err = capsys.readouterr().err
    assert "--sim-max-depth" in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_range_that_is_no_number_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["nees", "--runs", "2", "--sim-max-depth", "deep"])
    assert exit_info.value.code == 2 and "--sim-max-depth" in capsys.readouterr().err


@pytest.fixture(scope="module")
def sweep(benchmark_script):
    return benchmark_script("nees_depth_sweep")


def test_depth_sweep_end_to_end(sweep, tmp_path, capsys):
    from vislam.ekf.config import LANDMARK_PARAMETERISATIONS

    out = tmp_path / "sweep"
    assert sweep.main(["--runs", "2", "--frames", "30", "--depths", "25,15",
                       "--estimators", "ekf-joint", "-j", "1", "--out", str(out)]) == 0
    data = json.loads((out / "nees_depth_sweep.json").read_text())
    assert data["depths"] == [15.0, 25.0] and data["runs"] == 2 and data["frames"] == 30
    rows = data["rows"]
    assert len(rows) == 2 * len(LANDMARK_PARAMETERISATIONS)
    assert {r["parameterisation"] for r in rows} == set(LANDMARK_PARAMETERISATIONS)
    assert all(r["estimator"] == "ekf-joint" and r["anees_pose"] > 0 for r in rows)
    assert (out / "nees_depth_sweep.png").read_bytes().startswith(PNG_MAGIC)
    assert "| 15 |" in capsys.readouterr().out


def test_depth_sweep_refuses_a_folder_it_did_not_write(sweep, tmp_path, capsys):
    (tmp_path / "mine.txt").write_text("keep me")
    assert sweep.main(["--runs", "2", "--frames", "30", "--depths", "15",
                       "--estimators", "ekf-joint", "-j", "1", "--out", str(tmp_path)]) == 2
    assert "--out" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine.txt"]
    with pytest.raises(SystemExit):
        sweep.main(["--depths", "2"])
