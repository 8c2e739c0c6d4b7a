"""The estimator protocol (eval/registry.py): vislam's own estimators are entry points like a
user's; a user's ``MODULE:FUNCTION`` runs through bench, run and nees with every figure filled,
installing and registering nothing; a broken one is one line and exit 2, with nothing written."""

from __future__ import annotations

import json
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from vislam.ekf.config import FilterConfig
from vislam.ekf.errors import EstimationError, InputError
from vislam.eval import registry
from vislam.eval.drives import simulated_sequence
from vislam.eval.cli import main

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

REPO = Path(__file__).resolve().parents[1]

#: A user's estimator: vislam's invariant EKF, its covariances inflated 4x (honest but cautious).
GOOD = '''
from vislam.eval.builtin import ekf_invariant


def estimate(seq, settings):
    est = ekf_invariant(seq, settings)
    est.estimator = "inflated"
    est.pose_cov = est.pose_cov * 4.0
    est.landmark_cov = est.landmark_cov * 4.0
    return est
'''

#: Broken estimators: function body -> the words the one-line error must contain.
BROKEN = {
    "raises": ("def estimate(seq, settings):\n    raise ZeroDivisionError('my bug')",
               "raised ZeroDivisionError: my bug"),
    "short": ("def estimate(seq, settings):\n"
              "    est = dead_reckoning(seq, settings)\n"
              "    est.poses = est.poses[:-1]\n    return est",
              "poses of shape"),
    "nan": ("def estimate(seq, settings):\n"
            "    est = dead_reckoning(seq, settings)\n"
            "    est.poses[3, 0, 3] = float('nan')\n    return est",
            "frame 3"),
    "asymmetric": ("def estimate(seq, settings):\n"
                   "    est = dead_reckoning(seq, settings)\n"
                   "    est.pose_cov[5, 0, 1] += 1.0\n    return est",
                   "not symmetric"),
    "not_an_estimate": ("def estimate(seq, settings):\n    return seq.timestamps",
                        "not a vislam.ekf.estimate.Estimate"),
    "not_callable": ("estimate = 3", "neither a Filter class"),
}


def _module(folder: Path, name: str, body: str) -> str:
    (folder / f"{name}.py").write_text(
        "from vislam.eval.builtin import dead_reckoning  # noqa: F401\n" + textwrap.dedent(body))
    return name


@pytest.fixture
def user_folder(tmp_path, monkeypatch):
    """A folder with the user's module, as the current folder (nothing installed, sys.path as
    it was)."""
    folder = tmp_path / "project"
    folder.mkdir()
    monkeypatch.chdir(folder)
    yield folder
    for name in [m for m in sys.modules if m.startswith("user_")]:
        del sys.modules[name]


def test_builtin_estimators_are_entry_points_as_pyproject_registers_them():
    project = tomllib.loads((REPO / "pyproject.toml").read_text())
    declared = project["project"]["entry-points"][registry.ENTRY_POINT_GROUP]
    assert declared == registry.BUILTIN_ENTRY_POINTS
    from importlib.metadata import entry_points

    installed = {e.name: e.value for e in entry_points(group=registry.ENTRY_POINT_GROUP)}
    assert {k: installed.get(k) for k in declared} == declared
    assert registry.known_names()[: len(registry.ESTIMATOR_NAMES)] == list(registry.ESTIMATOR_NAMES)


@pytest.mark.parametrize("name", registry.ESTIMATOR_NAMES)
def test_every_builtin_resolves_to_a_filter_class_or_a_protocol_function(name):
    fn = registry.resolve(name)
    if name in registry.SMOOTHERS:
        assert fn.__module__ == "vislam.eval.builtin"
        assert fn.__name__ == name.replace("-", "_")
    else:  # a per-frame filter class, run by the one driver under its registered name
        from vislam.ekf.filter import is_filter_class

        assert is_filter_class(fn.filter_class) and fn.filter_class.name == name


