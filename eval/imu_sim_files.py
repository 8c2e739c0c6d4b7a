"""A simulated raw-IMU drive written as every command reads it: ``DIR/NAME.npz`` (the raw-IMU
file form, :mod:`eval.inertial_files`), ``DIR/groundtruth/NAME.csv`` (the true IMU poses,
velocities and biases at the camera frames, ASL/OpenVINS csv, the simulator's world) and
``DIR/NAME_landmarks.npz`` (each track's true landmark, in the estimates' world: what
``vislam bench`` scores the maps with; a drive made with a fault also holds its true value,
``imu_time_offset`` () s and ``imu_noise_scale`` (), each only when not the default)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from vislam.ekf.inertial import InertialDrive
from vislam.eval.export import save_npz_reproducible
from vislam.eval.imu_sim import ImuTruth
from vislam.eval.inertial_files import save_inertial_drive
from vislam.eval.inertial_truth import inertial_truth_path, world_from_file
from vislam.eval.trajectory_files import TimedTrajectory, write_trajectory


def truth_trajectory(drive: InertialDrive, truth: ImuTruth) -> TimedTrajectory:
    """The truth at the camera frames as a time-stamped trajectory (absolute times, s)."""
    state = np.concatenate([truth.frame_velocity, truth.frame_gyro_bias, truth.frame_accel_bias], axis=1)
    return TimedTrajectory(drive.time_origin_ns * 1e-9 + drive.timestamps, truth.frame_poses,
                           "simulation", "asl", state)


def write_imu_simulation(folder: str | Path, drive: InertialDrive, truth: ImuTruth) -> Path:
    """Write ``drive`` and its truth into ``folder`` (module docstring); returns the drive's path."""
    folder = Path(folder)
    path = folder / f"{drive.name}.npz"
    save_inertial_drive(path, drive)
    write_trajectory(inertial_truth_path(path), truth_trajectory(drive, truth))
    W = world_from_file(truth.frame_poses[0])
    landmarks = truth.landmarks @ W[:3, :3].T + W[:3, 3]
    faults = {key: np.array(float(value)) for key, value, default in
              (("imu_time_offset", truth.imu_time_offset, 0.0),
               ("imu_noise_scale", truth.imu_noise_scale, 1.0)) if value != default}
    save_npz_reproducible(folder / f"{drive.name}_landmarks.npz",
                          {"landmarks": landmarks, **faults})
    return path
