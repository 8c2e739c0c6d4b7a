"""The velocity check (graph.data_check, `vislam inspect --check`): velocities and vision agree
within their noise on a drive solved under its true model, and a wrong file is flagged."""

from __future__ import annotations

import numpy as np
import pytest

from vislam.ekf.config import FilterConfig
from vislam.ekf.model import apply_model, model_config, per_interval_config
from vislam.eval.cli import main
from vislam.eval.simulate import SimConfig, simulate, write_simulation
from vislam.graph.data_check import (
    MIN_VARIANCE_FRACTION,
    _threshold,
    interval_residuals,
    velocity_check,
)
from vislam.graph.stretches import stretch_labels
from vislam.graph.settings import SmootherSettings
from vislam.graph.smoother import solve_smoother

SETTINGS = SmootherSettings(compute_marginals=False)
#: Velocity noise per sample of the drives (m/s). At the shared data's 0.5 m/s a lever arm
#: wrong by metres hardly shows in a 10 s stretch (graph.data_check docstring); at 0.2 it does.
SIGMA_V = 0.2


def check_under(result, model=None, settings=SETTINGS, extrinsic="model"):
    """The check of a simulated drive solved under ``model`` (default its true model), with
    the model's extrinsic or (``extrinsic="file"``) the file's."""
    model = result.model if model is None else model
    if extrinsic == "model":
        seq, config = apply_model(result.sequence, FilterConfig(), model)
    else:
        seq, config = result.sequence, model_config(FilterConfig(), model)
    config = per_interval_config(config, model)  # the check reads one interval at a time
    solution = solve_smoother(seq, config, settings)
    return velocity_check(solution, config), solution, config


@pytest.fixture(scope="module")
def kitti_drive():
    """300 frames with the shared data's extrinsic fault in the file (the true one in the
    model)."""
    return simulate(SimConfig(seed=0, n_frames=300, velocity_sigma=SIGMA_V,
                              file_extrinsic_fault="kitti"))


def _assert_consistent(check):
    assert check.n_intervals == 299
    assert sum(s.n_intervals for s in check.stretches) == check.n_intervals
    assert check.dof == sum(s.dof for s in check.stretches)
    assert check.dof == 6 * (check.n_intervals - check.n_excluded_intervals) - check.n_excluded_dims
    for s in check.stretches:
        assert 0 < s.dof <= 6 * s.n_intervals and s.dof_linear <= 3 * s.n_intervals
        assert np.isfinite([s.chi2, s.chi2_linear, s.chi2_angular]).all()
        assert s.threshold > s.dof  # the 99.9 % quantile lies above the mean


@pytest.mark.regression
@pytest.mark.parametrize("seed", [0, 1])
def test_true_model_agrees_and_chi2_per_dof_is_near_one(seed, kitti_drive):
    result = kitti_drive if seed == 0 else simulate(
        SimConfig(seed=seed, n_frames=300, velocity_sigma=SIGMA_V))
    check, _, _ = check_under(result)  # the true model: its extrinsic, its noise
    _assert_consistent(check)
    assert [s.n_intervals for s in check.stretches] == [100, 100, 99]
    assert check.stretches[0].start_s == 0.0 and check.stretches[-1].end_s == pytest.approx(29.9)
    assert check.agrees, check.lines()
    assert 0.85 < check.ratio < 1.2
    assert 0.8 < check.ratio_linear < 1.25 and 0.8 < check.ratio_angular < 1.25
    assert check.n_excluded_intervals == 0  # no repeat events: vision spans every interval
    lines = check.lines()
    assert lines[0] == "velocity vs vision: agree within the noise in all 3 stretches (99.9 %)"
    assert "overall chi2/dof" in lines[1] and "nan" not in " ".join(lines)


@pytest.mark.regression
def test_wrong_extrinsic_in_the_file_is_flagged_in_the_linear_velocity(kitti_drive):
    check, _, _ = check_under(kitti_drive, extrinsic="file")  # true noise, the file's extrinsic
    _assert_consistent(check)
    assert len(check.flagged) >= 2, check.lines()
    assert all(s.flagged_linear for s in check.flagged)
    assert not any(s.flagged_angular for s in check.stretches)  # a lever arm: v = w x dl
    assert check.ratio_linear > 1.5 and check.ratio_angular < 1.25
    lines = check.lines()
    assert lines[0].startswith(f"velocity vs vision: {len(check.flagged)} of 3 stretches "
                               "disagree beyond the noise (99.9 %)")
    assert "linear velocity residuals" in lines[0] and "x their noise (chi2/dof" in lines[0]


@pytest.mark.regression
def test_velocities_noisier_than_the_settings_say_are_flagged_in_the_linear_part():
    result = simulate(SimConfig(seed=0, n_frames=300, velocity_sigma=0.5))
    wrong = result.model.replace(velocity_sigma=(0.05, 0.05, 0.05))  # per sample, like the sim's
    check, _, config = check_under(result, wrong)
    assert config.velocity_sigmas == pytest.approx(np.full(3, 0.05 / np.sqrt(2)))
    assert len(check.flagged) == len(check.stretches) == 3
    assert all(s.flagged_linear for s in check.stretches)
    # about (0.5 / 0.05)^2 = 100 times the variance, less what the smoother absorbed
    assert check.ratio_linear > 10.0
    assert check.ratio_linear > 10.0 * check.ratio_angular
    assert check.ratio_angular < 1.5
    assert all(s.describe().split(": ", 1)[1].startswith("linear velocity residuals")
               for s in check.stretches)