def test_names_are_listed_once():
    """Every list of estimator names derives from the entry points."""
    from vislam.ekf.estimators import ESTIMATORS, filter_names

    assert tuple(ESTIMATORS) == filter_names() == tuple(
        n for n in registry.ESTIMATOR_NAMES if n not in registry.SMOOTHERS)
    assert set(registry.SMOOTHER_INITIAL_FROM) <= set(filter_names())
    assert set(registry.DEFAULT_BENCH) <= set(registry.ESTIMATOR_NAMES)


def test_a_user_module_runs_under_the_protocol(user_folder):
    mod = _module(user_folder, "user_good", GOOD)
    seq = simulated_sequence(0, 30).sequence
    est = registry.get_estimator(f"{mod}:estimate")(seq, FilterConfig())
    ref = registry.get_estimator("ekf-invariant")(seq, FilterConfig())
    np.testing.assert_array_equal(est.poses, ref.poses)
    np.testing.assert_allclose(est.pose_cov, 4.0 * ref.pose_cov)
    assert str(user_folder) not in sys.path  # searched for the import only


def test_a_file_path_names_a_module_too(user_folder):
    _module(user_folder, "user_file", GOOD)
    fn = registry.resolve(f"{user_folder / 'user_file.py'}:estimate")
    assert fn.__name__ == "estimate"


@pytest.mark.parametrize("spec, words", [
    ("user_nowhere:estimate", "no module 'user_nowhere'"),
    ("user_good:nothing", "has no 'nothing'"),
    (":estimate", "expected MODULE:CLASS or MODULE:FUNCTION"),
    ("user_good:", "expected MODULE:CLASS or MODULE:FUNCTION"),
    ("no_such_file.py:estimate", "no file no_such_file.py"),
])
def test_a_missing_callable_is_named(user_folder, spec, words):
    _module(user_folder, "user_good", GOOD)
    with pytest.raises(InputError, match=words):
        registry.parse_estimator_list(spec, registry.DEFAULT_BENCH)


def test_a_module_that_fails_on_import_is_named(user_folder):
    (user_folder / "user_import_error.py").write_text("raise RuntimeError('half-written')\n")
    with pytest.raises(registry.UserEstimatorError,
                       match="importing user_import_error raised RuntimeError: half-written"):
        registry.resolve("user_import_error:estimate")


@pytest.mark.parametrize("fault", sorted(BROKEN))
def test_a_broken_estimate_is_a_user_error_naming_the_fault(user_folder, fault):
    body, words = BROKEN[fault]
    mod = _module(user_folder, f"user_{fault}", body)
    seq = simulated_sequence(0, 20).sequence
    with pytest.raises(registry.UserEstimatorError) as info:
        registry.get_estimator(f"{mod}:estimate")(seq, FilterConfig())
    assert words in str(info.value) and f"{mod}:estimate" in str(info.value)
    assert "\n" not in str(info.value)


def test_contract_of_the_builtin_estimators_is_checked_as_estimation_error():
    seq = simulated_sequence(0, 20).sequence
    est = registry.get_estimator("dead-reckoning")(seq, FilterConfig())
    est.pose_cov = est.pose_cov.copy()
    est.pose_cov[2] = -np.eye(6)
    with pytest.raises(EstimationError, match="frame 2 that is not positive semi-definite"):
        registry.check_contract(est, seq, "dead-reckoning")
    est = registry.get_estimator("dead-reckoning")(seq, FilterConfig())
    est.poses = est.poses.copy()
    est.poses[4, :3, :3] *= 1.1
    with pytest.raises(EstimationError, match="frame 4 that is not a rigid transform"):
        registry.check_contract(est, seq, "dead-reckoning")


def test_the_list_keeps_builtins_in_table_order_and_user_estimators_as_given(user_folder):
    _module(user_folder, "user_good", GOOD)
    names = registry.parse_estimator_list("user_good:estimate,smoother,dead-reckoning",
                                          registry.DEFAULT_BENCH)
    assert names == ["dead-reckoning", "smoother", "user_good:estimate"]
    assert registry.file_stem("pkg.mod:estimate") == "pkg.mod-estimate"


