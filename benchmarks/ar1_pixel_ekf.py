"""ekf-joint under two readings of pixel errors that drift along a track, on simulated road
drives whose errors are AR(1) (issue 34; docs/findings.md, "Pixel errors as AR(1) in ekf-joint").

    .venv/bin/python benchmarks/ar1_pixel_ekf.py --a 0.9 --frames 300 --seeds 10

Each drive runs under its true model: ``long-run`` (every estimator's reading, independent rows
with the long-run sigma ``s sqrt(tau)``) and ``ar1`` (``pixel_reading = "ar1"``: the exact
differenced rows with a clone of the previous pose, ekf/joint.py). Prints each seed's aligned
ATE (m) and mean pose NEES, and their means. With ``--a 0`` both readings are the white filter,
the floor of its own consistency on these drives.
"""

from __future__ import annotations

import argparse

import numpy as np


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--a", type=float, default=0.9, help="AR(1) coefficient of the errors")
    parser.add_argument("--frames", type=int, default=300, help="frames per drive")
    parser.add_argument("--seeds", type=int, default=10, help="drives (seeds 0..N-1)")
    args = parser.parse_args(argv)

    from vislam.ekf.config import FilterConfig
    from vislam.ekf.joint import run_joint
    from vislam.ekf.model import apply_model
    from vislam.eval.consistency import pose_nees
    from vislam.eval.metrics import ate_rmse
    from vislam.eval.sim_config import SimConfig
    from vislam.eval.simulate import DEFAULT_SIM, simulate, true_model

    readings = ("long-run", "ar1")
    ate = {r: [] for r in readings}
    nees = {r: [] for r in readings}
    for seed in range(args.seeds):
        sim = simulate(SimConfig(**{**DEFAULT_SIM.__dict__, "seed": seed, "n_frames": args.frames,
                                    "pixel_correlation": args.a}))
        seq, config = apply_model(sim.sequence, FilterConfig(), true_model(sim))
        frames = np.arange(len(sim.poses))
        for r in readings:
            est = run_joint(seq, config.replace(pixel_reading=r))
            ate[r].append(ate_rmse(est.poses, sim.poses, align="se3"))
            nees[r].append(float(np.nanmean(pose_nees(est, frames, sim.poses))))
    print(f"a {args.a}, {args.frames} frames, seeds 0-{args.seeds - 1}: ekf-joint aligned ATE (m) "
          "/ mean pose NEES")
    for r in readings:
        print(f"{r:9s} ATE " + " ".join(f"{x:.3f}" for x in ate[r]) + f"  mean {np.mean(ate[r]):.4f}")
        print(f"{'':9s} NEES " + " ".join(f"{x:.2f}" for x in nees[r]) + f"  mean {np.mean(nees[r]):.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