def test_intervals_without_vision_are_left_out_not_nan():
    """Repeat events leave intervals no track spans: without the twist-smoothness prior their
    residual is forced to zero (R ~ 0); with it, it measures the prior, not vision."""
    result = simulate(SimConfig(seed=2, n_frames=150, velocity_sigma=SIGMA_V,
                                repeat_event_rate=0.05))
    check, solution, config = check_under(result, settings=SETTINGS.replace(gap_twist_prior="off"))
    w, R, W = interval_residuals(solution, config)
    from vislam.graph.factors import unconstrained_intervals

    gaps = unconstrained_intervals(solution.problem.rows, solution.poses.shape[0])
    assert gaps.sum() >= 2
    scale = np.sqrt(np.diag(W))
    assert np.abs(w[gaps] / scale).max() < 1e-3  # forced to zero
    lam = np.linalg.eigvalsh(R[gaps] / np.outer(scale, scale))
    assert lam.max() < MIN_VARIANCE_FRACTION  # nothing left to test there
    assert check.n_excluded_intervals == int(gaps.sum())
    assert check.dof == 6 * (check.n_intervals - int(gaps.sum())) - check.n_excluded_dims
    assert np.isfinite([check.chi2, check.ratio, check.ratio_linear, check.ratio_angular]).all()
    assert 0.8 < check.ratio < 1.2 and check.agrees
    assert f"{int(gaps.sum())} intervals without vision" in check.lines()[1]


def test_stretches_and_thresholds():
    t = 0.1 * np.arange(299)  # interval start times of a 300-frame drive
    labels = stretch_labels(t, 10.0)
    assert np.bincount(labels).tolist() == [100, 100, 99]
    assert np.bincount(stretch_labels(0.1 * np.arange(120), 10.0)).tolist() == [120]  # 2 s left
    assert np.bincount(stretch_labels(0.1 * np.arange(160), 10.0)).tolist() == [100, 60]
    # a hole in the timestamps skips empty windows
    assert np.bincount(stretch_labels(np.r_[0.1 * np.arange(100), 50 + 0.1 * np.arange(100)],
                                      10.0)).tolist() == [100, 100]
    from scipy.stats import chi2

    assert _threshold(300, 0.999) == pytest.approx(chi2.ppf(0.999, 300))
    assert _threshold(0, 0.999) == 0.0
    # correlated intervals ("mean" pairing): same mean, 1.5 x the variance: a higher threshold
    assert _threshold(300, 0.999, 1.5) > _threshold(300, 0.999) + 5.0


def test_bad_arguments(kitti_drive):
    from vislam.ekf.errors import InputError

    for kwargs in ({"stretch_s": 0.0}, {"stretch_s": float("nan")}, {"level": 1.0}):
        with pytest.raises(InputError):
            velocity_check(None, FilterConfig(), **kwargs)


# --- the command line ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def drive_file(tmp_path_factory):
    folder = tmp_path_factory.mktemp("check")
    result = simulate(SimConfig(seed=4, n_frames=200, velocity_sigma=SIGMA_V))
    return write_simulation(result, folder, "drive")


def test_inspect_check_prints_the_check_after_the_summary(drive_file, capsys):
    path = str(drive_file["data"])
    assert main(["inspect", path]) == 0
    plain = capsys.readouterr().out
    assert "velocity" not in plain.replace("|v|", "")  # unchanged without --check
    assert main(["inspect", path, "--check", "--config", str(drive_file["model"])]) == 0
    out = capsys.readouterr().out
    assert out.startswith(plain)  # the usual output first, then the check
    extra = out[len(plain):].splitlines()
    assert extra[0].startswith("velocity check: smoother under velocity sigma 0.141,0.141,0.141 "
                               "m/s") and "the model's extrinsic" in extra[0]
    assert extra[1] == "velocity vs vision: agree within the noise in all 2 stretches (99.9 %)"
    ratio = float(extra[2].split("overall chi2/dof ")[1].split()[0])
    assert 0.8 < ratio < 1.25
    # no --config: the defaults (0.5 m/s per interval) overstate this drive's noise
    assert main(["inspect", path, "--check", "--stretch", "5"]) == 0
    out = capsys.readouterr().out
    assert "the file's extrinsic" in out and "in all 4 stretches" in out
    assert "note: linear velocity residuals are" in out


def test_inspect_check_bad_input_exit_2_with_one_line(drive_file, tmp_path, capsys):
    path = str(drive_file["data"])
    bad = tmp_path / "bad.toml"
    bad.write_text("[model]\nvelocity_sigma = -1\n")
    cases = [
        (["--check", "--config", str(bad)], str(bad)),
        (["--check", "--config", str(tmp_path / "missing.toml")], "missing.toml"),
        (["--check", "--velocity-sigma", "-1"], "--velocity-sigma"),
        (["--check", "--stretch", "0"], "--stretch"),
        (["--config", str(drive_file["model"])], "--config: estimator settings are used only"),
    ]
    for extra, expected in cases:
        assert main(["inspect", path, *extra]) == 2, extra
        captured = capsys.readouterr()
        assert captured.out == ""  # checked before anything is printed
        assert captured.err.count("\n") == 1 and expected in captured.err, captured.err
