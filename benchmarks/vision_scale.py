"""What vision says about a drive's speed scale where the speed is exact (issue 34;
docs/findings.md, "A slow speed error the drive cannot determine").

    .venv/bin/python benchmarks/vision_scale.py [--drives 40] [--frames 250]

Each campaign drive without a speed-scale fault (eval.campaign.draw_drive) runs through
ekf-joint under its true model (eval.campaign.drive_true_model) with a constant speed-scale
state (sigma 0.5 %, no walk). The true scale is 0, so the final estimate over its sigma, ``z``,
is standard normal if vision's scale is unbiased and the filter consistent. Prints one row per
drive and, per velocity edition, the mean and standard deviation of ``z`` and the mean of
``z^2``.
"""

from __future__ import annotations

import argparse

import numpy as np


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--drives", type=int, default=40)
    parser.add_argument("--frames", type=int, default=250)
    args = parser.parse_args(argv)
    from vislam.ekf.config import FilterConfig
    from vislam.ekf.driver import run_filter
    from vislam.ekf.joint import JointEKF
    from vislam.ekf.model import model_config, model_sequence
    from vislam.eval.campaign import draw_drive, drive_true_model

    z: dict[str, list[float]] = {}
    for seed in range(args.drives):
        drive = draw_drive(seed, args.frames)
        if drive.speed_scale is not None:
            continue
        result = drive.simulate()
        model = drive_true_model(drive, result).replace(speed_scale_sigma=0.005, speed_scale_walk=0.0)
        est = run_filter(JointEKF(), model_sequence(result.sequence, model),
                         model_config(FilterConfig(), model))
        s, sd = est.info["speed_scale"], est.info["speed_scale_sigma_final"]
        z.setdefault(drive.edition, []).append(s / sd)
        print(f"drive {seed:3d} {drive.edition:5s} s {100 * s:+.2f} % +- {100 * sd:.2f} %  z {s / sd:+.2f}",
              flush=True)
    for edition, values in z.items():
        v = np.array(values)
        print(f"{edition}: {v.size} drives, mean z {v.mean():+.2f} (standard error "
              f"{v.std(ddof=1) / np.sqrt(v.size):.2f}), sd z {v.std(ddof=1):.2f}, mean z^2 "
              f"{np.mean(v * v):.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
