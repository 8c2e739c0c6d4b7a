"""Raw-IMU noise identified by EM around the raw-IMU smoother (issue 39 item 2): identified vs
true vs sheet on simulated drives, and the smoother's ATE and pose NEES under the sheet's and
the identified figures, on simulation and on EuRoC V1_01's first 30 s.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/imu_noise_identification.py
        [--runs 5] [--frames 101] [--scale 3] [--pixel-sigma 0.1] [--iterations 12]
        [--euroc] [--data ../shared/data/euroc-v1_01] [--no-sim]

Simulation (:mod:`eval.imu_sim`, monocular room flight, seeds 0..runs-1): the IMU's true noise is
``--scale`` times the sheet the drive declares (``imu_noise_scale``). Per run: the four figures
identified over the sheet's, then the pose NEES (6 dof, against the truth in the estimate's
frame-0 gauge) and ATE of the smoother under the sheet and under the identified figures; ANEES
over the runs with its 95 % bounds. EuRoC (``--euroc``): the ASL IMU with gtsam's eqvio tracks,
the same solves and the usable figures' (the sheet's for what was withheld), ATE 4-dof aligned and pose NEES against the ground truth in the estimate's
gauge (as benchmarks/inertial_smoother.py).
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from vislam.eval.consistency import chi2_bounds  # noqa: E402
from vislam.eval.metrics import ate_rmse, nees, pose_errors  # noqa: E402
from vislam.graph.inertial_identification import (COLD_START_NEES, FIGURES,  # noqa: E402
                                                  identify_imu_noise, with_noise)
from vislam.graph.inertial_init import in_estimate_gauge  # noqa: E402
from vislam.graph.inertial_smoother import smooth  # noqa: E402


def scores(result, truth: np.ndarray) -> tuple[float, float]:
    """(mean pose NEES over frames 1.., 4-dof aligned ATE) of a smoother result."""
    est = result.estimate
    gauged = in_estimate_gauge(truth, est.poses)
    n = nees(pose_errors(est.poses, gauged), est.pose_cov)[1:]
    return float(np.nanmean(n)), ate_rmse(est.poses, truth, "yaw")


def simulated(args) -> None:
    from vislam.eval.imu_sim import simulate_imu
    from vislam.eval.imu_sim_config import ImuSimConfig

    print(f"simulated room flights, {args.frames} frames, pixel sigma {args.pixel_sigma} px, true IMU "
          f"noise {args.scale:g}x the sheet")
    print("seed | identified / sheet: " + " ".join(FIGURES) + " | undetermined | pixel | steps | "
          "NEES sheet / identified | ATE (mm) sheet / identified")
    rows = []
    for seed in range(args.runs):
        drive, truth = simulate_imu(ImuSimConfig(seed=seed, n_frames=args.frames, rest_s=1.0,
                                                 pixel_sigma=args.pixel_sigma,
                                                 imu_noise_scale=args.scale))
        fit = identify_imu_noise(drive, max_iterations=args.iterations)
        sheet = scores(smooth(drive), truth.frame_poses)
        ident = scores(smooth(with_noise(drive, fit.noise)), truth.frame_poses)
        rows.append((fit.ratio, sheet, ident))
        print(f"{seed:4d} | {' '.join(f'{r:.3f}' for r in fit.ratio)} | {','.join(fit.undetermined) or '-'} | "
              f"withheld {','.join(fit.withheld) or '-'} cold {fit.cold_start_nees:.2g} | "
              f"{fit.pixel_sigma:.3f} | {fit.iterations}{'' if fit.converged else '*'} | "
              f"{sheet[0]:.2f} / {ident[0]:.2f} | {sheet[1] * 1e3:.2f} / {ident[1] * 1e3:.2f}")
    ratios = np.array([r[0] for r in rows])
    lo, hi = chi2_bounds(len(rows), 6)
    a_sheet = float(np.mean([r[1][0] for r in rows]))
    a_ident = float(np.mean([r[2][0] for r in rows]))
    print(f"median identified / sheet: {' '.join(f'{x:.3f}' for x in np.median(ratios, axis=0))} "
          f"(truth {args.scale:g})")
    print(f"ANEES over {len(rows)} runs (95 % bounds [{lo:.2f}, {hi:.2f}]): sheet {a_sheet:.2f}, "
          f"identified {a_ident:.2f}  (* = EM not converged)")


def euroc(args) -> None:
    from vislam.eval.asl import read_asl_folder
    from vislam.eval.trajectory_files import read_trajectory
    from vislam.graph.inertial_init import to_gravity_world

    drive = read_asl_folder(args.data, "eqvio")
    gt = read_trajectory(f"{args.data}/groundtruth/V1_01_easy.csv")
    t = drive.timestamps + drive.time_origin_ns * 1e-9
    i = np.clip(np.searchsorted(gt.times, t - 1e-3), 0, gt.times.size - 1)
    if np.any(np.abs(gt.times[i] - t) > 1e-3):
        raise SystemExit("no ground truth within 1 ms of every camera frame")
    truth = to_gravity_world(gt.poses[i])
    fit = identify_imu_noise(drive, max_iterations=args.iterations)
    print(f"EuRoC V1_01 30 s: EM {fit.iterations} steps ({'converged' if fit.converged else 'NOT converged'}), "
          f"{fit.seconds:.0f} s; undetermined: {', '.join(fit.undetermined) or 'none'}; still moving: "
          f"{', '.join(fit.unconverged) or 'none'}; withheld: {', '.join(fit.withheld) or 'none'}; "
          f"cold-start check {fit.cold_start_nees:.3g} (allowed {COLD_START_NEES:g}); "
          f"{'trusted' if fit.trusted else 'NOT trusted'}")
    print("  posterior share: " + " ".join(f"{m:.3f}" for m in fit.missing_share))
    for name, sheet, value, sd, ratio in fit.rows():
        print(f"  {name:<20} sheet {sheet:.4g}  identified {value:.4g}  sigma {sd:.2g}  ratio {ratio:.3f}")
    print("  usable / sheet: " + " ".join(f"{r:.3f}" for r in fit.usable.as_array() / fit.sheet.as_array()))
    n, ate = scores(fit.result, truth)
    print(f"  smoother under the identified figures from EM's last solution: ATE 4-dof {ate:.4f} m, "
          f"pose NEES mean {n:.1f}")
    for what, d in (("sheet", drive), ("identified", with_noise(drive, fit.noise)),
                    ("usable", with_noise(drive, fit.usable))):
        n, ate = scores(smooth(d), truth)
        print(f"  smoother under the {what} figures: ATE 4-dof {ate:.4f} m, pose NEES mean {n:.1f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--frames", type=int, default=101)
    parser.add_argument("--scale", type=float, default=3.0, help="true IMU noise over the sheet's")
    parser.add_argument("--pixel-sigma", type=float, default=0.1)
    parser.add_argument("--iterations", type=int, default=12, help="EM steps at most")
    parser.add_argument("--euroc", action="store_true", help="also EuRoC V1_01's first 30 s")
    parser.add_argument("--no-sim", action="store_true", help="skip the simulated drives")
    parser.add_argument("--data", default="../shared/data/euroc-v1_01")
    args = parser.parse_args()
    if not args.no_sim:
        simulated(args)
    if args.euroc:
        euroc(args)


if __name__ == "__main__":
    main()
