"""FilterConfig: defaults, validation naming the setting at fault, TOML loading."""

import numpy as np
import pytest

from vislam.ekf.config import FilterConfig
from vislam.ekf.errors import InputError


def test_defaults_are_valid_and_matrices_full_rank():
    cfg = FilterConfig()
    assert np.linalg.matrix_rank(cfg.pixel_cov) == 4
    assert cfg.velocity_cov.shape == (6, 6)
    assert np.all(np.linalg.eigvalsh(cfg.initial_pose_cov) > 0)


@pytest.mark.parametrize(
    "change, key",
    [
        ({"pixel_sigma": 0.0}, "pixel_sigma"),
        ({"velocity_sigma": -1.0}, "velocity_sigma"),
        ({"gate_probability": 1.5}, "gate_probability"),
        ({"velocity_pairing": "sideways"}, "velocity_pairing"),
        ({"min_disparity": -2.0}, "min_disparity"),
        ({"max_depth": float("nan")}, "max_depth"),
    ],
)
def test_bad_values_name_the_setting(change, key):
    with pytest.raises(InputError, match=key):
        FilterConfig().replace(**change)


def test_unknown_setting_is_named():
    with pytest.raises(InputError, match="pixel_sigmaa"):
        FilterConfig().replace(pixel_sigmaa=1.0)


def test_toml(tmp_path):
    p = tmp_path / "s.toml"
    p.write_text('[filter]\npixel_sigma = 2.0\nvelocity_pairing = "next"\n')
    cfg = FilterConfig.from_toml(p)
    assert cfg.pixel_sigma == 2.0 and cfg.velocity_pairing == "next"
    p.write_text("pixel_sigma = 2.0\nbogus = 1\n")
    with pytest.raises(InputError, match=r"s\.toml.*bogus"):
        FilterConfig.from_toml(p)
    p.write_text("pixel_sigma = = 2\n")
    with pytest.raises(InputError, match="not valid TOML"):
        FilterConfig.from_toml(p)
    with pytest.raises(InputError, match="not found"):
        FilterConfig.from_toml(tmp_path / "missing.toml")


def test_toml_leaves_the_smoother_table_to_the_smoother(tmp_path):
    from vislam.graph.settings import SmootherSettings

    p = tmp_path / "s.toml"
    p.write_text('pixel_sigma = 2.0\n[smoother]\ninit = "isam2"\n')
    assert FilterConfig.from_toml(p).pixel_sigma == 2.0
    p.write_text('[filter]\npixel_sigma = 2.0\n[smoother]\ninit = "isam2"\nhuber_k = 2\n')
    assert FilterConfig.from_toml(p).pixel_sigma == 2.0
    s = SmootherSettings.from_mapping({"init": "isam2", "huber_k": 2}, "s.toml [smoother]")
    assert s.init == "isam2" and s.huber_k == 2.0
    with pytest.raises(InputError, match=r"s\.toml \[smoother\].*'gap_twist_prior'"):
        SmootherSettings.from_mapping({"gap_twist_prior": True}, "s.toml [smoother]")


# --- issue 11, item 5: every setting checked (type, finite, range), the file and key named ----

import argparse  # noqa: E402
import math  # noqa: E402
from pathlib import Path  # noqa: E402

from vislam.ekf.config import FILTER_RULES, MAX_SETTINGS_BYTES  # noqa: E402
from vislam.eval.commands.options import add_filter_arguments, filter_config_from_args, smoother_settings_from_args  # noqa: E402
from vislam.graph.settings import SMOOTHER_RULES, SmootherSettings  # noqa: E402


