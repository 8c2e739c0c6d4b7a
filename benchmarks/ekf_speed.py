"""Frames per second of each EKF estimator on one drive, BLAS pinned to one thread.

    .venv/bin/python benchmarks/ekf_speed.py [/path/to/0034.npz] [--modes a,b] [--repeat 1]
        [--set key=value ...]

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
from vislam.eval.loader import load_sequence  # noqa: E402


def main(argv=None) -> int:
    from vislam.ekf.estimators import ESTIMATORS

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("path", nargs="?", type=Path, default=drive_path("0034"))
    ap.add_argument("--modes", default=",".join(ESTIMATORS))
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--set", nargs="*", default=[])
    args = ap.parse_args(argv)
    seq = load_sequence(args.path)
    config = FilterConfig().replace(**parse_settings(args.set))
    print(f"{args.path.name}: {seq.n_frames} frames, {seq.n_tracks} tracks, "
          f"blas_threads={config.blas_threads}")
    print(f"load average {' '.join(f'{x:.2f}' for x in os.getloadavg())} on {os.cpu_count()} cores")
    for mode in args.modes.split(","):
        best_fps, best_wall, best_cpu = 0.0, np.inf, np.inf
        for _ in range(args.repeat):
            t0, c0 = time.perf_counter(), time.process_time()
            est = ESTIMATORS[mode](seq, config)
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
            fps = est.n_frames / est.runtime_s
            best_fps, best_wall, best_cpu = max(best_fps, fps), min(best_wall, wall), min(best_cpu, cpu)
        extra = f"  max state {est.info['max_state_dim']}" if "max_state_dim" in est.info else ""
        print(
            f"{mode:16s} {best_fps:8.1f} frames/s (filter steps, wall)  "
            f"{est.n_frames / best_cpu:8.1f} frames/s (CPU time, whole call)   "
            f"wall {best_wall:6.2f} s{extra}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
