"""Raw and SE(3)-aligned ATE of the EKF estimators on a drive with ground truth (0027).

    .venv/bin/python benchmarks/ekf_accuracy.py [--data DIR] [--drive 0027]
        [--modes dead-reckoning,mapping,ekf-decoupled,ekf-joint] [--set key=value ...]

Ground truth is found beside the drive (``groundtruth/<drive>.txt``, eval.groundtruth); only
frames with ground truth are scored (eval.metrics.ate_rmse). Prints one line per mode.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from vislam.ekf.config import FilterConfig
from vislam.eval.datasets import data_dir, drive_path
from vislam.eval.groundtruth import find_ground_truth
from vislam.eval.loader import load_sequence
from vislam.eval.metrics import ate_rmse


def parse_settings(items: list[str]) -> dict:
    out = {}
    for item in items:
        key, _, value = item.partition("=")
        low = value.lower()
        if low in ("true", "false"):
            out[key] = low == "true"
        elif low == "none":
            out[key] = None
        else:
            try:
                out[key] = int(value)
            except ValueError:
                try:
                    out[key] = float(value)
                except ValueError:
                    out[key] = value
    return out


def main(argv=None) -> int:
    from vislam.ekf.estimators import ESTIMATORS

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=data_dir())
    ap.add_argument("--drive", default="0027")
    ap.add_argument("--modes", default=",".join(ESTIMATORS))
    ap.add_argument("--set", nargs="*", default=[], help="FilterConfig overrides key=value")
    args = ap.parse_args(argv)
    path = drive_path(args.drive, args.data)
    seq = load_sequence(path)
    gt = find_ground_truth(path)
    if gt is None:
        ap.error(f"no ground truth beside {path}")
    config = FilterConfig().replace(**parse_settings(args.set))
    print(f"drive {args.drive}: {gt.frames.size} frames scored; settings {parse_settings(args.set) or 'defaults'}")
    for mode in args.modes.split(","):
        t0 = time.perf_counter()
        est = ESTIMATORS[mode](seq, config)
        wall = time.perf_counter() - t0
        poses = est.poses[gt.frames]
        raw, al = ate_rmse(poses, gt.poses), ate_rmse(poses, gt.poses, align="se3")
        print(
            f"{mode:16s} ATE raw {raw:7.2f} m  aligned {al:7.2f} m  "
            f"landmarks {int(est.has_landmark.sum()):5d}  updates {int(est.n_updates.sum()):6d}  "
            f"rejected {int(est.n_rejected.sum()):6d}  wall {wall:6.1f} s"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