def _args(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    add_filter_arguments(parser)
    return parser.parse_args(list(argv))


def _write(tmp_path, text: str | bytes, name: str = "settings.toml") -> Path:
    p = tmp_path / name
    p.write_bytes(text if isinstance(text, bytes) else text.encode())
    return p


def _error(path) -> str:
    """The InputError of reading settings file ``path`` as the CLI does (filter, then smoother)."""
    with pytest.raises(InputError) as info:
        args = _args("--config", str(path))
        filter_config_from_args(args)
        smoother_settings_from_args(args)
    msg = str(info.value)
    assert str(path) in msg and len(msg.splitlines()) == 1, msg
    return msg


@pytest.mark.parametrize(
    "text, needle",
    [
        # the failures the issue lists
        ("[filter]\ngyro_bias_walk = nan\n", "[filter]: setting 'gyro_bias_walk' must be a number from 0"),
        ('[filter]\nblas_threads = "x"\n', "[filter]: setting 'blas_threads' must be an integer from 1 to 1024, got 'x'"),
        ("[filter]\npixel_sigma = -1\n", "[filter]: setting 'pixel_sigma' must be a positive number"),
        ("pixel_sigma = -1\n", ": setting 'pixel_sigma' must be a positive number"),
        # types: a bool is not a number, a string is not, nor an array or a table
        ("[filter]\npixel_sigma = true\n", "'pixel_sigma' must be a positive number from 1e-12 to 10000, got true"),
        ('[filter]\npixel_sigma = "2"\n', "'pixel_sigma' must be a positive number from 1e-12 to 10000, got '2'"),
        ("[filter]\npixel_sigma = [1, 2]\n", "got an array [1, 2]"),
        ("[filter]\npixel_sigma = {a = 1}\n", "got a table {'a': 1}"),
        ("[filter]\nclean_tracks = 1\n", "'clean_tracks' must be true or false, got 1"),
        ('[filter]\nvelocity_pairing = 1\n', "'velocity_pairing' must be one of 'current', 'next', 'mean'"),
        ("[filter]\nblas_threads = 2.0\n", "'blas_threads' must be an integer from 1 to 1024, got 2.0"),
        ("[filter]\nblas_threads = 1000000000\n", "'blas_threads' must be an integer from 1 to 1024"),
        ("[filter]\nblas_threads = 0\n", "'blas_threads'"),
        # finiteness and sane bounds: squares must stay finite and positive
        ("[filter]\nvelocity_sigma = inf\n", "'velocity_sigma' must be a positive number from 1e-12 to 1000, "
         "or an array of 3 such numbers (x, y, z), got inf"),
        # per-axis sigmas: one number or exactly three, each checked
        ("[filter]\nvelocity_sigma = [0.5, 0.4]\n", "'velocity_sigma' must be a positive number from 1e-12 to 1000, "
         "or an array of 3 such numbers (x, y, z), got an array [0.5, 0.4]"),
        ("[filter]\ngyro_sigma = [0.05, nan, 0.05]\n", "'gyro_sigma' must be a positive number"),
        ("[filter]\ngyro_sigma = [0.05, 0, 0.05]\n", "got an array [0.05, 0, 0.05]"),
        ("[filter]\ngyro_sigma = [0.05, \"0.1\", 0.05]\n", "'gyro_sigma' must be"),
        ("[filter]\nvelocity_sigma = [[0.5, 0.4, 0.3]]\n", "'velocity_sigma' must be"),
        ("[filter]\nvelocity_sigma = [0.5, [0.4], 0.3]\n", "'velocity_sigma' must be"),
        ("[filter]\ngyro_sigma = -inf\n", "got -inf"),
        ("[filter]\nmax_depth = 1e400\n", "'max_depth' must be a positive number up to 1e+06, got inf"),
        ("[filter]\npixel_sigma = 1e200\n", "got 1e+200"),
        ("[filter]\ninitial_rotation_sigma = 1e-200\n", "got 1e-200"),
        ("[filter]\ngate_probability = 1.0\n", "'gate_probability' must be a probability in (0, 1) or 'none'/'off'"),
        ("[filter]\ngate_probability = nan\n", "'gate_probability'"),
        ("[filter]\nmin_disparity = -0.5\n", "'min_disparity' must be a number from 0 to 10000"),
        # the smoother table
        ("[smoother]\nhuber_k = nan\n", "[smoother]: setting 'huber_k' must be a positive number"),
        ("[smoother]\nmax_iterations = 10.5\n", "[smoother]: setting 'max_iterations' must be an integer"),
        ("[smoother]\nrejection_rounds = -1\n", "'rejection_rounds' must be an integer from 0 to 1000"),
        ("[smoother]\ncompute_marginals = \"yes\"\n", "'compute_marginals' must be true or false"),
        ("[smoother]\nlandmark_prior_sigma = 1e300\n", "'landmark_prior_sigma'"),
        ("[smoother]\nbogus = 1\n", "[smoother]: unknown setting 'bogus' (valid smoother settings: init, huber_k"),
        # the layout of the file
        ("[filter]\nbogus = 1\n", "[filter]: unknown setting 'bogus' (valid filter settings: pixel_sigma,"),
        ("filter = 3\n", "[filter] must be a table of settings, got 3"),
        ("[[filter]]\npixel_sigma = 1.0\n", "[filter] must be a table of settings, got an array"),
        ("smoother = \"fast\"\n", "[smoother] must be a table of settings, got 'fast'"),
        ("[smoothr]\ninit = \"ekf\"\n", "unknown table [smoothr] (valid tables: [filter], [smoother], [model], [file])"),
        # a drive's model beside the settings (ekf.model)
        ("[model]\nvelocity_sigma = 1\n", "[model]: missing setting 'gyro_sigma'"),
        ("model = 3\n", "[model] must be a table of settings, got 3"),
        ("[file]\npixel_sigma = 1.0\n", "[file]: a [file] table needs a [model] table beside it"),
        ("pixel_sigma = 2.0\n[filter]\nvelocity_sigma = 0.3\n", "unknown top-level key 'pixel_sigma'"),
        ("[filter]\npixel_sigma = 1.0\npixel_sigma = 2.0\n", "not valid TOML: Cannot overwrite a value"),
        ("[filter]\n[filter]\n", "not valid TOML"),
        ("pixel_sigma = = 2\n", "not valid TOML"),
        ("x = " + "[" * 5000 + "\n", "not valid TOML"),
    ],
)
def test_bad_settings_files_name_the_file_and_key(tmp_path, text, needle):
    assert needle in _error(_write(tmp_path, text))


def test_settings_file_that_cannot_be_read(tmp_path, monkeypatch):
    # missing, a folder, not UTF-8, too large
    assert "settings file not found" in _error(tmp_path / "missing.toml")
    folder = tmp_path / "folder.toml"
    folder.mkdir()
    assert "is a folder, not a settings file" in _error(folder)
    latin1 = _write(tmp_path, "# caf\xe9\npixel_sigma = 1.0\n".encode("latin-1"))
    assert "not UTF-8 text (byte 5, line 1)" in _error(latin1)
    assert "not UTF-8" in _error(_write(tmp_path, b"\xff\xfe\x00p\x00i", "utf16.toml"))
    big = _write(tmp_path, b"# " + b"x" * MAX_SETTINGS_BYTES + b"\n", "big.toml")
    assert "not a settings file" in _error(big)
    # permission denied: chmod does not deny root, so the open itself is made to fail
    denied = _write(tmp_path, "pixel_sigma = 1.0\n", "denied.toml")
    real_open = Path.open

    def fake_open(self, *args, **kwargs):
        if self.name == "denied.toml":
            raise PermissionError(13, "Permission denied", str(self))
        return real_open(self, *args, **kwargs)

    monkeypatch.setattr(Path, "open", fake_open)
    assert "permission denied reading the settings file" in _error(denied)


def test_good_settings_files(tmp_path):
    # a byte-order mark is allowed, an int where a float is expected is stored as a float,
    # "none"/"off" switch the gate off, an empty [filter] table keeps the defaults
    p = _write(tmp_path, b"\xef\xbb\xbf[filter]\npixel_sigma = 2\ngate_probability = \"Off\"\n"
                         b"blas_threads = 4\n[smoother]\nhuber_k = 2\nmax_iterations = 7\n")
    args = _args("--config", str(p))
    cfg, sm = filter_config_from_args(args), smoother_settings_from_args(args)
    assert cfg.pixel_sigma == 2.0 and isinstance(cfg.pixel_sigma, float)
    assert cfg.gate_probability is None and cfg.blas_threads == 4
    assert sm.huber_k == 2.0 and isinstance(sm.huber_k, float) and sm.max_iterations == 7
    p = _write(tmp_path, "[filter]\n")
    assert filter_config_from_args(_args("--config", str(p))) == FilterConfig()


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["--pixel-sigma", "-1"], "--pixel-sigma: must be a positive number from 1e-12 to 10000, got -1.0"),
        (["--pixel-sigma", "abc"], "--pixel-sigma: must be a positive number from 1e-12 to 10000, got 'abc'"),
        (["--velocity-sigma", "nan"], "--velocity-sigma: must be a positive number"),
        (["--gyro-sigma=-inf"], "--gyro-sigma: must be a positive number"),
        (["--velocity-sigma", "0.5,0.4"], "--velocity-sigma: must be a positive number from 1e-12 to 1000, "
                                          "or an array of 3 such numbers (x, y, z), got an array [0.5, 0.4]"),
        (["--velocity-sigma", "0.5,x,0.3"], "--velocity-sigma: must be a positive number"),
        (["--gyro-sigma", "0.05,0.05,0"], "--gyro-sigma: must be a positive number"),
        (["--max-depth", "1e400"], "--max-depth: must be a positive number up to 1e+06, got inf"),
        (["--min-disparity", "1e300"], "--min-disparity: must be a number from 0 to 10000"),
        (["--gate-probability", "1"], "--gate-probability: must be a probability in (0, 1)"),
        (["--gate-probability", "maybe"], "--gate-probability: must be a probability"),
        (["--velocity-pairing", "sideways"], "--velocity-pairing: must be one of 'current', 'next', 'mean'"),
        (["--smoother-init", "magic"], "--smoother-init: must be one of 'ekf', 'dead-reckoning', 'isam2'"),
        (["--gap-prior", "on"], "--gap-prior: must be one of 'linearised', 'exact', 'off'"),
    ],
)
def test_bad_flags_name_the_flag(argv, needle):
    args = _args(*argv)
    with pytest.raises(InputError) as info:
        filter_config_from_args(args)
        smoother_settings_from_args(args)
    assert str(info.value).startswith(needle), str(info.value)


