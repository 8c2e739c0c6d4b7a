"""Time the GTSAM smoother's stages on data files and score it where ground truth exists.

    .venv/bin/python benchmarks/smoother_timing.py FILE.npz [FILE.npz ...] [--init ekf|dead-reckoning|isam2] [--isam2]
        [--pairing mean|next|current] [--gyro-bias alternate|joint|off]

Prints, per file: the time split (build, initialise, optimise, marginals), LM iterations, the
process CPU time and load average (wall times on a shared 2-core machine depend on the load), and
when ``groundtruth/NAME.txt`` lies beside the file, raw and aligned ATE and KITTI drift. With
``--init ekf`` (the default) the EKF runs first and its time is printed apart: vislam bench
passes the EKF's estimate to the smoother in the same way.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from vislam.ekf.config import FilterConfig
from vislam.eval.groundtruth import find_ground_truth
from vislam.eval.loader import load_sequence


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("files", nargs="+", type=Path)
    parser.add_argument("--init", default="ekf", choices=("ekf", "dead-reckoning", "isam2"))
    parser.add_argument("--isam2", action="store_true", help="time the incremental smoother instead")
    parser.add_argument("--no-clean", action="store_true", help="skip track cleaning")
    parser.add_argument("--pairing", default="mean", choices=("current", "next", "mean"),
                        help="which velocity sample covers [k, k+1]")
    parser.add_argument("--gyro-bias", default="alternate", choices=("alternate", "joint", "off"))
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                        help="a SmootherSettings or FilterConfig field (repeatable), e.g. rejection_rounds=2")
    args = parser.parse_args()
    from vislam.graph.settings import SmootherSettings

    changes: dict[str, dict] = {"settings": {"gyro_bias": args.gyro_bias},
                                "config": {"clean_tracks": not args.no_clean, "velocity_pairing": args.pairing}}
    for item in args.set:
        name, _, text = item.partition("=")
        value = type(getattr(SmootherSettings(), name, getattr(FilterConfig(), name, 0.0)))(text)
        changes["settings" if hasattr(SmootherSettings(), name) else "config"][name] = value
    config = FilterConfig(**changes["config"])
    settings = SmootherSettings(**changes["settings"])
    if args.set:
        print(f"settings changed: {args.set}")
    print(f"load average before: {' '.join(f'{x:.2f}' for x in os.getloadavg())} on {os.cpu_count()} cores")
    from vislam.eval.metrics import trajectory_metrics
    from vislam.graph.isam2 import run_isam2
    from vislam.graph.smoother import run_smoother

    for path in args.files:
        seq = load_sequence(path)
        initial = None
        if args.init == "ekf" and not args.isam2:  # as bench does: the EKF's estimate passed in
            start = time.perf_counter()
            from vislam.ekf.estimators import ESTIMATORS
            from vislam.graph.smoother import EKF_INITIALISERS

            initial = ESTIMATORS[EKF_INITIALISERS[0]](seq, config, None)
            print(f"{path.name}: {initial.estimator} (the initial trajectory, timed apart as in "
                  f"vislam bench) {time.perf_counter() - start:.1f} s")
        start, cpu = time.perf_counter(), time.process_time()
        est = run_isam2(seq, config, settings=settings) if args.isam2 else run_smoother(
            seq, config, init=args.init, initial=initial, settings=settings)
        wall, cpu = time.perf_counter() - start, time.process_time() - cpu
        t = est.info["timing"]
        print(f"{path.name} {est.estimator} init={est.info.get('init', '-')} "
              f"cleaned={est.info['cleaning'].get('cleaned')} frames={est.n_frames} "
              f"landmarks={est.info['n_landmarks']} factors={est.info['n_stereo_factors']}")
        print(f"  time: total {wall:.1f} s = build {t['build_s']:.1f} + initialise {t['initialise_s']:.1f} "
              f"+ optimise {t['optimise_s']:.1f} + marginals {t['marginals_s']:.1f} s; "
              f"LM iterations {est.info.get('iterations_per_round', '-')}, "
              f"outliers removed {est.info.get('n_outliers_removed', '-')}")
        bias = est.info.get("gyro_bias")
        print(f"  process CPU time {cpu:.1f} s; load average now "
              f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}; gyro bias "
              f"{'-' if bias is None else np.round(bias, 4).tolist()} rad/s; pairing {args.pairing}")
        gt = find_ground_truth(path)
        if gt is not None:
            m = trajectory_metrics(est.poses[gt.frames], gt.poses)
            print(f"  vs ground truth ({gt.frames.size} frames): ATE raw {m['ate_rmse_m']:.2f} m, "
                  f"aligned (SE3) {m['ate_se3_rmse_m']:.2f} m, KITTI t_rel {m['kitti_t_rel_pct']:.2f} %, "
                  f"r_rel {m['kitti_r_rel_deg_per_100m']:.3f} deg/100m")

if __name__ == "__main__":
    main()
