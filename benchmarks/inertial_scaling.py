"""Per-stage time and peak memory of the raw-IMU smoother on simulated room flights of growing
length (issue 37: a 5-minute flight in 60 s on one core).

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/inertial_scaling.py 0.5 1 2 [--set NAME=VALUE ...]

(``NAME=VALUE``: an :class:`graph.inertial_smoother.InertialSmootherSettings` field, e.g.
``--set init_keyframe_stride=1 init_return_gap=None batch_ordering='"COLAMD"'`` for the pipeline
as it was before 2026-12-02.)

Each length runs in a fresh process (so that the peak resident memory is its own) and prints one
row: simulated minutes, frames, tracks, observations used, CPU seconds of build, incremental
(iSAM2 initial values), batch LM and marginals, the peak resident memory after each stage (GB),
the batch's 4-dof aligned ATE (m) and its mean pose NEES in the estimate's gauge.
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def _peak_gb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2 ** 20


def _settings(pairs: list[str]):
    """InertialSmootherSettings with ``name=value`` overrides (value a Python literal)."""
    import ast

    from vislam.graph.inertial_smoother import InertialSmootherSettings

    return InertialSmootherSettings(**{k: ast.literal_eval(v) for k, v in (p.split("=", 1) for p in pairs)})


def run_one(minutes: float, pairs: list[str]) -> str:
    import numpy as np

    from vislam.eval.imu_sim import simulate_imu
    from vislam.eval.imu_sim_config import ImuSimConfig
    from vislam.eval.metrics import ate_rmse, nees, pose_errors
    from vislam.graph.inertial_init import in_estimate_gauge
    from vislam.graph.inertial_smoother import batch_solve, build_problem, initial_solve, to_result

    drive, sim = simulate_imu(ImuSimConfig(n_frames=int(round(minutes * 60 * 20)) + 1))
    cpu, peak = [], []
    t0 = time.process_time()
    problem = build_problem(drive, _settings(pairs))
    cpu.append(time.process_time() - t0)
    peak.append(_peak_gb())
    print(f"  stage {len(cpu)}: {cpu[-1]:.1f} s CPU, peak {peak[-1]:.2f} GB", file=sys.stderr, flush=True)
    t0 = time.process_time()
    inc = initial_solve(problem)
    cpu.append(time.process_time() - t0)
    peak.append(_peak_gb())
    print(f"  stage {len(cpu)}: {cpu[-1]:.1f} s CPU, peak {peak[-1]:.2f} GB", file=sys.stderr, flush=True)
    t0 = time.process_time()
    sol = batch_solve(problem, inc)
    cpu.append(time.process_time() - t0)
    peak.append(_peak_gb())
    print(f"  stage {len(cpu)}: {cpu[-1]:.1f} s CPU, peak {peak[-1]:.2f} GB", file=sys.stderr, flush=True)
    t0 = time.process_time()
    result = to_result(problem, sol)
    cpu.append(time.process_time() - t0)
    peak.append(_peak_gb())
    print(f"  stage {len(cpu)}: {cpu[-1]:.1f} s CPU, peak {peak[-1]:.2f} GB", file=sys.stderr, flush=True)
    est = result.estimate
    truth = sim.frame_poses
    ate = ate_rmse(est.poses, truth, "yaw")
    err = pose_errors(est.poses, in_estimate_gauge(truth, est.poses))
    n = float(np.nanmean(nees(err, est.pose_cov)))
    return (f"| {minutes:g} | {drive.n_frames} | {drive.n_tracks} | {result.info['n_observations_used']} | "
            + " | ".join(f"{c:.1f}" for c in cpu) + f" | {sum(cpu):.1f} | "
            + " / ".join(f"{p:.2f}" for p in peak) + f" | {ate:.4f} | {n:.2f} |")


def main() -> None:
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("minutes", nargs="+", type=float, help="simulated minutes of each flight")
    parser.add_argument("--set", nargs="*", default=[], metavar="NAME=VALUE",
                        help="InertialSmootherSettings fields (each value a Python literal)")
    parser.add_argument("--one", action="store_true", help=argparse.SUPPRESS)  # a child's row
    args = parser.parse_args()
    if args.one:
        print(run_one(args.minutes[0], args.set), flush=True)
        return
    print("| minutes | frames | tracks | observations | build s | incremental s | batch s | marginals s "
          "| total s | peak GB after each stage | ATE 4-dof m | pose NEES |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |", flush=True)
    for m in args.minutes:
        subprocess.run([sys.executable, __file__, "--one", f"{m:g}", "--set", *args.set], check=True)


if __name__ == "__main__":
    main()