def test_flags_override_the_file_and_are_checked_after_merging(tmp_path):
    p = _write(tmp_path, "[filter]\npixel_sigma = 2.0\ngate_probability = 0.5\n")
    cfg = filter_config_from_args(_args("--config", str(p), "--pixel-sigma", "3",
                                        "--gate-probability", "none"))
    assert cfg.pixel_sigma == 3.0 and cfg.gate_probability is None
    sm = smoother_settings_from_args(_args("--smoother-init", "isam2", "--gap-prior", "off"))
    assert (sm.init, sm.gap_twist_prior) == ("isam2", "off")
    # a bad file is reported even when a flag would override the bad key
    p = _write(tmp_path, "[filter]\npixel_sigma = nan\n")
    with pytest.raises(InputError, match="settings.toml"):
        filter_config_from_args(_args("--config", str(p), "--pixel-sigma", "3"))
    # an empty --config is a file name like any other, not "no file"
    with pytest.raises(InputError, match="empty path"):
        filter_config_from_args(_args("--config", ""))


@pytest.mark.parametrize(
    "change",
    [
        {"pixel_sigma": True}, {"pixel_sigma": "1"}, {"pixel_sigma": 1e200}, {"pixel_sigma": 10**400},
        {"gyro_bias_walk": math.nan}, {"gyro_bias_walk": -1e-9}, {"blas_threads": "x"},
        {"blas_threads": 2.0}, {"blas_threads": 10**9}, {"gate_probability": 0.0},
        {"clean_tracks": "yes"}, {"triangulation": None}, {"initial_position_sigma": [1.0]},
    ],
)
def test_replace_and_the_constructor_validate(change):
    key = next(iter(change))
    with pytest.raises(InputError, match=f"setting '{key}'"):
        FilterConfig().replace(**change)
    with pytest.raises(InputError, match=f"setting '{key}'"):
        FilterConfig(**change)


