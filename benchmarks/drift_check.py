"""Does the model explain the drive? The drift check (graph.drift_check) on drives and models.

    .venv/bin/python benchmarks/drift_check.py [DRIVE ...] [--model identified|true]
                                              [--stretch 10] [--frames N]

``DRIVE`` is a path to a drive (.npz), ``default`` (the simulator's default drive; ``default:SEED``
the same with another seed) or
``campaign:SEED`` (a drive of the campaign, eval.campaign.draw_drive); default: ``default
campaign:0 campaign:1``. ``--model identified`` (default) uses the model `vislam bench`
identifies (cached in VISLAM_CACHE_DIR), ``true`` a simulated drive's true model
(eval.campaign.drive_true_model; eval.simulate.true_model for ``default``). Per drive it
prints the check's lines and, where the drive has ground truth, the smoother's aligned ATE and
mean pose NEES beside dead reckoning's (computed here from the same solution), so that the
check's verdict can be read against the truth.
"""

from __future__ import annotations

import argparse
import time


def _drive(name: str, frames: int | None):
    """``(BenchSequence, true model or None)``."""
    from vislam.eval.drives import bench_sequence

    if name == "default" or name.startswith("default:"):
        from vislam.eval.simulate import default_simulation, true_model

        result = default_simulation(int(name.split(":", 1)[1]) if ":" in name else 0)
        return bench_sequence(result), true_model(result)
    if name.startswith("campaign:"):
        from vislam.eval.campaign import draw_drive, drive_true_model

        drive = draw_drive(int(name.split(":", 1)[1]), *([frames] if frames else []))
        result = drive.simulate()
        return bench_sequence(result), drive_true_model(drive, result)
    bs = bench_sequence(name)
    if frames:
        import dataclasses

        bs = dataclasses.replace(bs, sequence=bs.sequence.window(0, min(frames, bs.sequence.n_frames)))
    return bs, None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("drives", nargs="*", default=["default", "campaign:0", "campaign:1"])
    parser.add_argument("--model", choices=("identified", "true"), default="identified")
    parser.add_argument("--stretch", type=float, default=10.0)
    parser.add_argument("--frames", type=int, default=None)
    args = parser.parse_args(argv)
    from vislam.ekf.config import FilterConfig
    from vislam.eval.drives import apply_model_to
    from vislam.eval.model_cache import identified_model
    from vislam.graph.drift_check import drift_check
    from vislam.graph.settings import SmootherSettings
    from vislam.graph.smoother import solve_smoother

    for name in args.drives:
        t0 = time.perf_counter()
        bs, truth_model = _drive(name, args.frames)
        if args.model == "true":
            if truth_model is None:
                print(f"{name}: no true model (not a simulated drive); skipped")
                continue
            model = truth_model
        else:
            model = identified_model(bs.sequence).model
        (b,) = apply_model_to([bs], model, FilterConfig(), args.model)
        solution = solve_smoother(b.sequence, b.config, SmootherSettings())
        check = drift_check(solution, b.config, stretch_s=args.stretch)
        print(f"{name} ({args.model} model, {b.sequence.n_frames} frames, "
              f"{time.perf_counter() - t0:.1f} s):")
        for line in check.lines():
            print("  " + line)
        worst = sorted(check.stretches, key=lambda s: -s.ratio)[:3]
        print("  worst stretches: " + "; ".join(
            f"{s.start_s:.0f}-{s.end_s:.0f} s chi2/dof {s.ratio:.1f} ({s.dof} dof)" for s in worst))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
