"""Time-stamped ground truth of raw-IMU drives, in the formats VIO users have.

- **ASL / OpenVINS csv** (EuRoC's ``state_groundtruth_estimate0/data.csv``, OpenVINS's
  ``groundtruth/*.csv``): ``time [ns], px, py, pz, qw, qx, qy, qz`` and, in 17 columns, the
  velocity (world frame), gyro bias and accelerometer bias;
- **TUM text** (``t [s] tx ty tz qx qy qz qw``, whitespace-separated; EuRoC's 200 Hz original
  and the output of most VIO systems): poses only. TUM puts the quaternion's ``w`` last, ASL
  first.

Both are read by the checked readers of :mod:`eval.export` (every fault one line naming the
file and line); this module tells them apart (commas or whitespace) and keeps the state
columns. vislam writes ground truth beside a converted drive in the ASL form.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from vislam.ekf.errors import InputError
from vislam.eval.export import (
    read_euroc_state,
    read_tum_checked,
    text_lines,
    write_euroc,
)


@dataclass(frozen=True)
class TimedTrajectory:
    """``times`` (n,) s (the file's clock); ``poses`` (n, 4, 4) world_T_body; ``state`` (n, 9)
    velocity (world frame), gyro bias, accelerometer bias, or None where the file has none;
    ``source`` the file and ``form`` "asl" or "tum"."""

    times: np.ndarray
    poses: np.ndarray
    source: str
    form: str
    state: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.times.size)

    @property
    def velocity(self) -> np.ndarray | None:
        return None if self.state is None else self.state[:, 0:3]

    @property
    def gyro_bias(self) -> np.ndarray | None:
        return None if self.state is None else self.state[:, 3:6]

    @property
    def accel_bias(self) -> np.ndarray | None:
        return None if self.state is None else self.state[:, 6:9]

    def between(self, start: float, end: float) -> TimedTrajectory:
        """The rows with ``start <= time <= end`` (seconds)."""
        keep = (self.times >= start) & (self.times <= end)
        return TimedTrajectory(self.times[keep], self.poses[keep], self.source, self.form,
                               None if self.state is None else self.state[keep])


def read_trajectory(path: str | os.PathLike) -> TimedTrajectory:
    """The trajectory in ``path``: ASL/OpenVINS csv when its first data line has commas, else
    TUM text."""
    path = Path(path)
    first = next(iter(text_lines(path, "trajectory file")), None)
    if first is None:
        raise InputError(f"{path}: trajectory file has no pose lines")
    if "," in " ".join(first[1]):
        times, poses, _, state = read_euroc_state(path)
        return TimedTrajectory(times, poses, str(path), "asl", state)
    times, poses, _ = read_tum_checked(path)
    return TimedTrajectory(times, poses, str(path), "tum")


def write_trajectory(path: str | os.PathLike, traj: TimedTrajectory) -> Path:
    """``traj`` as an ASL/OpenVINS csv (17 columns where it has the state), atomically."""
    return write_euroc(path, traj.times, traj.poses, traj.state)
