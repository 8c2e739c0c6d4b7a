"""Writing a simulated drive as the shared data lays it out (the data file, the ground truth,
the true landmarks and the true model), byte for byte the same for the same drive."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from vislam.eval.export import FLOAT_FORMAT, atomic_write, save_npz_reproducible
from vislam.eval.loader import sparse_arrays


def camera_groundtruth(poses: np.ndarray, cam_T_imu: np.ndarray) -> np.ndarray:
    """KITTI ground truth: left-camera poses in the left-camera frame of frame 0,
    ``P(k) = cam_T_imu @ T_imu(k) @ inv(cam_T_imu)`` (the shared data's README).

    The general matrix inverse is deliberate: the shared ``cam_T_imu`` is orthonormal only to
    about 1e-7, and only the exact inverse makes ``P(0)`` the identity and lets a reader recover
    ``T_imu(k) = inv(cam_T_imu) @ P(k) @ cam_T_imu`` to rounding."""
    return cam_T_imu @ poses @ np.linalg.inv(cam_T_imu)


def write_simulation(
    result, out_dir: str | os.PathLike, name: str | None = None
) -> dict[str, Path]:
    """Write a drive (an :class:`eval.simulate.SimResult`) as the shared data lays it out;
    returns the paths by role.

    * ``data``: ``out_dir/NAME.npz``, the real data's keys and shapes (time_stamps (1, T),
      linear/rotational_velocity (3, T), K, b, cam_T_imu) with the observations in the sparse
      layout (obs_frame (N,), obs_track (N,), obs_pixels (N, 4), n_tracks: one row per
      observation, in frame then track order; :mod:`eval.loader`): nothing of size tracks x
      frames is built, so the file and its writing grow with the observations;
    * ``groundtruth``: ``out_dir/groundtruth/NAME.txt``, KITTI poses of the left camera with the
      time since frame 0 prepended (13 columns);
    * ``landmarks``: ``out_dir/NAME_landmarks.npz`` with ``landmarks`` (n_tracks, 3) the true
      world position per track index (world = IMU at frame 0), ``track_landmark``
      (n_tracks,), ``landmark_points`` (n_landmarks, 3), ``poses`` (T, 4, 4) true world_T_imu
      and ``true_velocities`` (T, 6); a drive with a stream's time offset also holds it, as
      ``velocity_time_offset`` / ``gyro_time_offset`` () in seconds (absent when zero, so the
      file of a drive without one is unchanged);
    * ``model``: ``out_dir/NAME_model.toml``, the true model of the drive (ekf.model, a
      ``[model]`` table and the file's extrinsic under ``[file]``).

    The ground truth is made with the true extrinsic: a user converting it with a faulty file
    extrinsic gets wrong IMU poses, exactly as with the shared data.

    Files carry no write time: the same result always gives the same bytes.
    """
    seq = result.sequence
    name = name or seq.name
    out_dir = Path(out_dir)
    calib = seq.calibration
    data = {
        "time_stamps": seq.timestamps[None, :],
        **sparse_arrays(seq.obs, seq.n_tracks),
        "linear_velocity": seq.linear_velocity.T,
        "rotational_velocity": seq.angular_velocity.T,
        "K": calib.K,
        "b": np.array(calib.baseline),
        "cam_T_imu": calib.cam_T_imu,
    }
    paths = {
        "data": save_npz_reproducible(out_dir / f"{name}.npz", data),
    }
    gt = camera_groundtruth(result.poses, result.cam_T_imu)
    rows = np.concatenate(
        [(seq.timestamps - seq.timestamps[0])[:, None], gt[:, :3, :4].reshape(-1, 12)], axis=1
    )
    paths["groundtruth"] = atomic_write(
        out_dir / "groundtruth" / f"{name}.txt",
        lambda fh: np.savetxt(fh, rows, fmt=FLOAT_FORMAT, delimiter=" "),
    )
    paths["landmarks"] = save_npz_reproducible(
        out_dir / f"{name}_landmarks.npz",
        {
            "landmarks": result.landmarks,
            "track_landmark": result.track_landmark,
            "landmark_points": result.landmark_points,
            "poses": result.poses,
            "true_velocities": result.true_velocities,
            **{key: np.array(float(getattr(result.config, key)))
               for key in ("velocity_time_offset", "gyro_time_offset")
               if getattr(result.config, key, 0.0)},
        },
    )
    model_text = result.model.to_toml().encode("utf-8")
    paths["model"] = atomic_write(out_dir / f"{name}_model.toml", lambda fh: fh.write(model_text))
    return paths
