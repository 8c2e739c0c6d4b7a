"""Generalisation on drives nobody tuned for (issue 34, item 5): a fixed set of the campaign's
random drives (eval/campaign.py: 1-60 tracks a frame, slow speed-scale errors, correlated
velocity and pixel errors, a wrong extrinsic in the file, a lens term, a gyro bias, either
edition's velocity noise), each run as `vislam bench` with no flags runs it, and each held to

* every SLAM estimator's aligned ATE at most 1.1x dead reckoning's, and
* dead reckoning's and the smoother's mean pose NEES inside the band bench reports,

plus the simulated drive of the measured failure (:func:`eval.campaign.sparse_slow_speed_drive`:
about 2-3 observations a frame and a speed off by up to 1.6 % over 15 s stretches, like the
2019-edition drive of KITTI 06 on which the identified model made every estimator
overconfident).

The drives that fail on the code this file was written against are marked
``xfail(strict=True)`` with what they showed then: once the identification (issue 34, items
1-4) makes one pass, its mark must go (strict: an unexpected pass fails). The 31 drives run in two
worker processes, models identified into an empty cache: about 215 s of CPU in all (1.5-17 s
a drive, dense drives the dearest), so about 2 minutes on 2 free cores
(``benchmarks/campaign.py --drives 30`` prints the same table).
"""

from __future__ import annotations

import json
import os
from concurrent.futures import ProcessPoolExecutor

import pytest

from vislam.eval.campaign import draw_drive, evaluate_drive, sparse_slow_speed_drive

pytestmark = pytest.mark.regression

#: The fixed set: the campaign's first drives (benchmarks/campaign.py --first-seed 0).
FIXED_SEEDS = tuple(range(30))
#: Frames of each drive of the fixed set (the campaign's default).
FRAMES = 250
#: Drives that fail on the code of this file's commit, and what they showed (issue 34).
FAILING_TODAY: dict[int, str] = {
    4: "9.8 obs/frame, noisy: pose NEES dead reckoning 29.5, smoother 21.3",
    7: "7.5 obs/frame, noisy: pose NEES dead reckoning 21.8, smoother 24.8",
    8: "2.2 obs/frame, noisy: pose NEES dead reckoning 39.1, smoother 68.4",
    10: "2.3 obs/frame, clean: ATE ekf-joint 1.27x, ekf-invariant 1.29x dead reckoning's; "
        "pose NEES dead reckoning 29.7, smoother 53.1",
    11: "7.3 obs/frame, clean: pose NEES dead reckoning 92.3, smoother 92.8",
    12: "0.6 obs/frame, noisy: pose NEES dead reckoning 179, smoother 279",
    13: "2.1 obs/frame, noisy: pose NEES dead reckoning 50.1, smoother 70.5",
    14: "8.2 obs/frame, clean: ATE ekf-joint 1.27x, ekf-invariant 1.27x, smoother 1.18x dead "
        "reckoning's",
    15: "2.0 obs/frame, clean: pose NEES dead reckoning 73.8, smoother 78.9",
    16: "57.0 obs/frame, clean: pose NEES dead reckoning 25.3, smoother 36.2",
    20: "1.2 obs/frame, clean: pose NEES dead reckoning 8.19e+03, smoother 7.15e+03",
    24: "1.6 obs/frame, noisy: ATE ekf-joint 1.33x, ekf-invariant 1.33x, smoother 1.40x dead "
        "reckoning's; pose NEES dead reckoning 127, smoother 550",
    25: "2.4 obs/frame, clean: pose NEES dead reckoning 13.7, smoother 14.6",
    27: "57.8 obs/frame, noisy: pose NEES dead reckoning 16.7, smoother 5.86",
    28: "2.1 obs/frame, clean: ATE ekf-joint 1.34x, ekf-invariant 1.34x dead reckoning's; "
        "pose NEES dead reckoning 1.11e+03, smoother 1.54e+03",
}
#: The measured failure, as it shows on the code of this file's commit.
REPRODUCTION_TODAY = ("2.3 obs/frame: pose NEES dead reckoning 3.95e+04, smoother 3.98e+04 (the "
                      "identified velocity sigma 0.003 m/s, white); ATE 1.0x dead reckoning's")
