"""Accuracy on the shared drive 0027 (KITTI odometry 07) against its ground truth: a bound per
estimator on the SE(3)-aligned ATE (m) and on the KITTI drift t_rel (%, 100-800 m segments),
set about 10 % above what the code measured when the bound was set, so a regression fails.

Every estimator runs once (``eval.benchmark.run_jobs``, 2 worker processes, the smoother
starting from the invariant EKF as in ``vislam bench``), with the default FilterConfig."""

from __future__ import annotations

import pytest

from tests.regression.breaks import run_name, skip_or_fail

pytestmark = [pytest.mark.slow, pytest.mark.realdata]

DRIVE = "0027"
#: estimator -> (aligned ATE bound m, t_rel bound %). Measured (default settings, cleaned
#: tracks): see MEASURED; bounds = measured x 1.1, rounded up.
MEASURED = {
    "dead-reckoning": (16.394, 8.009),
    "mapping": (16.394, 8.009),
    "ekf-decoupled": (14.090, 5.899),
    "ekf-joint": (5.985, 2.756),
    "ekf-invariant": (5.893, 2.722),
    "smoother": (2.883, 1.554),
}
MARGIN = 1.10
BOUNDS = {n: (round(a * MARGIN + 0.005, 2), round(t * MARGIN + 0.005, 2)) for n, (a, t) in MEASURED.items()}


@pytest.fixture(scope="module")
def scores_0027(kitti_data_dir, regression_config):
    """{estimator: trajectory scores} of every estimator on 0027."""
    import time

    from vislam.eval.benchmark import load_bench_sequence, run_jobs
    from vislam.eval.runjob import JobResult, trajectory_scores

    path = kitti_data_dir / f"{DRIVE}.npz"
    if not path.is_file():
        skip_or_fail(f"{path} not found")
    bs = load_bench_sequence(path)
    if bs.gt is None:
        skip_or_fail(f"no ground truth for {path} (expected {path.parent}/groundtruth/{DRIVE}.txt)")
    names = {n: run_name(n) for n in MEASURED}
    t0 = time.perf_counter()
    outcomes = run_jobs({bs.name: bs.sequence}, list(dict.fromkeys(names.values())), regression_config,
                        jobs=2, show_progress=False)
    print(f"\n{DRIVE}: {len(set(names.values()))} estimators in {time.perf_counter() - t0:.1f} s")
    out = {}
    for name, run in names.items():
        res = outcomes[(bs.name, run)]
        out[name] = trajectory_scores(res.estimate, bs.gt) if isinstance(res, JobResult) else res.error
    return out


@pytest.mark.parametrize("name", list(MEASURED))
def test_accuracy_within_bounds(scores_0027, name):
    scores = scores_0027[name]
    assert isinstance(scores, dict), f"{name} failed on {DRIVE}: {scores}"
    ate, t_rel = scores["ate_aligned_m"], scores["rpe_trans_pct"]
    ate_bound, t_bound = BOUNDS[name]
    line = (f"{name} on {DRIVE}: aligned ATE {ate:.3f} m (bound {ate_bound} m), "
            f"KITTI t_rel {t_rel:.3f} % (bound {t_bound} %)")
    print(line)
    assert ate is not None and ate <= ate_bound, f"{line}: ATE {ate - ate_bound:+.3f} m over the bound"
    assert t_rel is not None and t_rel <= t_bound, f"{line}: t_rel {t_rel - t_bound:+.3f} % over the bound"
