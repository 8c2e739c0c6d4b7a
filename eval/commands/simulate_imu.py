"""`vislam simulate --imu`: a simulated raw-IMU drive (accelerometer and gyro at 200 Hz, camera
tracks at 20 Hz) with its ground truth, in the file form every command reads
(:mod:`eval.imu_sim`, :mod:`eval.imu_sim_files`)."""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

from vislam.ekf.errors import InputError
from vislam.eval.imu_sim_config import ImuSimConfig
from vislam.eval.imu_trajectories import SCENARIOS

#: The velocity-drive flags that mean nothing to a raw-IMU simulation (refused with --imu).
VELOCITY_ONLY = ("velocity_sigma", "gyro_sigma", "gyro_bias", "landmark_density", "repeat_event_rate",
                 "velocity_pairing", "file_extrinsic_fault", "file_extrinsic_offset", "radial_k1",
                 "pixel_correlation", "velocity_correlation", "velocity_time_offset",
                 "gyro_time_offset")


def imu_config(args: argparse.Namespace, parser_defaults: dict) -> tuple[ImuSimConfig, str]:
    """The raw-IMU simulation the flags ask for and the file name stem; InputError naming a
    flag that does not apply."""
    for dest in VELOCITY_ONLY:
        if getattr(args, dest, None) != parser_defaults.get(dest):
            raise InputError(f"--{dest.replace('_', '-')}: a setting of velocity drives; "
                             "--imu simulates a raw IMU (its noise: EuRoC's data sheet, "
                             "--imu-noise-scale)")
    if args.scenario not in SCENARIOS:
        raise InputError(f"--scenario {args.scenario}: --imu simulates {', '.join(SCENARIOS)}")
    camera = args.camera or "mono"
    d = ImuSimConfig()
    frames = d.n_frames if args.frames == parser_defaults.get("frames") else args.frames
    name = args.name if args.name is not None else f"imu-{args.scenario}-{camera}-seed{args.seed}"
    config = dataclasses.replace(d, seed=args.seed, scenario=args.scenario, camera=camera,
                                 n_frames=frames, pixel_sigma=args.pixel_sigma,
                                 noise_free=args.noise_free)
    faults = {key: getattr(args, key) for key in ("imu_time_offset", "imu_noise_scale")
              if getattr(args, key, None) is not None}
    if faults:  # checked where they are made: InputError naming the setting
        config = dataclasses.replace(config, **faults)
    return config, name


def outputs(name: str) -> tuple[str, ...]:
    return (f"{name}.npz", f"groundtruth/{name}.csv", f"{name}_landmarks.npz")


def run_imu(args: argparse.Namespace, parser_defaults: dict, check_name) -> int:
    """``vislam simulate --imu``; ``parser_defaults`` every flag's default, ``check_name`` the
    command's check of ``--name``."""
    from vislam.eval.imu_sim import simulate_imu
    from vislam.eval.imu_sim_files import write_imu_simulation
    from vislam.eval.output_dir import OutputDir

    config, name = imu_config(args, parser_defaults)
    check_name(name)
    with OutputDir(args.out, force=args.force, expected=outputs(name)) as tmp:
        start = time.perf_counter()
        drive, truth = simulate_imu(config)
        drive = dataclasses.replace(drive, name=name)
        sim_s = time.perf_counter() - start
        write_imu_simulation(tmp, drive, truth)
    duration = float(drive.imu.time[-1] - drive.imu.time[0])
    print(f"simulated {drive.name}: raw IMU, {drive.imu.time.size} samples at {drive.imu_rate:.0f} Hz "
          f"({duration:.1f} s, at rest for the first {truth.motion_start_s:.1f} s), "
          f"{drive.n_frames} frames, {drive.n_tracks} {config.camera} tracks, {len(drive.obs)} "
          f"observations, in {sim_s:.2f} s")
    if truth.imu_time_offset or truth.imu_noise_scale != 1.0:
        print(f"faults made: IMU stamps late by {truth.imu_time_offset:g} s, IMU noise "
              f"{truth.imu_noise_scale:g} times the declared densities")
    for rel in outputs(name):
        print(f"wrote {Path(args.out) / rel}")
    return 0
