"""vislam.testing, the public pytest helpers: they pass a correct user filter and catch a broken
one (the invariant EKF told half the true pixel noise; dead reckoning with its covariance
halved), with messages that state the figure, the bounds and the verdict; failed runs are named;
accuracy bounds on a drive; and the README's example runs as written."""

from __future__ import annotations

import importlib
import re
import subprocess
import sys
from pathlib import Path

import pytest

from vislam.eval.consistency import chi2_bounds
from vislam.testing import NEAR_FIELD

REPO = Path(__file__).resolve().parents[1]
MODULE = "vislam_testing_user_filters"
USER_FILTERS = '''
import dataclasses

from vislam.eval.builtin import dead_reckoning, ekf_invariant

CALLS = {"n": 0}


def good(seq, settings):
    return ekf_invariant(seq, settings)


def half_pixel_noise(seq, settings):  # overconfident: assumes half the true pixel noise
    config = settings.filter.replace(pixel_sigma=0.5 * settings.filter.pixel_sigma)
    return ekf_invariant(seq, dataclasses.replace(settings, filter=config))


def dr(seq, settings):
    return dead_reckoning(seq, settings)


def dr_half_cov(seq, settings):  # overconfident: pose covariance halved
    est = dead_reckoning(seq, settings)
    return dataclasses.replace(est, pose_cov=0.5 * est.pose_cov)


def boom(seq, settings):
    raise RuntimeError("the filter diverged")


def fails_from_the_fourth(seq, settings):
    CALLS["n"] += 1
    if CALLS["n"] > 3:
        raise RuntimeError("the filter diverged")
    return dead_reckoning(seq, settings)
'''
RUNS, FRAMES = 8, 80
SMALL = {"runs": RUNS, "frames": FRAMES}


@pytest.fixture(scope="module")
def user(tmp_path_factory):
    """A user's module of filters, importable by name (its folder on sys.path)."""
    folder = tmp_path_factory.mktemp("user")
    (folder / f"{MODULE}.py").write_text(USER_FILTERS)
    with pytest.MonkeyPatch.context() as mp:
        mp.syspath_prepend(str(folder))
        yield importlib.import_module(MODULE)
    sys.modules.pop(MODULE, None)


@pytest.fixture(scope="module")
def study(user):
    """The good and the broken filter, and one that always raises, beside the smoother."""
    from vislam.testing import monte_carlo

    return monte_carlo([f"{MODULE}:good", f"{MODULE}:half_pixel_noise", f"{MODULE}:boom"],
                       runs=RUNS, frames=FRAMES, sim=NEAR_FIELD)


def _bounds(runs: int, dof: int) -> str:
    lo, hi = chi2_bounds(runs, dof)
    return rf"95 % bounds \[{lo:.2f}, {hi:.2f}\]"


def test_a_correct_filter_passes(study):
    from vislam.testing import assert_agrees_with_smoother, assert_nees_consistent

    name = f"{MODULE}:good"
    checks = assert_nees_consistent(study, name)
    assert [(c.quantity, c.verdict, c.ok) for c in checks] == [
        ("pose ANEES", "inside", True), ("landmark ANEES", "inside", True)]
    assert re.fullmatch(rf"{name}: pose ANEES \d+\.\d\d over {RUNS} runs x {FRAMES - 1} steps, "
                        rf"{_bounds(RUNS, 6)}: inside", checks[0].message), checks[0].message
    agree = assert_agrees_with_smoother(study, name)
    assert agree.verdict == "agrees" and agree.value >= agree.bounds[0]
    assert f"of {RUNS * (FRAMES - 1)} frames" in agree.message


def test_the_broken_filter_fails_with_figure_bounds_and_verdict(study):
    from vislam.testing import assert_nees_consistent

    name = f"{MODULE}:half_pixel_noise"
    with pytest.raises(AssertionError) as info:
        assert_nees_consistent(study, name)
    pose, landmark = str(info.value).splitlines()
    m = re.fullmatch(rf"{name}: pose ANEES (\d+\.\d\d) over {RUNS} runs x {FRAMES - 1} steps, "
                     rf"{_bounds(RUNS, 6)}: above \(overconfident\)", pose)
    assert m, pose
    assert float(m.group(1)) > 2 * chi2_bounds(RUNS, 6)[1]  # far above, not by a hair
    assert re.fullmatch(rf"{name}: landmark ANEES \d+\.\d\d over {RUNS} runs x \d+ landmarks, "
                        rf"{_bounds(RUNS, 3)}: above \(overconfident\)", landmark), landmark
    check = study.consistency(name, "pose")
    assert not check and check.verdict == "above" and check.value > check.bounds[1]


def test_the_broken_filter_disagrees_with_the_smoother(study):
    from vislam.testing import assert_agrees_with_smoother

    name = f"{MODULE}:half_pixel_noise"
    with pytest.raises(AssertionError) as info:
        assert_agrees_with_smoother(study, name)
    m = re.fullmatch(
        rf"{name}: the smoother inside its 3-sigma on (0\.\d{{4}}) of {RUNS * (FRAMES - 1)} frames "
        r"\(median NEES vs smoother \d+\.\d\d\), chi-square predicts 0\.9973, required >= "
        r"(0\.\d{4}) \(binomial 1 % allowance\): disagrees \(the smoother is outside its 3-sigma "
        r"too often: overconfident\)", str(info.value))
    assert m, str(info.value)
    assert float(m.group(1)) < 0.95 < float(m.group(2))