REPRODUCTION = "sparse-slow-speed"
WORKERS = 2


def _evaluate(drive, cache: str):
    os.environ["VISLAM_CACHE_DIR"] = cache  # a throwaway worker: the models go to this run's cache
    return evaluate_drive(drive)


@pytest.fixture(scope="module")
def outcomes(tmp_path_factory) -> dict:
    """Every drive of this file, run once per session: key -> eval.campaign.DriveOutcome."""
    cache = str(tmp_path_factory.mktemp("models"))
    drives = {REPRODUCTION: sparse_slow_speed_drive()}  # the longest first
    drives.update({seed: draw_drive(seed, FRAMES) for seed in FIXED_SEEDS})
    with ProcessPoolExecutor(max_workers=WORKERS) as pool:
        futures = {key: pool.submit(_evaluate, drive, cache) for key, drive in drives.items()}
        return {key: f.result() for key, f in futures.items()}


def _assert_meets_both(outcome) -> None:
    __tracebackhide__ = True
    if not outcome.ok:
        lines = [f"drive {outcome.drive.seed} ({outcome.drive.describe()}; "
                 f"{outcome.obs_per_frame:.1f} observations a frame):"]
        for a in outcome.assertions:
            lines.append(f"  {a.name}: {'passes' if a.ok else 'FAILS'}")
            lines += [f"    {x}" for x in a.detail]
        pytest.fail("\n".join(lines), pytrace=False)


def _param(seed: int):
    why = FAILING_TODAY.get(seed)
    if why is None:
        return pytest.param(seed, id=f"seed{seed}")
    return pytest.param(seed, id=f"seed{seed}",
                        marks=pytest.mark.xfail(strict=True, reason=f"issue 34: {why}"))


@pytest.mark.parametrize("seed", [_param(s) for s in FIXED_SEEDS])
def test_campaign_drive_meets_both_assertions(outcomes, seed):
    _assert_meets_both(outcomes[seed])


@pytest.mark.xfail(strict=True, reason=f"issue 34: the measured failure: {REPRODUCTION_TODAY}")
def test_sparse_drive_with_slow_speed_errors_meets_both_assertions(outcomes):
    """The drive of the measured failure: sparse tracks and a slow speed-scale error, which
    the identification must not turn into a confident, wrong model."""
    _assert_meets_both(outcomes[REPRODUCTION])


#: A drive of the fixed set (sparse, so cheap) run through `vislam bench` itself.
BENCH_SEED = 8


def test_outcome_is_what_vislam_bench_reports(outcomes, tmp_path, monkeypatch):
    """evaluate_drive gives, to the bit, the figures `vislam bench DIR` with no flags writes
    into results.json for the same drive."""
    from vislam.eval.campaign import ESTIMATORS
    from vislam.eval.cli import main
    from vislam.eval.simulate import write_simulation

    drive = draw_drive(BENCH_SEED, FRAMES)
    write_simulation(drive.simulate(), tmp_path / "data", drive.sim.name)
    monkeypatch.setenv("VISLAM_CACHE_DIR", str(tmp_path / "models"))
    assert main(["bench", str(tmp_path / "data"), "--out", str(tmp_path / "out"), "-q",
                 "-j", "1", "-e", ",".join(ESTIMATORS)]) == 0
    results = json.loads((tmp_path / "out" / "results.json").read_text())
    (sequence,) = results["sequences"]
    rows = {r["name"]: r for r in sequence["estimators"]}
    figures = outcomes[BENCH_SEED].figures
    for name in ESTIMATORS:
        got = figures[name]
        assert (got.ate_aligned_m, got.t_rel_pct, got.nees_pose_mean) == (
            rows[name]["ate_aligned_m"], rows[name]["rpe_trans_pct"],
            rows[name]["nees_pose_mean"]), name
