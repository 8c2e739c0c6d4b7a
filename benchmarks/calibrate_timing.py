"""How long `vislam calibrate` (model identification, issue 12) takes on each drive given.

    .venv/bin/python benchmarks/calibrate_timing.py ../shared/data/kitti-pr3/0034.npz [...]

Prints, per drive: frames, seconds of identification (EM around the smoother with the
extrinsic, the pairing comparison and the bias test; loading excluded) in wall-clock and CPU
time (the process's: what to compare on a shared machine), E-steps, and the
identified linear velocity sigmas and lever arm. The issue's budget: 0034 in at most 60 s.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np


def main(paths: list[str]) -> int:
    from vislam.ekf.config import FilterConfig
    from vislam.eval.loader import load_sequence
    from vislam.graph.extrinsic import lever_arm
    from vislam.graph.identification import identify_model
    from vislam.graph.settings import SmootherSettings

    for path in paths:
        seq = load_sequence(path, clean=False)
        t0, c0 = time.perf_counter(), time.process_time()
        fit = identify_model(seq, FilterConfig(), SmootherSettings(compute_marginals=False))
        seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
        print(f"{path}: {seq.n_frames} frames, {seconds:.1f} s ({cpu:.1f} s of CPU: on a busy "
              f"machine the figure to compare), {fit.iterations} E-steps, "
              f"velocity sigma {np.round(fit.velocity_sigma, 3)}, pairing {fit.pairing}, "
              f"lever arm {np.round(lever_arm(fit.cam_T_imu), 3)}", flush=True)
    return 0


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("paths", nargs="*", metavar="FILE.npz",
                        default=["../shared/data/kitti-pr3/0034.npz"],
                        help="drives to identify (default: the shared 0034)")
    sys.exit(main(parser.parse_args().paths))
