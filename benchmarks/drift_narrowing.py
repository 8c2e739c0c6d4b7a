"""Where the drift check says the model claims too little for dead reckoning: narrowing the
undetermined slow levels to the upper end of what the stretches allow (issue 34, experiment).

    .venv/bin/python benchmarks/drift_narrowing.py [--seeds 1,9,14,22,28] [--frames 250]
                                                   [--quantile 0.05] [--cache DIR]

For each campaign drive: the identified model's drift check (graph.drift_check); where its
statistic lies below the ``quantile`` of chi-square (the model's dead reckoning wider than the
drive's stretches allow), the undetermined long-run velocity and gyro levels are scaled down by
one factor ``f`` (never below the pairing's floor), found by bisection on ``log f`` so that the
statistic reaches that quantile: the widest slow levels the stretches allow at that level.
Prints each estimator's aligned ATE over dead reckoning's and its mean pose NEES under the
identified and the narrowed model.
"""

from __future__ import annotations

import argparse
import os
import tempfile


def narrowed(model, f: float):
    """``model`` with its undetermined long-run levels' variance ratios times ``f`` (>= floor)."""
    from vislam.ekf.model import interval_sigma_factor

    floor = 1.0 / interval_sigma_factor(model.velocity_pairing) ** 2
    changes = {}
    for kind in ("velocity", "gyro"):
        times = getattr(model, f"{kind}_correlation_time")
        if times is None:
            continue
        changes[f"{kind}_correlation_time"] = tuple(
            max(floor, t * f) if f"{kind}_correlation_time_{a}" in model.noise_undetermined else t
            for t, a in zip(times, "xyz"))
    return model.replace(**changes)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", default="1,9,14,22,28")
    parser.add_argument("--frames", type=int, default=250)
    parser.add_argument("--quantile", type=float, default=0.05)
    parser.add_argument("--cache", default=None)
    args = parser.parse_args(argv)
    tmp = None
    if args.cache is None:
        tmp = tempfile.TemporaryDirectory(prefix="vislam-narrow-")
        os.environ["VISLAM_CACHE_DIR"] = tmp.name
    else:
        os.environ["VISLAM_CACHE_DIR"] = args.cache
    import math

    from vislam.ekf import chi_square as chi2
    from vislam.ekf.config import FilterConfig
    from vislam.eval.campaign import BASELINE, ESTIMATORS, draw_drive
    from vislam.eval.drives import apply_model_to, bench_sequence
    from vislam.eval.model_cache import identified_model
    from vislam.eval.simulate import write_simulation
    from vislam.eval.testing import run_drive
    from vislam.graph.drift_check import drift_widening
    from vislam.graph.settings import SmootherSettings

    for seed in [int(s) for s in args.seeds.split(",")]:
        drive = draw_drive(seed, args.frames)
        with tempfile.TemporaryDirectory() as folder:
            bs = bench_sequence(write_simulation(drive.simulate(), folder, drive.sim.name)["data"])
            model = identified_model(bs.sequence).model
            seq = bs.sequence

            def statistic(m):
                check, _ = drift_widening(seq, FilterConfig(), m, SmootherSettings())
                return check

            check = statistic(model)
            target = float(chi2.ppf(args.quantile, check.dof)) if check.dof else 0.0
            models = {"identified": model}
            line = f"drive {seed} ({drive.describe()}): chi2 {check.chi2:.2f} on {check.dof} dof"
            if check.dof and check.chi2 < target:
                lo, hi = math.log(1e-3), 0.0  # stat(lo) >= target > stat(hi)
                if statistic(narrowed(model, math.exp(lo))).chi2 < target:
                    f = math.exp(lo)
                else:
                    for _ in range(7):
                        mid = 0.5 * (lo + hi)
                        if statistic(narrowed(model, math.exp(mid))).chi2 >= target:
                            lo = mid
                        else:
                            hi = mid
                    f = math.exp(lo)
                models["narrowed"] = narrowed(model, f)
                line += f" < {target:.2f}: slow levels x{f:.3g}"
            print(line, flush=True)
            for name, m in models.items():
                (b,) = apply_model_to([bs], m, FilterConfig(), "config")
                study = run_drive(list(ESTIMATORS), b)
                base = study.scores[BASELINE]["ate_aligned_m"]
                cells = [f"{est} {study.scores[est]['ate_aligned_m'] / base:.2f}x/"
                         f"{study.scores[est]['nees_pose_mean']:.1f}"
                         for est in ESTIMATORS if est in study.scores and est != BASELINE]
                print(f"  {name:10s} dead reckoning {base:.3f} m/"
                      f"{study.scores[BASELINE]['nees_pose_mean']:.2f}; " + ", ".join(cells), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