@pytest.mark.slow
def test_bench_runs_a_user_estimator_with_every_figure(user_folder, tmp_path):
    mod = _module(user_folder, "user_bench", GOOD)
    name = f"{mod}:estimate"
    out = tmp_path / "bench"
    rc = main(["bench", "--frames", "60", "--model", "as-given", "-e", f"{name},smoother",
               "-j", "2", "--out", str(out), "-q"])
    assert rc == 0
    results = json.loads((out / "results.json").read_text())
    (seq,) = results["sequences"]
    rows = {r["name"]: r for r in seq["estimators"]}
    assert list(rows) == ["smoother", name]
    row = rows[name]
    assert row["error"] is None
    figures = {k: v for k, v in row.items() if k not in ("error", "rpe_trans_pct",
                                                         "rpe_rot_deg_per_100m")}
    assert all(v is not None for v in figures.values()), figures  # 60 frames: no KITTI segment
    assert all(v is not None for v in row["vs_smoother"].values()), row["vs_smoother"]
    folder = out / seq["name"]
    assert (folder / "user_bench-estimate.tum").is_file()
    assert (folder / "user_bench-estimate.estimate.npz").is_file()
    assert f"| {name} |" in (out / "summary.md").read_text()


@pytest.mark.slow
def test_nees_runs_a_user_estimator(user_folder, tmp_path):
    mod = _module(user_folder, "user_nees", GOOD)
    name = f"{mod}:estimate"
    out = tmp_path / "nees"
    assert main(["nees", "--runs", "3", "--frames", "40", "-e", name, "-j", "2",
                 "--out", str(out), "-q"]) == 0
    row = json.loads((out / "nees.json").read_text())["estimators"][name]
    assert row["runs_failed"] == 0
    assert row["anees_pose"] is not None and row["anees_landmark"] is not None
    assert row["verdict_pose"] is not None


@pytest.mark.parametrize("command", ["bench", "nees", "run"])
def test_a_broken_user_estimator_exits_2_with_one_line_and_writes_nothing(
        user_folder, tmp_path, capsys, command):
    body, words = BROKEN["short"]
    name = f"{_module(user_folder, 'user_short_' + command, body)}:estimate"
    out = tmp_path / "out"
    argv = {
        "bench": ["bench", "--frames", "30", "--model", "as-given", "-e", f"dead-reckoning,{name}",
                  "-j", "1"],
        "nees": ["nees", "--runs", "2", "--frames", "30", "-e", name, "-j", "1"],
        "run": ["run", "--estimator", name],
    }[command]
    if command == "run":
        main(["simulate", "--frames", "30", "--out", str(tmp_path / "sim")])
        drive = [p for p in (tmp_path / "sim").glob("*.npz") if not p.stem.endswith("_landmarks")]
        argv = argv[:1] + [str(drive[0])] + argv[1:]
    rc = main([*argv, "--out", str(out), "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2
    assert len(err) == 1 and words in err[0] and name in err[0], err
    assert not out.exists()


def test_a_missing_user_module_exits_2_before_any_work(user_folder, tmp_path, capsys):
    out = tmp_path / "out"
    rc = main(["bench", "--frames", "30", "-e", "user_absent:estimate", "--out", str(out), "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "no module 'user_absent'" in err[0]
    assert not out.exists()


def test_a_user_estimator_has_a_colour_of_its_own_in_every_figure(monkeypatch, tmp_path):
    from vislam.eval import drive_figures, plots

    for name in ("my_filter:estimate", "pkg.mod:run", "other:estimate"):
        colour = plots.line_style(name, i=3)["color"]
        assert colour not in plots.COLOURS.values()  # never the smoother's red or an EKF's
        assert plots.line_style(name, i=0)["color"] == colour == plots._colour(name, 5)
    # and it is among the filters compared with the smoother, as vislam's EKFs are
    seen = {}

    def spy(path, ekfs, ref, title):
        seen["names"] = list(ekfs)
        return path

    monkeypatch.setattr(plots, "plot_vs_smoother", spy)
    bs = simulated_sequence(0, 30)
    ests = {n: registry.get_estimator(n)(bs.sequence, FilterConfig())
            for n in ("dead-reckoning", "smoother")}
    ests["user:estimate"] = ests["dead-reckoning"]
    drive_figures.sequence_figures(tmp_path, bs, ests)
    assert seen["names"] == ["user:estimate"]
