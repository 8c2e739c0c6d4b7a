"""Check ekf-invariant on the shared drives: frames/s on 0034 and ATE on 0027 (raw and SE(3)-aligned).

Usage: .venv/bin/python benchmarks/invariant_check.py [--data DIR] [--variants]
Prints one line per run. ``--variants`` also runs the gyro-bias state and each velocity pairing.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from ekf.config import FilterConfig
from ekf.invariant import run_invariant


def load(path: Path):
    from eval.loader import load_sequence

    return load_sequence(path)


def ate(est, data_dir: Path, seq):
    from eval.groundtruth import find_ground_truth
    from eval.metrics import ate_rmse

    gt = find_ground_truth(data_dir / "0027.npz")
    est_p = est.poses[gt.frames]
    return ate_rmse(est_p, gt.poses), ate_rmse(est_p, gt.poses, align="se3")


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default=os.environ.get("VISLAM_DATA", "/work/shared/data/kitti-pr3"))
    ap.add_argument("--variants", action="store_true")
    args = ap.parse_args()
    data = Path(args.data)

    seq34 = load(data / "0034.npz")
    t0, c0 = time.perf_counter(), time.process_time()
    est = run_invariant(seq34, FilterConfig())
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    print(
        f"0034 defaults: {seq34.n_frames / wall:.0f} frames/s wall, "
        f"{seq34.n_frames / cpu:.0f} frames/s of process CPU time "
        f"({seq34.n_frames / est.runtime_s:.0f} frames/s in the filter steps), "
        f"{int(est.n_updates.sum())} updates, {int(est.n_rejected.sum())} rejected, "
        f"{int(est.has_landmark.sum())} landmarks"
    )

    seq27 = load(data / "0027.npz")
    configs = {"defaults": FilterConfig()}
    if args.variants:
        configs["gyro_bias"] = FilterConfig(gyro_bias=True)
        for pairing in ("current", "next"):
            configs[f"pairing={pairing}"] = FilterConfig(velocity_pairing=pairing)
        configs["no cleaning"] = FilterConfig(clean_tracks=False)
    for name, cfg in configs.items():
        t0 = time.perf_counter()
        est = run_invariant(seq27, cfg)
        wall = time.perf_counter() - t0
        raw, aligned = ate(est, data, seq27)
        extra = ""
        if cfg.gyro_bias:
            extra = f", bias {np.round(est.info['gyro_bias'], 4).tolist()}"
        print(
            f"0027 {name}: ATE raw {raw:.2f} m, aligned {aligned:.2f} m, "
            f"{seq27.n_frames / wall:.0f} frames/s{extra}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
