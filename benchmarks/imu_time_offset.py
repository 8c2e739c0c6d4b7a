"""The camera-IMU time offset of raw-IMU drives by maximum likelihood around the raw-IMU
smoother (issue 39 item 1; graph.inertial_time_offset; docs/findings.md, "The camera-IMU time
offset of raw-IMU drives").

    .venv/bin/python benchmarks/imu_time_offset.py [--frames N] [--seeds LIST] [--offsets MS]
        [--euroc] [--inflation LIST]

Simulated flights (room) and car drives (road), each camera, each seed and each offset made by
the simulator (``ImuSimConfig.imu_time_offset``): the estimate, its sigma, the error in sigmas,
the likelihood ratio against zero, the decision and the seconds it took. ``--euroc``: EuRoC
V1_01's first 30 s (../shared/data/euroc-v1_01 with gtsam's eqvio tracks) under the data
sheet's IMU noise times each ``--inflation`` factor, and at 100 Hz (every second IMU sample).
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "euroc-v1_01"


def simulated(frames: int, seeds: list[int], offsets: list[float]) -> None:
    from vislam.eval.imu_sim import simulate_imu
    from vislam.eval.imu_sim_config import ImuSimConfig
    from vislam.graph.inertial_time_offset import identify_imu_time_offset

    print("| drive | seed | true (ms) | estimate (ms) | sigma (ms) | error / sigma | LR | kept | s |")
    print("|---|---|---|---|---|---|---|---|---|")
    for scenario in ("room", "road"):
        for camera in ("mono", "stereo"):
            for seed in seeds:
                for off in offsets:
                    drive, _ = simulate_imu(ImuSimConfig(scenario=scenario, camera=camera, seed=seed,
                                                         n_frames=frames, imu_time_offset=off))
                    f = identify_imu_time_offset(drive)
                    print(f"| {scenario} {camera} | {seed} | {1e3 * off:+.0f} | {1e3 * f.estimate:+.2f} | "
                          f"{1e3 * f.sigma:.2f} | {(f.estimate - off) / f.sigma:+.1f} | "
                          f"{f.statistic:.3g} | {'yes' if f.kept else 'no'} | {f.seconds:.1f} |",
                          flush=True)


def euroc(inflations: list[float]) -> None:
    from vislam.ekf.filter import ImuSamples
    from vislam.eval.asl import read_asl_folder
    from vislam.graph.inertial_smoother import InertialSmootherSettings
    from vislam.graph.inertial_time_offset import identify_imu_time_offset

    drive = read_asl_folder(DATA, "eqvio")
    for k in inflations:
        f = identify_imu_time_offset(drive, InertialSmootherSettings(imu_noise_inflation=k))
        print(f"EuRoC V1_01, 200 Hz, the sheet's IMU noise x{k:g}: {f.words()} ({f.seconds:.1f} s)",
              flush=True)
    half = dataclasses.replace(drive, imu=ImuSamples(drive.imu.time[::2], drive.imu.accel[::2],
                                                     drive.imu.gyro[::2]))
    f = identify_imu_time_offset(half)
    print(f"EuRoC V1_01, 100 Hz (every second sample), the sheet's IMU noise: {f.words()} "
          f"({f.seconds:.1f} s)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=201, help="camera frames a simulated drive (20 Hz)")
    parser.add_argument("--seeds", default="1,2", help="simulation seeds, comma-separated")
    parser.add_argument("--offsets", default="0,30,100,-30",
                        help="offsets to simulate (ms, the IMU's stamps late), comma-separated")
    parser.add_argument("--euroc", action="store_true", help="EuRoC V1_01 instead of the simulation")
    parser.add_argument("--inflation", default="1,3,8",
                        help="with --euroc: factors on the sheet's IMU noise, comma-separated")
    args = parser.parse_args()
    if args.euroc:
        euroc([float(x) for x in args.inflation.split(",")])
    else:
        simulated(args.frames, [int(x) for x in args.seeds.split(",")],
                  [float(x) * 1e-3 for x in args.offsets.split(",")])


if __name__ == "__main__":
    main()
