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

The drives that fail on the code this file was last measured against are marked
``xfail(strict=True)`` with what they showed then: once the identification (issue 34, items
1-4) makes one pass, its mark must go (strict: an unexpected pass fails). Measured last on
branch h-undet (issue 34 items 1 and 3, undetermined noise levels conservative): drives 4, 7,
8, 16 and 27 pass now (their NEES was overconfident), drives 1, 9, 17 and 22 fail now (clean
velocities: the conservative slow-error prior lets vision carry the forward motion, and vision
is the worse source there; docs/findings.md, "Undetermined means conservative"). Since the
filters' and the smoother's residual gyro bias starts from the identified bias's own sigma
(ekf.model.model_config, issue 34 item 3; main, 2026-11-28), drive 20 passes too (its EKFs were
1.13x dead reckoning's ATE, now 0.82x) and drive 28's ratio fell from 1.34x to 1.24x. The 31
drives run in two worker processes, models identified into an empty cache: about 280 s of CPU
in all (4-24 s a drive, dense drives the dearest), so about 3 minutes on 2 free cores
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
#: Drives that fail on the code of this file's commit, and what they showed (issue 34; branch
#: h-undet, benchmarks/campaign.py --drives 30).
FAILING_TODAY: dict[int, str] = {
    1: "13.4 obs/frame, clean: ATE ekf-joint 2.65x, ekf-invariant 2.66x, smoother 1.97x dead"
        " reckoning's; pose NEES dead reckoning 0.743, smoother 8.17",
    9: "37.7 obs/frame, clean: ATE ekf-joint 1.28x, ekf-invariant 1.26x, smoother 1.22x dead"
        " reckoning's",
    10: "2.3 obs/frame, clean: ATE ekf-joint 2.15x, ekf-invariant 2.14x, smoother 2.09x dead "
        "reckoning's",
    11: "7.3 obs/frame, clean: ATE ekf-joint 1.23x, ekf-invariant 1.23x dead reckoning's",
    12: "0.6 obs/frame, noisy: pose NEES dead reckoning 11.7, smoother 23.6",
    13: "2.1 obs/frame, noisy: ATE ekf-joint 1.14x, ekf-invariant 1.15x, smoother 1.26x dead "
        "reckoning's",
    14: "8.2 obs/frame, clean: ATE ekf-joint 2.02x, ekf-invariant 2.00x, smoother 1.70x dead "
        "reckoning's; pose NEES dead reckoning 0.829, smoother 4.62",
    15: "2.0 obs/frame, clean: ATE ekf-joint 1.69x, ekf-invariant 1.70x, smoother 1.70x dead "
        "reckoning's; pose NEES dead reckoning 1.03, smoother 2.41",
    17: "16.1 obs/frame, clean: ATE ekf-joint 1.40x, ekf-invariant 1.40x, smoother 1.29x dead"
        " reckoning's; pose NEES dead reckoning 0.839, smoother 4.77",
    22: "30.3 obs/frame, clean: ATE ekf-joint 4.62x, ekf-invariant 4.61x, smoother 2.71x dead"
        " reckoning's",
    24: "1.6 obs/frame, noisy: ATE ekf-joint 1.21x, ekf-invariant 1.21x, smoother 1.36x dead "
        "reckoning's; pose NEES dead reckoning 6.12, smoother 26.7",
    25: "2.4 obs/frame, clean: ATE ekf-joint 2.31x, ekf-invariant 2.31x, smoother 2.08x dead "
        "reckoning's",
    28: "2.1 obs/frame, clean: ATE ekf-joint 1.24x, ekf-invariant 1.24x, smoother 1.13x dead "
        "reckoning's",
}
#: The measured failure, as it shows on the code of this file's commit.
REPRODUCTION_TODAY = ("2.3 obs/frame: ATE smoother 1.14x dead reckoning's (0.463 m against 0.405 "
                      "m); pose NEES now inside the band (dead reckoning 2.23, smoother 13.6; it "
                      "was 3.95e+04 and 3.98e+04 under the white 0.003 m/s model)")
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