def test_a_failing_filter_is_reported_and_does_not_stop_the_others(study):
    from vislam.testing import assert_agrees_with_smoother, assert_nees_consistent

    name = f"{MODULE}:boom"
    assert study.failed_runs(name) == RUNS and study.failed_runs(f"{MODULE}:good") == 0
    with pytest.raises(AssertionError) as info:
        assert_nees_consistent(study, name, what="pose")
    assert str(info.value) == (
        f"{name}: pose ANEES: no run completed; {RUNS} of {RUNS} runs failed: estimator "
        f"'{name}' raised RuntimeError: the filter diverged (a user's estimator that fails "
        "stops its runs: 0 done before)")
    with pytest.raises(AssertionError, match="no step compared with the smoother.*the filter diverged"):
        assert_agrees_with_smoother(study, name)


def test_failed_runs_are_counted_and_may_be_allowed(user):
    from vislam.testing import assert_nees_consistent, monte_carlo

    user.CALLS["n"] = 0
    name = f"{MODULE}:fails_from_the_fourth"
    study = monte_carlo(name, reference=None, sim=NEAR_FIELD, **SMALL)
    assert study.failed_runs() == RUNS - 3
    with pytest.raises(AssertionError) as info:
        assert_nees_consistent(study, what="pose")
    assert re.fullmatch(rf"{name}: pose ANEES \d+\.\d\d over 3 runs x {FRAMES - 1} steps, "
                        rf"{_bounds(3, 6)}: \w+( \(\w+\))?; {RUNS - 3} of {RUNS} runs failed: "
                        rf"estimator '{name}' raised RuntimeError: the filter diverged \(a user's "
                        r"estimator that fails stops its runs: 3 done before\)", str(info.value))
    (check,) = assert_nees_consistent(study, what="pose", max_failed_runs=RUNS - 3)
    assert check.ok and f"{RUNS - 3} of {RUNS} runs failed" in check.message
    assert check.message.endswith(f"allowed {RUNS - 3})")


def test_module_function_strings_run_by_the_helper(user):
    """An estimator given directly (not a study): the helper runs the Monte Carlo itself; a
    pose-only filter (dead reckoning) with what="pose"; its covariance halved is caught."""
    from vislam.testing import assert_nees_consistent

    (check,) = assert_nees_consistent(f"{MODULE}:dr", what="pose", sim=NEAR_FIELD, **SMALL)
    assert check.verdict == "inside", check.message
    with pytest.raises(AssertionError, match=rf"^{MODULE}:dr_half_cov: pose ANEES \d+\.\d\d over "
                       rf"{RUNS} runs x {FRAMES - 1} steps, {_bounds(RUNS, 6)}: above "
                       r"\(overconfident\)$"):
        assert_nees_consistent(f"{MODULE}:dr_half_cov", what="pose", sim=NEAR_FIELD, **SMALL)
    with pytest.raises(AssertionError, match=r"landmark ANEES: no landmark estimated in any run "
                       r"\(pass what='pose' for an estimator without a map\)"):
        assert_nees_consistent(f"{MODULE}:dr", sim=NEAR_FIELD, **SMALL)


def test_callables_in_worker_processes(user):
    """Module-level callables, shown as module:function, run in 2 worker processes."""
    from vislam.testing import assert_agrees_with_smoother, assert_nees_consistent, monte_carlo

    study = monte_carlo([user.good, user.half_pixel_noise], jobs=2, sim=NEAR_FIELD, **SMALL)
    assert study.subjects == (f"{MODULE}:good", f"{MODULE}:half_pixel_noise")
    assert study.estimators[-1] == "smoother"
    assert_nees_consistent(study, user.good)
    assert_agrees_with_smoother(study, user.good)
    with pytest.raises(AssertionError, match=r"pose ANEES .*: above \(overconfident\)"):
        assert_nees_consistent(study, user.half_pixel_noise)
    # the same broken filter given directly, under a label of one's own
    with pytest.raises(AssertionError, match=r"^half-pixel: the smoother inside its 3-sigma .*: disagrees"):
        assert_agrees_with_smoother({"half-pixel": user.half_pixel_noise}, sim=NEAR_FIELD, **SMALL)


def test_the_study_matches_the_seeded_drive(user):
    """The same seed gives the same numbers, and the label of vislam's own is its name."""
    from vislam.testing import monte_carlo

    a = monte_carlo("dead-reckoning", reference=None, runs=3, frames=40)
    b = monte_carlo({"dr": "dead-reckoning"}, reference=None, runs=3, frames=40)
    assert a.subjects == ("dead-reckoning",) and b.subjects == ("dr",)
    assert a.pose_anees().mean == b.pose_anees("dr").mean
    assert a.frames == 40 and a.sim.n_frames == 40 and a.sim.seed == 0