@pytest.mark.parametrize(
    "change",
    [
        {"huber_k": math.inf}, {"huber_k": False}, {"max_iterations": 0}, {"max_iterations": 2.0},
        {"relative_error_tol": 0.0}, {"absolute_error_tol": math.nan}, {"min_depth": -1.0},
        {"init": "magic"}, {"compute_marginals": 1}, {"isam2_relinearize_skip": 10**12},
    ],
)
def test_smoother_replace_and_constructor_validate(change):
    key = next(iter(change))
    with pytest.raises(InputError, match=f"smoother setting '{key}'"):
        SmootherSettings().replace(**change)
    with pytest.raises(InputError, match=f"smoother setting '{key}'"):
        SmootherSettings(**change)


def test_every_field_has_a_rule_and_the_defaults_follow_it():
    for rules, obj in ((FILTER_RULES, FilterConfig()), (SMOOTHER_RULES, SmootherSettings())):
        for name, rule in rules.items():
            assert rule.check(getattr(obj, name)) == getattr(obj, name)
    # numpy scalars are accepted and stored as Python numbers
    cfg = FilterConfig(pixel_sigma=np.float32(2.0), blas_threads=np.int64(2), gyro_bias=np.bool_(False))
    assert type(cfg.pixel_sigma) is float and type(cfg.blas_threads) is int and cfg.gyro_bias is False


