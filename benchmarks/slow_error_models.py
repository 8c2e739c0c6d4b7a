"""How the campaign's drives fare under each way of modelling a slow velocity error that the
drive cannot determine (issue 34; docs/findings.md, "A slow speed error the drive cannot
determine").

    .venv/bin/python benchmarks/slow_error_models.py [--seeds 1,10,14,22,25] [--frames 250]
                                                     [--pixel-sigma PX] [--min-disparity PX]

For each campaign drive (eval.campaign.draw_drive), the estimators of the campaign run under:

* ``identified``: the model `vislam bench` identifies (an undetermined long-run velocity level
  takes the white-equivalent speed-scale prior, graph.parameter_uncertainty);
* ``id, slow white``: the same with every undetermined long-run velocity level white (what
  the identification did before issue 34's item 1: optimistic);
* ``id, scale state``: the same as the last, with the slow error carried as a speed-scale
  state instead (FilterConfig.speed_scale: 0.5 % over 20 s, graph.parameter_uncertainty's
  prior);
* ``true``: the drive's true model (eval.campaign.drive_true_model: with a speed-scale state
  where the drive carries the fault);
* ``true + scale``: the true model with the 0.5 %-over-20-s speed-scale state added.

Prints per drive and model each estimator's aligned ATE as a multiple of dead reckoning's and
its mean pose NEES, and ekf-joint's final speed scale (+- its sigma). ``--pixel-sigma`` makes
the drives again with that pixel noise (everything else as drawn); ``--min-disparity`` sets the
estimators' (FilterConfig.min_disparity).
"""

from __future__ import annotations

import argparse
import math
import os
import tempfile


def _models(drive, result, seq):
    from vislam.eval.campaign import drive_true_model
    from vislam.eval.model_cache import identified_model
    from vislam.graph.parameter_uncertainty import SPEED_SCALE_PRIOR, SPEED_SCALE_TIME_S

    identified = identified_model(seq).model
    scale = {"speed_scale_sigma": SPEED_SCALE_PRIOR,
             "speed_scale_walk": SPEED_SCALE_PRIOR / math.sqrt(SPEED_SCALE_TIME_S)}
    time = list(identified.velocity_correlation_time or (1.0, 1.0, 1.0))
    for i, axis in enumerate("xyz"):
        if f"velocity_correlation_time_{axis}" in identified.noise_undetermined:
            time[i] = 1.0
    white = identified.replace(velocity_correlation_time=None if time == [1.0] * 3 else tuple(time))
    true = drive_true_model(drive, result)
    return {"identified": identified, "id, slow white": white,
            "id, scale state": white.replace(**scale), "true": true,
            "true + scale": true if true.speed_scale_sigma is not None else true.replace(**scale)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", default="1,10,14,22,25")
    parser.add_argument("--frames", type=int, default=250)
    parser.add_argument("--pixel-sigma", type=float, default=None)
    parser.add_argument("--min-disparity", type=float, default=None)
    args = parser.parse_args(argv)
    seeds = [int(s) for s in args.seeds.split(",")]
    with tempfile.TemporaryDirectory(prefix="vislam-slow-") as cache:
        os.environ["VISLAM_CACHE_DIR"] = cache
        from vislam.ekf.config import FilterConfig
        from vislam.eval.campaign import BASELINE, ESTIMATORS, draw_drive
        from vislam.eval.drives import apply_model_to, bench_sequence
        from vislam.eval.simulate import write_simulation
        from vislam.eval.testing import run_drive

        print("per model: each estimator's aligned ATE / dead reckoning's (x) and mean pose "
              "NEES; s: ekf-joint's final speed scale +- sigma")
        import dataclasses

        settings = FilterConfig() if args.min_disparity is None else FilterConfig(
            min_disparity=args.min_disparity)
        for seed in seeds:
            drive = draw_drive(seed, args.frames)
            if args.pixel_sigma is not None:
                drive = dataclasses.replace(drive, sim=dataclasses.replace(
                    drive.sim, pixel_sigma=args.pixel_sigma))
            result = drive.simulate()
            with tempfile.TemporaryDirectory() as folder:
                bs = bench_sequence(write_simulation(result, folder, drive.sim.name)["data"])
                print(f"drive {seed}: {drive.describe()}", flush=True)
                for name, model in _models(drive, result, bs.sequence).items():
                    (b,) = apply_model_to([bs], model, settings, "config")
                    study = run_drive(list(ESTIMATORS), b)
                    base = study.scores[BASELINE]["ate_aligned_m"]
                    cells = []
                    for est in ESTIMATORS:
                        s = study.scores.get(est)
                        cells.append(f"{est} failed" if s is None else
                                     f"{est} {s['ate_aligned_m'] / base:.2f}x/"
                                     f"{s['nees_pose_mean']:.1f}")
                    info = study.estimates["ekf-joint"].info if "ekf-joint" in study.estimates else {}
                    scale = ("" if "speed_scale" not in info else
                             f"  s {info['speed_scale']:+.4f} +- {info['speed_scale_sigma_final']:.4f}")
                    print(f"  {name:16s} dead reckoning {base:.3f} m; " + ", ".join(cells[1:])
                          + scale, flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