def test_misuse_is_named(study):
    from vislam.ekf.errors import InputError
    from vislam.testing import assert_nees_consistent, monte_carlo

    with pytest.raises(ValueError, match="the study has 3 estimators"):
        assert_nees_consistent(study)
    with pytest.raises(KeyError, match="'ekf-joint' is not in the study"):
        study.consistency("ekf-joint")
    with pytest.raises(InputError, match="unknown estimator 'no-such-filter'"):
        monte_carlo("no-such-filter", runs=1, frames=10)
    with pytest.raises(TypeError, match="leave it out"):
        assert_nees_consistent("dead-reckoning", "dead-reckoning", runs=1, frames=10)
    with pytest.raises(TypeError, match="would not be used"):
        assert_nees_consistent(study, f"{MODULE}:good", runs=3)
    with pytest.raises(ValueError, match="is the study's reference"):
        study.agreement("smoother")


def test_accuracy_on_a_simulated_drive_and_a_file(user, tmp_path):
    from vislam.eval.simulate import SimConfig, simulate, write_simulation
    from vislam.testing import assert_accuracy, run_drive

    sim = SimConfig(seed=0, n_frames=200, name="drive")
    drive = run_drive(["dead-reckoning", user.good], sim)
    ok = assert_accuracy(drive, name=user.good, ate_aligned_max=100.0, t_rel_max=100.0)
    assert [c.verdict for c in ok] == ["within", "within"]
    value = drive.scores[f"{MODULE}:good"]["ate_aligned_m"]
    assert ok[0].message == f"{MODULE}:good on drive: aligned ATE {value:.3f} m, bound 100 m: within"
    with pytest.raises(AssertionError) as info:
        assert_accuracy(drive, name="dead-reckoning", ate_aligned_max=0.01, t_rel_max=100.0)
    ate = drive.scores["dead-reckoning"]["ate_aligned_m"]
    assert str(info.value) == (f"dead-reckoning on drive: aligned ATE {ate:.3f} m, bound 0.01 m: "
                               f"over by {ate - 0.01:+.3f} m")

    # a file with its ground truth beside it, the estimator given directly
    paths = write_simulation(simulate(sim), tmp_path)
    (check,) = assert_accuracy(f"{MODULE}:dr", paths["data"], ate_max=1000.0)
    assert check.ok and check.message.startswith(f"{MODULE}:dr on drive: ATE ")
    with pytest.raises(AssertionError, match=r"the estimator failed: estimator .*boom.* diverged"):
        assert_accuracy(f"{MODULE}:boom", paths["data"], ate_max=1000.0)
    paths["groundtruth"].unlink()
    with pytest.raises(AssertionError, match=r"^dead-reckoning on drive: ATE: no figure \(the drive "
                       r"has no ground truth\), bound 1000 m$"):
        assert_accuracy("dead-reckoning", paths["data"], ate_max=1000.0)


def test_vislam_testing_is_the_public_module():
    import vislam
    import vislam.eval.folder_checks as saved
    import vislam.eval.testing as impl
    import vislam.testing as public

    assert sorted(public.__all__) == sorted(impl.__all__ + saved.__all__)
    for name in public.__all__:
        home = impl if name in impl.__all__ else saved
        assert getattr(public, name) is getattr(home, name)
        assert getattr(home, name).__doc__ or name in ("NEAR_FIELD", "THREE_SIGMA"), name
    assert vislam.testing is public and "assert_nees_consistent" in public.__doc__


def readme_examples() -> dict[str, str]:
    """{file name: code} of the README's blocks marked ``<!-- readme-example: NAME -->``."""
    text = (REPO / "README.md").read_text(encoding="utf-8")
    found = re.findall(r"<!-- readme-example: (\S+) -->\s*```python\n(.*?)```", text, flags=re.S)
    return dict(found)


def test_the_readme_example_runs(tmp_path):
    """The README's user filter and its test, written out as they stand and run by pytest."""
    examples = readme_examples()
    assert set(examples) == {"my_filter.py", "test_my_filter.py"}
    code_lines = sum(len([ln for ln in c.splitlines() if ln.strip()]) for c in examples.values())
    assert code_lines <= 25, code_lines  # about 20 lines
    for name, code in examples.items():
        (tmp_path / name).write_text(code, encoding="utf-8")
    proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "."],
                          cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert re.search(r"\b2 passed\b", proc.stdout), proc.stdout[-3000:]


def test_the_readme_quotes_the_broken_filters_message(study):
    """The failure the README quotes is what the helpers say of its filter told half the pixel
    noise (the same study: 8 runs x 80 frames, near field, seed 0)."""
    text = " ".join((REPO / "README.md").read_text(encoding="utf-8").split())
    quoted = re.search(r"`(my_filter:estimate: pose ANEES [^`]*)`", text)
    assert quoted, "the README quotes no failure message"
    got = study.consistency(f"{MODULE}:half_pixel_noise", "pose").message
    assert quoted.group(1) == got.replace(f"{MODULE}:half_pixel_noise", "my_filter:estimate")
