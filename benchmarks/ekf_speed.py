"""Frames per second of each EKF estimator on one drive, BLAS pinned to one thread.

    .venv/bin/python benchmarks/ekf_speed.py [/path/to/0034.npz] [--modes a,b] [--repeat 1]
        [--set key=value ...]

A raw-IMU drive (vislam's file form with ``imu_time``: ``vislam convert``) runs the raw-IMU
filters (``ekf-imu``, ``ekf-imu-invariant``: the ``ekf-`` names of the
``vislam.inertial_estimators`` group) and prints the IMU samples per second beside the frames.

Reports the filter's own per-step time (Estimate.step_time_s, excluding loading and cleaning)
as frames/s, the wall time of the whole call, and frames/s from the process CPU time of the
whole call (cleaning included): with BLAS on one thread that is the single-core throughput,
which does not drop when other processes share the cores (the wall-clock figures do; the
load average is printed).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from ekf_accuracy import parse_settings  # noqa: E402

from vislam.ekf.config import FilterConfig  # noqa: E402
from vislam.eval.datasets import drive_path  # noqa: E402
from vislam.eval.drives import load_bench_sequence  # noqa: E402
from vislam.eval.registry import INERTIAL_ESTIMATOR_NAMES, drive_kind, get_estimator  # noqa: E402


def main(argv=None) -> int:
    from vislam.ekf.estimators import ESTIMATORS

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("path", nargs="?", type=Path, default=drive_path("0034"))
    ap.add_argument("--modes", default=None, help="comma-separated estimators (default: the "
                    "drive kind's EKFs)")
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--set", nargs="*", default=[])
    args = ap.parse_args(argv)
    seq = load_bench_sequence(args.path).sequence
    raw_imu = drive_kind(seq) == "raw-imu"
    default = [n for n in INERTIAL_ESTIMATOR_NAMES if n.startswith("ekf-")] if raw_imu else ESTIMATORS
    modes = args.modes.split(",") if args.modes else list(default)
    config = FilterConfig().replace(**parse_settings(args.set))
    samples = f", {seq.imu.time.size} IMU samples" if raw_imu else ""
    print(f"{args.path.name}: {seq.n_frames} frames, {seq.n_tracks} tracks{samples}, "
          f"blas_threads={config.blas_threads}")
    print(f"load average {' '.join(f'{x:.2f}' for x in os.getloadavg())} on {os.cpu_count()} cores")
    for mode in modes:
        best_fps, best_wall, best_cpu = 0.0, np.inf, np.inf
        for _ in range(args.repeat):
            t0, c0 = time.perf_counter(), time.process_time()
            est = get_estimator(mode)(seq, config)
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
            fps = est.n_frames / est.runtime_s
            best_fps, best_wall, best_cpu = max(best_fps, fps), min(best_wall, wall), min(best_cpu, cpu)
        extra = f"  max state {est.info['max_state_dim']}" if "max_state_dim" in est.info else ""
        if raw_imu:
            extra += f"  {seq.imu.time.size / best_cpu:9.0f} IMU samples/s (CPU)"
        print(
            f"{mode:16s} {best_fps:8.1f} frames/s (filter steps, wall)  "
            f"{est.n_frames / best_cpu:8.1f} frames/s (CPU time, whole call)   "
            f"wall {best_wall:6.2f} s{extra}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