# --- the command line: a bad --config is one line, exit 2, nothing written --------------------


@pytest.fixture(scope="module")
def sim_file(tmp_path_factory):
    from vislam.eval.simulate import SimConfig, simulate, write_simulation

    folder = tmp_path_factory.mktemp("sim")
    return write_simulation(simulate(SimConfig(seed=4, n_frames=30, name="short")), folder)["data"]


@pytest.mark.parametrize(
    "content",
    [b"[filter]\ngyro_bias_walk = nan\n", b"[filter]\nblas_threads = \"x\"\n", b"\xff\xfe bad",
     b"[filter]\npixel_sigma = -1\n", None],
)
def test_cli_bad_config_exits_2_with_one_line_and_writes_nothing(sim_file, tmp_path, capsys, content):
    from vislam.eval.cli import main

    bad = tmp_path / "bad.toml"
    if content is None:
        bad.mkdir()  # a folder given as the settings file
    else:
        bad.write_bytes(content)
    out = tmp_path / "out"
    rc = main(["run", str(sim_file), "--estimator", "dead-reckoning", "--out", str(out),
               "--config", str(bad), "-q"])
    captured = capsys.readouterr()
    assert rc == 2
    err = captured.err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("vislam run: error: ") and str(bad) in err[0]
    assert "Traceback" not in captured.err and not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.toml"]


# --- issue 12: per-axis velocity noise -----------------------------------------------------------


def test_per_axis_sigmas_from_the_constructor_a_file_and_flags(tmp_path):
    cfg = FilterConfig(velocity_sigma=[0.5, 0.4, 0.3], gyro_sigma=np.array([0.01, 0.02, 0.03]))
    assert cfg.velocity_sigma == (0.5, 0.4, 0.3) and cfg.gyro_sigma == (0.01, 0.02, 0.03)
    np.testing.assert_array_equal(np.diag(cfg.velocity_cov),
                                  np.array([0.5, 0.4, 0.3, 0.01, 0.02, 0.03]) ** 2)
    assert np.count_nonzero(cfg.velocity_cov - np.diag(np.diag(cfg.velocity_cov))) == 0
    # one number still means every axis, and the two spellings give the same covariance
    np.testing.assert_array_equal(FilterConfig(velocity_sigma=0.5).velocity_cov,
                                  FilterConfig(velocity_sigma=(0.5, 0.5, 0.5)).velocity_cov)
    import json

    assert json.loads(json.dumps(cfg.to_dict()))["velocity_sigma"] == [0.5, 0.4, 0.3]
    p = _write(tmp_path, "[filter]\nvelocity_sigma = [0.5, 0.4, 1]\ngyro_sigma = 0.02\n")
    cfg = filter_config_from_args(_args("--config", str(p)))
    assert cfg.velocity_sigma == (0.5, 0.4, 1.0) and cfg.gyro_sigma == 0.02
    assert all(type(x) is float for x in cfg.velocity_sigma)
    cfg = filter_config_from_args(_args("--config", str(p), "--gyro-sigma", "0.1, 0.2,0.3",
                                        "--velocity-sigma", "0.7"))
    assert cfg.gyro_sigma == (0.1, 0.2, 0.3) and cfg.velocity_sigma == 0.7
    assert FilterConfig(**FilterConfig(velocity_sigma=(1, 2, 3)).to_dict()).velocity_sigma == (1.0, 2.0, 3.0)
